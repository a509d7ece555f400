"""pointillist's Mitsuba 3 plugins, written in Python on Dr.Jit.

Each plugin lives in its own module under ``plugins/integrators/``,
``plugins/samplers/`` or ``plugins/bsdfs/``, and its name is the module's file name,
as in Mitsuba (whose sampler ``independent`` is the library ``independent.so``):
``plugins/samplers/jitter.py`` is the sampler ``jitter`` of scene XML and
``mi.load_dict``. The kind (integrator, sampler, BSDF) is the folder. A plugin module
names its class at module level::

    PLUGIN_CLASS = JitterSampler

and its docstring opens with one line ``The ``jitter`` sampler: what it does.``
(:func:`summary`, shown by ``pointillist compare -h``). Modules whose names start with
``_`` are helpers, never registered. Nothing else lists the plugins: :func:`available`
reads the folders (importing nothing), :func:`register` registers what it finds and
gives each class its name as the attribute ``PLUGIN_NAME``, and ``pointillist compare``
sweeps every sampler found.

Because Mitsuba's Python base classes (``mi.SamplingIntegrator``, ``mi.BSDF``,
``mi.Sampler``) only exist once a variant is set, plugin modules are imported
after ``mi.set_variant``: when Mitsuba first builds the plugin (:func:`plugin_class`;
:func:`register` registers the names); they are re-imported when the variant changes.
This package itself imports neither Mitsuba nor Dr.Jit (``pointillist -h`` lists the
samplers without a libLLVM); its sub-packages, which hold the plugins, point Dr.Jit at a
usable libLLVM first
(:func:`pointillist.core.llvm.ensure_llvm`).

Usage::

    import mitsuba as mi
    mi.set_variant("llvm_ad_rgb")
    from pointillist import plugins
    plugins.register()
    scene = mi.load_file("scenes/whitted.xml")
"""

from __future__ import annotations

import ast
import importlib
import pkgutil
import sys
import threading
from pathlib import Path

__all__ = ["register", "registered", "plugin_class", "available", "summary", "KINDS", "DEFAULT_VARIANT"]

#: Folder -> Mitsuba registration function name.
KINDS = {
    "integrators": "register_integrator",
    "samplers": "register_sampler",
    "bsdfs": "register_bsdf",
}

#: The variant the project is built for.
DEFAULT_VARIANT = "llvm_ad_rgb"

_registered: dict[str, dict[str, str]] = {}


def _module_names(folder: str) -> list[str]:
    """The plugin names of a folder of :data:`KINDS`: its modules not starting with ``_``, sorted
    (read from the folder: importing the sub-package would load libLLVM)."""
    return sorted(info.name for info in pkgutil.iter_modules([str(Path(__path__[0]) / folder)])
                  if not info.name.startswith("_") and not info.ispkg)


def available(kind: str | None = None) -> dict[str, str]:
    """``name -> kind`` (``integrator``, ``sampler``, ``bsdf``) of every plugin, from the file names.

    Imports no plugin and no Mitsuba (cheap enough for a command's ``-h``): the plugins
    :func:`register` registers. ``kind`` keeps only that kind.

    Examples
    --------
    >>> available("sampler")["jitter"], "whitted" in available("integrator")
    ('sampler', True)
    """
    kinds = {folder[:-1]: folder for folder in KINDS}
    if kind is not None and kind not in kinds:
        raise ValueError(f"kind: expected one of {', '.join(kinds)}, got {kind!r}")
    return {name: singular for singular, folder in kinds.items() if kind in (None, singular)
            for name in _module_names(folder)}


def summary(name: str) -> str:
    """What plugin ``name`` does, in one line: its module docstring's first line after the colon.

    Reads the module's source (imports nothing).

    Examples
    --------
    >>> summary("grid")
    'samples at the centres of a regular sub-pixel grid'
    """
    kind = available().get(name)
    if kind is None:
        raise ValueError(f"name: no pointillist plugin named {name!r}; expected one of "
                         f"{', '.join(sorted(available()))}")
    source = Path(__path__[0]) / f"{kind}s" / f"{name}.py"
    docstring = ast.get_docstring(ast.parse(source.read_text(encoding="utf-8"))) or ""
    first = docstring.splitlines()[0] if docstring else ""
    head, colon, text = first.partition(":")
    if not colon or f"``{name}``" not in head:
        raise ValueError(f"plugin {name}: its module docstring must open with 'The ``{name}`` {kind}: ...', "
                         f"got {first!r}")
    return text.strip().rstrip(".")


def register() -> dict[str, str]:
    """Register every plugin of the project with Mitsuba for the current variant.

    Registers the names only: a plugin's module is imported when Mitsuba first builds one
    (:func:`plugin_class`), so that a command pays for the plugins its scene uses (importing them
    all took a quarter of a second). Idempotent: a second call for the same variant does nothing.
    Returns a mapping ``plugin name -> kind`` of what is registered (:func:`available`).

    Raises
    ------
    RuntimeError
        If no Mitsuba variant is set (call ``mi.set_variant`` first).
    """
    from pointillist.core.llvm import ensure_llvm

    ensure_llvm()
    import mitsuba as mi

    variant = mi.variant()
    if not variant:
        raise RuntimeError(
            "pointillist.plugins.register(): no Mitsuba variant is set; call "
            f"mitsuba.set_variant({DEFAULT_VARIANT!r}) first"
        )
    if variant in _registered:
        return dict(_registered[variant])
    names: dict[str, str] = {}
    for folder, function in KINDS.items():
        for name in _module_names(folder):
            getattr(mi, function)(name, lambda props, name=name: plugin_class(name)(props))
            names[name] = folder[:-1]
    _registered[variant] = names
    return dict(names)


_IMPORTING = threading.Lock()  # Mitsuba builds a scene's objects in several threads at once


def plugin_class(name: str) -> type:
    """The class of plugin ``name`` for the current Mitsuba variant.

    Imports its module on first use (re-imports it after a variant change: Mitsuba's base classes
    differ per variant) and gives the class its file's name as ``PLUGIN_NAME``.

    Examples
    --------
    >>> import mitsuba as mi
    >>> _ = mi.set_variant("llvm_ad_rgb")
    >>> plugin_class("jitter").PLUGIN_NAME
    'jitter'
    """
    import mitsuba as mi

    kind = available().get(name)
    if kind is None:
        raise ValueError(f"name: no pointillist plugin named {name!r}; expected one of "
                         f"{', '.join(sorted(available()))}")
    variant = mi.variant()
    if not variant:
        raise RuntimeError(f"plugin {name}: no Mitsuba variant is set; call mitsuba.set_variant"
                           f"({DEFAULT_VARIANT!r}) first")
    module_name = f"{__name__}.{kind}s.{name}"
    with _IMPORTING:
        module = sys.modules.get(module_name)
        if module is None:
            module = importlib.import_module(module_name)
        elif not _of_this_variant(module.PLUGIN_CLASS, mi):
            module = importlib.reload(module)
        cls = module.PLUGIN_CLASS
        cls.PLUGIN_NAME = name  # the file's name: written nowhere else
    return cls


def _of_this_variant(cls: type, mi) -> bool:
    """Whether ``cls`` derives from the current variant's Mitsuba classes (each variant has its own)."""
    return all(getattr(mi, base.__name__, None) is base for base in cls.__mro__ if base.__module__ == "mitsuba")


def registered() -> dict[str, str]:
    """What :func:`register` registered for the current variant (empty if nothing)."""
    import mitsuba as mi

    return dict(_registered.get(mi.variant() or "", {}))
