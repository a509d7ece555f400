"""Every docstring example of a package runs and shows what it says (one test per module).

The packages are parametrised by name: ``pointillist`` (its own modules, the workflows, commands
and ground; not the two installed sub-packages below, which have their own entries) and
``pointillist.plugins``. Examples run from the repository root (they name ``scenes/...``), with
``...`` matching any text and whitespace compared loosely.
"""

from __future__ import annotations

import doctest
import importlib
import pkgutil
import signal
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

#: Sub-packages that are packages of their own here (a folder of the repository each).
SEPARATE = ("pointillist.plugins", "pointillist.imaging")

#: Package name -> the sub-packages it leaves to their own entry.
PACKAGES = {"pointillist": SEPARATE, "pointillist.plugins": (), "pointillist.imaging": ()}

#: Modules never imported here: importing the console script blocks SIGINT and SIGTERM in this
#: thread for good (its first line, until its ``main`` runs), which every later test's child
#: processes would inherit; ``__main__`` runs the command line.
NOT_IMPORTED = ("pointillist.console", "pointillist.__main__")


def _modules(package: str) -> list[str]:
    """``package`` and every module below it, but those of the sub-packages it leaves out."""
    skip = PACKAGES[package]
    root = importlib.import_module(package)
    names = [package] + [info.name for info in pkgutil.walk_packages(root.__path__, package + ".")]
    return [name for name in names if not any(name == s or name.startswith(s + ".") for s in skip)
            and name not in NOT_IMPORTED]


CASES = [(package, module) for package in PACKAGES for module in _modules(package)]


@pytest.mark.parametrize("package, module", CASES, ids=[module for _, module in CASES])
def test_docstring_examples_run(package, module, monkeypatch, mi):
    monkeypatch.chdir(ROOT)
    imported = importlib.import_module(module)
    finder = doctest.DocTestFinder(exclude_empty=True)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    tests = [t for t in finder.find(imported, module) if t.examples
             and (t.filename is None or Path(t.filename).resolve() == Path(imported.__file__).resolve())]
    failures = []
    for test in tests:
        result = runner.run(test, out=failures.append)
        assert result.attempted == len(test.examples)
    assert not failures, "".join(failures)


def test_every_package_has_examples():
    """The parametrisation finds the modules, and they hold examples (a finder that found none would
    pass every test above)."""
    finder = doctest.DocTestFinder(exclude_empty=True)
    for package in PACKAGES:
        modules = _modules(package)
        assert len(modules) > 5, package
        counted = sum(len(t.examples) for m in modules for t in finder.find(importlib.import_module(m), m))
        assert counted > 20, (package, counted)


@pytest.mark.skipif(not hasattr(signal, "pthread_sigmask"), reason="POSIX signal masks")
def test_importing_every_module_leaves_the_signals_deliverable():
    """Importing the modules of the examples may not block SIGINT/SIGTERM (the console script's
    import does): the later tests' child processes would inherit the mask and ignore signals."""
    for _, module in CASES:
        importlib.import_module(module)
    assert not {signal.SIGINT, signal.SIGTERM} & signal.pthread_sigmask(signal.SIG_BLOCK, [])
