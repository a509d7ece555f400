"""Point curves and look-up tables: gamma, quantisation, a LUT (8-bit in, 8-bit out)."""

from __future__ import annotations

from typing import Any

import drjit as dr
import numpy as np
from drjit.llvm.ad import Float, UInt32

from pointillist.core import checks
from pointillist.imaging.arrays import (TensorXf, TensorXu8, as_tensor, eager_if_shared, is_uint8, opaque_scalar,
                                        refuse_gradients)
from pointillist.imaging.tone._shared import (_done, _finish, _levels, _look_up_bytes, _pointwise, _positive, _sanitize,
                                              _u8_indices, _white)

__all__ = ["gamma", "quantize", "QUANTIZE_MODES", "lut"]


@eager_if_shared
def gamma(image: Any, gamma: float, a: float = 1.0, max_value: float = 255.0) -> TensorXf | TensorXu8:
    """Gamma correction V = (I / a)^(1/gamma) on intensities normalised to 0..1.

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
        Intensities on 0 to ``max_value``. ``uint8`` input goes through a 256-entry table.
    gamma : float
        > 0. gamma < 1 darkens (encoding), gamma > 1 lightens (decoding), 1 is the identity.
    a : float
        > 0, the normalising constant of the formula of :ref:`conventions-tone` (1: ``max_value`` maps to itself).
    max_value : float
        > 0, the intensity of white (255).

    Returns
    -------
    drjit.llvm.ad.TensorXf or drjit.llvm.ad.TensorXu8
        ``max_value * (I / max_value / a)^(1/gamma)``, same shape; uint8 (rounded) for uint8 input.

    Raises
    ------
    ValueError
        If ``gamma``, ``a`` or ``max_value`` is not a finite number > 0.

    Notes
    -----
    Edges: 0 stays 0 and white stays white for every gamma (a = 1). gamma -> 0
    (e.g. 1e-3) sends everything below white to 0; a huge gamma (1e3) sends
    everything above 0 to almost white. Negative input is clipped to 0;
    values above ``max_value`` follow the same power curve. NaN -> 0,
    +inf -> white with a :class:`NonFiniteWarning`.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.tone import gamma
    >>> np.asarray(gamma(np.array([[0.0, 63.75, 255.0]]), 0.5), dtype=float).round(3).tolist()
    [[0.0, 15.938, 255.0]]
    """
    # The kernel sees 1 / gamma, never gamma: beyond float32 (gamma < 3e-39 or > 3e38) the exponent
    # rounds to inf or 0, the limits of the curve, which it handles (see `curve`).
    g = checks.real(gamma, "gamma", low=0.0, low_open=True, float32=False)
    a = _positive(a, "a")
    max_value = _positive(max_value, "max_value")
    scale = checks.float32_finite(1.0 / (a * max_value), "a", "the scale 1 / (a max_value)")
    scale, exponent = opaque_scalar(Float, scale), opaque_scalar(Float, 1.0 / g)
    top = opaque_scalar(Float, max_value)

    def curve(x: Float) -> Float:
        v = dr.maximum(x, 0.0) * scale
        # 0 and 1 are fixed points for every exponent: dr.power gives NaN for 0^0 and 1^inf,
        # which a gamma beyond float32's range (1/gamma = 0 or inf) would otherwise produce.
        return top * dr.select((v == 0.0) | (v == 1.0), v, dr.power(v, exponent))

    return _pointwise(image, curve, max_value, "gamma")



@eager_if_shared
def quantize(image: Any, levels: int, *, max_value: float = 255.0, mode: str = "nearest") -> TensorXf | TensorXu8:
    """Quantise to ``levels`` evenly spaced grey levels spanning 0..max_value.

    The levels are ``k * max_value / (levels - 1)``, k = 0..levels-1. Two ways to pick one:

    - ``mode="nearest"`` (default, the course's): the level nearest to I,
      ``k = floor(I * (levels - 1) / max_value + 0.5)`` (a tie goes up);
    - ``mode="bins"``: 0..max_value cut into ``levels`` equal-width bins, bin k giving level k,
      ``k = min(floor(I * levels / max_value), levels - 1)`` (at 4 levels on 0..255, 42 of the
      256 inputs get another level than the nearest one, up to 63 away instead of 42).

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
        Intensities; clipped to 0..max_value. ``uint8`` input goes through a table.
    levels : int
        Number of output levels, 2..2^24 (256 on 0..255 integers is the identity).
    max_value : float
        > 0, the intensity of white.
    mode : {"nearest", "bins"}
        How a value picks its level (above).

    Returns
    -------
    drjit.llvm.ad.TensorXf or drjit.llvm.ad.TensorXu8
        Same shape, at most ``levels`` distinct values, always including 0 and
        max_value when the input reaches them; uint8 (rounded: levels=3 gives 0, 128, 255)
        for uint8 input.

    Raises
    ------
    ValueError
        If ``levels`` < 2 or ``mode`` is unknown.

    Notes
    -----
    levels = 2 is a threshold at max_value / 2 in both modes. A constant image stays one
    level. NaN -> 0, +inf -> white with a :class:`NonFiniteWarning`.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.tone import quantize
    >>> np.asarray(quantize(np.array([[0, 42, 43, 127, 128, 255]]), 4)).tolist()
    [[0.0, 0.0, 85.0, 85.0, 170.0, 255.0]]
    >>> np.asarray(quantize(np.array([[0, 42, 43, 127, 128, 255]]), 4, mode="bins")).tolist()
    [[0.0, 0.0, 0.0, 85.0, 170.0, 255.0]]
    """
    refuse_gradients(image, "quantize")
    levels = _levels(levels)
    max_value = _white(max_value, levels)
    mode = checks.choice(mode, "mode", QUANTIZE_MODES)
    top = opaque_scalar(Float, max_value)
    last = opaque_scalar(Float, levels - 1)
    if mode == "bins":
        n = opaque_scalar(Float, levels)

        def curve(x: Float) -> Float:
            k = dr.minimum(dr.floor(dr.maximum(x, 0.0) * n / top), last)
            return k * top / last  # not k * step: the top level must be max_value exactly (21 * (255 / 21) > 255)
    else:
        def curve(x: Float) -> Float:
            k = dr.floor(dr.minimum(dr.maximum(x, 0.0), top) * last / top + 0.5)
            return k * top / last

    return _pointwise(image, curve, max_value, "quantize")


#: The two rules of :func:`quantize`: the nearest level (the course's, default) or equal-width bins.
QUANTIZE_MODES = ("nearest", "bins")


def _table(table: Any, channels: int, eight_bit: bool = False) -> tuple[Float | UInt32, int]:
    """The checked table as float32 values, or with ``eight_bit`` as their uint8 rounding held in
    UInt32 (numpy's rint of the float32 values = :func:`~pointillist.imaging.arrays.to_uint8`, no kernel)."""
    values = checks.real_array(table, "table")
    if values.ndim == 2 and values.shape[1] == 1:
        values = values[:, 0]
    if values.shape != (256,) and values.shape != (256, channels):
        allowed = "(256,)" + (f" or (256, {channels})" if channels > 1 else "")
        raise ValueError(f"table: expected shape {allowed}, got {values.shape}")
    width = 1 if values.ndim == 1 else channels
    values = np.ascontiguousarray(values, dtype=np.float32).reshape(-1)
    if eight_bit:
        return UInt32(np.rint(np.clip(values, 0, 255)).astype(np.uint32)), width
    return Float(values), width


@eager_if_shared
def lut(image: Any, table: Any) -> TensorXf | TensorXu8:
    """Apply a 256-entry look-up table to 8-bit data: out = table[I].

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
        8-bit intensities. ``uint8`` arrays are read as they are (no float
        conversion); other input is rounded to the nearest integer (half to
        even) and clipped to 0..255.
    table : array_like, (256,) or (256, C)
        The value of each input level; (256, C) gives one table per channel (as ``cv2.LUT``).

    Returns
    -------
    drjit.llvm.ad.TensorXf or drjit.llvm.ad.TensorXu8
        Same shape as ``image``: float32 table values, or for uint8 input (as ``cv2.LUT`` with a
        uint8 table) uint8, the table values rounded half to even and clipped to 0..255.

    Raises
    ------
    ValueError
        If ``table`` has another shape or non-finite entries.

    Notes
    -----
    NaN reads entry 0, +inf entry 255, with a :class:`NonFiniteWarning`.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.tone import lut
    >>> np.asarray(lut(np.array([[0, 1, 255]], np.uint8), 255 - np.arange(256))).tolist()
    [[255, 254, 0]]
    >>> np.asarray(lut(np.array([[0.0, 1.0, 255.0]]), 255 - np.arange(256))).tolist()
    [[255.0, 254.0, 0.0]]
    """
    refuse_gradients(image, "lut")
    if is_uint8(image):
        values, shape = _u8_indices(image)
        channels = shape[2] if len(shape) == 3 else 1
        table, width = _table(table, channels, eight_bit=True)
        index = values if width == 1 else values * width + dr.arange(UInt32, dr.width(values)) % width
        return _done(TensorXu8(_look_up_bytes(table, index), shape))
    tensor = as_tensor(image)
    channels = tensor.shape[2] if tensor.ndim == 3 else 1
    table, width = _table(table, channels)
    clean, count = _sanitize(tensor.array, 255.0)
    values = UInt32(dr.clip(dr.round(clean), 0.0, 255.0))
    index = values if width == 1 else values * width + dr.arange(UInt32, dr.width(values)) % width
    return _finish(TensorXf(dr.gather(Float, table, index), tensor.shape), count, "lut")


#: Pixels are counted in pairs: two 8-bit bins make one index of a 256 x 256 table.
