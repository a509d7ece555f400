"""pointillist's Mitsuba bsdf plugins, one per module (see :mod:`plugins`)."""

from pointillist.core.llvm import ensure_llvm as _ensure_llvm

_ensure_llvm()  # before any plugin module imports Mitsuba (and Dr.Jit)
