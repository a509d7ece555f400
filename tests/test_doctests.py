"""Every docstring example of a package runs and gives what it shows.

One test per module of each package in ``PACKAGES`` (found by walking the package, so a new module
is covered without an edit here). A module without examples passes; a package whose modules hold
no example at all fails (a walk that finds nothing is a broken walk). Add a package by adding its
name to ``PACKAGES``.
"""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest

#: The packages whose docstring examples run in the suite.
PACKAGES = ("pointillist.imaging",)

_FLAGS = doctest.NORMALIZE_WHITESPACE | doctest.ELLIPSIS


def modules_of(package: str) -> list[str]:
    """``package`` and every module below it, sorted."""
    root = importlib.import_module(package)
    names = [package]
    if hasattr(root, "__path__"):
        names += [info.name for info in pkgutil.walk_packages(root.__path__, prefix=f"{package}.")]
    return sorted(names)


def _examples(module_name: str) -> list[doctest.DocTest]:
    module = importlib.import_module(module_name)
    finder = doctest.DocTestFinder(exclude_empty=True)
    return [test for test in finder.find(module, module_name) if test.examples]


@pytest.mark.parametrize("module_name", [name for package in PACKAGES for name in modules_of(package)])
def test_docstring_examples_run(module_name):
    runner = doctest.DocTestRunner(optionflags=_FLAGS)
    for test in _examples(module_name):
        runner.run(test)
    result = runner.summarize(verbose=False)
    assert result.failed == 0, f"{module_name}: {result.failed} of {result.attempted} examples failed"


@pytest.mark.parametrize("package", PACKAGES)
def test_packages_hold_examples(package):
    """The walk finds the modules and their examples (>= one example in each of several modules)."""
    counts = {name: sum(len(test.examples) for test in _examples(name)) for name in modules_of(package)}
    assert sum(1 for count in counts.values() if count) >= 5, counts
