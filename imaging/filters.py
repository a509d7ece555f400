"""Spatial filters: cross-correlation, edges, median and thresholding (SPEC "Imaging definitions").

Every window operation here (:func:`correlate`, :func:`sobel`, :func:`prewitt`,
:func:`laplacian`, :func:`zero_crossings`, :func:`median`) runs as one Dr.Jit
kernel over all pixels. The taps of the window are *contiguous* loads: the
image is copied once into a flat buffer with a margin of ``ry * W + rx`` pixels
at both ends and every tap ``(dy, dx)`` reads a zero-copy shifted view of that
buffer (Dr.Jit maps numpy memory without copying), so no tap needs a gather.
Pixels where the window does not fit (the *border ring*, ``ry`` rows and ``rx``
columns on each side) are then handled by the border mode:

================  ==============================================  =========================  ========================
``border``        border pixels                                   scipy.ndimage ``mode``     OpenCV ``borderType``
================  ==============================================  =========================  ========================
``"zero"``        set to 0 (the course's choice, the default)     (none)                     (none)
``"crop"``        dropped: the output is ``(H - 2ry, W - 2rx)``   (none)                     (none)
``"keep"``        keep the input's values                         (none)                     (none)
``"clamp"``       window sees the edge pixel repeated             ``"nearest"``              ``BORDER_REPLICATE``
``"reflect"``     window sees ``dcb|abcd|cba`` (edge repeated)    ``"reflect"``              ``BORDER_REFLECT``
``"mirror"``      window sees ``dcb|abcd|cba`` without the edge   ``"mirror"``               ``BORDER_REFLECT_101``
``"wrap"``        window sees the image periodically              ``"wrap"``/``"grid-wrap"`` ``BORDER_WRAP``
``"constant"``    window sees zeros outside the image             ``"constant", cval=0``     ``BORDER_CONSTANT``
================  ==============================================  =========================  ========================

``reflect`` follows scipy's ``"reflect"`` = OpenCV's ``BORDER_REFLECT`` (the
edge pixel is repeated); ``mirror`` is the other convention. Reflection and
wrapping repeat as often as needed, so a window larger than the image is fine.
For the padded modes the ring's taps are gathered on the host into small arrays
and pass through the same Dr.Jit combination code, then are scattered into the
result.

Colour images (H, W, C) are filtered per channel. Intensities are on 0..255 by
convention, but any float values (negative, HDR) are accepted.

Speed notes (measured, benchmarks/imaging_spatial.py): the padded copy is one
memory pass (about 1 ms at 2048x2048) and is the price of contiguous taps; a
full-size output cannot be built from unpadded shifted views, and the
alternatives (scatter of the interior, ``dr.concat``, gathers) measured 2-6x
slower than the copy. Minimum and maximum are written as compare + select
(``_min``, ``_max``, ``_exchange``): ``dr.minimum``/``dr.maximum`` lower to
LLVM's NaN-propagating ``llvm.minimum``, about 8x slower per exchange here.
The normalisation's min/max folds 16 zero-copy views of the result in one pass
(``_finite_extrema``). Every array a kernel maps is 64-byte aligned, so a call
never compiles a kernel again merely because numpy placed memory differently.
"""

from __future__ import annotations

import functools
import math
import threading
from collections.abc import Callable, Sequence
from typing import Any

import drjit as dr
import numpy as np
from drjit.llvm import Bool, Float, UInt32

from pointillist.imaging.arrays import TensorXf, as_tensor, eager_if_shared, opaque_scalar

__all__ = [
    "SOBEL_X", "SOBEL_Y", "PREWITT_X", "PREWITT_Y", "GAUSSIAN_3", "LOW_PASS", "HIGH_PASS",
    "LAPLACIAN", "KERNELS", "BORDERS", "correlate", "normalize", "sobel", "prewitt",
    "laplacian", "zero_crossings", "threshold", "median",
]

# --- Kernel constants (SPEC "Imaging definitions", cross-correlation) -------------------------
#: Sobel x (SPEC): responds to intensity increasing to the right; = OpenCV ``Sobel(dx=1)``.
SOBEL_X = np.array([[-1, 0, 1], [-2, 0, 2], [-1, 0, 1]], dtype=np.float32)
#: Sobel y (SPEC): responds to intensity increasing *upwards* (= -OpenCV ``Sobel(dy=1)``).
SOBEL_Y = np.array([[1, 2, 1], [0, 0, 0], [-1, -2, -1]], dtype=np.float32)
#: Prewitt x (SPEC, ``[[1, 0, -1]] * 3`` rows): note the sign is opposite to SOBEL_X.
PREWITT_X = np.array([[1, 0, -1], [1, 0, -1], [1, 0, -1]], dtype=np.float32)
#: Prewitt y (SPEC).
PREWITT_Y = np.array([[1, 1, 1], [0, 0, 0], [-1, -1, -1]], dtype=np.float32)
#: The course's 3x3 Gaussian (SPEC), unnormalised (sum 25).
GAUSSIAN_3 = np.array([[1, 3, 1], [3, 9, 3], [1, 3, 1]], dtype=np.float32)
#: Low pass (SPEC): all ones, unnormalised (sum 9).
LOW_PASS = np.ones((3, 3), dtype=np.float32)
#: High pass (SPEC): 8 at the centre, -1 around (sum 0).
HIGH_PASS = np.array([[-1, -1, -1], [-1, 8, -1], [-1, -1, -1]], dtype=np.float32)
#: 4-neighbour Laplacian, the second-derivative kernel of ``cv2.Laplacian(ksize=1)``.
LAPLACIAN = np.array([[0, 1, 0], [1, -4, 1], [0, 1, 0]], dtype=np.float32)

#: Named kernels (the names ``pointillist post`` accepts).
KERNELS: dict[str, np.ndarray] = {
    "sobel_x": SOBEL_X, "sobel_y": SOBEL_Y, "prewitt_x": PREWITT_X, "prewitt_y": PREWITT_Y,
    "gaussian": GAUSSIAN_3, "low_pass": LOW_PASS, "high_pass": HIGH_PASS, "laplacian": LAPLACIAN,
}
for _k in KERNELS.values():
    _k.setflags(write=False)

#: The border modes (see the module docstring).
BORDERS = ("zero", "crop", "keep", "clamp", "reflect", "mirror", "wrap", "constant")
_PADDED = frozenset({"clamp", "reflect", "mirror", "wrap", "constant"})

Taps = dict[tuple[int, int], Float]


# --- Argument checks ---------------------------------------------------------------------------
def _check_border(border: Any) -> str:
    if not isinstance(border, str) or border not in BORDERS:
        raise ValueError(f"border: expected one of {', '.join(map(repr, BORDERS))}, got {border!r}")
    return border


def _check_kernel(kernel: Any) -> np.ndarray:
    if isinstance(kernel, str):
        if kernel not in KERNELS:
            raise ValueError(f"kernel: unknown kernel name {kernel!r}; known: {', '.join(KERNELS)}")
        return KERNELS[kernel]
    try:
        array = np.asarray(kernel, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise TypeError(f"kernel: expected a 2-D array of numbers or a kernel name, got {type(kernel).__name__}") from error
    if array.ndim == 1:
        array = array[None, :]
    if array.ndim != 2 or array.size == 0:
        raise ValueError(f"kernel: expected a non-empty 2-D array, got shape {array.shape}")
    if array.shape[0] % 2 == 0 or array.shape[1] % 2 == 0:
        raise ValueError(f"kernel: expected odd height and width (a centre tap), got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError("kernel: expected finite weights")
    return array.astype(np.float32)


def _check_size(size: Any) -> int:
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)):
        raise TypeError(f"size: expected an odd positive int, got {type(size).__name__}")
    if size <= 0 or size % 2 == 0:
        raise ValueError(f"size: expected an odd positive int, got {size}")
    return int(size)


# --- The window engine -------------------------------------------------------------------------
_scratch = threading.local()


def _aligned_empty(length: int) -> np.ndarray:
    """An uninitialised float32 array whose data starts on a 64-byte boundary.

    Dr.Jit compiles a contiguous load as ``align 64`` or ``align 1`` depending on the
    pointer it maps, so arrays handed to kernels must have a reproducible alignment, or
    the same kernel is compiled again whenever numpy's allocation lands elsewhere.
    """
    raw = np.empty(length + 16, dtype=np.float32)
    start = (-raw.ctypes.data % 64) // 4
    return raw[start:start + length]


def _padded_buffer(length: int) -> np.ndarray:
    """A reusable per-thread float32 buffer of at least ``length`` elements (no page faults)."""
    buffer = getattr(_scratch, "buffer", None)
    if buffer is None or buffer.size < length or buffer.size > 4 * length + (1 << 20):
        buffer = _aligned_empty(length)
        _scratch.buffer = buffer
    else:
        dr.sync_thread()     # LLVM kernels run asynchronously: the last call's may still read it
    return buffer[:length]


def _source_index(j: np.ndarray, n: int, border: str) -> np.ndarray:
    """Map integer coordinates ``j`` (any value) into 0..n-1 for a padded border mode (-1 = zero)."""
    if border == "clamp":
        return np.clip(j, 0, n - 1)
    if border == "reflect":          # scipy 'reflect', OpenCV BORDER_REFLECT: period 2n
        m = np.mod(j, 2 * n)
        return np.where(m < n, m, 2 * n - 1 - m)
    if border == "mirror":           # scipy 'mirror', OpenCV BORDER_REFLECT_101: period 2n - 2
        if n == 1:
            return np.zeros_like(j)
        m = np.mod(j, 2 * n - 2)
        return np.where(m < n, m, 2 * n - 2 - m)
    if border == "wrap":
        return np.mod(j, n)
    return np.where((j >= 0) & (j < n), j, -1)   # constant (zero padding)


class _Window:
    """Shifted zero-copy views of one image for window operations with radii (ry, rx)."""

    def __init__(self, tensor: TensorXf, ry: int, rx: int, *, edge: bool = False):
        shape = tuple(tensor.shape)
        self.shape = shape
        self.H, self.W = shape[0], shape[1]
        self.C = shape[2] if len(shape) == 3 else 1
        self.N = self.H * self.W * self.C
        self.ry, self.rx = ry, rx
        self.source = np.asarray(tensor).reshape(-1)
        self.margin = (ry * self.W + rx) * self.C
        padded = _padded_buffer(self.N + 2 * self.margin)
        padded[:self.margin] = 0.0
        padded[self.margin + self.N:] = 0.0
        padded[self.margin:self.margin + self.N] = self.source
        if edge:    # rows above / below the image repeat the first / last row (clamp border)
            row = self.W * self.C
            padded[self.margin - ry * row:self.margin] = np.tile(self.source[:row], ry)
            padded[self.margin + self.N:self.margin + self.N + ry * row] = np.tile(self.source[-row:], ry)
        self.padded = padded
        index = dr.arange(UInt32, self.N)
        pixel = index // self.C if self.C > 1 else index
        y = pixel // self.W
        x = pixel - y * self.W
        self.x, self.y = x, y
        if self.has_interior:
            self.inside = (y >= ry) & (y < self.H - ry) & (x >= rx) & (x < self.W - rx)
        else:
            self.inside = dr.zeros(Bool, self.N)

    @property
    def has_interior(self) -> bool:
        return self.H > 2 * self.ry and self.W > 2 * self.rx

    def tap(self, dy: int, dx: int) -> Float:
        start = self.margin + (dy * self.W + dx) * self.C
        return Float(self.padded[start:start + self.N])

    def taps(self, offsets: Sequence[tuple[int, int]]) -> Taps:
        return {d: self.tap(*d) for d in offsets}

    def clamped_taps(self, offsets: Sequence[tuple[int, int]]) -> Taps:
        """Taps under the ``clamp`` border for *every* pixel, ring included (needs ``edge=True``).

        Rows come clamped from the replicated margins; a column ``x + dx`` outside the image
        is replaced, with selects on ``x``, by the tap that reads the edge column instead
        (``dx' = clamp(x + dx, 0, W - 1) - x``), so no ring pass is needed.
        """
        taps = {}
        for dy, dx in offsets:
            value = self.tap(dy, dx)
            for k in range(min(abs(dx), self.W)):   # x + dx < 0: x = k reads column 0, tap dx' = -k
                if dx < 0:                    # x + dx > W - 1: W - 1 - x = k reads tap dx' = k
                    value = dr.select(self.x == k, self.tap(dy, -k), value)
                else:
                    value = dr.select(self.x == self.W - 1 - k, self.tap(dy, k), value)
            taps[(dy, dx)] = value
        return taps

    def ring_taps(self, border: str, offsets: Sequence[tuple[int, int]]) -> tuple[UInt32, Taps]:
        """Element indices of the ring and, per tap, the ring's values under a padded border mode."""
        index, zero, elements = _ring_plan(self.H, self.W, self.C, self.ry, self.rx, border, tuple(offsets))
        pixels = self.source.reshape(self.H * self.W, self.C)
        block = _aligned_empty(index.size * self.C).reshape(*index.shape, self.C)
        np.take(pixels, index, axis=0, out=block)          # one block: reproducible alignment per tap
        if zero is not None:
            block[zero] = 0.0
        taps = {d: Float(block[k].reshape(-1)) for k, d in enumerate(offsets)}
        return elements, taps


@functools.lru_cache(maxsize=32)
def _ring_plan(H: int, W: int, C: int, ry: int, rx: int, border: str,
               offsets: tuple[tuple[int, int], ...]) -> tuple[np.ndarray, np.ndarray | None, UInt32]:
    """Source pixel of every (tap, ring pixel) under a padded border mode, cached per geometry.

    The ring is the pixels where the window does not fit (``ry`` rows and ``rx`` columns on
    each side). Returns the (taps, ring) source pixel indices, the mask of taps that read the
    zero outside (``constant`` only, else None) and the ring's element indices.
    """
    top = np.arange(min(ry, H))
    bottom = np.arange(max(H - ry, min(ry, H)), H)
    rows = np.concatenate([top, bottom])
    ys = [np.repeat(rows, W)]
    xs = [np.tile(np.arange(W), rows.size)]
    middle = np.arange(min(ry, H), max(H - ry, min(ry, H)))
    if middle.size:
        cols = np.concatenate([np.arange(min(rx, W)), np.arange(max(W - rx, min(rx, W)), W)])
        ys.append(np.repeat(middle, cols.size))
        xs.append(np.tile(cols, middle.size))
    ys, xs = np.concatenate(ys), np.concatenate(xs)
    dys = np.array([d[0] for d in offsets])[:, None]
    dxs = np.array([d[1] for d in offsets])[:, None]
    sy = _source_index(ys[None, :] + dys, H, border)          # (taps, ring pixels)
    sx = _source_index(xs[None, :] + dxs, W, border)
    index = np.maximum(sy * W + sx, 0)
    zero = ((sy < 0) | (sx < 0)) if border == "constant" else None
    elements = ((ys * W + xs)[:, None] * C + np.arange(C)[None, :]).reshape(-1)
    for array in (index, zero):
        if array is not None:
            array.setflags(write=False)
    return index, zero, UInt32(elements.astype(np.uint32))


def _window_apply(tensor: TensorXf, ry: int, rx: int, border: str, offsets: Sequence[tuple[int, int]],
                  combine: Callable[[Taps], tuple[Float, ...]], *, absolute: bool = False,
                  reduce: bool = False) -> tuple[list[Float], _Window, tuple[float, float] | None]:
    """Run ``combine`` over every pixel's window and apply the border mode.

    Returns the full-size flat outputs (border pixels 0 for ``zero``/``crop``, the input
    for ``keep``), the window, and with ``reduce`` the (min, max) of the finite values of
    the first output over the computed pixels (``None`` when there are none). With
    ``reduce`` and a non-padded border, the first output's ring holds NaN (left out of
    min/max): the caller refills it (``_rescale`` with the ``inside`` mask).
    """
    clamp = border == "clamp"
    window = _Window(tensor, ry, rx, edge=clamp)
    outs = list(combine(window.clamped_taps(offsets) if clamp else window.taps(offsets)))
    if absolute:
        outs[0] = dr.abs(outs[0])
    padded = border in _PADDED          # every pixel computed (no zero / keep / crop ring)
    if not padded:
        fill = window.tap(0, 0) if border == "keep" else Float(0.0)
        fills = [fill] * len(outs)
        if reduce:
            fills[0] = Float(math.nan)
        outs = [dr.select(window.inside, o, f) for o, f in zip(outs, fills)]
    dr.eval(*outs)
    if padded and not clamp:            # clamp's ring is already right (`_Window.clamped_taps`)
        elements, ring = window.ring_taps(border, offsets)
        if dr.width(elements):
            values = list(combine(ring))
            if absolute:
                values[0] = dr.abs(values[0])
            for out, value in zip(outs, values):
                dr.scatter(out, value, elements)
            dr.eval(*outs)
    bounds = _finite_extrema(outs[0]) if reduce else None
    return outs, window, bounds


#: Ways of the first min/max folding pass in `_finite_extrema` (lane j folds entries j + k * n // 16).
_REDUCE_WAYS = 16


def _min(a: Float, b: Float) -> Float:
    """``min(a, b)`` as compare + select: one ``vminps`` (``dr.minimum`` lowers to the slower,
    NaN-propagating ``llvm.minimum``, about 8x slower here). NaN in ``a`` gives ``b``."""
    return dr.select(a < b, a, b)


def _max(a: Float, b: Float) -> Float:
    """``max(a, b)`` as compare + select (see `_min`). NaN in ``a`` gives ``b``."""
    return dr.select(a > b, a, b)


def _finite_extrema(values: Float) -> tuple[float, float] | None:
    """(min, max) of the finite entries of an evaluated flat array; ``None`` when there are none.

    One Dr.Jit pass folds 16 zero-copy views of the array (lane ``j`` takes entries
    ``j + k * n // 16``, k = 0..15) into per-lane min and max, then numpy finishes the
    short per-lane results and the < 16 tail entries. (Dr.Jit's ``dr.min`` costs a
    slower separate reduction per extremum, and ``mode="symbolic"`` fuses it as atomics
    that cost about 3x a pass here.)
    """
    array = values.numpy().reshape(-1)
    lanes = array.size // _REDUCE_WAYS // 16 * 16     # views share the base's alignment: <= 2 kernels per size
    pieces = []
    rest = array
    if lanes >= 1024:
        low = high = None
        for k in range(_REDUCE_WAYS):
            view = Float(array[k * lanes:(k + 1) * lanes])
            finite = dr.isfinite(view)
            lo, hi = dr.select(finite, view, math.inf), dr.select(finite, view, -math.inf)
            low, high = (lo, hi) if low is None else (_min(lo, low), _max(hi, high))
        dr.eval(low, high)
        pieces = [low.numpy(), high.numpy()]
        rest = array[_REDUCE_WAYS * lanes:]
    rest = rest[np.isfinite(rest)]
    if rest.size:
        pieces += [rest, rest]
    lows = [float(p.min()) for p in pieces[0::2] if p.size]
    highs = [float(p.max()) for p in pieces[1::2] if p.size]
    low, high = min(lows, default=math.inf), max(highs, default=-math.inf)
    return (low, high) if low <= high else None


def _finish(values: Float, window: _Window, border: str) -> TensorXf:
    """Wrap a flat full-size result as a tensor; ``crop`` drops the ring."""
    tensor = TensorXf(values, window.shape)
    if border != "crop":
        return tensor
    H, W, ry, rx = window.H, window.W, window.ry, window.rx
    if H <= 2 * ry or W <= 2 * rx:
        raise ValueError(f"border='crop': the image ({H}x{W}) is smaller than the window "
                         f"({2 * ry + 1}x{2 * rx + 1}); nothing is left")
    return TensorXf(np.ascontiguousarray(np.asarray(tensor)[ry:H - ry, rx:W - rx]))


def _rescale(values: Float, bounds: tuple[float, float] | None, mask: Bool | None,
             fill: Float | None) -> Float:
    """(v - min) * 255 / (max - min) where ``mask``; non-finite and constant cases per `normalize`."""
    low, high = bounds if bounds is not None else (0.0, 0.0)
    scale = 255.0 / (high - low) if high > low else 0.0
    if not math.isfinite(scale):       # max - min underflows to a subnormal
        scale = 255.0 / (np.float64(high) - np.float64(low))
    scaled = _min(_max((values - dr.opaque(Float, low)) * dr.opaque(Float, scale), Float(0.0)), Float(255.0))
    scaled = dr.select(dr.isinf(values), 255.0, scaled)
    scaled = dr.select(dr.isnan(values), values, scaled)
    if mask is not None:
        scaled = dr.select(mask, scaled, fill)
    return scaled


# --- Public operations ------------------------------------------------------------------------
def _weighted_sum(kernel: np.ndarray) -> tuple[list[tuple[int, int]], Callable[[Taps], tuple[Float]]]:
    """Taps and combination for a correlation kernel; weights are opaque (no recompilation)."""
    ry, rx = kernel.shape[0] // 2, kernel.shape[1] // 2
    offsets = [(dy - ry, dx - rx) for dy in range(kernel.shape[0]) for dx in range(kernel.shape[1])
               if kernel[dy, dx] != 0.0]

    def combine(taps: Taps) -> tuple[Float]:
        total = Float(0.0)
        for dy, dx in offsets:
            total = dr.fma(taps[(dy, dx)], opaque_scalar(Float, float(kernel[dy + ry, dx + rx])), total)
        return (total,)

    return offsets, combine


def correlate(image: Any, kernel: Any, *, border: str = "zero", normalize: bool = False) -> TensorXf:
    """Cross-correlate ``image`` with an odd-sized ``kernel`` (SPEC "Cross-correlation").

    ``out[y, x] = sum_{i, j} kernel[i, j] * image[y + i - ry, x + j - rx]`` (no kernel flip:
    correlation, like ``cv2.filter2D`` and ``scipy.ndimage.correlate``), for every pixel
    where the kernel fits; the other pixels follow ``border``.

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
        Intensities; colour channels are filtered independently.
    kernel : array_like (kh, kw) or str
        Weights with odd height and width (1-D input is one row), or a name from
        :data:`KERNELS` (``"sobel_x"``, ``"gaussian"``, ...). Kernels are not normalised:
        divide by the sum yourself for an averaging filter.
    border : str
        ``"zero"`` (default), ``"crop"``, ``"keep"``, ``"clamp"``, ``"reflect"``,
        ``"mirror"``, ``"wrap"`` or ``"constant"`` (module docstring).
    normalize : bool
        Make the result positive (absolute value) and stretch it to 0..255:
        ``(|I| - min) * 255 / (max - min)``, min and max over the computed pixels only
        (for ``zero``/``keep`` the ring stays 0 / keeps the input and does not count).

    Returns
    -------
    drjit.llvm.TensorXf
        Same shape as ``image`` (``crop``: ``(H - kh + 1, W - kw + 1[, C])``).

    Raises
    ------
    ValueError
        Even, empty or non-finite kernels, an unknown border, ``crop`` of an image smaller
        than the kernel.

    Notes
    -----
    ===============  ==========================  ==========================================
    domain           range                       edges
    ===============  ==========================  ==========================================
    any float        any float (0..255 with      constant image -> interior = value * sum of
                     ``normalize``)              weights; normalised constant -> all 0;
                                                 image smaller than the kernel -> all border;
                                                 NaN/inf propagate through non-zero weights
                                                 (zero weights are skipped) and are left out
                                                 of min/max (inf -> 255, NaN stays NaN).
    ===============  ==========================  ==========================================

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.filters import correlate, GAUSSIAN_3
    >>> img = np.zeros((5, 5)); img[2, 2] = 1.0
    >>> np.asarray(correlate(img, GAUSSIAN_3))[1:4, 1:4].tolist()
    [[1.0, 3.0, 1.0], [3.0, 9.0, 3.0], [1.0, 3.0, 1.0]]
    >>> np.asarray(correlate(img, GAUSSIAN_3))[0].tolist()   # the border ring is set to 0
    [0.0, 0.0, 0.0, 0.0, 0.0]
    """
    kernel = _check_kernel(kernel)
    border = _check_border(border)
    if not isinstance(normalize, (bool, np.bool_)):
        raise TypeError(f"normalize: expected a bool, got {type(normalize).__name__}")
    tensor = as_tensor(image)
    ry, rx = kernel.shape[0] // 2, kernel.shape[1] // 2
    offsets, combine = _weighted_sum(kernel)
    if not offsets:                                    # an all-zero kernel
        offsets = [(0, 0)]
        combine = lambda taps: (taps[(0, 0)] * 0.0,)  # noqa: E731
    (out,), window, bounds = _window_apply(tensor, ry, rx, border, offsets, combine,
                                           absolute=normalize, reduce=normalize)
    if normalize:
        padded = border in _PADDED
        fill = window.tap(0, 0) if border == "keep" else Float(0.0)
        out = _rescale(out, bounds, None if padded else window.inside, fill)
        dr.eval(out)
    return _finish(out, window, border)


@eager_if_shared
def normalize(image: Any, *, absolute: bool = True) -> TensorXf:
    """Min-max normalise to 0..255 over the whole image (SPEC): ``(|I| - min) * 255 / (max - min)``.

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
        Any float values; min and max are taken over all channels together.
    absolute : bool
        Make negative values positive first (absolute value), as the SPEC asks for
        correlation results (default True). With False the signed values are stretched.

    Returns
    -------
    drjit.llvm.TensorXf
        Same shape, values in 0..255.

    Notes
    -----
    ===============  ===============  =====================================================
    domain           range            edges
    ===============  ===============  =====================================================
    any float        0..255           constant image (max = min) -> all 0, no division by
                                      zero; NaN and +-inf are left out of min/max; inf ->
                                      255 (-inf too when ``absolute``), NaN stays NaN;
                                      huge values are scaled without overflow.
    ===============  ===============  =====================================================

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.filters import normalize
    >>> np.asarray(normalize(np.array([[-2.0, 1.0], [3.0, 5.0]]))).tolist()
    [[63.75, 0.0], [127.5, 255.0]]
    """
    if not isinstance(absolute, (bool, np.bool_)):
        raise TypeError(f"absolute: expected a bool, got {type(absolute).__name__}")
    tensor = as_tensor(image)
    values = dr.abs(tensor.array) if absolute else tensor.array
    dr.eval(values)
    out = _rescale(values, _finite_extrema(values), None, None)
    out = dr.select(values == -math.inf, 0.0, out)
    return TensorXf(out, tensor.shape)


def _gradient(image: Any, kx: np.ndarray, ky: np.ndarray, border: str, components: bool):
    border = _check_border(border)
    if not isinstance(components, (bool, np.bool_)):
        raise TypeError(f"components: expected a bool, got {type(components).__name__}")
    tensor = as_tensor(image)
    offsets_x, combine_x = _weighted_sum(kx)
    offsets_y, combine_y = _weighted_sum(ky)
    offsets = sorted(set(offsets_x) | set(offsets_y))

    def combine(taps: Taps) -> tuple[Float, Float, Float]:
        (gx,), (gy,) = combine_x(taps), combine_y(taps)
        return dr.sqrt(dr.fma(gx, gx, gy * gy)), gx, gy

    outs, window, _ = _window_apply(tensor, 1, 1, border, offsets, combine if components else
                                    (lambda taps: combine(taps)[:1]))
    results = tuple(_finish(o, window, border) for o in outs)
    return results if components else results[0]


def sobel(image: Any, *, border: str = "zero", components: bool = False):
    """Sobel gradient magnitude ``sqrt(gx^2 + gy^2)`` with the SPEC's SOBEL_X and SOBEL_Y.

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
    border : str
        As in :func:`correlate` (default ``"zero"``: the 1-pixel ring is 0).
    components : bool
        Also return the correlations with SOBEL_X and SOBEL_Y: ``(magnitude, gx, gy)``.

    Returns
    -------
    drjit.llvm.TensorXf or tuple of them

    Notes
    -----
    Domain any float; range magnitude >= 0. A constant image has zero gradient
    everywhere; one-pixel images are all border. Not normalised: follow with
    :func:`normalize` for display. ``gy`` is positive where intensity grows *upwards*.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.filters import sobel
    >>> step = np.array([[0, 0, 10, 10]] * 3, dtype=float)
    >>> np.asarray(sobel(step))[1].tolist()
    [0.0, 40.0, 40.0, 0.0]
    """
    return _gradient(image, SOBEL_X, SOBEL_Y, border, components)


def prewitt(image: Any, *, border: str = "zero", components: bool = False):
    """Prewitt gradient magnitude ``sqrt(gx^2 + gy^2)`` with the SPEC's PREWITT_X and PREWITT_Y.

    Same parameters, returns and edge cases as :func:`sobel`. Note PREWITT_X is
    ``[[1, 0, -1]] * 3``, so ``gx`` is positive where intensity grows to the *left*.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.filters import prewitt
    >>> step = np.array([[0, 0, 10, 10]] * 3, dtype=float)
    >>> np.asarray(prewitt(step))[1].tolist()
    [0.0, 30.0, 30.0, 0.0]
    """
    return _gradient(image, PREWITT_X, PREWITT_Y, border, components)


def laplacian(image: Any, *, border: str = "zero") -> TensorXf:
    """Second derivative: correlation with :data:`LAPLACIAN` ``[[0,1,0],[1,-4,1],[0,1,0]]``.

    Equals ``cv2.Laplacian(image, ksize=1)`` inside the image. Follow with
    :func:`zero_crossings` for edges. Constant and linear ramps give 0.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.filters import laplacian
    >>> np.asarray(laplacian(np.array([[0, 0, 0], [0, 1, 0], [0, 0, 0]])))[1, 1].item()
    -4.0
    """
    return correlate(image, LAPLACIAN, border=border)


def zero_crossings(image: Any, *, connectivity: int = 8, max_value: float = 255.0) -> TensorXf:
    """Zero crossings of a second derivative: a pixel above zero with a neighbour below zero (SPEC).

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
        Usually the output of :func:`laplacian`.
    connectivity : {8, 4}
        Neighbours looked at: the 8 around the pixel, or the 4 edge-adjacent ones.
        Neighbours outside the image do not exist (they never count as below zero).
    max_value : float
        Value of crossing pixels; all others are 0.

    Returns
    -------
    drjit.llvm.TensorXf
        Same shape, values in {0, max_value}. A constant image (or all zeros) has no
        crossings; NaN is neither above nor below zero.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.filters import zero_crossings
    >>> np.asarray(zero_crossings(np.array([[1.0, -1.0, 0.0, 2.0]]))).tolist()
    [[255.0, 0.0, 0.0, 0.0]]
    """
    if connectivity not in (4, 8) or isinstance(connectivity, bool):
        raise ValueError(f"connectivity: expected 4 or 8, got {connectivity!r}")
    if not isinstance(max_value, (int, float, np.integer, np.floating)) or not np.isfinite(max_value):
        raise ValueError(f"max_value: expected a finite number, got {max_value!r}")
    tensor = as_tensor(image)
    window = _Window(tensor, 1, 1)
    centre = window.tap(0, 0)
    neighbours = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1)
                  if (dy, dx) != (0, 0) and (connectivity == 8 or dy == 0 or dx == 0)]
    below = Bool(False)
    for dy, dx in neighbours:
        exists = Bool(True)       # rows outside the image read the zero margin: never below zero
        if dx < 0:
            exists = window.x > 0
        elif dx > 0:
            exists = window.x < window.W - 1
        below |= exists & (window.tap(dy, dx) < 0.0)
    out = dr.select((centre > 0.0) & below, dr.opaque(Float, float(max_value)), 0.0)
    dr.eval(out)
    return TensorXf(out, tensor.shape)


@eager_if_shared
def threshold(image: Any, level: float = 128, *, max_value: float = 255.0) -> TensorXf:
    """Threshold: values below ``level`` become 0, values at or above it ``max_value``.

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
        Intensities (0..255 by convention; any real values are accepted).
    level : float
        The threshold (SPEC: 128 for dithering). A value equal to ``level`` becomes ``max_value``.
    max_value : float
        The value of "on" pixels (default 255).

    Returns
    -------
    drjit.llvm.TensorXf
        Same shape as ``image``, values in {0, max_value}. NaN compares false and becomes 0.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.filters import threshold
    >>> np.asarray(threshold(np.array([[0, 127], [128, 255]]))).tolist()
    [[0.0, 0.0], [255.0, 255.0]]
    """
    if not isinstance(level, (int, float, np.integer, np.floating)) or isinstance(level, bool) or not np.isfinite(level):
        raise ValueError(f"level: expected a finite number, got {level!r}")
    if not isinstance(max_value, (int, float, np.integer, np.floating)) or not np.isfinite(max_value):
        raise ValueError(f"max_value: expected a finite number, got {max_value!r}")
    tensor = as_tensor(image)
    values = dr.select(tensor.array >= dr.opaque(Float, float(level)), dr.opaque(Float, float(max_value)), 0.0)
    return TensorXf(values, tensor.shape)


# --- Median: a sorting network held in registers ----------------------------------------------
#: Devillard's / Paeth's 19-exchange median-of-9 network (N. Devillard, "Fast median search:
#: an ANSI C implementation", 1998, ``opt_med9``); pairs (i, j) leave min in i, max in j.
_MEDIAN9 = ((1, 2), (4, 5), (7, 8), (0, 1), (3, 4), (6, 7), (1, 2), (4, 5), (7, 8), (0, 3),
            (5, 8), (4, 7), (3, 6), (1, 4), (2, 5), (4, 7), (4, 2), (6, 4), (4, 2))


#: Devillard's 99-exchange median-of-25 network (N. Devillard 1998, ``opt_med25``, after
#: Graphics Gems); median in wire 12. Checked on all 2^25 0-1 inputs against Batcher's sort
#: (0-1 principle) in tests/test_spatial_fast_paths.py. 113 exchanges remain of a pruned Batcher.
_MEDIAN25 = (
    (0, 1), (3, 4), (2, 4), (2, 3), (6, 7), (5, 7), (5, 6), (9, 10), (8, 10), (8, 9), (12, 13),
    (11, 13), (11, 12), (15, 16), (14, 16), (14, 15), (18, 19), (17, 19), (17, 18), (21, 22),
    (20, 22), (20, 21), (23, 24), (2, 5), (3, 6), (0, 6), (0, 3), (4, 7), (1, 7), (1, 4),
    (11, 14), (8, 14), (8, 11), (12, 15), (9, 15), (9, 12), (13, 16), (10, 16), (10, 13),
    (20, 23), (17, 23), (17, 20), (21, 24), (18, 24), (18, 21), (19, 22), (8, 17), (9, 18),
    (0, 18), (0, 9), (10, 19), (1, 19), (1, 10), (11, 20), (2, 20), (2, 11), (12, 21), (3, 21),
    (3, 12), (13, 22), (4, 22), (4, 13), (14, 23), (5, 23), (5, 14), (15, 24), (6, 24), (6, 15),
    (7, 16), (7, 19), (13, 21), (15, 23), (7, 13), (7, 15), (1, 9), (3, 11), (5, 17), (11, 17),
    (9, 17), (4, 10), (6, 12), (7, 14), (4, 6), (4, 7), (12, 14), (10, 14), (6, 7), (10, 12),
    (6, 10), (6, 17), (12, 17), (7, 17), (7, 10), (12, 18), (7, 12), (10, 18), (12, 20),
    (10, 20), (10, 12))
#: Fixed median networks: window size -> (exchanges, wire holding the median).
_MEDIAN_NETWORKS = {9: (_MEDIAN9, 4), 25: (_MEDIAN25, 12)}


def _batcher(n: int) -> list[tuple[int, int]]:
    """Batcher's odd-even merge sort network on the next power of two >= n (Knuth, TAOCP 5.3.4)."""
    size = 1 << max(0, (n - 1).bit_length())
    pairs = []
    p = 1
    while p < size:
        k = p
        while k >= 1:
            for j in range(k % p, size - k, 2 * k):
                for i in range(min(k, size - j - k)):
                    if (i + j) // (2 * p) == (i + j + k) // (2 * p):
                        pairs.append((i + j, i + j + k))
            k //= 2
        p *= 2
    return pairs


def _exchange(a: Float, b: Float) -> tuple[Float, Float]:
    """Compare-exchange: (min, max) from one compare and two selects (``vminps``/``vmaxps``-like;
    ``dr.minimum``/``dr.maximum`` lower to NaN-propagating ``llvm.minimum``, 8x slower here)."""
    less = a < b
    return dr.select(less, a, b), dr.select(less, b, a)


def _median_network(values: list[Float]) -> Float:
    """Median of the values with compare-exchanges only (Dr.Jit drops the unused halves)."""
    n = len(values)
    if n in _MEDIAN_NETWORKS:
        network, middle = _MEDIAN_NETWORKS[n]
        wires = list(values)
        for i, j in network:
            wires[i], wires[j] = _exchange(wires[i], wires[j])
        return wires[middle]
    wires: list[Float | None] = list(values) + [None] * ((1 << (n - 1).bit_length()) - n)  # None = +inf
    for i, j in _batcher(n):
        if wires[j] is None:
            continue                       # min(x, +inf) = x: nothing moves
        if wires[i] is None:
            wires[i], wires[j] = wires[j], None
            continue
        wires[i], wires[j] = _exchange(wires[i], wires[j])
    return wires[n // 2]


def median(image: Any, size: int = 3, *, border: str = "clamp") -> TensorXf:
    """Median filter: the ``size`` x ``size`` window sorted, the middle value replaces the centre (SPEC).

    The window's values are held in registers and pass through a sorting network
    (Devillard's 19-exchange network for 3x3 and 99-exchange network for 5x5, Batcher's
    odd-even merge sort otherwise; only the exchanges that lead to the middle value are
    compiled). An exchange is one compare and two selects.

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
        Channels are filtered independently.
    size : int
        Odd window size (1 returns the image).
    border : str
        As in :func:`correlate`; the default ``"clamp"`` matches ``cv2.medianBlur``
        (the course only defines border handling for correlation).

    Returns
    -------
    drjit.llvm.TensorXf

    Notes
    -----
    Domain any float; range within the input's range. Constant images are unchanged.
    NaN inside a window gives an unspecified value of that window (min/max are not
    NaN-aware), as in OpenCV.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.filters import median
    >>> img = np.full((3, 3), 10.0); img[1, 1] = 255.0     # salt noise
    >>> np.asarray(median(img))[1, 1].item()
    10.0
    """
    size = _check_size(size)
    border = _check_border(border)
    tensor = as_tensor(image)
    r = size // 2
    if r == 0:   # the identity, as a copy: numpy input shares the caller's memory
        values = Float(tensor.array) if dr.is_array_v(image) else Float(np.array(tensor.array, dtype=np.float32))
        return _finish(values, _Window(tensor, 0, 0), border)
    offsets = [(dy, dx) for dy in range(-r, r + 1) for dx in range(-r, r + 1)]

    def combine(taps: Taps) -> tuple[Float]:
        return (_median_network([taps[d] for d in offsets]),)

    (out,), window, _ = _window_apply(tensor, r, r, border, offsets, combine)
    return _finish(out, window, border)
