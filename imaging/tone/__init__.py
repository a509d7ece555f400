"""Tone operations: gamma, contrast stretching, histogram equalisation, quantisation,
look-up tables and HDR tone mapping (:ref:`conventions-tone`).

Every function takes a numpy array or a Dr.Jit tensor of shape (H, W) or
(H, W, C) and returns a ``drjit.llvm.ad.TensorXf`` (``np.asarray`` gives numpy).
The display-domain operations work on intensities 0 to ``max_value`` (255 by
default); :func:`tonemap` turns linear HDR renders into such intensities.

8-bit in, 8-bit out (as OpenCV and Pillow do): for 8-bit input (a numpy ``uint8``
array or a ``drjit.llvm.ad.TensorXu8``), :func:`gamma`, :func:`contrast_stretch`,
:func:`quantize`, :func:`lut` and :func:`equalize_histogram` return a
``drjit.llvm.ad.TensorXu8`` (``np.asarray`` gives uint8) holding the float32 result
rounded as the 8-bit writers round it (clipped to 0..255, half to even:
:func:`pointillist.imaging.arrays.to_uint8`); float input keeps float32 output. Pass
``image.astype(np.float32)`` for unrounded float output. 8-bit input is served by a
256-entry table computed with the same formula, read without converting the image
to float first.

Notes
-----
Non-finite input (the policy of every function here): NaN becomes 0, +inf
becomes white (``max_value``; 255 after :func:`tonemap`), -inf becomes 0, and a
:class:`NonFiniteWarning` reports how many values were replaced.

======================  ==============================  ====================================  ============
Function                Domain                          Range                                 uint8 input
======================  ==============================  ====================================  ============
``gamma``               [0, max_value]; < 0 -> 0        [0, max_value] (a = 1)                uint8 out
``contrast_stretch``    clipped to [0, max_value]       [0, max_value]                        uint8 out
``equalize_histogram``  rounded to ``levels`` bins      ``levels`` values in [0, max_value]   uint8 out
``quantize``            clipped to [0, max_value]       ``levels`` values in [0, max_value]   uint8 out
``lut``                 rounded, clipped to 0..255      the table's values                    uint8 out
``tonemap``             linear >= 0 (< 0 -> 0, clamped  display values [0, 255]               float32 out
                        at 1e15 after exposure)
======================  ==============================  ====================================  ============

"uint8 out": the float32 result rounded half to even and clipped to 0..255, as
:func:`pointillist.imaging.io.to_8bit` writes it (so a table value 254.6 reads 255).

Parameters are checked for the float32 computation (:func:`pointillist.core.checks.real`): every
real parameter must be finite in float32 (``|x| <= 3.4e38``, a value > 0 must stay > 0 there),
and so must what is derived from it: gamma's scale 1 / (a max_value), the stretch's slopes,
(levels - 1) / max_value and max_value (levels - 1); a ValueError names the parameter.
"""

from __future__ import annotations

from pointillist.imaging.arrays import NonFiniteWarning
from pointillist.imaging.tone.curves import QUANTIZE_MODES, gamma, lut, quantize
from pointillist.imaging.tone.equalisation import contrast_stretch, dynamic_range, equalize_histogram, histogram
from pointillist.imaging.tone.operators import (ACES_CONSTANTS, HABLE_CONSTANTS, TONEMAP_OPERATORS, TONEMAP_TABLE,
                                                TonemapOperator, tonemap)

__all__ = [
    "NonFiniteWarning",
    "TONEMAP_OPERATORS",
    "TONEMAP_TABLE",
    "TonemapOperator",
    "HABLE_CONSTANTS",
    "ACES_CONSTANTS",
    "gamma",
    "contrast_stretch",
    "equalize_histogram",
    "histogram",
    "quantize",
    "QUANTIZE_MODES",
    "lut",
    "tonemap",
    "dynamic_range",
]
