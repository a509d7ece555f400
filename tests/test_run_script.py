"""The README's entry point ``./run`` (bootstraps make/python3, then calls make)."""

from __future__ import annotations

import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_run_rejects_an_unknown_target_with_status_2_and_usage():
    done = subprocess.run([str(ROOT / "run"), "deploy"], capture_output=True, text=True)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == ["usage: ./run demo|test|docs|setup|clean [MAKE_VARIABLE=value ...]"]
    assert done.stdout == ""


def test_run_without_a_target_prints_usage():
    done = subprocess.run([str(ROOT / "run")], capture_output=True, text=True)
    assert done.returncode == 2 and done.stderr.startswith("usage: ./run")


def test_run_passes_the_target_to_make(tmp_path):
    # make and python3 are present here, so nothing is installed; extra arguments go to
    # make, whose dry run prints the commands `make demo` would run.
    done = subprocess.run([str(ROOT / "run"), "demo", "--dry-run"], capture_output=True, text=True,
                          cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "pointillist render scenes/default.xml -o out/default.exr --png" in done.stdout


def test_run_docs_builds_the_site_strictly_and_says_where_it_is(tmp_path):
    done = subprocess.run([str(ROOT / "run"), "docs", "--dry-run"], capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert ".venv/bin/sphinx-build -W --keep-going -q -b html docs docs/_build/html" in done.stdout
    assert "docs/_build/html/index.html" in done.stdout
