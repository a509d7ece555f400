"""``clip``: the exposed linear value itself, clipped to 0..1 (then sRGB-encoded)."""

from __future__ import annotations

from drjit.llvm.ad import Float

from pointillist.imaging.tone.operators._registry import TonemapOperator, register

__all__: list[str] = []


def _clip(channels: list[Float], white: float | None) -> list[Float]:
    """x."""
    return channels


register(TonemapOperator("clip", (), _clip, "x", order=0))
