"""``aces``: K. Narkowicz's fit of the ACES filmic curve (2016)."""

from __future__ import annotations

from drjit.llvm.ad import Float

from pointillist.imaging.tone.operators._registry import TonemapOperator, register

__all__ = ["ACES_CONSTANTS"]

#: The constants of Krzysztof Narkowicz's "ACES Filmic Tone Mapping Curve" (2016): x (a x + b) / (x (c x + d) + e).
ACES_CONSTANTS = {"a": 2.51, "b": 0.03, "c": 2.43, "d": 0.59, "e": 0.14}


def _aces(channels: list[Float], white: float | None) -> list[Float]:
    """x (a x + b) / (x (c x + d) + e) per channel."""
    k = ACES_CONSTANTS
    return [(c * (k["a"] * c + k["b"])) / (c * (k["c"] * c + k["d"]) + k["e"]) for c in channels]


register(TonemapOperator("aces", (), _aces, "Narkowicz's fit of the ACES filmic curve (ACES_CONSTANTS)", order=40))
