"""Helpers shared by pointillist's Python BSDFs (``lambert``, ``phong``).

Not a plugin (the leading underscore keeps :func:`plugins.register` away). The
property readers are in :mod:`pointillist.plugins.properties`.
Imported after the Mitsuba variant is set.
"""

from __future__ import annotations

import math

import drjit as dr

__all__ = ["texture_range", "safe_power"]


def texture_range(texture) -> float:
    """Largest value a texture can return (``Texture.max()``), or ``inf`` if unknown."""
    try:
        return float(texture.max())
    except Exception:  # a texture without max(): no bound known
        return math.inf


def safe_power(x, n):
    """``x ** n`` for ``x >= 0`` and ``n >= 0`` without NaN: ``0 ** n`` is 0 for every ``n``
    (also ``n = 0``: the measure-zero point where a Phong lobe meets its horizon)."""
    positive = x > 0
    return dr.select(positive, dr.power(dr.select(positive, x, 1.0), n), 0.0)
