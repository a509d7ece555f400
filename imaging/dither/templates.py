"""Ordered dithering, patterning and halftoning by threshold templates (Bayer, clustered dot,
blue noise)."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Any

import drjit as dr
import numpy as np
from drjit.llvm.ad import Float, Float64, UInt8, UInt32

from pointillist.core import checks
from pointillist.imaging.arrays import (TensorXf, TensorXu8, as_tensor, divmod_u32, eager_if_shared, is_uint8,
                                        opaque_scalar, refuse_gradients)
from pointillist.imaging.dither._shared import (_check_bool, _check_levels, _check_template, _levels_1bit, _pixels,
                                                _result, _srgb_decode_255)
from pointillist.imaging.wavefront import clip_intensity

__all__ = ["TEMPLATE_4", "bayer", "clustered_dot", "intensity_thresholds", "ordered", "pattern",
           "halftone", "blue_noise_mask", "blue_noise"]

#: The conventions' 4 x 4 template (= ``bayer(4)``): a pixel is white where p >= its entry.
TEMPLATE_4: np.ndarray = np.array([[1, 9, 3, 11], [13, 5, 15, 7], [4, 12, 2, 10], [16, 8, 14, 6]], dtype=np.int64)
TEMPLATE_4.setflags(write=False)


_DATA = Path(__file__).resolve().parent.parent / "data"
_BLUE_NOISE_FILE = _DATA / "blue_noise_64.npy"


def bayer(n: int) -> np.ndarray:
    """The n x n Bayer index matrix (n a power of two), entries 1..n^2 (a template).

    Built by the Bayer recursion on 0-based matrices, M_1 = [[0]] and
    M_2n = [[4 M_n, 4 M_n + 2], [4 M_n + 3, 4 M_n + 1]], plus 1; ``bayer(4)`` is the conventions'
    :data:`TEMPLATE_4`. ``bayer(1)`` is [[1]] (plain thresholding at the middle of 0..255).

    Examples
    --------
    >>> from pointillist.imaging.dither import bayer
    >>> bayer(2).tolist()
    [[1, 3], [4, 2]]
    """
    n = checks.integer(n, "n", low=1, high=4096)
    if n & (n - 1):
        raise ValueError(f"n: expected a power of two from 1 to 4096, got {n!r}")
    m = np.zeros((1, 1), dtype=np.int64)
    while m.shape[0] < n:
        m = np.block([[4 * m, 4 * m + 2], [4 * m + 3, 4 * m + 1]])
    return m + 1


def clustered_dot(n: int) -> np.ndarray:
    """An n x n clustered-dot growth template, entries 1..n^2.

    Pixels are numbered by distance from the pattern's centre (ties by angle, counter-clockwise
    from the right), so the white dot grows outward from the centre as the level rises
    (n = 3: [[8, 5, 9], [4, 1, 2], [7, 3, 6]]); every level-j pattern contains level j - 1's.

    Examples
    --------
    >>> from pointillist.imaging.dither import clustered_dot
    >>> clustered_dot(2).tolist()
    [[3, 4], [2, 1]]
    """
    n = checks.integer(n, "n", low=1, high=256)
    yy, xx = np.mgrid[0:n, 0:n].astype(np.float64)
    c = (n - 1) / 2.0
    dy, dx = yy - c, xx - c
    radius = np.round(np.hypot(dy, dx), 9)
    angle = np.round(np.mod(np.arctan2(dy, dx), 2 * np.pi), 9)
    order = np.lexsort((angle.ravel(), radius.ravel()))
    template = np.empty(n * n, dtype=np.int64)
    template[order] = np.arange(1, n * n + 1)
    return template.reshape(n, n)


def _intensity(image: Any) -> tuple[TensorXf, Float]:
    refuse_gradients(image, "dithering")
    tensor = as_tensor(image)
    return tensor, clip_intensity(tensor.array)


def _ordered_values(values: Float, thresholds: Float, cells: int, levels: int) -> Float:
    """The conventions' ordered rule generalised to ``levels``: p = min(floor(f (n^2+1)), n^2), up where p >= T.

    f is the intensity's position inside its gap between two output levels (0..1); for
    ``levels=2`` that is I / 255 and the rule is exactly the conventions' rule.
    """
    # Written so that every step is exact for integer intensities (products < 2^24, one
    # correctly rounded division whose quotient cannot round across an integer).
    gaps = opaque_scalar(Float, float(levels - 1))
    full = opaque_scalar(Float, 255.0)
    scaled = values * gaps
    base = dr.minimum(dr.floor(scaled / full), gaps - 1.0)
    rest = scaled - base * full
    n2 = opaque_scalar(Float, float(cells))
    p = dr.minimum(dr.floor(rest * (n2 + 1.0) / full), n2)
    up = dr.select(p >= thresholds, 1.0, 0.0)
    return (base + up) * full / gaps


def _coordinates(count: int, width: int, channels: int) -> tuple[UInt32, UInt32]:
    """Row and column of every value of a flat (H, W, C) array of ``count`` values."""
    pixel = divmod_u32(dr.arange(UInt32, count), channels, count)[0]
    return divmod_u32(pixel, width, -(-count // channels))


def _template_index(n: int, y: UInt32, x: UInt32) -> UInt32:
    """Row-major index of the template entry at (y mod n, x mod n) (shifts and masks for 2^k)."""
    if n & (n - 1) == 0:  # powers of two (Bayer, TEMPLATE_4, blue noise): no division
        mask = opaque_scalar(UInt32, n - 1)
        return ((y & mask) << opaque_scalar(UInt32, n.bit_length() - 1)) | (x & mask)
    return divmod_u32(y, n, dr.width(y))[1] * opaque_scalar(UInt32, n) + divmod_u32(x, n, dr.width(x))[1]


def _template_thresholds(template: np.ndarray, y: UInt32, x: UInt32) -> Float:
    n = template.shape[0]
    return dr.gather(Float, _template_table(template.tobytes(), n), _template_index(n, y, x))


@lru_cache(maxsize=32)
def _template_table(data: bytes, n: int) -> Float:
    """The template entries as an evaluated Float table (cached: no copy per call)."""
    table = Float(np.frombuffer(data, dtype=np.int64).astype(np.float32))
    dr.eval(table)
    return table


def intensity_thresholds(template: Any) -> np.ndarray:
    """The conventions' ordered-dithering rule as one threshold per template entry, on 0..255.

    p = min(floor(I (n^2 + 1) / 255), n^2) >= T holds exactly when I (n^2 + 1) >= 255 T (T <= n^2),
    i.e. when I >= 255 T / (n^2 + 1). Returned is, per entry T, the smallest float32 x with
    x (n^2 + 1) >= 255 T in exact arithmetic (products of a float32 and an integer below 2^29 are
    exact in float64), so ``I >= table`` is the conventions' rule for EVERY float32 I, not only integers.
    For 8-bit input it is the same as I >= ceil(255 T / (n^2 + 1)) (OpenCV's pre-tiled map).

    Parameters
    ----------
    template : array_like, (n, n)
        A permutation of 1..n^2.

    Returns
    -------
    numpy.ndarray
        float32, shape (n, n), values in (0, 255).

    Examples
    --------
    >>> from pointillist.imaging.dither import TEMPLATE_4, intensity_thresholds
    >>> intensity_thresholds([[1, 3], [4, 2]]).tolist()  # 255 T / 5
    [[51.0, 153.0], [204.0, 102.0]]
    >>> bool(intensity_thresholds(TEMPLATE_4)[0, 0] == 15.0)  # 255 / 17
    True
    """
    template = _check_template(template)
    return _intensity_thresholds(template.tobytes(), template.shape[0]).reshape(template.shape).copy()


@lru_cache(maxsize=32)
def _intensity_thresholds(data: bytes, n: int) -> np.ndarray:
    template = np.frombuffer(data, dtype=np.int64).astype(np.float64)
    cells = float(n * n + 1)
    target = 255.0 * template  # exact
    x = (target / cells).astype(np.float32)
    up, down = np.float32(np.inf), np.float32(-np.inf)
    while np.any(low := x.astype(np.float64) * cells < target):  # below: step up
        x = np.where(low, np.nextafter(x, up), x)
    while np.any(fits := np.nextafter(x, down).astype(np.float64) * cells >= target):  # not smallest
        x = np.where(fits, np.nextafter(x, down), x)
    return x


@lru_cache(maxsize=32)
def _threshold_table(data: bytes, n: int) -> Float:
    table = Float(_intensity_thresholds(data, n))
    dr.eval(table)
    return table


def _ordered_1bit(values: Float, template: np.ndarray, y: UInt32, x: UInt32) -> Any:
    """1-bit ordered dithering in one pass: the mask of pixels where I >= the entry's intensity threshold.

    No clipping is needed: NaN compares false (black, as NaN -> 0), values above 255 pass every
    threshold (< 255) and values below 0 pass none (> 0), exactly as after clipping.
    """
    n = template.shape[0]
    table = _threshold_table(template.tobytes(), n)
    return values >= dr.gather(Float, table, _template_index(n, y, x))


@eager_if_shared
def ordered(image: Any, template: Any = TEMPLATE_4, *, levels: int = 2, linear: bool = False) -> TensorXf | TensorXu8:
    """Ordered dithering: one p per pixel, compared with the template entry at that pixel.

    As :ref:`conventions-dithering` defines it.

    p = min(floor(I (n^2 + 1)), n^2) with I = intensity / 255; the pixel is white where p >= the
    template number at (y mod n, x mod n).

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
        Intensities on 0..255; NaN -> 0, clipped to 0..255. A numpy ``uint8`` array is read as
        packed bytes (4 per 32-bit word), without a float32 copy.
    template : array_like, (n, n)
        A permutation of 1..n^2 (default the conventions' :data:`TEMPLATE_4`; see :func:`bayer`,
        :func:`clustered_dot`, :func:`blue_noise_mask`). A 1 x 1 template [[1]] is a threshold at
        255 / 2 (p >= 1 for I >= 1/2).
    levels : int
        Output levels (2..256); between two levels the same rule places the pixel.
    linear : bool
        Decode sRGB before comparing (dither linear light).

    Returns
    -------
    drjit.llvm.ad.TensorXf or drjit.llvm.ad.TensorXu8
        Same shape; 0 and 255 (or the ``levels`` values). 0 stays 0 and 255 stays 255. uint8 for
        uint8 input (levels rounded half to even).

    Notes
    -----
    1-bit output (``levels=2``) is one pass over the image: the rule p >= T is turned into
    I >= 255 T / (n^2 + 1) (:func:`intensity_thresholds`, exact for every float32 I), so a pixel
    costs one read, one look-up in an n x n table (the template index from shifts and masks for
    power-of-two templates and widths, else a float reciprocal), one comparison and one write.
    ``levels > 2`` computes p per pixel (exact for integer intensities).

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.dither import ordered
    >>> np.asarray(ordered(np.full((4, 4), 128.0))).astype(int).tolist()[0]
    [255, 0, 255, 0]
    """
    return _ordered(image, _check_template(template), _check_levels(levels), _check_bool(linear, "linear"))


#: Largest pre-tiled threshold map kept (bytes: 16 MiB, e.g. 4096 x 4096 grey; larger images use the per-pixel
#: table), and how many are kept (by template and shape).
_TILED_MAP_BYTES = 1 << 24
_TILED_MAPS = 2


@lru_cache(maxsize=_TILED_MAPS)
def _tiled_map(data: bytes, n: int, shape: tuple[int, ...]) -> UInt8:
    """The template's 8-bit thresholds ceil(255 T / (n^2 + 1)) tiled over an image of ``shape``
    (evaluated, one byte per value): for uint8 I, I >= this is the conventions' rule (see
    :func:`intensity_thresholds`). This is OpenCV's pre-tiled map; reading it is a contiguous
    stream, where the n x n table costs one gather per pixel (about 2x the whole pass here)."""
    channels = shape[2] if len(shape) == 3 else 1
    count = int(np.prod(shape))
    y, x = _coordinates(count, shape[1], channels)
    levels = UInt32(np.ceil(_intensity_thresholds(data, n)).astype(np.uint32))  # exact: see the docstring
    tiled = UInt8(dr.gather(UInt32, levels, _template_index(n, y, x)))
    dr.eval(tiled)
    return tiled


def _ordered(image: Any, template: np.ndarray, levels: int, linear: bool) -> TensorXf | TensorXu8:
    values, shape = _pixels(image)
    eight_bit = isinstance(values, UInt8)
    if eight_bit and levels == 2 and not linear and dr.width(values) <= _TILED_MAP_BYTES:
        # 8-bit, 1 bit: compare the bytes with the cached pre-tiled map (three contiguous streams)
        up = values >= _tiled_map(template.tobytes(), template.shape[0], shape)
        return _levels_1bit(up, shape, True)
    values = Float(values)  # uint8: one byte per value, widened inside the kernel (no float32 copy)
    if linear:
        values = _srgb_decode_255(clip_intensity(values))
    channels = shape[2] if len(shape) == 3 else 1
    n = template.shape[0]
    y, x = _coordinates(dr.width(values), shape[1], channels)
    if levels == 2:
        return _levels_1bit(_ordered_1bit(values, template, y, x), shape, eight_bit)
    if not linear:
        values = clip_intensity(values)
    thresholds = _template_thresholds(template, y, x)
    return _result(_ordered_values(values, thresholds, n * n, levels), shape, eight_bit)


@eager_if_shared
def pattern(image: Any, template: Any = TEMPLATE_4, *, levels: int = 2, linear: bool = False) -> TensorXf | TensorXu8:
    """Pattern dithering (:ref:`conventions-dithering`): one p per n x n block from the block's average intensity.

    Blocks start at the top-left corner; blocks cut by the right or bottom edge average the
    pixels they have. Each block shows the pattern of its p (white where p >= template number).

    Parameters and edges as in :func:`ordered`. A 1 x 1 template thresholds each pixel at
    255 / 2.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.dither import pattern
    >>> np.asarray(pattern(np.array([[0.0, 255.0], [0.0, 255.0]]), [[1, 3], [4, 2]])).astype(int).tolist()
    [[255, 0], [0, 255]]
    """
    template = _check_template(template)
    levels = _check_levels(levels)
    linear = _check_bool(linear, "linear")
    eight_bit = is_uint8(image)
    tensor, values = _intensity(image)
    if linear:
        values = _srgb_decode_255(values)
    shape = tuple(tensor.shape)
    height, width = shape[0], shape[1]
    channels = shape[2] if len(shape) == 3 else 1
    n = template.shape[0]
    by, bx = -(-height // n), -(-width // n)
    y, x = _coordinates(dr.width(values), width, channels)
    c = divmod_u32(dr.arange(UInt32, dr.width(values)), channels, dr.width(values))[1]
    sy, ty = divmod_u32(y, n, height)
    sx, tx = divmod_u32(x, n, width)
    block = (sy * opaque_scalar(UInt32, bx) + sx) * opaque_scalar(UInt32, channels) + c
    sums = dr.zeros(Float64, by * bx * channels)
    dr.scatter_add(sums, Float64(values), block)
    # Pixels per block, cut by the right and bottom edges: min(n, H - n sy) min(n, W - n sx).
    N = opaque_scalar(UInt32, n)
    count = dr.minimum(N, opaque_scalar(UInt32, height) - sy * N) * dr.minimum(N, opaque_scalar(UInt32, width) - sx * N)
    mean = Float(dr.gather(Float64, sums, block) / Float64(count))
    index = ty * N + tx
    if levels == 2:
        up = mean >= dr.gather(Float, _threshold_table(template.tobytes(), n), index)
        return _levels_1bit(up, shape, eight_bit)
    thresholds = dr.gather(Float, _template_table(template.tobytes(), n), index)
    return _result(_ordered_values(mean, thresholds, n * n, levels), shape, eight_bit)


@eager_if_shared
def halftone(image: Any, n: int = 3, *, template: Any = None) -> TensorXf | TensorXu8:
    """Halftoning (:ref:`conventions-dithering`): every pixel becomes an n x n pattern; n^2 + 1 grey levels.

    p = min(floor(I (n^2 + 1)), n^2) with I = intensity / 255; in the pixel's pattern a cell is
    white where p >= its template number. The patterns form a growth sequence (a cell on at
    level j is on at every level above). The output is n times larger in each direction.

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
        Intensities on 0..255; NaN -> 0, clipped to 0..255.
    n : int
        Pattern size (1..64); n = 1 is a threshold at 255 / 2.
    template : array_like (n, n), optional
        The growth order; default :func:`clustered_dot` (n) (clustered dot); ``bayer(n)`` gives
        dispersed dots.

    Returns
    -------
    drjit.llvm.ad.TensorXf or drjit.llvm.ad.TensorXu8
        Shape (n H, n W) or (n H, n W, C), values 0 and 255 (uint8 for uint8 input).

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.dither import halftone
    >>> np.asarray(halftone(np.array([[128.0]]), 2)).astype(int).tolist()
    [[0, 0], [255, 255]]
    """
    n = checks.integer(n, "n", low=1, high=64)
    template = clustered_dot(int(n)) if template is None else _check_template(template)
    if template.shape[0] != n:
        raise ValueError(f"template: expected shape ({n}, {n}), got {template.shape}")
    values, shape = _pixels(image)  # uint8: read as bytes
    eight_bit = isinstance(values, UInt8)
    height, width = shape[0], shape[1]
    channels = shape[2] if len(shape) == 3 else 1
    out_shape = (height * n, width * n) + ((channels,) if len(shape) == 3 else ())
    count = height * n * width * n * channels
    pixel, c = divmod_u32(dr.arange(UInt32, count), channels, count)
    oy, ox = divmod_u32(pixel, width * n, -(-count // channels))
    sy, ty = divmod_u32(oy, n, height * n)
    sx, tx = divmod_u32(ox, n, width * n)
    source = (sy * opaque_scalar(UInt32, width) + sx) * opaque_scalar(UInt32, channels) + c
    # The raw value: the 1-bit rule needs no clipping (see _ordered_1bit), so no pass before.
    intensity = Float(dr.gather(type(values), values, source))
    table = _threshold_table(template.tobytes(), n)
    up = intensity >= dr.gather(Float, table, ty * opaque_scalar(UInt32, n) + tx)
    return _levels_1bit(up, out_shape, eight_bit)


def blue_noise_mask() -> np.ndarray:
    """The shipped 64 x 64 blue-noise threshold mask, entries 1..4096 (a template).

    ``void_and_cluster(64, sigma=1.5, seed=0)``, stored as ``imaging/data/blue_noise_64.npy``
    (regenerate with ``np.save(path, void_and_cluster(64))``).
    """
    return _blue_noise_mask().view()  # read-only


@lru_cache(maxsize=1)
def _blue_noise_mask() -> np.ndarray:
    mask = _check_template(np.load(_BLUE_NOISE_FILE), "blue noise mask")
    mask.setflags(write=False)
    return mask


@eager_if_shared
def blue_noise(image: Any, *, levels: int = 2, linear: bool = False, mask: Any = None) -> TensorXf | TensorXu8:
    """Ordered dithering with a blue-noise (void-and-cluster) threshold mask.

    Same rule as :func:`ordered` with the 64 x 64 :func:`blue_noise_mask` (4097 levels): no
    visible period, no Bayer crosshatch.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.dither import blue_noise
    >>> int((np.asarray(blue_noise(np.full((64, 64), 64.0))) == 255).sum())  # p = floor(64 * 4097 / 255)
    1028
    """
    if mask is None:  # the shipped mask: loaded and checked once per process
        return _ordered(image, _blue_noise_mask(), _check_levels(levels), _check_bool(linear, "linear"))
    return ordered(image, mask, levels=levels, linear=linear)


