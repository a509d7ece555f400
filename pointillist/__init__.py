"""pointillist: a physically based renderer of Mitsuba 3 plugins written in Python on Dr.Jit.

The command line (``pointillist render|compare|post|mip``) lives in
:mod:`pointillist.cli`; the workflows it runs live beside it. Library users
start with :func:`setup`::

    import pointillist
    mi = pointillist.setup()          # llvm_ad_rgb, plugins registered
    scene = mi.load_file("scenes/default.xml")
"""

from __future__ import annotations

__version__ = "0.1.0"
__all__ = ["setup", "__version__"]


def setup(variant: str = "llvm_ad_rgb", *, plugins: bool = True):
    """Point Dr.Jit at a usable libLLVM, set the Mitsuba variant, register the plugins.

    Returns the ``mitsuba`` module. With ``plugins=False`` the plugins are not registered (yet):
    enough to parse a scene (about a third less start-up), not to build one that uses them; a
    later ``setup()`` registers them. Raises :class:`pointillist.core.llvm.LLVMNotFoundError`
    when no usable libLLVM exists, ValueError for an unknown variant, and
    :class:`pointillist.core.errors.UsageError` when the current folder no longer exists.
    """
    import os

    from pointillist.core.errors import UsageError
    from pointillist.core.llvm import ensure_llvm

    try:  # Mitsuba's file resolver starts from the current folder: its import fails without one
        os.getcwd()
    except FileNotFoundError:
        raise UsageError("the current folder no longer exists (it was deleted or moved); change to an existing "
                         "folder first") from None
    ensure_llvm()
    import mitsuba as mi

    if variant not in mi.variants():
        raise ValueError(f"variant: unknown Mitsuba variant {variant!r}; available: {', '.join(mi.variants())}")
    if mi.variant() != variant:
        mi.set_variant(variant)
    if plugins:
        from pointillist import plugins as registry

        registry.register()
    from pointillist.core import signals

    signals.check()  # a safe point: start-up (imports, libLLVM check, plugins) is done
    return mi
