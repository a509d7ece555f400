"""``hable``: Hable's filmic curve (John Hable, "Uncharted 2: HDR Lighting", GDC 2010)."""

from __future__ import annotations

import numpy as np
from drjit.llvm.ad import Float

from pointillist.core import checks
from pointillist.imaging.arrays import opaque_scalar
from pointillist.imaging.tone.operators._curves import HDR_MAX
from pointillist.imaging.tone.operators._registry import TonemapOperator, register

__all__ = ["HABLE_CONSTANTS"]

#: The constants of Hable's filmic curve (John Hable, "Uncharted 2: HDR Lighting", GDC 2010): shoulder strength A,
#: linear strength B, linear angle C, toe strength D, toe numerator E, toe denominator F,
#: linear white point W, and the exposure bias applied before the curve.
HABLE_CONSTANTS = {"A": 0.15, "B": 0.50, "C": 0.10, "D": 0.20, "E": 0.02, "F": 0.30,
                   "W": 11.2, "exposure_bias": 2.0}


def _hable(channels: list[Float], white: float | None) -> list[Float]:
    """f(2 x) / f(W) per channel (``white`` sets W)."""
    k = HABLE_CONSTANTS
    A, B, C, D, E, F = (k[n] for n in "ABCDEF")

    def f(v):
        # Hable's f with its two terms over one denominator: the constant terms D E / (D F) and
        # E / F cancel exactly, so small values keep their precision (the plain difference is
        # 0 below about 1e-16 in float64 and 1e-8 in float32)
        return v * ((F - E) * A * v + B * (C * F - E)) / (F * (v * (A * v + B) + D * F))

    w = white if white is not None else k["W"]
    norm = opaque_scalar(Float, checks.float32_finite(1.0 / float(f(np.float64(min(w, HDR_MAX)))), "white",
                                                      "hable's normalisation 1 / f(white)"))
    return [f(k["exposure_bias"] * c) * norm for c in channels]


register(TonemapOperator("hable", ("white",), _hable,
                         "Hable's filmic curve f(2 x) / f(W), f(x) = (x (A x + C B) + D E) / (x (A x + B) + D F) "
                         "- E / F (HABLE_CONSTANTS; white sets W = 11.2), computed as x ((F - E) A x + B (C F - E)) "
                         "/ (F (x (A x + B) + D F)) (the same function without the cancellation of its constant "
                         "terms)",
                         order=30))
