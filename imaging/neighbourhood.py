"""The padded-window engine of the spatial filters (:mod:`pointillist.imaging.filters`).

A window operation (``correlate``, ``sobel``, ``prewitt``, ``laplacian``,
``zero_crossings``, ``median`` of :mod:`pointillist.imaging.filters`) runs as one Dr.Jit
kernel over all pixels. The taps of the window are *contiguous* loads: the
image is copied once into a flat buffer with a margin of ``ry * W + rx`` pixels
at both ends and every tap ``(dy, dx)`` reads a zero-copy shifted view of that
buffer (Dr.Jit maps numpy memory without copying), so no tap needs a gather.
Pixels where the window does not fit (the *border ring*, ``ry`` rows and ``rx``
columns on each side) are then handled by the border mode:

================  ==============================================  ===========================  ========================
``border``        border pixels                                   scipy.ndimage ``mode``       OpenCV ``borderType``
================  ==============================================  ===========================  ========================
``"zero"``        set to 0 (the course's choice, the default)     (none)                       (none)
``"crop"``        dropped: the output is ``(H - 2ry, W - 2rx)``   (none)                       (none)
``"keep"``        keep the input's values                         (none)                       (none)
``"clamp"``       window sees the edge pixel repeated             ``"nearest"``                ``BORDER_REPLICATE``
``"reflect"``     window sees ``dcb|abcd|cba`` (edge repeated)    ``"reflect"``                ``BORDER_REFLECT``
``"mirror"``      window sees ``dcb|abcd|cba`` without the edge   ``"mirror"``                 ``BORDER_REFLECT_101``
``"wrap"``        window sees the image periodically              ``"wrap"``/``"grid-wrap"``   ``BORDER_WRAP``
``"constant"``    window sees zeros outside the image             ``"constant", cval=0``       ``BORDER_CONSTANT``
================  ==============================================  ===========================  ========================

``reflect`` follows scipy's ``"reflect"`` = OpenCV's ``BORDER_REFLECT`` (the
edge pixel is repeated); ``mirror`` is the other convention. ``BORDER_WRAP`` names
OpenCV's equivalent of ``wrap`` for ``cv2.copyMakeBorder``; ``cv2.filter2D`` refuses it
(an assertion, ``columnBorderType != BORDER_WRAP``): pad with ``copyMakeBorder`` first. Reflection and
wrapping repeat as often as needed, so a window larger than the image is fine.
For the padded modes the ring's taps are gathered on the host into small arrays
and pass through the same Dr.Jit combination code, then are scattered into the
result.

Speed notes (measured, benchmarks/imaging_spatial.py): the padded copy is one
memory pass (about 1 ms at 2048x2048) and is the price of contiguous taps; a
full-size output cannot be built from unpadded shifted views, and the
alternatives (scatter of the interior, ``dr.concat``, gathers) measured 2-6x
slower than the copy. Minimum and maximum are written as compare + select
(``select_min``, ``select_max``, the median's exchanges): ``dr.minimum``/``dr.maximum``
lower to LLVM's NaN-propagating ``llvm.minimum``, about 8x slower per exchange here.
The normalisation's min/max folds 16 zero-copy views of the result in one pass
(``finite_extrema``). Every array a kernel maps is 64-byte aligned, so a call
never compiles a kernel again merely because numpy placed memory differently.

The engine knows nothing of the formulas: :func:`window_apply` runs a ``combine`` function
(taps -> outputs) over every pixel's window and applies the border mode.
"""

from __future__ import annotations

import functools
import math
import threading
from collections.abc import Callable, Sequence
from typing import Any

import drjit as dr
import numpy as np
from drjit.llvm.ad import Bool, Float, Int32, UInt32

from pointillist.imaging.arrays import TensorXf

__all__ = ["BORDERS", "PADDED_BORDERS", "Taps", "Window", "check_border", "window_apply", "window_result",
           "finite_extrema", "select_min", "select_max"]

#: Border modes of the window operations (see the table above).
BORDERS = ("zero", "crop", "keep", "clamp", "reflect", "mirror", "wrap", "constant")
#: The border modes whose ring is computed from padded taps (every output pixel is computed).
PADDED_BORDERS = frozenset({"clamp", "reflect", "mirror", "wrap", "constant"})

#: The values of a window's taps, by offset ``(dy, dx)``: what a ``combine`` function receives.
Taps = dict[tuple[int, int], Float]


def check_border(border: Any) -> str:
    """``border`` if it is one of :data:`BORDERS`, else a ValueError naming the argument."""
    if not isinstance(border, str) or border not in BORDERS:
        raise ValueError(f"border: expected one of {', '.join(map(repr, BORDERS))}, got {border!r}")
    return border


#: Per-thread reusable padded buffer (see `_padded_buffer`).
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


class Window:
    """Shifted zero-copy views of one image for window operations with radii (ry, rx)."""

    def __init__(self, tensor: TensorXf, ry: int, rx: int, *, edge: bool = False):
        shape = tuple(tensor.shape)
        self.shape = shape
        self.H, self.W = shape[0], shape[1]
        self.C = shape[2] if len(shape) == 3 else 1
        self.N = self.H * self.W * self.C
        self.ry, self.rx = ry, rx
        index = dr.arange(UInt32, self.N)
        pixel = index // self.C if self.C > 1 else index
        y = pixel // self.W
        x = pixel - y * self.W
        self.x, self.y = x, y
        if self.has_interior:
            self.inside = (y >= ry) & (y < self.H - ry) & (x >= rx) & (x < self.W - rx)
        else:
            self.inside = dr.zeros(Bool, self.N)
        #: An input that tracks gradients is read with gathers (differentiable) instead of
        #: through the host-side padded copy: see :meth:`mapped_taps`.
        self.gathered = bool(dr.grad_enabled(tensor))
        if self.gathered:
            self.values = tensor.array
            return
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

    @property
    def has_interior(self) -> bool:
        return self.H > 2 * self.ry and self.W > 2 * self.rx

    def tap(self, dy: int, dx: int) -> Float:
        if self.gathered:           # zeros outside the image (only the interior's taps are used)
            return self.mapped_taps([(dy, dx)], "constant")[(dy, dx)]
        start = self.margin + (dy * self.W + dx) * self.C
        return Float(self.padded[start:start + self.N])

    def mapped_taps(self, offsets: Sequence[tuple[int, int]], border: str) -> Taps:
        """Taps for *every* pixel under a padded border mode, read with gathers from the image.

        The path of inputs that track gradients (a gather is differentiable; the padded copy goes
        through the host): row and column ``y + dy``, ``x + dx`` are mapped into the image by the
        same rule as the ring (:func:`_source_index`), ``constant`` reading 0 outside.
        """
        H, W, C = self.H, self.W, self.C
        channel = dr.arange(UInt32, self.N) % C if C > 1 else UInt32(0)
        taps = {}
        for dy, dx in offsets:
            rows = _source_index(np.arange(H) + dy, H, border).astype(np.int64)
            cols = _source_index(np.arange(W) + dx, W, border).astype(np.int64)
            row = dr.gather(Int32, Int32(rows.astype(np.int32)), self.y)
            col = dr.gather(Int32, Int32(cols.astype(np.int32)), self.x)
            valid = (row >= 0) & (col >= 0)
            element = (UInt32(row) * W + UInt32(col)) * C + channel
            taps[(dy, dx)] = dr.gather(Float, self.values, element, valid)
        return taps

    def taps(self, offsets: Sequence[tuple[int, int]]) -> Taps:
        if self.gathered:
            return self.mapped_taps(offsets, "constant")
        return {d: self.tap(*d) for d in offsets}

    def clamped_taps(self, offsets: Sequence[tuple[int, int]]) -> Taps:
        """Taps under the ``clamp`` border for *every* pixel, ring included (needs ``edge=True``).

        Rows come clamped from the replicated margins; a column ``x + dx`` outside the image
        is replaced, with selects on ``x``, by the tap that reads the edge column instead
        (``dx' = clamp(x + dx, 0, W - 1) - x``), so no ring pass is needed.
        """
        if self.gathered:
            return self.mapped_taps(offsets, "clamp")
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


def window_apply(tensor: TensorXf, ry: int, rx: int, border: str, offsets: Sequence[tuple[int, int]],
                  combine: Callable[[Taps], tuple[Float, ...]], *, absolute: bool = False,
                  reduce: bool = False) -> tuple[list[Float], Window, tuple[float, float] | None]:
    """Run ``combine`` over every pixel's window and apply the border mode.

    Returns the full-size flat outputs (border pixels 0 for ``zero``/``crop``, the input
    for ``keep``), the window, and with ``reduce`` the (min, max) of the finite values of
    the first output over the computed pixels (``None`` when there are none). With
    ``reduce`` and a non-padded border, the first output's ring holds NaN (left out of
    min/max): the caller refills it (``_rescale`` with the ``inside`` mask).
    """
    clamp = border == "clamp"
    window = Window(tensor, ry, rx, edge=clamp)
    padded = border in PADDED_BORDERS          # every pixel computed (no zero / keep / crop ring)
    if window.gathered:                        # every pixel's taps under the border mode at once
        outs = list(combine(window.mapped_taps(offsets, border if padded else "constant")))
    else:
        outs = list(combine(window.clamped_taps(offsets) if clamp else window.taps(offsets)))
    if absolute:
        outs[0] = dr.abs(outs[0])
    if not padded:
        fill = window.tap(0, 0) if border == "keep" else Float(0.0)
        fills = [fill] * len(outs)
        if reduce:
            fills[0] = Float(math.nan)
        outs = [dr.select(window.inside, o, f) for o, f in zip(outs, fills)]
    dr.eval(*outs)
    if padded and not clamp and not window.gathered:   # clamp's ring is already right (`clamped_taps`)
        elements, ring = window.ring_taps(border, offsets)
        if dr.width(elements):
            values = list(combine(ring))
            if absolute:
                values[0] = dr.abs(values[0])
            for out, value in zip(outs, values):
                dr.scatter(out, value, elements)
            dr.eval(*outs)
    bounds = finite_extrema(dr.detach(outs[0])) if reduce else None
    return outs, window, bounds


#: Ways of the first min/max folding pass in `finite_extrema` (lane j folds entries j + k * n // 16).
_REDUCE_WAYS = 16


def select_min(a: Float, b: Float) -> Float:
    """``min(a, b)`` as compare + select: one ``vminps`` (``dr.minimum`` lowers to the slower,
    NaN-propagating ``llvm.minimum``, about 8x slower here). NaN in ``a`` gives ``b``."""
    return dr.select(a < b, a, b)


def select_max(a: Float, b: Float) -> Float:
    """``max(a, b)`` as compare + select (see `select_min`). NaN in ``a`` gives ``b``."""
    return dr.select(a > b, a, b)


def _fold_extrema(views: list, absolute: bool, counted: Bool | None) -> tuple[np.ndarray, np.ndarray]:
    """Per-lane (min, max) of the finite (absolute) values of equally long ``views``, where ``counted``."""
    low = high = None
    for view in views:
        view = dr.abs(view) if absolute else view
        finite = dr.isfinite(view) if counted is None else dr.isfinite(view) & counted
        lo, hi = dr.select(finite, view, math.inf), dr.select(finite, view, -math.inf)
        low, high = (lo, hi) if low is None else (select_min(lo, low), select_max(hi, high))
    dr.eval(low, high)
    return low.numpy(), high.numpy()


def finite_extrema(values: Float, *, absolute: bool = False, shape: tuple[int, ...] | None = None,
                   ring: tuple[int, int] = (0, 0)) -> tuple[float, float] | None:
    """(min, max) of the finite entries of an evaluated flat array; ``None`` when there are none.

    ``absolute``: of the absolute values. With the image ``shape`` (H, W[, C]), ``ring`` (ry, rx)
    leaves out the pixels less than ry rows or rx columns from the border (the ring a zero-border
    window step leaves uncomputed). One Dr.Jit pass folds 16 zero-copy views of the array into
    per-lane min and max (lane ``j`` of view ``k`` takes entry ``j + k * n // 16``; with a ring,
    16 bands of whole interior rows, so a lane's column and hence its mask is the same in every
    view), then numpy finishes the per-lane results and the entries left over. (Dr.Jit's
    ``dr.min`` costs a slower separate reduction per extremum, and ``mode="symbolic"`` fuses it
    as atomics that cost about 3x a pass here.)
    """
    array = values.numpy().reshape(-1)
    pieces = []
    ry, rx = ring
    if shape is None or not (ry or rx):
        lanes = array.size // _REDUCE_WAYS // 16 * 16     # views share the base's alignment: <= 2 kernels per size
        rest = array
        if lanes >= 1024:
            pieces += _fold_extrema([Float(array[k * lanes:(k + 1) * lanes]) for k in range(_REDUCE_WAYS)],
                                    absolute, None)
            rest = array[_REDUCE_WAYS * lanes:]
    else:
        height, width = shape[0], shape[1]
        channels = shape[2] if len(shape) == 3 else 1
        if height <= 2 * ry or width <= 2 * rx:
            return None
        row = width * channels
        rows = height - 2 * ry
        band = rows // _REDUCE_WAYS                       # whole rows per view
        first = ry
        if band * row >= 1024:
            column = (dr.arange(UInt32, band * row) // channels) % width if channels > 1 else \
                dr.arange(UInt32, band * row) % width
            counted = (column >= rx) & (column < width - rx) if rx else None
            pieces += _fold_extrema([Float(array[(ry + k * band) * row:(ry + (k + 1) * band) * row])
                                     for k in range(_REDUCE_WAYS)], absolute, counted)
            first = ry + _REDUCE_WAYS * band
        rest = array.reshape(height, width, channels)[first:height - ry, rx:width - rx].reshape(-1)
    rest = np.abs(rest) if absolute else rest
    rest = rest[np.isfinite(rest)]
    if rest.size:
        pieces += [rest, rest]
    lows = [float(p.min()) for p in pieces[0::2] if p.size]
    highs = [float(p.max()) for p in pieces[1::2] if p.size]
    low, high = min(lows, default=math.inf), max(highs, default=-math.inf)
    return (low, high) if low <= high else None


def window_result(values: Float, window: Window, border: str) -> TensorXf:
    """Wrap a flat full-size result as a tensor; ``crop`` drops the ring."""
    tensor = TensorXf(values, window.shape)
    if border != "crop":
        return tensor
    H, W, ry, rx = window.H, window.W, window.ry, window.rx
    if H <= 2 * ry or W <= 2 * rx:
        raise ValueError(f"border='crop': the image ({H}x{W}) is smaller than the window "
                         f"({2 * ry + 1}x{2 * rx + 1}); nothing is left")
    if dr.grad_enabled(values):        # the same crop with a (differentiable) gather
        C = window.shape[2] if len(window.shape) == 3 else 1
        h, w = H - 2 * ry, W - 2 * rx
        index = dr.arange(UInt32, h * w * C)
        pixel, channel = index // C, index % C
        y, x = pixel // w, pixel % w
        kept = dr.gather(Float, values, ((y + ry) * W + x + rx) * C + channel)
        return TensorXf(kept, (h, w) + tuple(window.shape[2:]))
    return TensorXf(np.ascontiguousarray(np.asarray(tensor)[ry:H - ry, rx:W - rx]))
