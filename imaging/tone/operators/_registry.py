"""The table of tone-mapping operators: each operator's module registers itself here."""

from __future__ import annotations

from typing import Callable, NamedTuple

from drjit.llvm.ad import Float

__all__ = ["TonemapOperator", "TONEMAP_TABLE", "register"]


class TonemapOperator(NamedTuple):
    """A tone-mapping operator: its name, the keyword parameters it takes, its curve
    (``curve(channels, white) -> channels``, linear to 0..1 before clipping and the sRGB encoding),
    one line saying what it computes, and its place in listings (``order``, ascending)."""

    name: str
    parameters: tuple[str, ...]
    curve: Callable[[list[Float], float | None], list[Float]]
    summary: str
    order: int = 100


#: The tone-mapping operators of :func:`~pointillist.imaging.tone.tonemap` by name, in ``order``.
TONEMAP_TABLE: dict[str, TonemapOperator] = {}


def register(operator: TonemapOperator) -> TonemapOperator:
    """Add ``operator`` to :data:`TONEMAP_TABLE` (kept sorted by ``order``); ValueError for a name
    that is taken."""
    if operator.name in TONEMAP_TABLE:
        raise ValueError(f"operator: {operator.name!r} is already registered")
    entries = sorted([*TONEMAP_TABLE.values(), operator], key=lambda op: (op.order, op.name))
    TONEMAP_TABLE.clear()
    TONEMAP_TABLE.update((op.name, op) for op in entries)
    return operator
