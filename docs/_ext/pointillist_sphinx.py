"""Sphinx extension of pointillist's documentation site.

What the site needs beyond Sphinx, numpydoc and myst-nb:

- Mitsuba's reStructuredText vocabulary in plugin docstrings: the ``pluginparameters`` table,
  the ``monosp`` role, the ``tabs`` / ``code-tab`` pair and the ``|int|``-style type names
  (:data:`PARAMETER_TYPES`, added to every page's prolog by ``docs/conf.py``).
- ``.. pointillist-cli-help::``: the ``-h`` text of every command, from the parser itself.
- ``.. pointillist-plugins:: KIND``: the plugin reference. It calls :func:`pointillist.setup`
  (plugin classes exist only once a Mitsuba variant is set) and renders the class docstring of
  every registered plugin of that kind, each under the label ``plugin-NAME``.
- In the API reference a plugin class shows a pointer to its plugin section (its docstring is user
  documentation with section titles, which cannot stand inside an autodoc entry) and none of the
  Mitsuba interface methods it overrides; a name a package re-exports points to where it is defined.
- Checks that fail a build run with ``-W``: every public module, function, class and constant of
  ``pointillist``, ``pointillist.plugins`` and ``pointillist.imaging`` is in the API reference, every
  public function and class has a docstring, every registered plugin has its section, and every page
  is reachable from the index through the tables of contents.
- API stub pages of modules that no longer exist (after a module moved) are removed before
  autosummary writes the new ones.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import inspect
import os
import pkgutil
import shutil
import subprocess
import sys
import types
import typing
import warnings
from pathlib import Path

from docutils import nodes
from docutils.parsers.rst import Directive, directives
from docutils.statemachine import StringList
from sphinx.util import logging
from sphinx.util.nodes import nested_parse_with_titles

LOGGER = logging.getLogger(__name__)

#: The packages whose public modules the API reference documents.
API_PACKAGES = ("pointillist", "pointillist.plugins", "pointillist.imaging")

#: Mitsuba's type names of plugin parameters, as used in ``.. pluginparameters::`` tables.
PARAMETER_TYPES = ("bool", "int", "float", "string", "spectrum", "texture", "transform", "integrator",
                   "sampler", "bsdf", "emitter", "film", "rfilter", "volume", "medium", "phase", "shape",
                   "sensor")

#: Plugin kinds: the folder of ``plugins/`` -> the directive's argument and the section title.
PLUGIN_KINDS = {"integrators": "integrator", "samplers": "sampler", "bsdfs": "bsdf"}


# ---------------------------------------------------------------------- Mitsuba's vocabulary
def parameter_type_prolog() -> str:
    """reStructuredText substitutions ``|int|`` ... for :data:`PARAMETER_TYPES` (italic type names)."""
    return "\n".join(f".. |{name}| replace:: *{name}*" for name in PARAMETER_TYPES) + "\n"


def monosp_role(name, rawtext, text, lineno, inliner, options=None, content=None):
    """``:monosp:`grid``` (Mitsuba's role for plugin and parameter names): inline code."""
    return [nodes.literal(rawtext, text)], []


class PluginParameters(Directive):
    """``.. pluginparameters::``: a two-level bullet list, one item per parameter holding a list
    of its name, type and description (a fourth item, Mitsuba's flags, is accepted and dropped),
    rendered as a table."""

    has_content = True
    optional_arguments = 1
    option_spec = {"extra-rows": directives.nonnegative_int}

    def run(self):
        container = nodes.Element()
        self.state.nested_parse(self.content, self.content_offset, container)
        rows = self._rows(container)
        table = nodes.table(classes=["pluginparameters"])
        group = nodes.tgroup(cols=3)
        table += group
        for width in (20, 12, 68):
            group += nodes.colspec(colwidth=width)
        head = nodes.thead()
        head += self._row([[nodes.paragraph(text=label)] for label in ("Parameter", "Type", "Description")])
        group += head
        body = nodes.tbody()
        for name, kind, description in rows:
            body += self._row([[nodes.paragraph("", "", nodes.literal(text=name.astext()))], kind, description])
        group += body
        return [table]

    def _rows(self, container):
        if len(container) != 1 or not isinstance(container[0], nodes.bullet_list):
            raise self.error("pluginparameters: expected one bullet list (one item per parameter)")
        rows = []
        for index, item in enumerate(container[0].children, 1):
            if len(item) != 1 or not isinstance(item[0], nodes.bullet_list) or len(item[0]) not in (3, 4):
                raise self.error(f"pluginparameters: row {index} must be a list of name, type and description")
            cells = [list(cell.children) for cell in item[0].children[:3]]
            rows.append((nodes.Element("", *cells[0]), cells[1], cells[2]))
        return rows

    @staticmethod
    def _row(cells):
        row = nodes.row()
        for children in cells:
            entry = nodes.entry()
            entry.extend(children)
            row += entry
        return row


class Tabs(Directive):
    """``.. tabs::`` (sphinx-tabs' name, as Mitsuba's docstrings use it): its ``code-tab`` blocks
    one after the other."""

    has_content = True

    def run(self):
        container = nodes.container(classes=["code-tabs"])
        self.state.nested_parse(self.content, self.content_offset, container)
        return [container]


class CodeTab(Directive):
    """``.. code-tab:: LANGUAGE``: a highlighted code block captioned with the language."""

    has_content = True
    required_arguments = 1
    CAPTIONS = {"xml": "Scene XML", "python": "Python (mi.load_dict)"}

    def run(self):
        language = self.arguments[0].lower()
        code = "\n".join(self.content)
        block = nodes.literal_block(code, code, language=language)
        caption = nodes.paragraph(classes=["code-tab-caption"])
        caption += nodes.strong(text=self.CAPTIONS.get(language, language))
        return [caption, block]


# ------------------------------------------------------------------------- plugin reference
def plugin_classes() -> dict[str, tuple[str, type]]:
    """``name -> (kind, class)`` of every plugin :func:`pointillist.plugins.register` registers."""
    import pointillist
    from pointillist import plugins

    pointillist.setup()
    return {name: (kind, plugins.plugin_class(name)) for name, kind in plugins.registered().items()}


def plugin_title(docstring: str) -> tuple[str, list[str], list[str]]:
    """Split a plugin docstring into its title (Mitsuba's docstrings open with an underlined
    title, possibly after a label ``.. _name:``; else the first line), the labels before the title
    and the lines after it."""
    lines = docstring.strip().splitlines()
    labels = []
    while lines and (lines[0].startswith(".. _") or not lines[0].strip()):
        line = lines.pop(0)
        if line.strip():
            labels.append(line)
    underline = lines[1].strip() if len(lines) > 1 else ""
    if len(underline) >= 3 and len(set(underline)) == 1 and not underline[0].isalnum():
        return lines[0].strip(), labels, lines[2:]
    return lines[0].strip(), labels, lines[1:]


def is_plugin_class(obj) -> bool:
    """A class registered with Mitsuba by pointillist (its module's ``PLUGIN_CLASS``)."""
    if not inspect.isclass(obj):
        return False
    module = sys.modules.get(obj.__module__)
    return module is not None and getattr(module, "PLUGIN_CLASS", None) is obj


class PluginReference(Directive):
    """``.. pointillist-plugins:: integrator|sampler|bsdf``: the class docstring of each registered
    plugin of that kind, in name order, under the label ``plugin-NAME``."""

    required_arguments = 1

    def run(self):
        kind = self.arguments[0]
        if kind not in PLUGIN_KINDS.values():
            raise self.error(f"pointillist-plugins: kind must be one of {', '.join(PLUGIN_KINDS.values())}")
        env = self.state.document.settings.env
        lines = StringList()
        source = env.doc2path(env.docname)
        for name, (plugin_kind, cls) in sorted(plugin_classes().items()):
            if plugin_kind != kind:
                continue
            if cls is None or not inspect.getdoc(cls):
                LOGGER.warning("plugin %r has no class docstring to document", name, location=source)
                continue
            env.note_dependency(inspect.getsourcefile(cls))
            title, labels, body = plugin_title(inspect.getdoc(cls))
            text = [f".. _plugin-{name}:", *labels, "", title, "^" * len(title), "", *body, "",
                    f"Class: :class:`{cls.__module__}.{cls.__qualname__}`", ""]
            for line in text:
                lines.append(line, f"{cls.__module__}.{cls.__qualname__} docstring")
        section = nodes.section()
        section.document = self.state.document
        nested_parse_with_titles(self.state, lines, section)
        return section.children


# ----------------------------------------------------------------------------- command line
class CommandLineHelp(Directive):
    """``.. pointillist-cli-help::``: the ``-h`` text of ``pointillist`` and of each sub-command,
    as :func:`pointillist.cli.build_parser` builds it (so the page lists every option there is)."""

    def run(self):
        import argparse

        from pointillist.cli import build_parser

        parser = build_parser()
        commands = next(action for action in parser._actions if isinstance(action, argparse._SubParsersAction))
        result = []
        for name, subparser in [("pointillist", parser), *sorted(commands.choices.items())]:
            prog = name if name == "pointillist" else f"pointillist {name}"
            text = _help_text(subparser)
            result.append(nodes.rubric(text=f"{prog} -h", ids=[nodes.make_id(f"cli-{name}")]))
            result.append(nodes.literal_block(text, text, language="text"))
        return result


def _help_text(parser) -> str:
    """``parser``'s help at a fixed width of 100 columns (argparse reads ``COLUMNS``)."""
    saved = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "100"
    try:
        return parser.format_help()
    finally:
        if saved is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = saved


# --------------------------------------------------------------------------- API reference
def public_modules() -> list[str]:
    """Every public module of :data:`API_PACKAGES` (no name part starting with ``_``), sorted."""
    import pointillist

    pointillist.setup()  # the plugin modules subclass Mitsuba's classes of the variant
    names = set()
    for package_name in API_PACKAGES:
        package = importlib.import_module(package_name)
        names.add(package_name)
        for info in pkgutil.walk_packages(package.__path__, package_name + "."):
            if not any(part.startswith("_") for part in info.name.split(".")):
                names.add(info.name)
    return sorted(names)


def api_map() -> dict[str, dict[str, list[str]]]:
    """What the API page of each public module lists: ``module -> {"classes", "functions", "data",
    "submodules"}`` (names, in the module's order; submodules sorted, short names).

    The page template reads it (``autosummary_context``) so that the pages and
    :func:`check_consistency` share one definition of public (:func:`public_names`); autosummary's
    own lists leave out constants without a doc comment and count a submodule as public only when
    the package's ``__all__`` names it."""
    pages = {}
    for name in public_modules():
        module = importlib.import_module(name)
        entries = {"classes": [], "functions": [], "data": [], "submodules": []}
        for member in public_names(module):
            value = getattr(module, member, None)
            if inspect.isclass(value):
                entries["classes"].append(member)
            elif is_function(value):
                entries["functions"].append(member)
            elif not inspect.ismodule(value):
                entries["data"].append(member)
        if hasattr(module, "__path__"):
            entries["submodules"] = sorted(info.name for info in pkgutil.iter_modules(module.__path__)
                                           if not info.name.startswith("_"))
        pages[name] = entries
    return pages


def is_function(value) -> bool:
    """A function, a builtin, or a function behind a wrapper (``functools.lru_cache``)."""
    return inspect.isfunction(value) or inspect.isbuiltin(value) or (
        callable(value) and not inspect.isclass(value) and inspect.isfunction(getattr(value, "__wrapped__", None)))


def public_names(module: types.ModuleType) -> list[str]:
    """A module's public names: its ``__all__``, else the functions and classes defined in it."""
    if hasattr(module, "__all__"):
        return [name for name in module.__all__ if name != "__version__"]
    return sorted(name for name, value in vars(module).items()
                  if not name.startswith("_") and (inspect.isfunction(value) or inspect.isclass(value))
                  and value.__module__ == module.__name__)


def defined_in(value, module_name: str) -> str | None:
    """The full name under which ``value`` (a function or class) is documented when the module
    ``module_name`` only re-exports it from another public module; None when it is its own."""
    if not (inspect.isfunction(value) or inspect.isclass(value)):
        return None
    home = getattr(value, "__module__", None)
    if not home or home == module_name or any(part.startswith("_") for part in home.split(".")):
        return None
    if not home.startswith(tuple(package + "." for package in API_PACKAGES)):
        return None
    return f"{home}.{value.__qualname__}"


def _inherited_docstring(value, lines: list[str]) -> bool:
    """Whether the docstring autodoc found for a constant is only that of its type (``float``'s for
    a float without a ``#:`` comment), or none."""
    own = "\n".join(lines).strip()
    inherited = getattr(type(value), "__doc__", None)  # a descriptor for some types: then none
    return not own or (isinstance(inherited, str) and own == inspect.cleandoc(inherited).strip())


def value_summary(value) -> list[str]:
    """Lines describing an undocumented constant by its value (short values shown as they are)."""
    import numpy as np

    if isinstance(value, np.ndarray):
        lines = [f"A ``{value.dtype}`` array of shape ``{value.shape}``" + (":" if value.size <= 64 else "."), ""]
        if value.size <= 64:
            lines += ["::", "", *("   " + row for row in np.array2string(value, separator=", ").splitlines()), ""]
        return lines
    if isinstance(value, dict):
        keys = ", ".join(f"``{key!r}``" for key in list(value)[:24]) + (", ..." if len(value) > 24 else "")
        return [f"A mapping of {len(value)} entries: {keys}.", ""]
    text = repr(value)
    if isinstance(value, (str, int, float, bool, tuple, frozenset)) and len(text) <= 120 and "\n" not in text:
        return [f"Value: ``{text}``", ""]
    if hasattr(value, "__len__"):
        return [f"A ``{type(value).__name__}`` of {len(value)} items.", ""]
    return [f"A ``{type(value).__name__}``.", ""]


def reexported_doc_comment(name: str, value) -> list[str] | None:
    """The ``#:`` comment of a constant that a package or module re-exports from one of the
    package's modules (autodoc looks for it in the re-exporting source only); None when it is
    defined there (or no module of the package holds it with a comment)."""
    from sphinx.pycode import ModuleAnalyzer

    exporter, _, attribute = name.rpartition(".")
    module = sys.modules.get(exporter)
    if module is None:
        return None
    if ("", attribute) in ModuleAnalyzer.for_module(exporter).find_attr_docs():
        return None
    package = module if hasattr(module, "__path__") else sys.modules.get(exporter.rpartition(".")[0])
    if package is None or not hasattr(package, "__path__"):
        return None
    for info in pkgutil.walk_packages(package.__path__, prefix=f"{package.__name__}."):
        home = importlib.import_module(info.name)
        if vars(home).get(attribute) is value:
            comment = ModuleAnalyzer.for_module(info.name).find_attr_docs().get(("", attribute))
            if comment:
                return [*comment, f"(Defined in :mod:`{info.name}`.)", ""]
    return None


def process_docstring(app, what, name, obj, options, lines):
    """Plugin classes: a pointer to their plugin section; re-exports: a pointer to their home;
    constants without a doc comment: their value (autodoc would show their type's docstring)."""
    if what == "class" and is_plugin_class(obj):
        title = plugin_title(inspect.getdoc(obj) or "Mitsuba plugin")[0]
        plugin = obj.__module__.rsplit(".", 1)[-1]  # a plugin's name is its module's file name
        lines[:] = [f"{title}. A Mitsuba plugin; its parameters and behaviour: :ref:`plugin-{plugin}`.", ""]
        return
    if what in ("data", "attribute"):
        comment = reexported_doc_comment(name, obj)
        if comment is not None:
            lines[:] = comment
            return
        if _inherited_docstring(obj, lines):
            lines[:] = value_summary(obj)
            return
    module_name = name.rpartition(".")[0]
    home = defined_in(obj, module_name)
    if home is not None and home != name:
        role = "class" if inspect.isclass(obj) else "func"
        lines[:] = [f"Re-exported here; documented as :{role}:`{home}`.", ""]


def process_signature(app, what, name, obj, options, signature, return_annotation):
    """Keep autodoc's own signature for a type alias (``Taps = dict[...]``, documented as data).

    numpydoc answers a signature for any callable, and an alias of ``dict`` is callable; Sphinx 9
    then writes that answer into the data entry's empty list of signatures (an IndexError, "error
    while formatting signature"). The first answer is the one Sphinx uses, and this handler runs
    before numpydoc's."""
    if isinstance(obj, (types.GenericAlias, typing._GenericAlias)):
        return signature, return_annotation
    return None


def skip_member(app, what, name, obj, skip, options):
    """Leave out the Mitsuba interface methods of plugin classes (documented by Mitsuba)."""
    qualname = getattr(obj, "__qualname__", "")
    owner_name = qualname.split(".")[0] if "." in qualname else None
    module = sys.modules.get(getattr(obj, "__module__", None) or "")
    if what == "class" and owner_name and module is not None and is_plugin_class(getattr(module, owner_name, None)):
        return True
    return None


def make_gallery(app) -> None:
    """Run ``gallery/make.py`` into ``gallery/_generated`` (the pictures and the page listing them)
    unless that folder holds what this version of the script made: its SHA-256 in ``.made-by``
    (``POINTILLIST_GALLERY=1`` makes them again). In a subprocess: the script renders with Mitsuba."""
    script = Path(app.srcdir) / "gallery" / "make.py"
    out = Path(app.srcdir) / "gallery" / "_generated"
    digest = hashlib.sha256(script.read_bytes()).hexdigest()
    stamp = out / ".made-by"
    if os.environ.get("POINTILLIST_GALLERY") != "1" and stamp.is_file() and stamp.read_text() == digest \
            and (out / "gallery.md").is_file():
        return
    shutil.rmtree(out, ignore_errors=True)
    done = subprocess.run([sys.executable, str(script), str(out)], capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"docs/gallery/make.py failed (status {done.returncode}):\n{done.stderr[-3000:]}")
    stamp.write_text(digest)


def prepare_build(app):
    """Point the notebooks' output files into the build folder and delete the generated API pages
    of modules that no longer import (a module moved or was removed)."""
    os.environ.setdefault("POINTILLIST_NOTEBOOK_OUT", str(Path(app.outdir).parent / "notebook-out"))
    folder = Path(app.srcdir) / "api" / "generated"
    for stub in folder.glob("*.rst") if folder.is_dir() else ():
        try:
            spec = importlib.util.find_spec(stub.stem)
        except (ImportError, ValueError):
            spec = None
        if spec is None:
            stub.unlink()


def reachable_documents(env) -> set[str]:
    """Documents reachable from the index through the tables of contents."""
    seen, stack = set(), [env.config.root_doc]
    while stack:
        docname = stack.pop()
        if docname not in seen:
            seen.add(docname)
            stack.extend(env.toctree_includes.get(docname, ()))
    return seen


def check_consistency(app, env):
    """Fail the strict build where the reference misses a public name, a docstring, a plugin or a page."""
    objects = env.domains["py"].objects
    labels = env.domains["std"].labels
    for module_name in public_modules():
        module = importlib.import_module(module_name)
        if module_name not in objects:
            LOGGER.warning("API reference: public module %s is not documented", module_name)
        for name in public_names(module):
            if not hasattr(module, name):
                LOGGER.warning("API reference: %s.__all__ names %r, which the module does not define",
                               module_name, name)
                continue
            value = getattr(module, name)
            full = f"{module_name}.{name}"
            if full not in objects:
                LOGGER.warning("API reference: public name %s is not documented", full)
            if (is_function(value) or inspect.isclass(value)) and not inspect.getdoc(value):
                LOGGER.warning("API reference: public %s %s has no docstring",
                               "class" if inspect.isclass(value) else "function", full)
    for name in sorted(plugin_classes()):
        if f"plugin-{name}" not in labels:
            LOGGER.warning("plugin reference: registered plugin %r has no section", name)
    unreachable = sorted(set(env.found_docs) - reachable_documents(env))
    for docname in unreachable:
        LOGGER.warning("page %s is not reachable from the index through a table of contents", docname)


def setup(app):
    # numpydoc reads every class docstring for its signature whatever the other handlers answer;
    # the plugin classes' docstrings are Mitsuba's reStructuredText, not numpydoc (their titles
    # read as unknown sections). Their text is rendered by PluginReference instead.
    warnings.filterwarnings("ignore", message=r"Unknown section .* in the docstring of \w+ in .*/plugins/",
                            category=UserWarning)
    app.add_role("monosp", monosp_role)
    app.add_directive("pluginparameters", PluginParameters)
    app.add_directive("tabs", Tabs)
    app.add_directive("code-tab", CodeTab)
    app.add_directive("pointillist-plugins", PluginReference)
    app.add_directive("pointillist-cli-help", CommandLineHelp)
    app.connect("builder-inited", prepare_build, priority=100)  # before autosummary (500)
    app.connect("builder-inited", make_gallery, priority=100)
    app.connect("autodoc-process-docstring", process_docstring, priority=100)  # before numpydoc (500)
    app.connect("autodoc-process-signature", process_signature, priority=100)  # before numpydoc (500)
    app.connect("autodoc-skip-member", skip_member)
    app.connect("env-check-consistency", check_consistency)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
