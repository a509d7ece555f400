"""Dithering and halftoning (SPEC "Dithering"): thresholding, error diffusion, halftone patterns,
pattern and ordered dithering, Bayer and blue-noise masks, and the dither error.

Every operation takes a numpy array or a Dr.Jit tensor of shape ``(H, W)`` or ``(H, W, C)`` with
intensities on 0..255 and returns a float32 ``drjit.llvm.TensorXf`` whose values are output levels:
0 and 255 for 1-bit dithering, or ``k * 255 / (levels - 1)`` for ``levels=N``. Colour images are
dithered per channel.

Conventions fixed by the SPEC: the threshold is 128 and a value ``>=`` the threshold becomes 255;
simple error diffusion sends 100 % of the error to the next pixel along a serpentine scan;
Floyd-Steinberg scans left to right and splits the error 7/16 right, 3/16 below-left, 5/16 below
and 1/16 below-right, dropping the error that would leave the image; a halftone pattern of size
n x n shows n^2 + 1 levels, p = min(floor(I (n^2 + 1)), n^2) for I in 0..1, and a pixel is white
where p >= its template number.

Parallel error diffusion
------------------------
Error diffusion reads as a sequential scan, but with a raster scan pixel (y, x) depends only on
pixels of the rows above up to column x + R (R = how far left the kernel reaches in the rows
below) and on its left neighbours. Lanes of one SIMD packet each own a row of a band of P rows
(P = the Dr.Jit packet width): lane i processes column t - s i at step t of ONE symbolic loop,
where the skew s > R / dy makes every value a lane reads a value that another lane wrote in an
earlier step (the wavefront over x + s y). Lanes keep a sliding window of the errors of the rows
above in registers, so one step costs one gather of the input, one gather per source row of the
error buffer, one scatter of the error and one scatter of the output. The error buffer is a
small rolling buffer of P + 2 rows. Bands run one after another inside the same loop, so the whole
image is a single kernel launch per call (one packet per colour channel, channels in parallel).
The additions happen in exactly the order in which a sequential scan adds the contributions
(rows further up first, each row in its scan order, then the pixel's own row), in float64, with
no fused multiply-add, so the result is bit-identical to a sequential float64 reference.
Serpentine scans reverse every other row, which makes row y wait for the end of row y - 1: those
run as one sequential lane per channel (still one kernel).

Notes
-----
==========================  ==============================  =================================
Function                    Domain                          Range
==========================  ==============================  =================================
``threshold``               any real (NaN -> 0)             {0, 255}
``error_diffusion``,        any real; NaN -> 0, clipped     ``levels`` values
``floyd_steinberg``,        to 0..255 before diffusing      ``k * 255 / (levels - 1)``
``diffuse``
``halftone``                any real; clipped to 0..255     {0, 255}, shape (n H, n W[, C])
``pattern``, ``ordered``,   any real; clipped to 0..255     ``levels`` values
``blue_noise``
``dither_error``            two images of the same shape    (total, average), float64
==========================  ==============================  =================================

Examples
--------
>>> import numpy as np
>>> from pointillist.imaging.dither import floyd_steinberg
>>> np.asarray(floyd_steinberg(np.full((2, 4), 64.0))).tolist()
[[0.0, 0.0, 0.0, 0.0], [0.0, 255.0, 0.0, 255.0]]
"""

from __future__ import annotations

import inspect
import math
import os
import warnings
from functools import lru_cache
from pathlib import Path
from typing import Any, Callable, NamedTuple

import drjit as dr
import numpy as np
from drjit.llvm import Float, Float64, Int32, UInt8, UInt32

from pointillist.imaging.arrays import (TensorXf, as_tensor, check_shape, divmod_u32, eager_if_shared, is_uint8,
                                        opaque_scalar)
from pointillist.imaging.filters import threshold

__all__ = [
    "TEMPLATE_4",
    "KERNELS",
    "DiffusionKernel",
    "DitherError",
    "threshold",
    "error_diffusion",
    "floyd_steinberg",
    "diffuse",
    "halftone",
    "clustered_dot",
    "pattern",
    "ordered",
    "bayer",
    "blue_noise",
    "blue_noise_mask",
    "intensity_thresholds",
    "void_and_cluster",
    "dither_error",
    "dither",
    "dither_options",
    "DITHER_METHODS",
]

#: The SPEC's 4 x 4 template (= ``bayer(4)``): a pixel is white where p >= its entry.
TEMPLATE_4: np.ndarray = np.array([[1, 9, 3, 11], [13, 5, 15, 7], [4, 12, 2, 10], [16, 8, 14, 6]], dtype=np.int64)
TEMPLATE_4.setflags(write=False)


class DiffusionKernel(NamedTuple):
    """An error-diffusion kernel: ``weights`` are ``(dy, dx, numerator)`` for a left-to-right scan.

    The error of a pixel is sent to (y + dy, x + dx) with weight ``numerator / divisor`` (mirrored
    in x on right-to-left rows of a serpentine scan).
    """

    name: str
    weights: tuple[tuple[int, int, int], ...]
    divisor: int
    source: str


#: Error-diffusion kernels, by name (weights from the cited papers; the usual tables, e.g. in
#: Lee Crocker et al., "DHALF.TXT", 1991, and Ulichney, "Digital Halftoning", 1987).
KERNELS: dict[str, DiffusionKernel] = {k.name: k for k in (
    DiffusionKernel("floyd_steinberg", ((0, 1, 7), (1, -1, 3), (1, 0, 5), (1, 1, 1)), 16,
                    "Floyd & Steinberg, Proc. SID 17(2), 1976 (and the SPEC)"),
    DiffusionKernel("jarvis_judice_ninke",
                    ((0, 1, 7), (0, 2, 5), (1, -2, 3), (1, -1, 5), (1, 0, 7), (1, 1, 5), (1, 2, 3),
                     (2, -2, 1), (2, -1, 3), (2, 0, 5), (2, 1, 3), (2, 2, 1)), 48,
                    "Jarvis, Judice & Ninke, Comput. Graph. Image Process. 5(1), 1976"),
    DiffusionKernel("stucki",
                    ((0, 1, 8), (0, 2, 4), (1, -2, 2), (1, -1, 4), (1, 0, 8), (1, 1, 4), (1, 2, 2),
                     (2, -2, 1), (2, -1, 2), (2, 0, 4), (2, 1, 2), (2, 2, 1)), 42,
                    "Stucki, IBM Research Report RZ1060, 1981"),
    DiffusionKernel("atkinson", ((0, 1, 1), (0, 2, 1), (1, -1, 1), (1, 0, 1), (1, 1, 1), (2, 0, 1)), 8,
                    "Bill Atkinson, Apple MacPaint, 1984 (diffuses 6/8 of the error)"),
    DiffusionKernel("burkes", ((0, 1, 8), (0, 2, 4), (1, -2, 2), (1, -1, 4), (1, 0, 8), (1, 1, 4), (1, 2, 2)),
                    32, "Daniel Burkes, CIS Graphics Support Forum, 1988"),
    DiffusionKernel("sierra",
                    ((0, 1, 5), (0, 2, 3), (1, -2, 2), (1, -1, 4), (1, 0, 5), (1, 1, 4), (1, 2, 2),
                     (2, -1, 2), (2, 0, 3), (2, 1, 2)), 32,
                    "Frankie Sierra, three-row filter, 1989"),
    DiffusionKernel("sierra_lite", ((0, 1, 2), (1, -1, 1), (1, 0, 1)), 4, "Frankie Sierra, filter lite, 1990"),
)}

#: The simple error diffusion of the SPEC: 100 % of the error to the next pixel of the scan.
SIMPLE_KERNEL = DiffusionKernel("simple", ((0, 1, 1),), 1, "SPEC: 100% of the error to the next pixel")

_DATA = Path(__file__).resolve().parent / "data"
_BLUE_NOISE_FILE = _DATA / "blue_noise_64.npy"
_MAX_LEVELS = 256


class DitherError(NamedTuple):
    """The error of a dithered image (SPEC): its total and average intensity minus the original's."""

    total: float
    average: float


# --------------------------------------------------------------------------------------------
# argument checks


def _check_level(level: Any) -> float:
    if isinstance(level, bool) or not isinstance(level, (int, float, np.integer, np.floating)) \
            or not math.isfinite(level):
        raise ValueError(f"level: expected a finite number, got {level!r}")
    return float(level)


def _check_levels(levels: Any) -> int:
    if isinstance(levels, bool) or not isinstance(levels, (int, np.integer)) or not 2 <= levels <= _MAX_LEVELS:
        raise ValueError(f"levels: expected an integer from 2 to {_MAX_LEVELS}, got {levels!r}")
    return int(levels)


def _check_bool(value: Any, name: str) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name}: expected True or False, got {value!r}")
    return bool(value)


def _check_template(template: Any, name: str = "template") -> np.ndarray:
    try:
        array = np.asarray(template)
    except Exception as error:  # noqa: BLE001
        raise TypeError(f"{name}: expected a square integer array, got {type(template).__name__}") from error
    if array.ndim != 2 or array.shape[0] != array.shape[1] or array.shape[0] == 0:
        raise ValueError(f"{name}: expected a square n x n array, got shape {array.shape}")
    if not (np.issubdtype(array.dtype, np.integer) or np.issubdtype(array.dtype, np.floating)):
        raise TypeError(f"{name}: expected integer entries, got dtype {array.dtype}")
    n = array.shape[0]
    if not np.all(np.isfinite(array)) or not np.array_equal(np.sort(array.ravel()), np.arange(1, n * n + 1)):
        raise ValueError(f"{name}: expected a permutation of 1..{n * n} (a growth sequence), got {array.tolist()}")
    return array.astype(np.int64)


# --------------------------------------------------------------------------------------------
# shared pieces


def _clipped(values: Float) -> Float:
    """NaN -> 0, then clip to 0..255 (so +inf -> 255 and -inf -> 0)."""
    return dr.clip(dr.select(dr.isnan(values), 0.0, values), 0.0, 255.0)


def _srgb_decode_255(values: Float) -> Float:
    """Display intensities 0..255 (sRGB-encoded) -> linear light on 0..255."""
    from pointillist.imaging.colour import srgb_decode

    return srgb_decode(TensorXf(values / 255.0, (1, dr.width(values)))).array * 255.0


def _quantiser(levels: int, level: float, linear: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tables (thresholds[levels-1], value in the working space[levels], output value[levels]), float64.

    Output levels L_k = k 255 / (levels - 1). In the working space (display, or linear light with
    ``linear``) with values V_k, the threshold between V_{k-1} and V_k lies at the fraction
    level / 255 of the gap (level 128 of 0..255: the SPEC threshold for 1-bit dithering). A value v
    becomes level k = the number of thresholds <= v.
    """
    k = np.arange(levels, dtype=np.float64)
    display = k * 255.0 / (levels - 1)
    if linear:
        from pointillist.imaging.colour import srgb_decode

        work = np.asarray(srgb_decode(display[None, :] / 255.0), dtype=np.float64)[0] * 255.0
        work[0], work[-1] = 0.0, 255.0
    else:
        work = display.copy()
    if levels == 2:
        thresholds = np.array([level])
    else:
        thresholds = work[:-1] + (work[1:] - work[:-1]) * (level / 255.0)
    return thresholds, work, display


# --------------------------------------------------------------------------------------------
# error diffusion


@lru_cache(maxsize=1)
def _packet_width() -> int:
    """The SIMD packet width of Dr.Jit's LLVM backend on this CPU (16 AVX-512, 8 AVX, else 4).

    Dr.Jit runs a kernel of at most one packet as one work unit, whose packets run in lockstep;
    the lanes of one band must stay in one packet, so this must not overestimate the real width.
    ``POINTILLIST_DITHER_LANES`` overrides it (a power of two <= the real width is always safe).
    """
    override = os.environ.get("POINTILLIST_DITHER_LANES")
    if override:
        value = int(override)
        if value < 1 or value & (value - 1):
            raise ValueError(f"POINTILLIST_DITHER_LANES: expected a power of two, got {override!r}")
        return value
    try:
        from numpy._core._multiarray_umath import __cpu_features__ as features
    except ImportError:  # numpy < 2
        from numpy.core._multiarray_umath import __cpu_features__ as features  # type: ignore
    if features.get("AVX512VL"):
        return 16
    if features.get("AVX"):
        return 8
    return 4


def _distinct_sets(delta_bytes: int, lanes: int) -> int:
    """How many L1 cache sets (64 sets of 64-byte lines, 4 KiB period) ``lanes`` addresses ``delta`` apart hit."""
    return len({((k * delta_bytes) % 4096) // 64 for k in range(lanes)})


def _schedule(kernel: tuple[tuple[int, int, float], ...], serpentine: bool, width: int, channels: int,
              lanes: int) -> dict[str, Any]:
    """Static plan of the wavefront: source windows, skew, arrival order, buffer layout."""
    rows = sorted({dy for dy, _, _ in kernel if dy > 0})

    def offset(dy: int, dx: int) -> int:
        # Column of the source of (y, x), relative to x, in the scan coordinate of row y.
        return dx if (serpentine and dy % 2) else -dx

    right = {dy: max(offset(dy, dx) for ddy, dx, _ in kernel if ddy == dy) for dy in rows}
    left = {dy: min(offset(dy, dx) for ddy, dx, _ in kernel if ddy == dy) for dy in rows}
    for dy in rows:
        right[dy] = max(right[dy], left[dy])
    prefetch = max([0] + [right[dy] for dy in rows])
    skew = max([1] + [right[dy] // dy + 1 for dy in rows])
    if serpentine:
        lanes = 1
    if lanes > 1:
        # Lanes of a band touch addresses (W - s) C floats apart: a multiple of 4 KiB maps them all
        # onto one L1 set (conflict misses). A slightly larger skew spreads them; it stays exact.
        want = min(lanes, 64) // 2
        for candidate in range(skew, skew + 64):
            if _distinct_sets((width - candidate) * channels * 4, lanes) >= want:
                skew = candidate
                break
    # Arrival order of the contributions at a pixel: rows further up first, each row in the order
    # it was scanned (rows of the other direction arrive right to left in our coordinate), then
    # our own row, farthest first.
    order = []
    for dy in sorted(rows, reverse=True):
        items = sorted(((offset(dy, dx), w) for ddy, dx, w in kernel if ddy == dy),
                       key=lambda item: item[0], reverse=bool(serpentine and dy % 2))
        order += [(dy, o, w) for o, w in items]
    own = sorted(((dx, w) for dy, dx, w in kernel if dy == 0), reverse=True)
    depth = max([0] + rows)
    stride = width + 2 * prefetch + 2
    if lanes > 1:
        for pad in range(0, 16):
            if _distinct_sets((stride + pad - skew) * 8, lanes) >= min(lanes, 64) // 2:
                stride += pad
                break
    return dict(rows=rows, right=right, left=left, prefetch=prefetch, skew=skew, order=order, own=own,
                lanes=lanes, slots=lanes + depth, stride=stride)


@lru_cache(maxsize=1)
def _lanes() -> int:
    """:func:`_packet_width`, verified once on this machine before it is trusted.

    The parallel schedule is only exact when a band's lanes share one SIMD packet. The width is
    read from CPU flags, not from Dr.Jit, so it is checked: a small random image is diffused with
    the guessed width and with one lane (always exact); on disagreement the width is halved
    until they agree, with a warning. Costs a few milliseconds once per process.
    """
    lanes = _packet_width()
    if lanes == 1 or os.environ.get("POINTILLIST_DITHER_LANES"):
        return lanes
    fs = KERNELS["floyd_steinberg"]
    weights = tuple((dy, dx, n / fs.divisor) for dy, dx, n in fs.weights)
    height, width = 2 * lanes + 3, 29
    rng = np.random.default_rng(20261122)
    values = Float(rng.uniform(0.0, 255.0, height * width).astype(np.float32))
    tables = _quantiser(2, 128.0, False)
    expected = _diffuse_core(values, height, width, 1, weights, False, tables, lanes=1).numpy()
    guess = lanes
    while lanes > 1 and not np.array_equal(
            _diffuse_core(values, height, width, 1, weights, False, tables, lanes=lanes).numpy(), expected):
        lanes //= 2
    if lanes != guess:
        warnings.warn(f"imaging.dither: Dr.Jit's SIMD packet is narrower than the {guess} lanes the CPU "
                      f"flags suggest; using {lanes} (set POINTILLIST_DITHER_LANES to choose)", RuntimeWarning,
                      stacklevel=2)
    return lanes


def _diffuse_core(values: Float, height: int, width: int, channels: int,
                  kernel: tuple[tuple[int, int, float], ...], serpentine: bool,
                  tables: tuple[np.ndarray, np.ndarray, np.ndarray], carry: bool = False,
                  lanes: int | None = None, clip: bool = False) -> Float:
    """Error diffusion of the flat (H, W, C) ``values``; returns the output levels.

    ``values``: evaluated float32 (already clipped, or raw with ``clip``: NaN -> 0 and the clip to
    0..255 then happen on each value as the loop reads it, saving a pass over the image) or
    uint8 (0..255, read as bytes). ``lanes``: rows processed together in one SIMD packet (default:
    :func:`_lanes`).
    """
    plan = _schedule(kernel, serpentine, width, channels, _lanes() if lanes is None else lanes)
    rows, right, left, order, own_w = plan["rows"], plan["right"], plan["left"], plan["order"], plan["own"]
    lanes, skew, prefetch, slots, stride = plan["lanes"], plan["skew"], plan["prefetch"], plan["slots"], plan["stride"]
    thresholds, work, display = tables
    levels = len(display)

    steps_per_band = width + prefetch + skew * (lanes - 1)
    bands = -(-height // lanes)
    total = bands * steps_per_band
    if total >= 2**31 or height * width * channels >= 2**31:
        raise ValueError(f"image: too large for error diffusion ({height} x {width} x {channels})")

    # The error buffer: `slots` rows of `stride` float64 per channel. It is gathered and scattered
    # in the same loop through two Dr.Jit arrays over the same memory: the schedule guarantees
    # that every value is read at a later step than the one that wrote it.
    memory = np.zeros(channels * slots * stride, dtype=np.float64)
    errors_in, errors_out = Float64(memory), Float64(memory)
    out = dr.empty(Float, height * width * channels)

    lane = dr.arange(Int32, lanes * channels)
    index = lane % lanes
    channel = lane // lanes
    W = dr.opaque(Int32, width)
    H = dr.opaque(Int32, height)
    C = dr.opaque(Int32, channels)
    S = dr.opaque(Int32, slots)
    B = dr.opaque(Int32, stride)
    T = dr.opaque(Int32, steps_per_band)
    end = dr.opaque(Int32, total)
    buffer_base = channel * (S * B) + prefetch
    if levels == 2:
        level_k = dr.opaque(Float64, float(thresholds[0]))
        work0, work1 = dr.opaque(Float64, float(work[0])), dr.opaque(Float64, float(work[1]))
        disp0, disp1 = dr.opaque(Float, float(display[0])), dr.opaque(Float, float(display[1])),
    else:
        threshold_table = Float64(thresholds)
        work_table = Float64(work)
        display_table = Float(display.astype(np.float32))
    search = [1 << b for b in reversed(range(max(1, (levels - 1).bit_length())))]

    step = dr.zeros(Int32, lanes * channels)
    t = dr.zeros(Int32, lanes * channels)
    y = Int32(index)
    slot = Int32(index)
    windows = [[dr.zeros(Float64, lanes * channels) for _ in range(right[dy] - left[dy] + 1)] for dy in rows]
    own = [dr.zeros(Float64, lanes * channels) for _ in range(max([0] + [dx for dx, _ in own_w]))]

    def body(step, t, y, slot, windows, own):
        x = t - (skew * index + prefetch)
        start = t == 0
        live = y < H
        odd = (y & 1) == 1
        for r, dy in enumerate(rows):
            window = [dr.select(start, 0.0, v) for v in windows[r]][1:]
            column = x + right[dy]
            source = slot - dy
            source = dr.select(source < 0, source + S, source)
            mask = live & (y >= dy) & (column >= 0) & (column < W)
            physical = dr.select(odd, W - 1 - column, column) if serpentine else column
            window.append(dr.gather(Float64, errors_in, buffer_base + source * B + physical, mask))
            windows[r] = window
        valid = live & (x >= 0) & (x < W)
        px = dr.select(odd, W - 1 - x, x) if serpentine else x
        pixel = (y * W + px) * C + channel
        read = Float(dr.gather(type(values), values, pixel, valid))
        v = Float64(_clipped(read) if clip else read)
        for dy, o, w in order:
            v = v + windows[rows.index(dy)][o - left[dy]] * w
        for dx, w in own_w:
            v = v + own[dx - 1] * w
        if levels == 2:
            on = v >= level_k
            q = dr.select(on, work1, work0)
            shown = dr.select(on, disp1, disp0)
        else:
            k = dr.zeros(Int32, dr.width(v))
            for jump in search:
                candidate = k + jump
                fits = candidate <= levels - 1
                bound = dr.gather(Float64, threshold_table, candidate - 1, fits & valid)
                k = dr.select(fits & (bound <= v), candidate, k)
            q = dr.gather(Float64, work_table, k, valid)
            shown = dr.gather(Float, display_table, k, valid)
        e = dr.select(valid, v - q, 0.0)
        if rows:
            dr.scatter(errors_out, e, buffer_base + slot * B + px, valid)
        dr.scatter(out, shown, pixel, valid)
        if own:
            own = [e] + own[:-1]
        t = t + 1
        wrap = t == T
        if own and not carry:
            own = [dr.select(wrap, 0.0, o) for o in own]
        nxt = slot + lanes
        nxt = dr.select(nxt >= S, nxt - S, nxt)
        slot = dr.select(wrap, nxt, slot)
        y = dr.select(wrap, y + lanes, y)
        t = dr.select(wrap, 0, t)
        return step + 1, t, y, slot, windows, own

    dr.while_loop((step, t, y, slot, windows, own), lambda step, *rest: step < end, body,
                  labels=("step", "t", "y", "slot", "windows", "own"), mode="symbolic",
                  label="error_diffusion")
    dr.eval(out)
    return out


def _pixels(image: Any) -> tuple[UInt8 | Float, tuple[int, ...]]:
    """The flat pixel values and shape of ``image``: a uint8 numpy image as its bytes (``UInt8``,
    shared, no float32 copy), anything else through :func:`as_tensor` (``Float``)."""
    if is_uint8(image):
        check_shape(image.shape, "image", None, False)
        return UInt8(np.ascontiguousarray(image).reshape(-1)), tuple(image.shape)
    tensor = as_tensor(image)
    return tensor.array, tuple(tensor.shape)


def _diffuse(image: Any, kernel: DiffusionKernel, *, level: float, levels: int, serpentine: bool,
             linear: bool, carry: bool = False) -> TensorXf:
    level = _check_level(level)
    levels = _check_levels(levels)
    serpentine = _check_bool(serpentine, "serpentine")
    linear = _check_bool(linear, "linear")
    values, shape = _pixels(image)  # uint8 bytes are widened as the loop reads them
    clip = False
    if linear:
        values = _srgb_decode_255(_clipped(Float(values)))
    elif not isinstance(values, UInt8):  # clipped in the diffusion loop itself: no separate pass
        clip = True
    dr.eval(values)
    height, width = shape[0], shape[1]
    channels = shape[2] if len(shape) == 3 else 1
    weights = tuple((dy, dx, n / kernel.divisor) for dy, dx, n in kernel.weights)
    out = _diffuse_core(values, height, width, channels, weights, serpentine,
                        _quantiser(levels, level, linear), carry=carry, clip=clip)
    return TensorXf(out, shape)


@eager_if_shared
def diffuse(image: Any, kernel: str = "floyd_steinberg", *, level: float = 128, levels: int = 2,
            serpentine: bool = False, linear: bool = False) -> TensorXf:
    """Error diffusion with a named kernel, exact and parallel (one Dr.Jit kernel launch).

    Each pixel (in scan order) becomes the nearest output level by the threshold rule, and its
    error (value - output, in float64) is added to the pixels not yet scanned with the kernel's
    weights ``numerator / divisor`` (a float64 constant); error that would leave the image is
    dropped. The result is bit-identical to that sequential float64 scan (see the module notes for
    the wavefront schedule).

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
        Intensities on 0..255. NaN becomes 0 and values are clipped to 0..255 first (so one
        huge value cannot flood the image with error). Channels are diffused independently.
    kernel : str
        One of :data:`KERNELS`: ``floyd_steinberg``, ``jarvis_judice_ninke``, ``stucki``,
        ``atkinson``, ``burkes``, ``sierra``, ``sierra_lite``.
    level : float
        Threshold on 0..255 (SPEC: 128; ``>=`` becomes the upper level). For ``levels > 2`` the
        thresholds lie at the same fraction ``level / 255`` of each gap between levels.
    levels : int
        Number of output levels, 2..256, at ``k * 255 / (levels - 1)``. ``levels=256`` leaves
        integer input unchanged.
    serpentine : bool
        Scan odd rows right to left with the kernel mirrored (runs sequentially: a serpentine
        row cannot start before the previous one ends).
    linear : bool
        Decode sRGB first and diffuse in linear light: thresholds and errors are measured in
        linear light (the output levels keep their display values), so the mean linear light is
        preserved, as careful dithering tools do.

    Returns
    -------
    drjit.llvm.TensorXf
        Same shape as ``image``; values in the ``levels`` output levels.

    Notes
    -----
    Edges: a constant 0 or 255 image stays constant (zero error); a 1 x 1 image is thresholded;
    1 x N and N x 1 images diffuse along their one row or column (lower rows do not exist, so that
    part of the error is dropped).

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.dither import diffuse
    >>> np.asarray(diffuse(np.full((1, 4), 100.0), "sierra_lite")).tolist()
    [[0.0, 255.0, 0.0, 0.0]]
    """
    if not isinstance(kernel, str) or kernel not in KERNELS:
        raise ValueError(f"kernel: expected one of {', '.join(KERNELS)}, got {kernel!r}")
    return _diffuse(image, KERNELS[kernel], level=level, levels=levels, serpentine=serpentine, linear=linear)


@eager_if_shared
def floyd_steinberg(image: Any, level: float = 128, serpentine: bool = False, *, levels: int = 2,
                    linear: bool = False) -> TensorXf:
    """Floyd-Steinberg error diffusion (SPEC): 7/16 right, 3/16 below-left, 5/16 below, 1/16 below-right.

    Same as ``diffuse(image, "floyd_steinberg", ...)``; see :func:`diffuse` for the parameters,
    the edges of the domain and exactness.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.dither import floyd_steinberg
    >>> np.asarray(floyd_steinberg(np.array([[100.0, 100.0]]))).tolist()
    [[0.0, 255.0]]
    """
    return _diffuse(image, KERNELS["floyd_steinberg"], level=level, levels=levels, serpentine=serpentine,
                    linear=linear)


@eager_if_shared
def error_diffusion(image: Any, level: float = 128, *, levels: int = 2, linear: bool = False) -> TensorXf:
    """Simple error diffusion (SPEC): 100 % of each pixel's error goes to the next pixel, serpentine.

    The scan runs left to right on even rows and right to left on odd rows; the next pixel after
    the end of a row is the pixel below it (the first of the next row in the scan), so the error
    follows the serpentine path and only the last pixel's error leaves the image. The scan is
    inherently sequential; it runs as one lane per channel inside one kernel.

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
        Intensities on 0..255 (NaN -> 0, clipped to 0..255).
    level : float
        Threshold (SPEC 128, ``>=`` goes up).
    levels : int
        Output levels 2..256 (see :func:`diffuse`).
    linear : bool
        Diffuse in linear light (see :func:`diffuse`).

    Returns
    -------
    drjit.llvm.TensorXf
        Same shape; values in the output levels.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.dither import error_diffusion
    >>> np.asarray(error_diffusion(np.array([[100.0, 100.0], [100.0, 100.0]]))).tolist()
    [[0.0, 255.0], [255.0, 0.0]]
    """
    return _diffuse(image, SIMPLE_KERNEL, level=level, levels=levels, serpentine=True, linear=linear, carry=True)


# --------------------------------------------------------------------------------------------
# halftoning, pattern and ordered dithering


def bayer(n: int) -> np.ndarray:
    """The n x n Bayer index matrix (n a power of two), entries 1..n^2 (a template).

    Built by the Bayer recursion on 0-based matrices, M_1 = [[0]] and
    M_2n = [[4 M_n, 4 M_n + 2], [4 M_n + 3, 4 M_n + 1]], plus 1; ``bayer(4)`` is the SPEC's
    :data:`TEMPLATE_4`. ``bayer(1)`` is [[1]] (plain thresholding at the middle of 0..255).

    Examples
    --------
    >>> from pointillist.imaging.dither import bayer
    >>> bayer(2).tolist()
    [[1, 3], [4, 2]]
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1 or n & (n - 1) or n > 4096:
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
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= 256:
        raise ValueError(f"n: expected an integer from 1 to 256, got {n!r}")
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
    tensor = as_tensor(image)
    return tensor, _clipped(tensor.array)


def _ordered_values(values: Float, thresholds: Float, cells: int, levels: int) -> Float:
    """SPEC ordered rule generalised to ``levels``: p = min(floor(f (n^2+1)), n^2), up where p >= T.

    f is the intensity's position inside its gap between two output levels (0..1); for
    ``levels=2`` that is I / 255 and the rule is exactly the SPEC's.
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
    """The SPEC's ordered-dithering rule as one threshold per template entry, on 0..255.

    p = min(floor(I (n^2 + 1) / 255), n^2) >= T holds exactly when I (n^2 + 1) >= 255 T (T <= n^2),
    i.e. when I >= 255 T / (n^2 + 1). Returned is, per entry T, the smallest float32 x with
    x (n^2 + 1) >= 255 T in exact arithmetic (products of a float32 and an integer below 2^29 are
    exact in float64), so ``I >= table`` is the SPEC rule for EVERY float32 I, not only integers.
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


def _ordered_1bit(values: Float, template: np.ndarray, y: UInt32, x: UInt32) -> Float:
    """1-bit ordered dithering in one pass: white where I >= the entry's intensity threshold.

    No clipping is needed: NaN compares false (black, as NaN -> 0), values above 255 pass every
    threshold (< 255) and values below 0 pass none (> 0), exactly as after clipping.
    """
    n = template.shape[0]
    table = _threshold_table(template.tobytes(), n)
    up = values >= dr.gather(Float, table, _template_index(n, y, x))
    return dr.select(up, opaque_scalar(Float, 255.0), opaque_scalar(Float, 0.0))


@eager_if_shared
def ordered(image: Any, template: Any = TEMPLATE_4, *, levels: int = 2, linear: bool = False) -> TensorXf:
    """Ordered dithering (SPEC): one p per pixel, compared with the template entry at that pixel.

    p = min(floor(I (n^2 + 1)), n^2) with I = intensity / 255; the pixel is white where p >= the
    template number at (y mod n, x mod n).

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
        Intensities on 0..255; NaN -> 0, clipped to 0..255. A numpy ``uint8`` array is read as
        packed bytes (4 per 32-bit word), without a float32 copy.
    template : array_like, (n, n)
        A permutation of 1..n^2 (default the SPEC's :data:`TEMPLATE_4`; see :func:`bayer`,
        :func:`clustered_dot`, :func:`blue_noise_mask`). A 1 x 1 template [[1]] is a threshold at
        255 / 2 (p >= 1 for I >= 1/2).
    levels : int
        Output levels (2..256); between two levels the same rule places the pixel.
    linear : bool
        Decode sRGB before comparing (dither linear light).

    Returns
    -------
    drjit.llvm.TensorXf
        Same shape; 0 and 255 (or the ``levels`` values). 0 stays 0 and 255 stays 255.

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


def _ordered(image: Any, template: np.ndarray, levels: int, linear: bool) -> TensorXf:
    values, shape = _pixels(image)
    values = Float(values)  # uint8: one byte per value, widened inside the kernel (no float32 copy)
    if linear:
        values = _srgb_decode_255(_clipped(values))
    channels = shape[2] if len(shape) == 3 else 1
    n = template.shape[0]
    y, x = _coordinates(dr.width(values), shape[1], channels)
    if levels == 2:
        return TensorXf(_ordered_1bit(values, template, y, x), shape)
    if not linear:
        values = _clipped(values)
    thresholds = _template_thresholds(template, y, x)
    return TensorXf(_ordered_values(values, thresholds, n * n, levels), shape)


@eager_if_shared
def pattern(image: Any, template: Any = TEMPLATE_4, *, levels: int = 2, linear: bool = False) -> TensorXf:
    """Pattern dithering (SPEC): one p per n x n block from the block's average intensity.

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
        return TensorXf(dr.select(up, opaque_scalar(Float, 255.0), opaque_scalar(Float, 0.0)), shape)
    thresholds = dr.gather(Float, _template_table(template.tobytes(), n), index)
    return TensorXf(_ordered_values(mean, thresholds, n * n, levels), shape)


@eager_if_shared
def halftone(image: Any, n: int = 3, *, template: Any = None) -> TensorXf:
    """Halftoning (SPEC): every pixel becomes an n x n pattern; n^2 + 1 grey levels.

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
    drjit.llvm.TensorXf
        Shape (n H, n W) or (n H, n W, C), values 0 and 255.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.dither import halftone
    >>> np.asarray(halftone(np.array([[128.0]]), 2)).astype(int).tolist()
    [[0, 0], [255, 255]]
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= 64:
        raise ValueError(f"n: expected an integer from 1 to 64, got {n!r}")
    template = clustered_dot(int(n)) if template is None else _check_template(template)
    if template.shape[0] != n:
        raise ValueError(f"template: expected shape ({n}, {n}), got {template.shape}")
    tensor = as_tensor(image)
    shape = tuple(tensor.shape)
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
    intensity = dr.gather(Float, tensor.array, source)
    table = _threshold_table(template.tobytes(), n)
    up = intensity >= dr.gather(Float, table, ty * opaque_scalar(UInt32, n) + tx)
    return TensorXf(dr.select(up, opaque_scalar(Float, 255.0), opaque_scalar(Float, 0.0)), out_shape)


def void_and_cluster(n: int = 64, *, sigma: float = 1.5, seed: int = 0, density: float = 0.1) -> np.ndarray:
    """An n x n blue-noise threshold mask by Ulichney's void-and-cluster method, entries 1..n^2.

    R. Ulichney, "The void-and-cluster method for dither array generation", Proc. SPIE 1913,
    1993. Energy = toroidal Gaussian (``sigma``) filter of the binary pattern. (1) A random initial
    pattern (``density`` of the cells, seeded) is relaxed by moving the tightest cluster's point to
    the largest void until that move changes nothing; (2) its points are ranked downward by
    repeatedly removing the tightest cluster; (3) ranks continue upward by filling the largest
    void up to half the cells; (4) then by turning off the tightest cluster of the remaining
    zeros. An offline tool (numpy; O(n^4) work): the shipped mask comes from it.

    Examples
    --------
    >>> from pointillist.imaging.dither import void_and_cluster
    >>> sorted(void_and_cluster(4, seed=1).ravel().tolist()) == list(range(1, 17))
    True
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 2 <= n <= 256:
        raise ValueError(f"n: expected an integer from 2 to 256, got {n!r}")
    if not (isinstance(sigma, (int, float)) and sigma > 0):
        raise ValueError(f"sigma: expected a positive number, got {sigma!r}")
    if not (isinstance(density, float) and 0 < density < 0.5):
        raise ValueError(f"density: expected a float in (0, 0.5), got {density!r}")
    d = np.minimum(np.arange(n), n - np.arange(n)).astype(np.float64)
    kernel = np.exp(-(d[:, None] ** 2 + d[None, :] ** 2) / (2.0 * sigma * sigma))

    def splat(energy: np.ndarray, index: int, sign: float) -> None:
        y, x = divmod(index, n)
        energy += sign * np.roll(np.roll(kernel, y, axis=0), x, axis=1)

    rng = np.random.default_rng(seed)
    count = max(1, int(density * n * n))
    pattern_ = np.zeros((n, n), dtype=bool)
    pattern_.flat[rng.choice(n * n, count, replace=False)] = True
    energy = np.real(np.fft.ifft2(np.fft.fft2(pattern_) * np.fft.fft2(kernel)))
    for _ in range(n * n):
        cluster = int(np.argmax(np.where(pattern_, energy, -np.inf)))
        pattern_.flat[cluster] = False
        splat(energy, cluster, -1.0)
        void = int(np.argmin(np.where(pattern_, np.inf, energy)))
        pattern_.flat[void] = True
        splat(energy, void, 1.0)
        if void == cluster:
            break
    rank = np.zeros(n * n, dtype=np.int64)
    work, work_energy = pattern_.copy(), energy.copy()
    for r in range(count - 1, -1, -1):
        cluster = int(np.argmax(np.where(work, work_energy, -np.inf)))
        work.flat[cluster] = False
        splat(work_energy, cluster, -1.0)
        rank[cluster] = r
    work, work_energy = pattern_.copy(), energy.copy()
    for r in range(count, n * n // 2):
        void = int(np.argmin(np.where(work, np.inf, work_energy)))
        work.flat[void] = True
        splat(work_energy, void, 1.0)
        rank[void] = r
    # Phase 3: the zeros are now the minority; their energy is that of the inverted pattern.
    zero_energy = np.real(np.fft.ifft2(np.fft.fft2(~work) * np.fft.fft2(kernel)))
    for r in range(n * n // 2, n * n):
        cluster = int(np.argmax(np.where(work, -np.inf, zero_energy)))
        work.flat[cluster] = True
        splat(zero_energy, cluster, -1.0)
        rank[cluster] = r
    return rank.reshape(n, n) + 1


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
def blue_noise(image: Any, *, levels: int = 2, linear: bool = False, mask: Any = None) -> TensorXf:
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


# --------------------------------------------------------------------------------------------
# one entry point


def _threshold_method(image: Any, *, level: float = 128) -> TensorXf:
    return threshold(image, level)


def _ordered_method(image: Any, *, n: int = 4, levels: int = 2, linear: bool = False) -> TensorXf:
    return ordered(image, bayer(n), levels=levels, linear=linear)


def _pattern_method(image: Any, *, n: int = 4, levels: int = 2, linear: bool = False) -> TensorXf:
    return pattern(image, bayer(n), levels=levels, linear=linear)


def _halftone_method(image: Any, *, n: int = 3) -> TensorXf:
    return halftone(image, n)


def _kernel_method(kernel: str) -> Any:
    def method(image: Any, *, level: float = 128, levels: int = 2, serpentine: bool = False,
               linear: bool = False) -> TensorXf:
        return diffuse(image, kernel, level=level, levels=levels, serpentine=serpentine, linear=linear)

    return method


#: The methods of :func:`dither`, by name: each a function ``(image, **options)`` whose keyword
#: parameters are the method's options and defaults. ``ordered``/``bayer`` and ``pattern`` use the
#: ``n`` x ``n`` Bayer matrix (``n=4``: the SPEC's :data:`TEMPLATE_4`).
DITHER_METHODS: dict[str, Callable[..., TensorXf]] = {
    "threshold": _threshold_method,
    "error_diffusion": error_diffusion,
    **{name: _kernel_method(name) for name in KERNELS},
    "ordered": _ordered_method,
    "bayer": _ordered_method,
    "blue_noise": blue_noise,
    "pattern": _pattern_method,
    "halftone": _halftone_method,
}


@lru_cache(maxsize=None)
def dither_options(method: str) -> tuple[str, ...]:
    """The option names :func:`dither` takes for ``method`` (the keyword parameters of its function).

    Examples
    --------
    >>> from pointillist.imaging.dither import dither_options
    >>> dither_options("halftone"), dither_options("ordered")
    (('n',), ('n', 'levels', 'linear'))
    """
    if not isinstance(method, str) or method not in DITHER_METHODS:
        raise ValueError(f"method: expected one of {', '.join(DITHER_METHODS)}, got {method!r}")
    parameters = list(inspect.signature(DITHER_METHODS[method]).parameters.values())[1:]
    return tuple(p.name for p in parameters)


def dither(image: Any, method: str = "floyd_steinberg", **options: Any) -> TensorXf:
    """Dither ``image`` with the named ``method`` of :data:`DITHER_METHODS` and its ``options``.

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
        Intensities on 0..255.
    method : str
        ``threshold`` (option ``level``), ``error_diffusion`` (``level``, ``levels``, ``linear``),
        an error-diffusion kernel of :data:`KERNELS` such as ``floyd_steinberg`` (``level``,
        ``levels``, ``serpentine``, ``linear``; see :func:`diffuse`), ``ordered`` or ``bayer``
        (``n``, ``levels``, ``linear``), ``blue_noise`` (``levels``, ``linear``, ``mask``),
        ``pattern`` (``n``, ``levels``, ``linear``) or ``halftone`` (``n``).
    **options
        The method's options (:func:`dither_options`); values are checked by the method.

    Returns
    -------
    drjit.llvm.TensorXf
        The dithered image (``halftone``: n times larger in each direction).

    Raises
    ------
    ValueError
        For an unknown method or an option the method does not take.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.dither import dither
    >>> np.asarray(dither(np.full((2, 4), 64.0), "floyd_steinberg")).tolist()
    [[0.0, 0.0, 0.0, 0.0], [0.0, 255.0, 0.0, 255.0]]
    >>> np.asarray(dither(np.array([[128.0]]), "halftone", n=2)).astype(int).tolist()
    [[0, 0], [255, 255]]
    """
    allowed = dither_options(method)
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise ValueError(f"{unknown[0]}: not an option of dither method {method!r} "
                         f"(its options: {', '.join(allowed) or 'none'})")
    return DITHER_METHODS[method](image, **options)


# --------------------------------------------------------------------------------------------
# error


def dither_error(original: Any, result: Any) -> DitherError:
    """The SPEC's dither error: total (and average) intensity of ``result`` minus ``original``'s.

    Sums in float64 over every value (all channels). NaN anywhere gives NaN.

    Parameters
    ----------
    original, result : array_like or Dr.Jit tensor
        Images of the same shape.

    Returns
    -------
    DitherError
        ``total`` = sum(result) - sum(original), ``average`` = total / number of values.

    Examples
    --------
    >>> from pointillist.imaging.dither import dither_error
    >>> dither_error([[100.0, 100.0]], [[0.0, 255.0]])
    DitherError(total=55.0, average=27.5)
    """
    a = as_tensor(original, "original")
    b = as_tensor(result, "result")
    if tuple(a.shape) != tuple(b.shape):
        raise ValueError(f"result: expected the shape of original {tuple(a.shape)}, got {tuple(b.shape)}")
    total = dr.sum(Float64(b.array) - Float64(a.array), mode="evaluated")
    total = float(total[0] if dr.width(total) else total)
    count = dr.width(a.array)
    return DitherError(total, total / count)
