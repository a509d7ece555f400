"""``reinhard_extended``: Reinhard's curve on each channel."""

from __future__ import annotations

import drjit as dr
from drjit.llvm.ad import Float

from pointillist.imaging.tone.operators._curves import white_point
from pointillist.imaging.tone.operators._registry import TonemapOperator, register

__all__: list[str] = []


def _reinhard_extended(channels: list[Float], white: float | None) -> list[Float]:
    """x (1 + x / w^2) / (1 + x) per channel; w defaults to the largest value of any channel."""
    brightest = channels[0] if len(channels) == 1 else dr.maximum(dr.maximum(channels[0], channels[1]), channels[2])
    w = white_point(brightest, white)
    return [(c + (c / w) * (c / w)) / (1.0 + c) for c in channels]


register(TonemapOperator("reinhard_extended", ("white",), _reinhard_extended,
                         "the same curve on each channel; w defaults to the largest value", order=20))
