"""Shared fixtures: the Mitsuba variant with pointillist's plugins, a CLI runner, a per-test RNG."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
SCENES = ROOT / "scenes"

# The suite's processes start with SIGINT and SIGTERM deliverable whoever started pytest: a CI
# runner may start it with the two blocked or ignored, and children inherit both. (The commands
# themselves unblock the two; tests/test_trust.py checks that on purpose, with a blocked child.)
if hasattr(signal, "pthread_sigmask"):
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)
if signal.getsignal(signal.SIGTERM) == signal.SIG_IGN:
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


@pytest.fixture(autouse=True)
def _signals_deliverable():
    """Before every test, SIGINT and SIGTERM unblocked in the suite's process: importing
    ``pointillist.console`` (as the docs' consistency check does with every module) blocks them,
    and every child started afterwards would inherit that mask."""
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
    yield


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
                          env=environment, capture_output=True, text=True, errors="surrogateescape",
                          timeout=timeout)


@pytest.fixture
def cli():
    """The :func:`run_cli` function (subprocess CLI runner)."""
    return run_cli


@pytest.fixture
def rng(request) -> np.random.Generator:
    """A generator seeded from the test's node id: the same numbers whether the test runs alone,
    in a file or in the whole suite, and in any order (never a module-level generator)."""
    return np.random.default_rng(zlib.crc32(request.node.nodeid.encode()))


def _aligned_copy(array, alignment: int = 64) -> np.ndarray:
    """A C-contiguous copy of ``array`` whose data starts at a multiple of ``alignment`` bytes."""
    array = np.asarray(array)
    buffer = np.empty(array.nbytes + alignment, np.uint8)
    start = (-buffer.ctypes.data) % alignment
    copy = buffer[start:start + array.nbytes].view(array.dtype).reshape(array.shape)
    copy[...] = array
    return copy


@pytest.fixture
def aligned():
    """Copy an array to 64-byte aligned memory. Dr.Jit compiles another variant of a kernel that
    reads a caller's numpy buffer in place when the buffer is 64-byte aligned (measured: the hash
    follows the alignment, not the size), so kernel-hash "no recompilation" checks use aligned inputs."""
    return _aligned_copy


def pytest_addoption(parser):
    """``--scenes PATH`` (repeatable): also check these scene files, or every scene under these
    folders, against Mitsuba (tests/test_corpus.py::test_your_scenes_render_as_in_mitsuba)."""
    parser.addoption("--scenes", action="append", default=[], metavar="PATH",
                     help="scene XML files or folders to check against Mitsuba, as `pointillist verify` does")
