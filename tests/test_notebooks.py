"""The notebooks of notebooks/: present, and stored without outputs.

They are executed top to bottom, in their quick mode (``POINTILLIST_NOTEBOOK_QUICK=1``), by the
documentation build of ``tests/test_docs.py`` (myst-nb, ``nb_execution_raise_on_error``: a cell that
raises fails the build), which also checks that each page shows the outputs and figures the
notebook made. Running them a second time here would double the suite's longest step.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parent.parent / "notebooks").glob("*.ipynb"))


def test_there_are_notebooks():
    assert {p.name for p in NOTEBOOKS} >= {"sampling_patterns.ipynb", "tone_and_dither.ipynb",
                                          "volume_mip.ipynb", "whitted_phong.ipynb", "progressive.ipynb"}


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_notebook_is_stored_without_outputs(path):
    notebook = json.loads(path.read_text())
    code = [cell for cell in notebook["cells"] if cell["cell_type"] == "code"]
    assert code, f"{path.name}: no code cell"
    assert all(not cell.get("outputs") and cell.get("execution_count") is None for cell in code), \
        f"{path.name}: outputs must be stripped in git"


def test_the_documentation_build_executes_every_notebook():
    """The site's notebook pages are these files (docs/notebooks links to notebooks/), executed."""
    docs = Path(__file__).resolve().parent.parent / "docs"
    assert (docs / "notebooks").resolve() == NOTEBOOKS[0].parent
    conf = (docs / "conf.py").read_text()
    assert 'nb_execution_mode = "cache"' in conf and "nb_execution_raise_on_error = True" in conf
