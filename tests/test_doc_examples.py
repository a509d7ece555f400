"""Every shell and Python example of the README and the documentation pages runs as written.

Each page's ``sh`` blocks run line by line, in order, in a folder made like a reader's: the sample
inputs of ``pointillist data`` (``scene.xml``, ``photo.png``, ``head.nii.gz``, ...), the repository's
``scenes/``, ``my.xml`` (a copy of the sample scene) and ``out/default.exr`` (what ``./run demo``
renders first). The pages share the folder, as one reader following them would (a sweep a second
page repeats reuses the first's renders, as the compare guide says). Every command must exit 0, write
the files its ``-o`` names (the PNG of ``--png`` too) and those its comment names under ``out/``, and
a render must print the line the pages describe (the timing line, or the end line of its passes);
the ``python`` blocks run as files there and must exit 0. A line that cannot run here matches one of
:data:`NOT_RUN`, which says why. The mip and the differentiable guides' blocks run with their outputs
checked in tests/test_data.py.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import ROOT, run_cli

#: Lines not run, by pattern, and why.
NOT_RUN = {
    r"^\./run ": "the set-up itself: .ci/run runs `./run test`, tests/test_run_script.py the script",
    r"pip install|-m venv|^venv/bin/": "installing: .ci/run installs the same way",
    r"~/mitsuba-tutorials": "a checkout of Mitsuba's tutorials (tests/test_corpus.py verifies scenes written alike)",
    r"tcp://host": "a Dask scheduler already running (tests/test_distributed.py starts one)",
    r"\bbig\.xml\b": "an hour-long budget; the same options with `--time 4` run on the line above",
    r"benchmarks/": "a benchmark: minutes, run by hand (benchmarks/RESULTS.md)",
    r"verify scenes/corpus": "two minutes of renders; tests/test_corpus.py checks each corpus scene against "
                             "Mitsuba, and `verify` on a folder",
}

#: Lines run from the repository (the page says: in the clone), not from the reader's folder.
FROM_THE_CLONE = r"^python3 pointillist/"

#: Pages whose blocks run elsewhere (tests/test_data.py) or are not examples.
ELSEWHERE = {"mip.md", "differentiable.md", "architecture.md", "command_line.md"}


def _pages() -> list[Path]:
    docs = ROOT / "docs"
    pages = [ROOT / "README.md", *sorted(docs.glob("*.md")), *sorted((docs / "guides").glob("*.md"))]
    return [p for p in pages if p.name not in ELSEWHERE and re.search(r"```(sh|python)\n", p.read_text())]


def _blocks(page: Path) -> list[tuple[str, str]]:
    return re.findall(r"```(sh|python)\n(.*?)```", page.read_text(), re.S)


def _skipped(line: str) -> str | None:
    return next((why for pattern, why in NOT_RUN.items() if re.search(pattern, line)), None)


@pytest.fixture(scope="module")
def reader_folder(tmp_path_factory):
    """What a reader has: the sample data, the repository's scenes, my.xml and out/default.exr."""
    folder = tmp_path_factory.mktemp("reader") / "data"
    done = run_cli("data", folder)
    assert done.returncode == 0, done.stderr
    shutil.copytree(ROOT / "scenes", folder / "scenes")
    shutil.copy(folder / "scene.xml", folder / "my.xml")
    done = subprocess.run([sys.executable, "-m", "pointillist", "render", "scenes/default.xml", "--png"], cwd=folder,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return folder


def test_every_page_with_examples_is_covered():
    assert {p.name for p in _pages()} >= {"README.md", "getting_started.md", "compare.md", "imaging.md",
                                          "progressive.md", "dask.md", "scenes.md", "whitted.md"}


@pytest.mark.parametrize("page", _pages(), ids=lambda p: p.name)
def test_the_examples_run_as_written(page, reader_folder):
    folder = reader_folder
    env = dict(os.environ, PATH=f"{os.path.dirname(sys.executable)}{os.pathsep}{os.environ.get('PATH', '')}")
    ran = 0
    for kind, block in _blocks(page):
        if kind == "python":
            script = folder / f"example_{ran}.py"
            script.write_text(_prelude(block) + block)
            done = subprocess.run([sys.executable, script.name], cwd=folder, env=env, capture_output=True, text=True,
                                  timeout=600)
            assert done.returncode == 0, (page.name, block, done.stderr[-3000:])
            ran += 1
            continue
        for line in block.strip().splitlines():
            command, _, comment = [part.strip() for part in re.split(r"\s+(#)\s", line, maxsplit=1) + ["", ""]][:3]
            if not command or _skipped(command):
                continue
            where = ROOT if re.match(FROM_THE_CLONE, command) else folder
            done = subprocess.run(["bash", "-c", command], cwd=where, env=env, capture_output=True, text=True,
                                  timeout=600)
            assert done.returncode == 0, (page.name, command, done.stderr[-3000:])
            for output in re.findall(r"(?:-o|--output) (\S+)", command):
                assert (folder / output).exists() or (folder / output.replace(".png", "_000.png")).exists(), command
                if " --png" in command and output.endswith(".exr"):
                    assert (folder / output).with_suffix(".png").is_file(), command
            if re.match(r"pointillist render .*--(time|target-error) ", command):   # the end line of passes
                assert re.search(r"\d+ spp in \d+ passes, .*, stopped by \w+$", done.stdout, re.M), command
            elif command.startswith("pointillist render") and "--tiles" not in command:   # the timing line
                assert re.search(r"^time: load [\d.]+ s, trace [\d.]+ s, JIT compile [\d.]+ s \(\d+ kernels, "
                                 r"\d+ from cache\), render [\d.]+ s, total [\d.]+ s$", done.stdout, re.M), command
            for named in re.findall(r"\b(out/[\w./-]+\.(?:png|exr|gif|html|csv|md))", comment):  # "# + out/turn.gif"
                assert (folder / named).is_file(), (command, named)
            ran += 1
    assert ran or all(_skipped(line) for kind, block in _blocks(page) for line in block.strip().splitlines()
                      if kind == "sh"), f"{page.name}: nothing ran"


def _prelude(block: str) -> str:
    """Names a snippet uses without defining: ``image`` / ``img``, the sample photo in grey (0..255)."""
    if re.search(r"\b(image|img)\b", block) and not re.search(r"^(image|img)\s*(,[^=]*)?=", block, re.M):
        return ("from pointillist.imaging.io import read_image as _read\n"
                "image = img = _read('photo.png').image[..., :3].mean(axis=2)\n")
    return ""


def test_the_reasons_name_what_runs_instead():
    """Every pattern of NOT_RUN matches some line of the pages (none is stale) and says why."""
    lines = [line for page in _pages() + [ROOT / "docs" / "guides" / "dask.md"] for kind, block in _blocks(page)
             if kind == "sh" for line in block.splitlines()]
    for pattern, why in NOT_RUN.items():
        assert any(re.search(pattern, line) for line in lines), pattern
        assert len(why) > 20
