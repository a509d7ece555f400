"""The project's structure: layers (import-linter), style (ruff), one installed name.

``plugins/`` and ``imaging/`` install as ``pointillist.plugins`` and ``pointillist.imaging``
(pyproject's ``package-dir``). import-linter reads a package from its folder, so the layer
check runs on a copy of the tree laid out as it installs.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
BIN = Path(sys.executable).parent
#: Repository folder of each installed package root.
INSTALLED = {"pointillist": ROOT / "pointillist", "pointillist.plugins": ROOT / "plugins",
             "pointillist.imaging": ROOT / "imaging"}


def _installed_layout(target: Path) -> Path:
    """Copy the Python sources into ``target`` as they install (``target/pointillist/...``)."""
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    shutil.copytree(ROOT / "pointillist", target / "pointillist", ignore=ignore)
    shutil.copytree(ROOT / "plugins", target / "pointillist" / "plugins", ignore=ignore)
    shutil.copytree(ROOT / "imaging", target / "pointillist" / "imaging", ignore=ignore)
    shutil.copy(ROOT / "pyproject.toml", target / "pyproject.toml")
    return target


def _lint_imports(layout: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(layout))
    return subprocess.run([str(BIN / "lint-imports"), "--no-cache"], cwd=layout, env=env, capture_output=True,
                          text=True, timeout=300)


def test_import_layers_hold(tmp_path):
    proc = _lint_imports(_installed_layout(tmp_path))
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-2000:]
    assert "6 kept, 0 broken" in proc.stdout


def test_a_crossed_layer_is_caught(tmp_path):
    """The check can fail: imaging importing a workflow, or Mitsuba, breaks two contracts."""
    layout = _installed_layout(tmp_path)
    with open(layout / "pointillist" / "imaging" / "window.py", "a") as handle:
        handle.write("\nfrom pointillist.mip import view_axes  # noqa\nimport mitsuba  # noqa\n")
    proc = _lint_imports(layout)
    assert proc.returncode != 0
    assert "Layers: cli > commands > workflows > plugins > imaging > ground BROKEN" in proc.stdout
    assert "no Mitsuba, no Dask BROKEN" in proc.stdout


def _layer_modules() -> set[str]:
    contract = next(c for c in PYPROJECT["tool"]["importlinter"]["contracts"] if c["type"] == "layers")
    names = set()
    for layer in contract["layers"]:
        names.update(part.strip() for part in layer.replace("|", ":").split(":"))
    return names


def test_every_module_of_pointillist_is_in_a_layer():
    """A new workflow module must be placed in the layers (else import-linter ignores it)."""
    layered = _layer_modules()
    modules = {f"pointillist.{p.stem}" for p in (ROOT / "pointillist").glob("*.py")
               if p.stem not in ("__init__", "__main__")}
    modules |= {f"pointillist.{p.parent.name}" for p in (ROOT / "pointillist").glob("*/__init__.py")}
    assert modules - layered == set(), f"not in any layer of pyproject's import-linter contract: {modules - layered}"
    assert {"pointillist.plugins", "pointillist.imaging"} <= layered


def test_the_ground_package_loads_nothing_heavy():
    """pointillist.core is the ground: importing all of it loads no numpy, Dr.Jit, Mitsuba or Dask and
    no other part of pointillist (a command's -h and a plain render rely on it)."""
    import subprocess
    import sys

    names = sorted(p.stem for p in (ROOT / "pointillist" / "core").glob("*.py") if p.stem != "__init__")
    assert {"checks", "errors", "files", "signals", "terminal", "llvm", "digests"} <= set(names)
    code = ("import sys; " + "; ".join(f"import pointillist.core.{n}" for n in names) + "; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('numpy', 'drjit', 'mitsuba', 'dask', "
            "'distributed') or (m.startswith('pointillist') and not m.startswith('pointillist.core') "
            "and m != 'pointillist')))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_every_package_folder_is_listed_for_setuptools():
    """pyproject lists packages by hand (package-dir mapping): a new sub-package must be added."""
    listed = set(PYPROJECT["tool"]["setuptools"]["packages"])
    found = set()
    for name, folder in INSTALLED.items():
        for init in folder.rglob("__init__.py"):
            if "__pycache__" not in init.parts:
                relative = init.parent.relative_to(folder).parts
                found.add(".".join((name, *relative)))
    assert found - listed == set(), f"add to [tool.setuptools] packages: {sorted(found - listed)}"
    assert PYPROJECT["tool"]["setuptools"]["package-dir"] == {
        name: str(folder.relative_to(ROOT)) for name, folder in INSTALLED.items()}


def test_ruff_is_clean():
    proc = subprocess.run([str(BIN / "ruff"), "check", "--no-cache", "."], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-2000:]


def test_wheel_has_one_top_level_package(tmp_path):
    """``pip wheel .`` gives a wheel whose only top-level package is ``pointillist``, with the
    plugins, the imaging module and their data inside it."""
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
                           "-w", str(tmp_path), str(ROOT)], capture_output=True, text=True, timeout=300)
    if proc.returncode != 0 and "setuptools" in proc.stderr and "build_meta" not in proc.stderr:
        pytest.fail(f"pip wheel failed: {proc.stderr[-2000:]}")
    assert proc.returncode == 0, proc.stderr[-2000:]
    from pointillist.compare.html import PAGE_SCRIPTS

    wheel = next(tmp_path.glob("pointillist-*.whl"))
    names = zipfile.ZipFile(wheel).namelist()
    top = {n.split("/")[0] for n in names if not n.split("/")[0].endswith((".dist-info", ".data"))}
    assert top == {"pointillist"}, top
    for expected in ("pointillist/plugins/integrators/whitted.py", "pointillist/imaging/filters.py",
                     "pointillist/imaging/data/blue_noise_64.npy", "pointillist/plugins/samplers/poisson_sets.npz",
                     "pointillist/commands/render.py", "pointillist/compare/page/report.html.in",
                     *(f"pointillist/compare/page/{name}" for name in PAGE_SCRIPTS)):
        assert expected in names, expected


def test_no_file_cites_the_project_s_issue_numbers():
    """A reader of the repository cannot look up this project's issues: code, tests, docs and
    benchmarks name what they refer to (the round, the goal, the defect), never an issue number.
    Another project's issue stays citable with its name (``Dr.Jit issue 536``) or its address."""
    import re
    import subprocess

    listed = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True)
    if listed.returncode != 0:
        pytest.skip("not a git checkout")
    cited = re.compile(r"(?<![\w/#.-])[Ii]ssues? #?\d+")
    foreign = re.compile(r"(Dr\.?Jit|drjit|Mitsuba|mitsuba|OpenEXR|numpy|Dask|github\.com)\S*\s*$")
    found = []
    for name in listed.stdout.split():
        path = ROOT / name
        if path.suffix not in {".py", ".md", ".rst", ".toml", ".js", ".in", ".ipynb", ".txt", ".cfg", ".sh", ""} \
                or not path.is_file():
            continue
        try:
            text = path.read_text()
        except UnicodeDecodeError:
            continue
        for number, line in enumerate(text.splitlines(), 1):
            for match in cited.finditer(line):
                if not foreign.search(line[:match.start()]):
                    found.append(f"{name}:{number}: {line.strip()[:100]}")
    assert found == []
