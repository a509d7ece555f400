"""Shared fixtures: the Mitsuba variant with pointillist's plugins, a CLI runner, a per-test RNG."""

from __future__ import annotations

import os
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
SCENES = ROOT / "scenes"


@pytest.fixture(scope="session")
def mi():
    """``mitsuba`` with the ``llvm_ad_rgb`` variant set and pointillist's plugins registered."""
    import pointillist

    return pointillist.setup("llvm_ad_rgb")


@pytest.fixture(scope="session")
def dr(mi):
    import drjit

    return drjit


def run_cli(*args: str, cwd: str | os.PathLike | None = None, env: dict | None = None,
            timeout: float = 300) -> subprocess.CompletedProcess:
    """Run ``python -m pointillist ARGS`` in a subprocess; returns the completed process."""
    environment = dict(os.environ, **(env or {}))
    return subprocess.run([sys.executable, "-m", "pointillist", *map(str, args)], cwd=cwd or ROOT,
                          env=environment, capture_output=True, text=True, timeout=timeout)


@pytest.fixture
def cli():
    """The :func:`run_cli` function (subprocess CLI runner)."""
    return run_cli


@pytest.fixture
def rng(request) -> np.random.Generator:
    """A generator seeded from the test's node id: the same numbers whether the test runs alone,
    in a file or in the whole suite, and in any order (never a module-level generator)."""
    return np.random.default_rng(zlib.crc32(request.node.nodeid.encode()))
