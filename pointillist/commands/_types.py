"""argparse ``type=`` converters and option groups shared by the sub-commands (a bad value: exit 2,
one line)."""

from __future__ import annotations

import argparse
import math

from pointillist.core.checks import UINT32_MAX

__all__ = ["positive_int", "non_negative_int", "positive_float", "finite_float", "add_cluster_options"]


def _parse(text: str, kind: type, expected: str):
    try:
        return kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None


def positive_int(text: str) -> int:
    """An int in 1..2^32-1."""
    value = _parse(text, int, "a positive integer")
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    if value > UINT32_MAX:
        raise argparse.ArgumentTypeError(f"expected an integer in 1..2^32-1, got {value}")
    return value


def non_negative_int(text: str) -> int:
    """An int in 0..2^32-1."""
    value = _parse(text, int, "a non-negative integer")
    if value < 0 or value > UINT32_MAX:
        raise argparse.ArgumentTypeError(f"expected an integer in 0..2^32-1, got {value}")
    return value


def positive_float(text: str) -> float:
    """A finite float > 0."""
    value = _parse(text, float, "a positive number")
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


def finite_float(text: str) -> float:
    """A finite float."""
    value = _parse(text, float, "a number")
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def add_cluster_options(container, *, work: str, shared: str) -> None:
    """The Dask options every distributed command has, declared once: ``--workers N`` (a local
    cluster of N worker processes) or ``--scheduler ADDRESS`` (an existing cluster), not both.

    ``container``: the parser or argument group they join; ``work``: what the cluster does
    ("render the tiles"); ``shared``: what the workers of an existing cluster must share.
    """
    cluster = container.add_mutually_exclusive_group()
    cluster.add_argument("--workers", type=positive_int, metavar="N",
                         help=f"{work} on a local Dask cluster of N worker processes")
    cluster.add_argument("--scheduler", metavar="ADDRESS",
                         help=f"{work} on an existing Dask cluster (e.g. tcp://host:8786); {shared}")
