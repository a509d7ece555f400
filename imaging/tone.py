"""Tone operations: gamma, contrast stretching, histogram equalisation, quantisation,
look-up tables and HDR tone mapping (SPEC "Imaging definitions").

Every function takes a numpy array or a Dr.Jit tensor of shape (H, W) or
(H, W, C) and returns a ``drjit.llvm.TensorXf`` (``np.asarray`` gives numpy).
The display-domain operations work on intensities 0 to ``max_value`` (255 by
default); :func:`tonemap` turns linear HDR renders into such intensities.

8-bit in, 8-bit out (as OpenCV and Pillow do): for 8-bit input (a numpy ``uint8``
array or a ``drjit.llvm.TensorXu8``), :func:`gamma`, :func:`contrast_stretch`,
:func:`quantize`, :func:`lut` and :func:`equalize_histogram` return a
``drjit.llvm.TensorXu8`` (``np.asarray`` gives uint8) holding the float32 result
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

Parameters are checked for the float32 computation (:func:`pointillist.checks.real`): every
real parameter must be finite in float32 (``|x| <= 3.4e38``, a value > 0 must stay > 0 there),
and so must what is derived from it: gamma's scale 1 / (a max_value), the stretch's slopes,
(levels - 1) / max_value and max_value (levels - 1); a ValueError names the parameter.
"""

from __future__ import annotations

import sys
from typing import Any, Callable

import drjit as dr
import numpy as np
from drjit.llvm import Array3f, Float, UInt8, UInt32

from pointillist import checks
from pointillist.imaging.arrays import (NonFiniteWarning, TensorXf, TensorXu8, as_tensor, check_shape, eager_if_shared,
                                        is_uint8, opaque_scalar, replace_non_finite, to_uint8, uint8_array,
                                        warn_non_finite)
from pointillist.imaging.colour import (REC709_LUMINANCE_WEIGHTS, hsv_from_rgb_values, rgb_from_hsv_values,
                                        srgb_encode_values)

__all__ = [
    "NonFiniteWarning",
    "TONEMAP_OPERATORS",
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

#: Hable's filmic curve (J. Hable, "Uncharted 2: HDR Lighting", GDC 2010): shoulder strength A,
#: linear strength B, linear angle C, toe strength D, toe numerator E, toe denominator F,
#: linear white point W, and the exposure bias applied before the curve.
HABLE_CONSTANTS = {"A": 0.15, "B": 0.50, "C": 0.10, "D": 0.20, "E": 0.02, "F": 0.30,
                   "W": 11.2, "exposure_bias": 2.0}

#: K. Narkowicz, "ACES Filmic Tone Mapping Curve" (2016): x (a x + b) / (x (c x + d) + e).
ACES_CONSTANTS = {"a": 2.51, "b": 0.03, "c": 2.43, "d": 0.59, "e": 0.14}

#: Tone-mapping operators and the extra keyword parameters each accepts.
TONEMAP_OPERATORS: dict[str, tuple[str, ...]] = {
    "clip": (),
    "reinhard": ("white",),
    "reinhard_extended": ("white",),
    "hable": ("white",),
    "aces": (),
    "log": ("white",),
}

#: The smallest default white point: float32's smallest normal number (an all-black image).
_TINY = float(np.finfo(np.float32).tiny)

#: Linear values are clamped here after exposure: every operator is saturated far below, and
#: the curves' squares stay finite in float32.
_HDR_MAX = 1e15




# --------------------------------------------------------------------------- argument checks

def _positive(value: Any, name: str) -> float:
    """A real > 0 that float32 holds (:func:`pointillist.checks.real`)."""
    return checks.real(value, name, low=0.0, low_open=True)


def _levels(value: Any, name: str = "levels", high: int = 1 << 24) -> int:
    return checks.integer(value, name, low=2, high=high)


def _white(max_value: Any, levels: int) -> float:
    """``max_value`` checked with the two scales a ``levels``-step operation derives from it:
    (levels - 1) / max_value (value -> level) and max_value x (levels - 1), both finite in float32."""
    max_value = _positive(max_value, "max_value")
    checks.float32_finite((levels - 1) / max_value, "max_value", f"(levels - 1) / max_value with {levels} levels")
    checks.float32_finite((levels - 1) * max_value, "max_value", f"max_value x (levels - 1) with {levels} levels")
    return max_value


# --------------------------------------------------------------------------- shared machinery

def _u8_indices(image: Any, name: str = "image") -> tuple[UInt32, tuple[int, ...]]:
    """Per-pixel UInt32 values of a uint8 image, read in place (no float conversion, no gather).

    The bytes are shared with Dr.Jit as a ``UInt8`` array (zero copy for C-contiguous input)
    and widened inside the consuming kernel, so reading them costs no pass of its own.
    Returns ``(values, shape)``.
    """
    image = uint8_array(image, name)
    return UInt32(UInt8(image.reshape(-1))), tuple(image.shape)


def _sanitize(values: Float, white: float | Float) -> tuple[Float, UInt32]:
    """NaN -> 0, +inf -> ``white``, -inf -> 0; also returns a counter of the replaced values."""
    return replace_non_finite(values, white)


def _done(result: TensorXf | TensorXu8) -> TensorXf | TensorXu8:
    """Evaluate ``result`` and wait for it: uint8 input is read in place, so the kernel must have
    finished before the caller may change or free the array."""
    dr.eval(result)
    dr.sync_thread()
    return result


def _finish(result: TensorXf | TensorXu8, count: UInt32, where: str) -> TensorXf | TensorXu8:
    """Evaluate ``result`` together with the non-finite counter and warn with the count."""
    return warn_non_finite(result, count, where, stacklevel=4)


def _look_up_bytes(table: UInt32, index: UInt32) -> UInt8:
    """``table[index]`` for a table of byte values held as UInt32: gathered as 32-bit words, then
    narrowed (LLVM scalarises a gather of bytes: about 4x slower than the 32-bit hardware gather)."""
    return UInt8(dr.gather(UInt32, table, index))


#: Evaluated uint8 tables of the point operations, by curve (:func:`_curve_key`): a repeated call
#: with the same parameters launches one kernel (the look-up), as ``cv2.LUT`` with a prepared table.
_BYTE_TABLES: dict[tuple, UInt32] = {}


def _curve_key(function: Callable[[Float], Float]) -> tuple | None:
    """What determines a curve: its code and the values it captures (Python scalars, and the
    one-element opaque Dr.Jit scalars by value, floats by their bits), or None (not cached) when
    it captures anything else."""
    values = []
    for cell in function.__closure__ or ():
        value = cell.cell_contents
        if dr.is_array_v(value) and dr.width(value) == 1:
            value = (type(value).__name__, value.numpy()[0].item())
        elif not isinstance(value, (bool, int, float, str)):
            return None
        values.append(value.hex() if isinstance(value, float) else
                      (value[0], value[1].hex()) if isinstance(value, tuple) and isinstance(value[1], float)
                      else value)
    return function.__code__, tuple(values)


def _pointwise(image: Any, function: Callable[[Float], Float], max_value: float,
               where: str) -> TensorXf | TensorXu8:
    """Apply ``function`` per value; uint8 input through a 256-entry table of the same function,
    rounded to uint8 (:func:`~pointillist.imaging.arrays.to_uint8`), giving uint8 output (the
    table is cached by :func:`_curve_key`)."""
    if is_uint8(image):
        key = _curve_key(function)
        table = _BYTE_TABLES.get(key) if key is not None else None
        if table is None:
            table = UInt32(to_uint8(function(dr.arange(Float, 256))))
            dr.eval(table)
            if key is not None:
                if len(_BYTE_TABLES) >= 64:
                    _BYTE_TABLES.clear()
                _BYTE_TABLES[key] = table
        values, shape = _u8_indices(image)
        return _done(TensorXu8(_look_up_bytes(table, values), shape))
    tensor = as_tensor(image)
    clean, count = _sanitize(tensor.array, max_value)
    return _finish(TensorXf(function(clean), tensor.shape), count, where)


# --------------------------------------------------------------------------- operations

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
        > 0, the normalising constant of the SPEC formula (1: ``max_value`` maps to itself).
    max_value : float
        > 0, the intensity of white (255).

    Returns
    -------
    drjit.llvm.TensorXf or drjit.llvm.TensorXu8
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
def contrast_stretch(image: Any, r1: float, s1: float, r2: float, s2: float, *,
                     max_value: float = 255.0) -> TensorXf | TensorXu8:
    """Piecewise-linear contrast stretching through (0, 0), (r1, s1), (r2, s2), (max, max).

    out = s1/r1 in for in < r1; (s2 - s1)/(r2 - r1) (in - r1) + s1 for r1 <= in <= r2;
    (max - s2)/(max - r2) (in - r2) + s2 for in > r2.

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
        Intensities; clipped to 0 to ``max_value`` first. ``uint8`` input goes through a table.
    r1, r2 : float
        Input breakpoints, 0 <= r1 <= r2 <= max_value.
    s1, s2 : float
        Output values at the breakpoints, each in 0..max_value (s1 > s2 inverts the middle).
    max_value : float
        > 0, the intensity of white.

    Returns
    -------
    drjit.llvm.TensorXf or drjit.llvm.TensorXu8
        Same shape, values in 0..max_value; uint8 (rounded) for uint8 input.

    Raises
    ------
    ValueError
        If a breakpoint is outside 0..max_value or r1 > r2.

    Notes
    -----
    Degenerate breakpoints never divide by zero: r1 = 0 drops the first segment,
    r2 = max drops the last; r1 = r2 = r drops the middle one, making a step:
    values below r follow the first segment, values at or above r the last
    (so r1 = r2 = r, s1 = 0, s2 = max is the SPEC threshold at r). Through
    (r1, r1) and (r2, r2) the stretch is the identity. NaN -> 0, +inf -> white
    with a :class:`NonFiniteWarning`.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.tone import contrast_stretch
    >>> np.asarray(contrast_stretch(np.array([[0, 50, 100, 150, 255]]), 50, 25, 150, 230)).tolist()
    [[0.0, 25.0, 127.5, 230.0, 255.0]]
    """
    max_value = _positive(max_value, "max_value")
    r1, s1, r2, s2 = (checks.real(v, n, low=0.0, high=max_value)
                      for v, n in ((r1, "r1"), (s1, "s1"), (r2, "r2"), (s2, "s2")))
    if r1 > r2:
        raise ValueError(f"r1: expected r1 <= r2, got r1 = {r1:g} > r2 = {r2:g}")
    slope1 = checks.float32_finite(s1 / r1 if r1 > 0 else 0.0, "r1", "the slope s1 / r1")
    slope2 = checks.float32_finite((s2 - s1) / (r2 - r1) if r2 > r1 else 0.0, "r2",
                                   "the slope (s2 - s1) / (r2 - r1)")
    slope3 = checks.float32_finite((max_value - s2) / (max_value - r2) if r2 < max_value else 0.0, "r2",
                                   "the slope (max_value - s2) / (max_value - r2)")
    # With r1 == r2 the middle segment is empty: its upper bound sits just below r1.
    upper = r2 if r2 > r1 else float(np.nextafter(np.float32(r1), np.float32(-np.inf)))
    k1, k2, k3 = opaque_scalar(Float, slope1), opaque_scalar(Float, slope2), opaque_scalar(Float, slope3)
    b1, b2, top = opaque_scalar(Float, r1), opaque_scalar(Float, r2), opaque_scalar(Float, max_value)
    o1, o2, mid_top = opaque_scalar(Float, s1), opaque_scalar(Float, s2), opaque_scalar(Float, upper)

    def curve(x: Float) -> Float:
        x = dr.clip(x, 0.0, top)
        return dr.select(x < b1, k1 * x,
                         dr.select(x <= mid_top, k2 * (x - b1) + o1, k3 * (x - b2) + o2))

    return _pointwise(image, curve, max_value, "contrast_stretch")


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
    drjit.llvm.TensorXf or drjit.llvm.TensorXu8
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
    drjit.llvm.TensorXf or drjit.llvm.TensorXu8
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
_PAIR_LEVELS = 256


#: Lanes of a Dr.Jit work block on the LLVM backend once a kernel has more than 2 x 16384 lanes a core:
#: the blocks are then lanes [16384 b, 16384 (b + 1)) and each runs on one thread at a time.
_BLOCK = 16384


def _byte_histogram(words: UInt32, tail: UInt32 | None, region: int = _BLOCK) -> np.ndarray | None:
    """256-bin histogram of bytes packed in ``words`` (+ ``tail``) with plain increments into private
    sub-histograms, or None when that cannot be used (too few words) or was not exact.

    Each work block of :data:`_BLOCK` lanes has its own table, each lane of a 16-wide SIMD packet its own
    column of it (bin-major, so the 16 lanes' counters of one bin share a cache line): a gather, an add
    and a scatter a byte, with no two lanes of a packet and no two threads ever updating the same counter,
    instead of a scatter-add whose lanes must be checked for equal addresses (a 16-step loop a packet).
    The tables are read and written through two Dr.Jit arrays over the same memory. Exactness does not
    rest on the block layout: a lost update (two writers, or a read reordered before a write) can only
    lower the total, so a total other than the byte count rejects the result. ``region``: lanes sharing
    a table (the block size; a test shares one table between threads to see the check refuse).
    """
    cores = max(1, dr.thread_count())
    count = dr.width(words)
    lanes = _BLOCK * max(8, 2 * cores + 1)  # past the regime where Dr.Jit sizes blocks by the core count
    if count < lanes:
        return None
    blocks = -(-lanes // region)
    raw = np.zeros(blocks * 4096 + 16, dtype=np.uint32)
    start = (-raw.ctypes.data % 64) // 4
    memory = raw[start:start + blocks * 4096]
    table_in, table_out = UInt32(memory), UInt32(memory)
    lane = dr.arange(UInt32, lanes)
    base = (lane // region) * 4096 + lane % 16
    total = dr.opaque(UInt32, count)
    stride = dr.opaque(UInt32, lanes)
    rounds = dr.opaque(UInt32, -(-count // lanes))

    def body(k, index):
        ok = index < total
        word = dr.gather(UInt32, words, index, ok)
        for byte in range(4):
            slot = base + ((word >> (8 * byte)) & 0xFF) * 16
            dr.scatter(table_out, dr.gather(UInt32, table_in, slot, ok) + 1, slot, ok)
        return k + 1, index + stride

    dr.while_loop((UInt32(0), UInt32(lane)), lambda k, index: k < rounds, body, mode="symbolic",
                  label="byte_histogram")
    dr.eval(table_out)
    dr.sync_thread()
    hist = memory.reshape(blocks, 256, 16).sum(axis=(0, 2), dtype=np.int64)
    if tail is not None:
        hist += np.bincount(tail.numpy(), minlength=256)[:256]
    expected = 4 * count + (dr.width(tail) if tail is not None else 0)
    return hist if int(hist.sum()) == expected else None


def _histogram_of(bins: UInt8 | UInt32, words: UInt32 | None, tail: UInt32 | None, levels: int) -> np.ndarray:
    """Histogram (``levels`` bins, int64) of the evaluated per-pixel ``bins``.

    For 8-bit bins (``levels`` <= 256) given as packed 32-bit ``words`` (four bins
    each; ``tail`` the 0..3 bins after the last whole word): private sub-histograms
    (:func:`_byte_histogram`) where the image is large enough; else the bins are counted in
    pairs with ``dr.scatter_add``: bytes (0, 1) and (2, 3) of each word index a 65,536-entry
    table, 2 additions for 4 pixels, and the table is summed both ways on the host (one
    read-back of 256 KiB instead of four more kernel launches). Otherwise one addition per
    pixel into ``levels`` bins.
    """
    if words is not None and levels <= _PAIR_LEVELS:
        hist = _byte_histogram(words, tail)
        if hist is not None:
            return hist[:levels]
    if words is None:
        hist = dr.zeros(UInt32, levels)
        dr.scatter_add(hist, 1, UInt32(bins))
        return hist.numpy().astype(np.int64)
    side = _PAIR_LEVELS
    pairs = side * side
    table = dr.zeros(UInt32, pairs + side)
    dr.scatter_add(table, 1, words & 0xFFFF)
    dr.scatter_add(table, 1, words >> 16)
    if tail is not None:
        dr.scatter_add(table, 1, pairs + tail)
    counts = table.numpy().astype(np.int64)
    by_pair = counts[:pairs].reshape(side, side)  # [second byte, first byte]
    hist = by_pair.sum(axis=0) + by_pair.sum(axis=1) + counts[pairs:]
    return hist[:levels]


def _equalization_table(hist: np.ndarray, n: int, levels: int, max_value: float) -> np.ndarray:
    """Output value of each level (float32): F(i) = max(0, round(L t(i) / (h w)) - 1), scaled to max_value.

    round() is half to even, done exactly in integers (on the host: ``levels`` entries).
    """
    t = np.cumsum(hist, dtype=np.uint64)
    numerator = t * np.uint64(levels)
    total = np.uint64(n)
    q = numerator // total
    twice_r = np.uint64(2) * (numerator - q * total)
    q = np.where((twice_r > total) | ((twice_r == total) & (q % np.uint64(2) == 1)), q + np.uint64(1), q)
    f = np.where(q > 0, q.astype(np.float64) - 1.0, 0.0)
    return (f * (max_value / (levels - 1))).astype(np.float32)


def _byte_table(table: np.ndarray) -> UInt32:
    """A float32 look-up table rounded as :func:`~pointillist.imaging.arrays.to_uint8` rounds (clip
    to 0..255, half to even; the table has no NaN), held as UInt32 for :func:`_look_up_bytes`."""
    return UInt32(np.clip(np.rint(table), 0.0, 255.0).astype(np.uint32))


def histogram(image: Any, levels: int = 256, *, max_value: float = 255.0) -> np.ndarray:
    """Histogram of the intensities rounded to ``levels`` bins, as computed by :func:`equalize_histogram`.

    Bin of I: clip(round(I (levels - 1) / max_value), 0, levels - 1); NaN counts in bin 0,
    +inf in the last bin.

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
        Intensities (all channels counted together).
    levels : int
        Number of bins, 2..65536.
    max_value : float
        > 0, the intensity of white.

    Returns
    -------
    numpy.ndarray
        int64 counts, shape (levels,), summing to the number of values.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.tone import histogram
    >>> histogram(np.array([[0, 0, 255]], np.uint8))[[0, 1, 255]].tolist()
    [2, 0, 1]
    """
    levels = _levels(levels, high=65536)
    max_value = _white(max_value, levels)
    bins, words, tail, _, _ = _bins(image, levels, max_value)
    return _histogram_of(bins, words, tail, levels)


def _packed(flat: np.ndarray) -> tuple[UInt32 | None, UInt32 | None]:
    """Contiguous uint8 ``flat`` as (whole UInt32 words, UInt32 tail of 0..3 bins), both zero copy.

    (None, None) when the bytes cannot be viewed as aligned little-endian words.
    """
    whole = flat.size - flat.size % 4
    if whole == 0 or flat.ctypes.data % 4 or sys.byteorder != "little":
        return None, None
    words = UInt32(flat[:whole].view(np.uint32))
    tail = UInt32(flat[whole:].astype(np.uint32)) if whole < flat.size else None
    return words, tail


def _bins(image: Any, levels: int, max_value: float):
    """Per-pixel bins, evaluated: (bins, packed words or None, tail or None, shape, non-finite counter).

    Bin of I: clip(round(I (levels - 1) / max_value), 0, levels - 1). ``uint8`` input with
    levels = 256 and max_value = 255 is its own bins (shared, no pass). Otherwise one
    pass computes them, as ``UInt8`` for levels <= 256 (a quarter of the bytes of float,
    and packed words for the pair histogram) or ``UInt32``.
    """
    if is_uint8(image) and levels == 256 and max_value == 255.0:
        flat = np.ascontiguousarray(image).reshape(-1)
        words, tail = _packed(flat)
        return UInt8(flat), words, tail, tuple(image.shape), None
    tensor = as_tensor(image)
    clean, count = _sanitize(tensor.array, max_value)
    scale, last = opaque_scalar(Float, (levels - 1) / max_value), opaque_scalar(Float, levels - 1)
    index = UInt32(dr.clip(dr.round(clean * scale), 0.0, last))
    if levels > _PAIR_LEVELS:
        dr.eval(index, count)
        return index, None, None, tuple(tensor.shape), count
    bins = UInt8(index)
    dr.eval(bins, count)
    words, tail = _packed(np.asarray(bins))
    return bins, words, tail, tuple(tensor.shape), count


@eager_if_shared
def equalize_histogram(image: Any, levels: int = 256, *, max_value: float = 255.0) -> TensorXf | TensorXu8:
    """Histogram equalisation (SPEC): F(i) = max(0, round(L t(i) / (h w)) - 1).

    t(i) is the cumulative histogram of grey level i, L = ``levels``. Colour
    images are equalised on the V (brightness) channel of HSV, keeping H and S.

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W), (H, W, 1) or (H, W, 3)
        Intensities on 0..max_value, binned as round(I (L - 1) / max_value)
        (for 8-bit data and L = 256, the grey level itself). ``uint8`` grey
        input is read without float conversion.
    levels : int
        Number of grey levels L, 2..65536.
    max_value : float
        > 0, the intensity of white.

    Returns
    -------
    drjit.llvm.TensorXf or drjit.llvm.TensorXu8
        Same shape; level F(i) is output as F(i) max_value / (L - 1); uint8 (rounded) for uint8
        input, as ``cv2.equalizeHist``.

    Raises
    ------
    ValueError
        If ``levels`` is outside 2..65536 or the image has 2 or > 3 channels.

    Notes
    -----
    A constant image (all pixels at level i) maps to L - 1 (white): t(i) = h w.
    A one-pixel image therefore becomes white. All-black becomes white too
    (the SPEC formula; OpenCV leaves such images unchanged). An image using
    every level equally is unchanged (its histogram is already flat). NaN -> 0,
    +inf -> white with a :class:`NonFiniteWarning`.

    The darkest level present does not map to 0: it maps to round(L t / (h w)) - 1 with t its
    own share of the pixels, where ``cv2.equalizeHist`` stretches the cumulative histogram so
    that it maps to 0 ((cdf - cdf_min) / (h w - cdf_min)). Measured on a 100x100 image with
    10 % black pixels (the rest uniform in 1..255): black becomes 25 here and 0 in OpenCV, and
    no level differs by more than those 25. Both are histogram equalisation; this is the SPEC's.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.tone import equalize_histogram
    >>> np.asarray(equalize_histogram(np.array([[0, 0, 0, 255]], np.uint8))).tolist()
    [[191, 191, 191, 255]]
    """
    levels = _levels(levels, high=65536)
    max_value = _white(max_value, levels)
    eight_bit = is_uint8(image)
    if eight_bit:
        image = uint8_array(image)
    if eight_bit and image.ndim == 3 and image.shape[2] == 3:  # bytes widened inside the HSV pass
        flat = image.reshape(-1)
        return _equalize_colour(TensorXf(Float(UInt8(flat)), image.shape), levels, max_value, eight_bit=True)
    if not eight_bit:
        tensor = as_tensor(image, channels=(1, 3))
        if tensor.ndim == 3 and tensor.shape[2] == 3:
            return _equalize_colour(tensor, levels, max_value)
    else:  # uint8 grey (uint8 RGB took the HSV branch above)
        check_shape(image.shape, "image", (1, 3), False)
    bins, words, tail, shape, count = _bins(image, levels, max_value)
    n = dr.width(bins)
    table = _equalization_table(_histogram_of(bins, words, tail, levels), n, levels, max_value)
    if eight_bit:
        return _done(TensorXu8(_look_up_bytes(_byte_table(table), UInt32(bins)), shape))
    result = TensorXf(dr.gather(Float, Float(table), UInt32(bins)), shape)
    if count is None:
        return _done(result)
    return _finish(result, count, "equalize_histogram")


def _equalize_colour(tensor: TensorXf, levels: int, max_value: float,
                     eight_bit: bool = False) -> TensorXf | TensorXu8:
    rgb = dr.unravel(Array3f, tensor.array)
    bad = ~(dr.isfinite(rgb.x) & dr.isfinite(rgb.y) & dr.isfinite(rgb.z))
    count = dr.zeros(UInt32, 1)
    dr.scatter_add(count, 1, UInt32(0), active=bad)
    top = opaque_scalar(Float, max_value)
    channels = [dr.clip(dr.select(dr.isfinite(c), c, dr.select(c > 0, top, 0.0)), 0.0, top)
                for c in (rgb.x, rgb.y, rgb.z)]
    h, s, v = hsv_from_rgb_values(*channels)
    scale, last = opaque_scalar(Float, (levels - 1) / max_value), opaque_scalar(Float, levels - 1)
    index = UInt32(dr.clip(dr.round(v * scale), 0.0, last))
    bins = UInt8(index) if levels <= _PAIR_LEVELS else index
    dr.eval(h, s, bins, count)  # one pass: V itself is not kept, only its bin
    words, tail = _packed(np.asarray(bins)) if levels <= _PAIR_LEVELS else (None, None)
    n = dr.width(bins)
    table = _equalization_table(_histogram_of(bins, words, tail, levels), n, levels, max_value)
    r, g, b = rgb_from_hsv_values(h, s, dr.gather(Float, Float(table), UInt32(bins)))
    values = dr.ravel(Array3f(r, g, b))
    if eight_bit:  # rounded in the same pass
        return _finish(TensorXu8(to_uint8(values), tensor.shape), count, "equalize_histogram")
    return _finish(TensorXf(values, tensor.shape), count, "equalize_histogram")


def _log1p(x: Float) -> Float:
    """log(1 + x) accurate for small x >= 0 (D. Goldberg, "What every computer scientist should
    know about floating-point arithmetic", 1991, thm. 4): log(u) x / (u - 1) with u = 1 + x
    rounded, and x where u rounds to 1. Plain ``log(1 + x)`` is 0 for x < 6e-8 in float32."""
    u = 1.0 + x
    return dr.select(u == 1.0, x, dr.log(u) * (x / (u - 1.0)))


def _luminance(channels: list[Float]) -> Float:
    if len(channels) == 1:
        return channels[0]
    wr, wg, wb = REC709_LUMINANCE_WEIGHTS
    return wr * channels[0] + wg * channels[1] + wb * channels[2]


@eager_if_shared
def tonemap(image: Any, operator: str = "clip", exposure: float = 0.0, **params: Any) -> TensorXf:
    """Tone-map a linear HDR render to display values 0..255 (curve, then the sRGB encoding).

    The image is scaled by 2^exposure, mapped to 0..1 by ``operator``, clipped,
    sRGB-encoded (:func:`imaging.colour.srgb_encode`) and scaled to 0..255.

    Operators (x a linear value, L the Rec. 709 luminance, w the white point):

    - ``clip``: x.
    - ``reinhard``: Reinhard et al. 2002, eq. 4, on luminance:
      L_d = L (1 + L / w^2) / (1 + L), colour scaled by L_d / L; w defaults
      to the image's largest luminance (``white=inf`` gives L / (1 + L)).
    - ``reinhard_extended``: the same curve on each channel; w defaults to the largest value.
    - ``hable``: Hable's filmic curve f(2 x) / f(W), f(x) = (x (A x + C B) + D E) /
      (x (A x + B) + D F) - E / F (:data:`HABLE_CONSTANTS`; ``white`` sets W = 11.2), computed as
      x ((F - E) A x + B (C F - E)) / (F (x (A x + B) + D F)) (the same function without the
      cancellation of its constant terms).
    - ``aces``: Narkowicz's fit of the ACES filmic curve (:data:`ACES_CONSTANTS`).
    - ``log``: logarithmic response L_d = log(1 + L) / log(1 + w) on luminance,
      w defaults to the largest luminance.

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W), (H, W, 1) or (H, W, 3)
        Linear light (an EXR render).
    operator : str
        One of :data:`TONEMAP_OPERATORS`.
    exposure : float
        Stops: the image is multiplied by 2^exposure first; -100..100.
    **params
        ``white`` (> 0) for the operators that take it.

    Returns
    -------
    drjit.llvm.TensorXf
        Same shape, display values in [0, 255] (not rounded).

    Raises
    ------
    ValueError
        Unknown ``operator``, a parameter the operator does not take, a
        non-positive ``white``, or ``exposure`` outside -100..100.

    Notes
    -----
    Negative values become 0; values are clamped at 1e15 after exposure (all
    curves are saturated long before; 1e30 maps to white without overflow).
    NaN -> 0, +inf -> 255, -inf -> 0, with a :class:`NonFiniteWarning` giving
    the count; the default white point ignores them. An all-black image stays
    black. Luminance operators scale colour by L_d / L (hue kept); channels
    above 1 after that are clipped.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.tone import tonemap
    >>> np.asarray(tonemap(np.array([[0.0, 1.0, 3.0]]), "reinhard", white=np.inf), dtype=float).round(2).tolist()
    [[0.0, 187.52, 224.61]]
    """
    if not isinstance(operator, str) or operator not in TONEMAP_OPERATORS:
        raise ValueError(f"operator: expected one of {', '.join(TONEMAP_OPERATORS)}, got {operator!r}")
    exposure = checks.real(exposure, "exposure", low=-100.0, high=100.0)
    unknown = set(params) - set(TONEMAP_OPERATORS[operator])
    if unknown:
        allowed = ", ".join(TONEMAP_OPERATORS[operator]) or "none"
        raise ValueError(f"{sorted(unknown)[0]}: not a parameter of tonemap operator {operator!r} "
                         f"(it takes: {allowed})")
    white = params.get("white")
    if white is not None:
        white = checks.real(white, "white", low=0.0, low_open=True, allow_inf=True)

    tensor = as_tensor(image, channels=(1, 3))
    nch = tensor.shape[2] if tensor.ndim == 3 else 1
    count = dr.zeros(UInt32, 1)
    scale = opaque_scalar(Float, 2.0 ** exposure)

    def prepare(values: Float) -> tuple[Float, Float]:
        """Sanitised, exposed, clamped channel and its +inf mask (counted); per pixel, so that
        the whole operator is one pass over the (H, W, 3) data, not one per step."""
        bad = ~dr.isfinite(values)
        dr.scatter_add(count, 1, UInt32(0), active=bad)
        return dr.clip(dr.select(bad, 0.0, values) * scale, 0.0, _HDR_MAX), bad & (values > 0)

    if nch == 3:
        rgb = dr.unravel(Array3f, tensor.array)
        prepared = [prepare(c) for c in (rgb.x, rgb.y, rgb.z)]
    else:
        prepared = [prepare(tensor.array)]
    channels = [c for c, _ in prepared]
    posinf = [p for _, p in prepared]

    def white_point(values: Float) -> Float:
        if white is not None:
            return opaque_scalar(Float, min(white, _HDR_MAX))
        return dr.maximum(dr.max(values), _TINY)  # its own reduction pass

    if operator == "clip":
        mapped = channels
    elif operator in ("reinhard", "log"):
        lum = _luminance(channels)
        w = white_point(lum)
        if operator == "reinhard":
            # L (1 + L / w^2) / (1 + L) as (L + (L / w)^2) / (1 + L): 1 / w^2 overflows for w < 1e-19
            relative = lum / w  # w = inf -> 0
            mapped_l = (lum + relative * relative) / (1.0 + lum)
        else:
            mapped_l = _log1p(lum) / _log1p(w)
        ratio = dr.select(lum > 0.0, mapped_l / lum, 0.0)
        mapped = [c * ratio for c in channels]
    elif operator == "reinhard_extended":
        w = white_point(channels[0] if nch == 1 else dr.maximum(dr.maximum(channels[0], channels[1]), channels[2]))
        mapped = [(c + (c / w) * (c / w)) / (1.0 + c) for c in channels]
    elif operator == "hable":
        k = HABLE_CONSTANTS
        A, B, C, D, E, F = (k[n] for n in "ABCDEF")

        def f(v):
            # Hable's f with its two terms over one denominator: the constant terms D E / (D F) and
            # E / F cancel exactly, so small values keep their precision (the plain difference is
            # 0 below about 1e-16 in float64 and 1e-8 in float32)
            return v * ((F - E) * A * v + B * (C * F - E)) / (F * (v * (A * v + B) + D * F))

        w = white if white is not None else k["W"]
        norm = opaque_scalar(Float, checks.float32_finite(1.0 / float(f(np.float64(min(w, _HDR_MAX)))), "white",
                                                          "hable's normalisation 1 / f(white)"))
        mapped = [f(k["exposure_bias"] * c) * norm for c in channels]
    else:  # aces
        k = ACES_CONSTANTS
        mapped = [(c * (k["a"] * c + k["b"])) / (c * (k["c"] * c + k["d"]) + k["e"]) for c in channels]

    display = [dr.select(inf, 255.0, srgb_encode_values(dr.clip(m, 0.0, 1.0)) * 255.0)
               for m, inf in zip(mapped, posinf)]
    values = dr.ravel(Array3f(*display)) if nch == 3 else display[0]
    return _finish(TensorXf(values, tensor.shape), count, "tonemap")


def dynamic_range(image: Any) -> float:
    """The dynamic range: the span max - min of the finite values (0 for a constant image).

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.tone import dynamic_range
    >>> dynamic_range(np.array([[10, 200], [30, 40]]))
    190.0
    """
    tensor = as_tensor(image)
    finite = dr.isfinite(tensor.array)
    if not dr.any(finite):
        raise ValueError("image: has no finite values")
    low = dr.min(dr.select(finite, tensor.array, np.inf))
    high = dr.max(dr.select(finite, tensor.array, -np.inf))
    return float(high[0] - low[0])
