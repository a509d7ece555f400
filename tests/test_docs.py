"""The documentation site (docs/): its strict build, what it must contain, and its pages in a browser.

The site is built once per session from the sources as they are (``sphinx-build -W``, warnings are
errors; the notebooks execute in their quick mode), into a temporary folder with an empty notebook
cache, as ``make docs`` builds it from a fresh clone. The built site is then checked against the
code independently of the build's own checks: every public module, function, class and constant
in the object inventory, every registered plugin on the plugin page with the parameters its
docstring lists, every page reachable from the index through links, every notebook with outputs,
every command-line option on the command-line page. Headless Chromium opens the index and the
search page (browser start-up shared with ``tests/test_compare_html.py``).

The docs extension's own checks (``docs/_ext/pointillist_sphinx.py``) are tested without a build:
each reports what it must report, on a fake build environment.
"""

from __future__ import annotations

import argparse
import html
import importlib
import importlib.util
import inspect
import logging
import os
import pkgutil
import re
import subprocess
import sys
import zlib
from html.parser import HTMLParser
from pathlib import Path
from types import ModuleType, SimpleNamespace
from urllib.parse import unquote, urldefrag, urlparse

import numpy as np
import pytest

from test_compare_html import console, run_chromium

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
PACKAGES = ("pointillist", "pointillist.plugins", "pointillist.imaging")
#: Pages Sphinx writes besides the documents (indices, search), not reached through the toctree.
GENERATED_PAGES = {"genindex.html", "py-modindex.html", "search.html"}


def _extension() -> ModuleType:
    """docs/_ext/pointillist_sphinx.py, imported by path (it is not part of the package)."""
    spec = importlib.util.spec_from_file_location("pointillist_sphinx", DOCS / "_ext" / "pointillist_sphinx.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# ------------------------------------------------------------------------ the build
@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The site built from scratch with warnings as errors: ``(html folder, sphinx-build's stderr)``."""
    for name in ("sphinx", "furo", "numpydoc", "myst_nb"):
        pytest.importorskip(name)
    out = tmp_path_factory.mktemp("docs")
    env = dict(os.environ, POINTILLIST_NOTEBOOK_QUICK="1", POINTILLIST_NOTEBOOK_OUT=str(out / "notebook-out"))
    done = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-b", "html", str(DOCS),
                           str(out / "html"), "-d", str(out / "doctrees")],
                          capture_output=True, text=True, timeout=1500, env=env, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-8000:]
    return SimpleNamespace(html=out / "html", stderr=done.stderr)


def public_api() -> dict[str, list[str]]:
    """``module -> public names`` for every public module of the three packages: a module is public
    when no part of its name starts with ``_``; its public names are its ``__all__``, or else the
    functions and classes it defines."""
    import pointillist

    pointillist.setup()  # plugin modules subclass Mitsuba's classes of the variant
    modules = {}
    for package_name in PACKAGES:
        package = importlib.import_module(package_name)
        names = [package_name] + [info.name for info in pkgutil.walk_packages(package.__path__, package_name + ".")]
        for name in names:
            if any(part.startswith("_") for part in name.split(".")):
                continue
            module = importlib.import_module(name)
            if hasattr(module, "__all__"):
                modules[name] = [n for n in module.__all__ if n != "__version__"]
            else:
                modules[name] = sorted(n for n, v in vars(module).items() if not n.startswith("_")
                                       and (inspect.isfunction(v) or inspect.isclass(v))
                                       and v.__module__ == name)
    return modules


def inventory(html_dir: Path) -> dict[str, str]:
    """``name -> domain:role`` of the site's ``objects.inv`` (Sphinx's format 2: four header lines,
    then zlib-compressed lines ``name domain:role priority uri display name``)."""
    data = (html_dir / "objects.inv").read_bytes()
    lines = data.split(b"\n", 4)
    assert lines[0] == b"# Sphinx inventory version 2"
    entries = {}
    for line in zlib.decompress(lines[4]).decode().splitlines():
        match = re.match(r"(.+?)\s+(\S+:\S+)\s+(-?\d+)\s+(\S+)\s+(.*)", line)
        if match:
            entries[match.group(1)] = match.group(2)
    return entries


class _Links(HTMLParser):
    def __init__(self):
        super().__init__()
        self.links, self.images, self.ids = [], [], set()
        self.classes: list[tuple[str, str]] = []

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "a" and attrs.get("href"):
            self.links.append(attrs["href"])
        if tag == "img" and attrs.get("src"):
            self.images.append(attrs["src"])
        if attrs.get("id"):
            self.ids.add(attrs["id"])
        if attrs.get("class"):
            self.classes.append((tag, attrs["class"]))


def parse(page: Path) -> _Links:
    parser = _Links()
    parser.feed(page.read_text(encoding="utf-8"))
    return parser


def text_of(page: Path) -> str:
    """A page's text without tags, entities decoded, whitespace collapsed."""
    return " ".join(html.unescape(re.sub(r"<[^>]+>", " ", page.read_text(encoding="utf-8"))).split())


# ------------------------------------------------------------------ the built site
@pytest.mark.slow  # builds the whole site and runs every notebook (about a minute on 2 quiet cores)
def test_site_builds_with_warnings_as_errors(site):
    assert (site.html / "index.html").is_file()
    # -W turns a Sphinx warning into a failed build; none is left in the log either. Sphinx writes
    # "WARNING: text" (a space after the colon); the notebook kernels' own lines are not Sphinx's:
    # "[IPKernelApp] WARNING | ...", and Python logging's "ERROR:tornado.general:..." of ipykernel's
    # race at kernel shutdown (a status published after its IO thread closed)
    assert not re.search(r"(^|: )(WARNING|ERROR|CRITICAL): ", site.stderr, re.M), site.stderr[-4000:]


@pytest.mark.slow
def test_every_public_name_is_in_the_api_reference(site):
    documented = inventory(site.html)
    missing = []
    for module, names in public_api().items():
        if documented.get(module) != "py:module":
            missing.append(module)
        missing += [f"{module}.{name}" for name in names
                    if not documented.get(f"{module}.{name}", "").startswith("py:")]
    assert missing == [], f"public names missing from the API reference: {missing}"
    # and the reference is the generated one, not a hand-kept list: one page per public module
    pages = {p.stem for p in (site.html / "api" / "generated").glob("*.html")}
    assert pages == set(public_api())


@pytest.mark.slow
def test_every_plugin_has_its_section_with_the_parameters_of_its_docstring(site, mi):
    from pointillist import plugins

    labels = inventory(site.html)
    page = site.html / "plugins.html"
    body = page.read_text(encoding="utf-8")
    for name in plugins.registered():
        assert labels.get(f"plugin-{name}") == "std:label", name
    # each section's table lists exactly the parameters its class docstring's table lists
    classes = {name: plugins.plugin_class(name) for name in plugins.registered()}
    for name, cls in classes.items():
        expected = re.findall(r"^\s*\* - (.+?)\s*$", inspect.getdoc(cls), re.M)
        section = body[body.index(f'id="plugin-{name}"'):]
        table = section[:section.index("</table>")]
        shown = [html.unescape(re.sub(r"<[^>]+>", "", cell)).strip()
                 for cell in re.findall(r"<tr[^>]*>\s*<td[^>]*>(.*?)</td>", table, re.S)]
        assert shown == expected and expected, (name, shown, expected)


@pytest.mark.slow
def test_every_page_is_reachable_from_the_index(site):
    """Follow the links of the built pages from index.html: every page Sphinx wrote is reached."""
    root = site.html.resolve()
    seen, todo = set(), [root / "index.html"]
    while todo:
        page = todo.pop()
        if page in seen or not page.is_file():
            continue
        seen.add(page)
        for href in parse(page).links:
            url = urlparse(href)
            if url.scheme or url.netloc or not url.path.endswith(".html"):
                continue
            todo.append((page.parent / unquote(urldefrag(url.path)[0])).resolve())
    pages = {p.resolve() for p in root.rglob("*.html") if not p.relative_to(root).parts[0].startswith("_")}
    unreached = sorted(str(p.relative_to(root)) for p in pages - seen if p.name not in GENERATED_PAGES)
    assert unreached == []
    # the pages the issue asks for are there
    for name in ("getting_started", "command_line", "conventions", "robustness", "benchmarks", "architecture",
                 "plugins", "api/index", "notebooks", "guides/whitted", "guides/compare", "guides/adaptive",
                 "guides/progressive", "guides/imaging", "guides/mip", "guides/dask"):
        assert root / f"{name}.html" in seen, name


@pytest.mark.slow
def _gallery_pictures() -> dict[str, str]:
    """docs/gallery/make.py's PICTURES (read from its source: importing it starts matplotlib)."""
    source = (DOCS / "gallery" / "make.py").read_text()
    start = source.index("PICTURES = {")
    namespace: dict = {}
    exec(source[start:source.index("}\n", start) + 1], namespace)
    return namespace["PICTURES"]


def test_the_gallery_shows_every_picture_and_each_guide_one(site):
    """The build made the gallery's pictures (not blank), the gallery page shows all of them, and every
    guide shows at least one."""
    from PIL import Image

    pictures = _gallery_pictures()
    assert len(pictures) >= 10

    def shown(page):
        found = {}
        for src in parse(page).images:
            name = Path(src).stem
            if name in pictures:
                path = (page.parent / src).resolve()
                assert path.is_file(), src
                found[name] = np.asarray(Image.open(path).convert("RGB")).astype(float)
        return found

    gallery = shown(site.html / "gallery.html")
    assert set(gallery) == set(pictures)
    for name, image in gallery.items():
        assert image.shape[0] > 100 and image.std() > 10, f"{name}.png looks blank"
    for guide in sorted((DOCS / "guides").glob("*.md")):
        if guide.stem != "index":
            assert shown(site.html / "guides" / f"{guide.stem}.html"), f"{guide.name}: no gallery picture"


def test_each_guide_opens_in_headless_chromium_with_its_picture(site, tmp_path):
    """Every guide page, opened in Chromium: no console message, and its gallery picture loaded (the
    DOM after the scripts ran names a picture of docs/gallery/make.py)."""
    pictures = _gallery_pictures()
    for guide in sorted((DOCS / "guides").glob("*.md")):
        if guide.stem == "index":
            continue
        done = run_chromium(site.html / "guides" / f"{guide.stem}.html", tmp_path, "--dump-dom", fragment="")
        assert done.returncode == 0 and console(done.stderr) == [], (guide.name, console(done.stderr))
        shown = {Path(src).stem for src in re.findall(r'<img[^>]+src="([^"]+)"', done.stdout)}
        assert shown & set(pictures), f"{guide.name}: no gallery picture in the page"


def test_notebooks_ran_and_show_their_outputs(site):
    notebooks = sorted((ROOT / "notebooks").glob("*.ipynb"))
    assert notebooks
    for notebook in notebooks:
        page = site.html / "notebooks" / f"{notebook.stem}.html"
        links = parse(page)
        figures = [src for src in links.images if "_images/" in src]
        assert figures, f"{notebook.name}: no output figure"
        for src in figures:
            assert (page.parent / src).resolve().is_file(), src
        assert "quick mode" in text_of(page)  # the first cell's output: it ran with POINTILLIST_NOTEBOOK_QUICK=1
        assert "Traceback" not in text_of(page)


@pytest.mark.slow
def test_conventions_page_holds_the_sections_code_cites(site):
    ids = parse(site.html / "conventions.html").ids
    for section in ("arrays", "non-finite", "arguments", "tone", "equalisation", "colour", "filters", "resampling",
                    "dithering", "rendering", "samplers", "adaptive", "mip", "errors", "edges"):
        assert f"conventions-{section}" in ids, section
    text = text_of(site.html / "conventions.html")
    assert "F(i) = max(0, round(L t(i) / (h w)) - 1)" in text
    assert "NaN becomes 0, +inf becomes white, -inf becomes 0" in text


@pytest.mark.slow
def test_command_line_page_lists_every_option(site):
    from pointillist.cli import build_parser

    text = text_of(site.html / "command_line.html")
    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices
    for name, subparser in commands.items():
        assert f"pointillist {name} -h" in text
        for action in subparser._actions:
            for option in action.option_strings:
                assert option in text, (name, option)


@pytest.mark.slow
def test_the_index_in_headless_chromium(site, tmp_path):
    page = site.html / "index.html"
    done = run_chromium(page, tmp_path, "--dump-dom", fragment="")
    assert done.returncode == 0, done.stderr[-3000:]
    assert console(done.stderr) == [], console(done.stderr)
    dom = done.stdout
    assert re.search(r'<body[^>]*data-theme="auto"', dom), "the theme's script did not run"  # set by a script
    navigation = dom[dom.index('class="sidebar-tree"'):]
    for title in ("Getting started", "Command line", "Guides", "Notebooks", "Conventions", "Plugin reference",
                  "API reference", "Numerical robustness", "Benchmarks", "Architecture"):
        assert f">{title}</a>" in navigation, title
    assert 'src="_images/compare_report.png"' in dom
    assert dom.count('class="copybtn') >= 1, "code blocks get a copy button (sphinx-copybutton's script)"
    shot = tmp_path / "index.png"
    done = run_chromium(page, tmp_path, f"--screenshot={shot}", "--window-size=1280,900", fragment="")
    assert done.returncode == 0 and console(done.stderr) == [], done.stderr[-2000:]
    from PIL import Image

    image = np.asarray(Image.open(shot).convert("RGB")).astype(float)
    assert image.shape == (900, 1280, 3) and image.std() > 10
    # the page drew dark text on a light background (not a blank or an error page)
    assert (image.mean(axis=2) > 240).mean() > 0.3 and (image.mean(axis=2) < 80).mean() > 0.005
    print(f"screenshot of the index: {shot}")


@pytest.mark.slow
def test_search_finds_the_equalisation_rule(site, tmp_path):
    """Sphinx's search runs in the page (its index is a script): the query lists the section."""
    done = run_chromium(site.html / "search.html", tmp_path, "--dump-dom", fragment="?q=equalisation")
    assert done.returncode == 0, done.stderr[-3000:]
    results = re.findall(r'<ul[^>]*class="search"[^>]*>(.*?)</ul>', done.stdout, re.S)
    assert results and 'href="conventions.html#conventions-equalisation"' in results[0], done.stdout[-3000:]
    # from disk (file://) the browser refuses the fetches of the result snippets; nothing else may fail
    other = [line for line in console(done.stderr) if "CORS policy" not in line and "Failed to fetch" not in line]
    assert other == []


# ----------------------------------------------------- the extension's checks, without a build
def test_plugin_parameters_table_from_a_two_level_list():
    from docutils import nodes
    from docutils.core import publish_doctree
    from docutils.parsers.rst import directives, roles

    ext = _extension()
    directives.register_directive("pluginparameters", ext.PluginParameters)
    roles.register_local_role("monosp", ext.monosp_role)
    source = ".. |int| replace:: *int*\n\n.. pluginparameters::\n\n * - max_depth\n   - |int|\n" \
             "   - Cut-off (Default: 5), see :monosp:`path`.\n * - seed\n   - |int|\n   - Seed.\n   - flags\n"
    tree = publish_doctree(source, settings_overrides={"report_level": 5})
    table = next(iter(tree.findall(nodes.table)))
    rows = [[entry.astext() for entry in row.findall(nodes.entry)] for row in table.findall(nodes.row)]
    assert rows == [["Parameter", "Type", "Description"], ["max_depth", "int", "Cut-off (Default: 5), see path."],
                    ["seed", "int", "Seed."]]
    assert "pluginparameters" in table["classes"]
    broken = publish_doctree(".. pluginparameters::\n\n * - only a name\n",
                             settings_overrides={"report_level": 5, "halt_level": 5})
    assert not list(broken.findall(nodes.table))
    assert any("row 1" in m.astext() for m in broken.findall(nodes.system_message))


def test_plugin_title_accepts_mitsubas_headings_and_plain_docstrings():
    ext = _extension()
    assert ext.plugin_title("Grid (:monosp:`grid`)\n-----\n\nBody\n") == ("Grid (:monosp:`grid`)", [], ["", "Body"])
    assert ext.plugin_title("\n.. _integrator-mip:\n\nMIP\n===\nBody") == ("MIP", [".. _integrator-mip:"], ["Body"])
    assert ext.plugin_title("Whitted tracer\n\nBody") == ("Whitted tracer", [], ["", "Body"])


def _fake_env(ext, objects, labels, docs, includes):
    return SimpleNamespace(domains={"py": SimpleNamespace(objects=objects), "std": SimpleNamespace(labels=labels)},
                           found_docs=set(docs), toctree_includes=includes, config=SimpleNamespace(root_doc="index"))


@pytest.fixture
def sphinx_warnings(caplog):
    """The messages of warnings logged through Sphinx's loggers (which may not reach the root logger)."""
    sphinx_logger = logging.getLogger("sphinx")
    level = sphinx_logger.level
    sphinx_logger.addHandler(caplog.handler)
    sphinx_logger.setLevel(logging.WARNING)
    yield lambda: [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    sphinx_logger.removeHandler(caplog.handler)
    sphinx_logger.setLevel(level)


def test_consistency_check_reports_each_gap(mi, caplog, sphinx_warnings, monkeypatch):
    """The build's check is quiet on a complete reference and names each thing that is missing."""
    ext = _extension()
    api = ext.api_map()
    objects = {name: None for name in api}
    objects.update({f"{module}.{member}": None for module, page in api.items()
                    for key in ("classes", "functions", "data") for member in page[key]})
    labels = {f"plugin-{name}": None for name in ext.plugin_classes()}
    includes = {"index": ["guide", "api"], "api": []}
    ext.check_consistency(None, _fake_env(ext, objects, labels, ["index", "guide", "api"], includes))
    assert sphinx_warnings() == []

    caplog.clear()
    del objects["pointillist.imaging.tone.gamma"], objects["pointillist.imaging.window"], labels["plugin-phong"]
    from pointillist.imaging import tone

    monkeypatch.setattr(tone.dynamic_range, "__doc__", None)
    ext.check_consistency(None, _fake_env(ext, objects, labels, ["index", "guide", "api", "orphan"], includes))
    messages = sphinx_warnings()
    assert "API reference: public name pointillist.imaging.tone.gamma is not documented" in messages
    assert "API reference: public module pointillist.imaging.window is not documented" in messages
    assert "API reference: public function pointillist.imaging.tone.dynamic_range has no docstring" in messages
    assert "plugin reference: registered plugin 'phong' has no section" in messages
    assert "page orphan is not reachable from the index through a table of contents" in messages


def test_generated_pages_of_removed_modules_are_deleted(tmp_path, monkeypatch):
    ext = _extension()
    folder = tmp_path / "api" / "generated"
    folder.mkdir(parents=True)
    (folder / "pointillist.imaging.tone.rst").write_text("kept")
    (folder / "pointillist.imaging.no_such_module.rst").write_text("stale")
    monkeypatch.setenv("POINTILLIST_NOTEBOOK_OUT", "")  # restored (removed) after the test
    monkeypatch.delenv("POINTILLIST_NOTEBOOK_OUT")
    ext.prepare_build(SimpleNamespace(srcdir=str(tmp_path), outdir=str(tmp_path / "_build" / "html")))
    assert sorted(p.name for p in folder.iterdir()) == ["pointillist.imaging.tone.rst"]
    assert os.environ["POINTILLIST_NOTEBOOK_OUT"] == str(tmp_path / "_build" / "notebook-out")


def test_no_page_cites_a_file_outside_the_repository():
    """The site is where the conventions live: no page refers to documents the repository lacks."""
    for page in DOCS.rglob("*"):
        if page.suffix in (".md", ".rst", ".py") and "_build" not in page.parts and "generated" not in page.parts:
            text = page.read_text(encoding="utf-8")
            assert "SPEC" not in text and "NOTES-mitsuba" not in text, page


def test_an_undocumented_constant_shows_its_value_not_its_types_docstring():
    """autodoc gives a constant without a ``#:`` comment its type's docstring (float's for 2.0)."""
    import functools

    ext = _extension()
    float_doc = inspect.cleandoc(float.__doc__).splitlines()
    assert ext._inherited_docstring(2.0, float_doc) and ext._inherited_docstring(2.0, [])
    assert not ext._inherited_docstring(2.0, ["The largest aspect ratio of a sample grid."])
    lines = ["The largest aspect ratio."]
    ext.process_docstring(None, "data", "pointillist.plugins.samplers.grid.RATIO", 2.0, {}, lines)
    assert lines == ["The largest aspect ratio."]
    ext.process_docstring(None, "data", "pointillist.plugins.samplers.grid.RATIO", 2.0, {}, float_doc)
    assert float_doc == ["Value: ``2.0``", ""]
    assert ext.value_summary(np.eye(2, dtype=np.int64))[:4] == ["A ``int64`` array of shape ``(2, 2)``:", "", "::", ""]
    assert ext.value_summary(np.zeros(65))[0] == "A ``float64`` array of shape ``(65,)``."
    assert ext.value_summary({"a": 1, "b": 2})[0] == "A mapping of 2 entries: ``'a'``, ``'b'``."
    assert ext.value_summary(tuple(range(100)))[0] == "A ``tuple`` of 100 items."
    assert ext.is_function(functools.lru_cache(maxsize=None)(lambda: 1)) and not ext.is_function(2.0)


def test_a_constant_a_module_reexports_from_a_sibling_keeps_its_doc_comment(mi):
    """grid re-exports ``MAX_GRID_ASPECT`` from the samplers' ``_base``: the row shows _base's comment."""
    from pointillist.plugins.samplers import grid

    ext = _extension()
    lines = inspect.cleandoc(float.__doc__).splitlines()
    ext.process_docstring(None, "data", "pointillist.plugins.samplers.grid.MAX_GRID_ASPECT", grid.MAX_GRID_ASPECT,
                          {}, lines)
    assert lines[0].startswith("Largest cols / rows ratio accepted without a warning")
    assert lines[-2] == "(Defined in :mod:`pointillist.plugins.samplers._base`.)"
