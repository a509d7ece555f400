"""What the tone-mapping curves share: luminance, the default white point, luminance-preserving
mapping, an accurate log(1 + x), and the clamp applied after exposure.

Each curve takes the exposed, clamped channels (one, or R, G, B) and the checked ``white`` (None: the
operator's default) and returns the mapped channels, to be clipped to 0..1 and sRGB-encoded.
"""

from __future__ import annotations

from typing import Callable

import drjit as dr
import numpy as np
from drjit.llvm.ad import Float

from pointillist.imaging.arrays import held_extreme, opaque_scalar
from pointillist.imaging.colour import REC709_LUMINANCE_WEIGHTS

__all__ = ["HDR_MAX", "log1p", "luminance", "white_point", "on_luminance"]

#: The smallest default white point: float32's smallest normal number (an all-black image).
_TINY = float(np.finfo(np.float32).tiny)

#: Linear values are clamped here after exposure: every operator is saturated far below, and
#: the curves' squares stay finite in float32.
HDR_MAX = 1e15


def log1p(x: Float) -> Float:
    """log(1 + x) accurate for small x >= 0 (D. Goldberg, "What every computer scientist should
    know about floating-point arithmetic", 1991, thm. 4): log(u) x / (u - 1) with u = 1 + x
    rounded, and x where u rounds to 1. Plain ``log(1 + x)`` is 0 for x < 6e-8 in float32."""
    u = 1.0 + x
    return dr.select(u == 1.0, x, dr.log(u) * (x / (u - 1.0)))


def luminance(channels: list[Float]) -> Float:
    """Rec. 709 luminance of R, G, B (a single channel is its own luminance)."""
    if len(channels) == 1:
        return channels[0]
    wr, wg, wb = REC709_LUMINANCE_WEIGHTS
    return wr * channels[0] + wg * channels[1] + wb * channels[2]


def white_point(values: Float, white: float | None) -> Float:
    """``white`` (opaque), or the largest of ``values`` (at least float32's smallest normal)."""
    if white is not None:
        return opaque_scalar(Float, min(white, HDR_MAX))
    w = dr.maximum(dr.max(values), _TINY)  # its own reduction pass
    if dr.grad_enabled(values):           # the derivative of the brightest value (one, on a tie)
        top = float(dr.max(dr.detach(values))[0])
        if top > _TINY:
            w = dr.replace_grad(w, held_extreme(values, top))
    return w


def on_luminance(curve: Callable[[Float, Float], Float]) -> Callable[[list[Float], float | None], list[Float]]:
    """An operator that maps the luminance L to L_d and scales every channel by L_d / L (hue kept)."""
    def mapped(channels: list[Float], white: float | None) -> list[Float]:
        lum = luminance(channels)
        mapped_l = curve(lum, white_point(lum, white))
        ratio = dr.select(lum > 0.0, mapped_l / lum, 0.0)
        return [c * ratio for c in channels]
    return mapped
