"""Contrast stretching, histograms, histogram equalisation and the dynamic range."""

from __future__ import annotations

import sys
from typing import Any

import drjit as dr
import numpy as np
from drjit.llvm.ad import Array3f, Float, UInt8, UInt32

from pointillist.core import checks
from pointillist.imaging.arrays import (TensorXf, TensorXu8, as_tensor, check_shape, eager_if_shared, is_uint8,
                                        opaque_scalar, refuse_gradients, to_uint8, uint8_array)
from pointillist.imaging.colour import hsv_from_rgb_values, rgb_from_hsv_values
from pointillist.imaging.tone._shared import (_done, _finish, _levels, _look_up_bytes, _pointwise, _positive, _sanitize,
                                              _white)

__all__ = ["contrast_stretch", "histogram", "equalize_histogram", "dynamic_range"]


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
    drjit.llvm.ad.TensorXf or drjit.llvm.ad.TensorXu8
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
    (so r1 = r2 = r, s1 = 0, s2 = max is the conventional threshold at r). Through
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
    refuse_gradients(image, "a histogram")
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
    """Histogram equalisation (:ref:`conventions-equalisation`): F(i) = max(0, round(L t(i) / (h w)) - 1).

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
    drjit.llvm.ad.TensorXf or drjit.llvm.ad.TensorXu8
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
    (the formula of :ref:`conventions-equalisation`; OpenCV leaves such images unchanged). An image using
    every level equally is unchanged (its histogram is already flat). NaN -> 0,
    +inf -> white with a :class:`NonFiniteWarning`.

    The darkest level present does not map to 0: it maps to round(L t / (h w)) - 1 with t its
    own share of the pixels, where ``cv2.equalizeHist`` stretches the cumulative histogram so
    that it maps to 0 ((cdf - cdf_min) / (h w - cdf_min)). Measured on a 100x100 image with
    10 % black pixels (the rest uniform in 1..255): black becomes 25 here and 0 in OpenCV, and
    no level differs by more than those 25. Both are histogram equalisation; this is the conventions' one.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.tone import equalize_histogram
    >>> np.asarray(equalize_histogram(np.array([[0, 0, 0, 255]], np.uint8))).tolist()
    [[191, 191, 191, 255]]
    """
    refuse_gradients(image, "equalize_histogram")
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
