"""Sphinx configuration of pointillist's documentation site (``make docs``).

Choices, and why:

- **Sphinx**, not MkDocs: the project's docstrings are numpydoc reStructuredText, and the plugin
  docstrings use Mitsuba's reStructuredText directives; Sphinx renders both as they are, and its
  ``-W`` mode turns every broken reference and docstring into a build error.
- **furo** theme: Mitsuba 3's own documentation uses it, so the site reads like the renderer it
  extends; it is small (no Bootstrap, one stylesheet), builds fast, has a searchable sidebar of the
  whole tree and a dark mode. pydata-sphinx-theme (numpy, scikit-image) suits larger sites with
  several top-level sections, at a higher build cost per page.
- **numpydoc** parses the docstrings' sections (Parameters, Returns, Raises, Examples, Notes).
- **autodoc + autosummary**, recursive from the three packages ``pointillist``,
  ``pointillist.plugins`` and ``pointillist.imaging``: the API reference is generated from the
  modules as they are, one page per module, so moving or splitting a module needs no edit here.
- **myst-nb** reads the Markdown pages (the README's language, so its sections copy over as they
  are) and executes the notebooks of ``notebooks/`` at build time (no pandoc needed, unlike
  nbsphinx), in their quick mode (``POINTILLIST_NOTEBOOK_QUICK=1``), caching the outputs under
  ``docs/_build/.jupyter_cache`` so that a rebuild re-runs only the notebooks that changed.
- Mitsuba plugin classes exist only after ``mitsuba.set_variant``: ``_ext/pointillist_sphinx.py``
  calls :func:`pointillist.setup` and renders each registered plugin's class docstring (with
  Mitsuba's ``pluginparameters`` tables) on the plugin reference page.

Strict builds (``sphinx-build -W``, as ``make docs`` and the test suite run it) also fail when a
public name is missing from the API reference or has no docstring, when a registered plugin has no
section, or when a page cannot be reached from the index (see ``_ext/pointillist_sphinx.py``).
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(DOCS / "_ext"))

# The notebooks run small (their quick mode) and write their files outside the repository's out/;
# set POINTILLIST_NOTEBOOK_QUICK=0 before `make docs` for the full sizes.
os.environ.setdefault("POINTILLIST_NOTEBOOK_QUICK", "1")
# The notebook kernels inherit this environment: with MPLBACKEND set (Agg, as in the test suite's
# notebook runs) `plt.show()` would draw nothing into the page; without it they use the inline backend.
os.environ.pop("MPLBACKEND", None)

import pointillist  # noqa: E402
from pointillist_sphinx import api_map, parameter_type_prolog  # noqa: E402

project = "pointillist"
author = "the pointillist authors"
copyright = "the pointillist authors, BSD-3-Clause"
release = version = pointillist.__version__
pointillist.setup()  # the plugin classes exist once a Mitsuba variant is set: autodoc imports them

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "numpydoc",
    "myst_nb",
    "sphinx_copybutton",
    "pointillist_sphinx",
]

# Copy buttons copy the commands, not the prompts or the outputs of a doctest.
copybutton_prompt_text = r">>> |\.\.\. |\$ "
copybutton_prompt_is_regexp = True
copybutton_only_copy_prompt_lines = False

root_doc = "index"
exclude_patterns = ["_build", "**.ipynb_checkpoints", "README.md", "gallery/_generated"]  # included by gallery.md
templates_path = ["_templates"]
html_static_path = ["_static"]
html_css_files = ["pointillist.css"]
rst_prolog = parameter_type_prolog()

# ------------------------------------------------------------------ theme
html_theme = "furo"
html_title = f"pointillist {release}"
html_theme_options = {"navigation_with_keys": True}
html_last_updated_fmt = None
html_copy_source = False

# ------------------------------------------------------------------ API reference
# The generated pages are made anew at each build: a page left from a module that was renamed or
# moved would name a module that no longer imports.
shutil.rmtree(Path(__file__).resolve().parent / "api" / "generated", ignore_errors=True)
autosummary_generate = True
autosummary_ignore_module_all = False  # a module's __all__ says what is public
autosummary_imported_members = False
autosummary_context = {"api": api_map()}  # module -> its public classes, functions, data, submodules
autodoc_default_options = {"member-order": "bysource"}
autodoc_typehints = "signature"
autodoc_preserve_defaults = True
autoclass_content = "class"
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_attributes_as_param_list = False

# Broken references are errors, but only to pointillist's own names: the other packages'
# inventories (Python, numpy, Dr.Jit, Mitsuba) cannot be fetched on an offline build machine.
nitpicky = True
# Private names (a part starting with "_", e.g. a plugin's private base class) are not documented.
nitpick_ignore_regex = [(r"py:.*", r"(?!pointillist\b).*"), (r"py:.*", r".*\._.*")]

# ------------------------------------------------------------------ Markdown and notebooks
myst_enable_extensions = ["colon_fence", "dollarmath", "deflist"]
myst_heading_anchors = 3
nb_execution_mode = "cache"
nb_execution_timeout = 600
nb_execution_raise_on_error = True
nb_execution_show_tb = True
nb_merge_streams = True

# benchmarks/RESULTS.md, included as it is, is written by the benchmark scripts: a heading that
# skips a level there must not fail the site's build.
suppress_warnings = ["myst.header"]
