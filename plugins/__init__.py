"""pointillist's Mitsuba 3 plugins, written in Python on Dr.Jit.

Each plugin lives in its own module under ``plugins/integrators/``,
``plugins/samplers/`` or ``plugins/bsdfs/``. A plugin module defines its class
at module level and names it::

    PLUGIN_NAME = "whitted"          # the name used in scene XML / load_dict
    PLUGIN_CLASS = WhittedIntegrator

The kind (integrator, sampler, BSDF) is the folder the module lives in.
Because Mitsuba's Python base classes (``mi.SamplingIntegrator``, ``mi.BSDF``,
``mi.Sampler``) only exist once a variant is set (mitsuba3 #1611), plugin
modules are imported by :func:`register`, after ``mi.set_variant``; they are
re-imported when the variant changes.

Usage::

    import mitsuba as mi
    mi.set_variant("llvm_ad_rgb")
    from pointillist import plugins
    plugins.register()
    scene = mi.load_file("scenes/whitted.xml")
"""

from __future__ import annotations

from pointillist.llvm import ensure_llvm as _ensure_llvm

_ensure_llvm()

import importlib  # noqa: E402
import pkgutil  # noqa: E402
import sys  # noqa: E402

__all__ = ["register", "registered", "KINDS", "DEFAULT_VARIANT"]

#: Folder -> Mitsuba registration function name.
KINDS = {
    "integrators": "register_integrator",
    "samplers": "register_sampler",
    "bsdfs": "register_bsdf",
}

#: The variant the project is built for.
DEFAULT_VARIANT = "llvm_ad_rgb"

_registered: dict[str, dict[str, str]] = {}


def _plugin_modules(kind: str) -> list[str]:
    package = importlib.import_module(f"{__name__}.{kind}")
    return sorted(
        f"{__name__}.{kind}.{info.name}"
        for info in pkgutil.iter_modules(package.__path__)
        if not info.name.startswith("_")
    )


def register() -> dict[str, str]:
    """Register every plugin of the project with Mitsuba for the current variant.

    Idempotent: a second call for the same variant does nothing. Returns a
    mapping ``plugin name -> kind`` of what is registered.

    Raises
    ------
    RuntimeError
        If no Mitsuba variant is set (call ``mi.set_variant`` first).
    """
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
    for kind, function in KINDS.items():
        for module_name in _plugin_modules(kind):
            module = sys.modules.get(module_name)
            if module is not None and getattr(module, "_VARIANT", None) != variant:
                module = importlib.reload(module)
            elif module is None:
                module = importlib.import_module(module_name)
            module._VARIANT = variant
            name, cls = module.PLUGIN_NAME, module.PLUGIN_CLASS
            getattr(mi, function)(name, lambda props, cls=cls: cls(props))
            names[name] = kind[:-1]
    _registered[variant] = names
    return dict(names)


def registered() -> dict[str, str]:
    """What :func:`register` registered for the current variant (empty if nothing)."""
    import mitsuba as mi

    return dict(_registered.get(mi.variant() or "", {}))
