"""``reinhard``: Reinhard et al. 2002, eq. 4, on luminance."""

from __future__ import annotations

from drjit.llvm.ad import Float

from pointillist.imaging.tone.operators._curves import on_luminance
from pointillist.imaging.tone.operators._registry import TonemapOperator, register

__all__: list[str] = []


def _reinhard_curve(lum: Float, w: Float) -> Float:
    """L_d = L (1 + L / w^2) / (1 + L), computed as (L + (L / w)^2) / (1 + L): 1 / w^2 overflows
    for w < 1e-19. ``w = inf`` gives L / (1 + L)."""
    relative = lum / w  # w = inf -> 0
    return (lum + relative * relative) / (1.0 + lum)


register(TonemapOperator("reinhard", ("white",), on_luminance(_reinhard_curve),
                         "Reinhard et al. 2002, eq. 4, on luminance: L_d = L (1 + L / w^2) / (1 + L), colour scaled "
                         "by L_d / L; w defaults to the image's largest luminance (white=inf gives L / (1 + L))",
                         order=10))
