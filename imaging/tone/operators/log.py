"""``log``: a logarithmic response on luminance."""

from __future__ import annotations

from drjit.llvm.ad import Float

from pointillist.imaging.tone.operators._curves import log1p, on_luminance
from pointillist.imaging.tone.operators._registry import TonemapOperator, register

__all__: list[str] = []


def _log_curve(lum: Float, w: Float) -> Float:
    """L_d = log(1 + L) / log(1 + w)."""
    return log1p(lum) / log1p(w)


register(TonemapOperator("log", ("white",), on_luminance(_log_curve),
                         "logarithmic response L_d = log(1 + L) / log(1 + w) on luminance, w defaults to the largest "
                         "luminance", order=50))
