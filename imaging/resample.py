"""Resampling: nearest, bilinear and Keys bicubic interpolation (:ref:`conventions-resampling`).

Two uses of the same interpolation:

- :func:`resize` maps an image (X_a, Y_a) -> (X_b, Y_b);
- :func:`sample` returns the interpolated values at real positions (x, y).

Conventions
-----------
Pixel centres sit at integer coordinates: pixel ``image[r, c]`` is at ``x = c``,
``y = r``. :func:`resize` uses OpenCV's pixel-centre mapping
``src = (dst + 0.5) * scale - 0.5`` with ``scale = size_in / size_out`` on each
axis, so the image's outer edges (at -0.5 and size - 0.5) map onto each other.
Outside the image, the edge pixels repeat (clamp / ``BORDER_REPLICATE``).
Downscaling does not low-pass filter first (like OpenCV's INTER_LINEAR and
INTER_CUBIC; it aliases).

- nearest: the pixel whose centre is nearest (ties go to the right/lower pixel):
  ``floor(src + 0.5)``; for resize this is ``floor((dst + 0.5) * scale)``, computed
  exactly in integers. It is the formula of OpenCV's ``INTER_NEAREST_EXACT``, but OpenCV
  evaluates it in fixed point and picks the other pixel at some exact ties: 201 of the
  1521 (input, output) width pairs in 1..39 differ (14 -> 5 pixels: output 2 sits at
  source 7.0 exactly; this takes pixel 7).
- bilinear: ``v = v1 + (v2 - v1)(x - x1)/(x2 - x1)`` in x, then the same in y.
- bicubic: Keys' cubic convolution kernel (R. Keys, "Cubic convolution
  interpolation for digital image processing", IEEE TASSP 29(6), 1981) with
  parameter ``a``: ``W(t) = (a+2)|t|^3 - (a+3)|t|^2 + 1`` for ``|t| <= 1``,
  ``a|t|^3 - 5a|t|^2 + 8a|t| - 4a`` for ``1 < |t| < 2``, 0 beyond. ``a = -0.5``
  (the default, Keys' choice: third-order accurate, C1-continuous) interpolates
  with a continuous derivative; OpenCV's INTER_CUBIC uses ``a = -0.75``. The
  kernel interpolates (W(0) = 1, W(1) = W(2) = 0) but can overshoot the input's
  range next to edges; ``clamp=True`` limits each 1-D pass to the range of its two
  central taps, so the result stays within the 2x2 pixels around the point.
  ``a`` is taken in -3..0 (:data:`KEYS_A_RANGE`), where W falls from its peak W(0) = 1 without
  going negative inside ``|t| < 1``: outside, the kernel is no longer a smoothing interpolator, and
  a huge ``a`` makes its weights cancel to rounding noise (``a = 1e30``) or overflow float32 to NaN.
"""

from __future__ import annotations

from typing import Any

import drjit as dr
import numpy as np
from drjit.llvm.ad import Float, Int32, UInt32, UInt64

from pointillist.core import checks
from pointillist.imaging.arrays import TensorXf, as_tensor, eager_if_shared

__all__ = ["INTERPOLATIONS", "KEYS_A", "KEYS_A_RANGE", "MAX_RESIZE_VALUES", "keys_kernel", "resize", "sample"]

#: The interpolation methods.
INTERPOLATIONS = ("nearest", "bilinear", "bicubic")
#: Keys' recommended kernel parameter (Keys 1981); OpenCV's INTER_CUBIC uses -0.75.
KEYS_A = -0.5

#: The most values (height x width x channels, output or bicubic's intermediate) :func:`resize`
#: makes: its index arithmetic is 32-bit signed, and Dr.Jit arrays stop at 2^32 entries.
MAX_RESIZE_VALUES = 2**31 - 1


#: The range of Keys' parameter: W is non-negative and non-increasing on [0, 1] (its peak W(0) = 1 at
#: the centre) exactly when -3 <= a <= 0; a > 0 makes W negative inside (0, 1), a < -3 raises it above 1.
KEYS_A_RANGE = (-3.0, 0.0)


def _check_method(method: Any) -> str:
    return checks.choice(method, "method", INTERPOLATIONS)


def _check_a(a: Any) -> float:
    return checks.real(a, "a", low=KEYS_A_RANGE[0], high=KEYS_A_RANGE[1])


def keys_kernel(t: Any, a: float = KEYS_A) -> np.ndarray:
    """Keys' cubic convolution kernel W(t) (numpy; for plots and checks).

    Examples
    --------
    >>> from pointillist.imaging.resample import keys_kernel
    >>> keys_kernel([0.0, 0.5, 1.0, 1.5, 2.0]).tolist()
    [1.0, 0.5625, 0.0, -0.0625, 0.0]
    """
    a = _check_a(a)
    t = np.abs(np.asarray(t, dtype=np.float64))
    inner = (a + 2) * t**3 - (a + 3) * t**2 + 1
    outer = a * t**3 - 5 * a * t**2 + 8 * a * t - 4 * a
    return np.where(t <= 1, inner, np.where(t < 2, outer, 0.0))


def _keys_weights(t: Float, a: Float) -> tuple[Float, Float, Float, Float]:
    """Weights of the taps at -1, 0, 1, 2 for a fractional offset t in [0, 1)."""
    s = 1.0 - t

    def inner(d):
        return dr.fma(dr.fma(a + 2.0, d, -(a + 3.0)), d * d, 1.0)

    def outer(d):   # a (d^3 - 5 d^2 + 8 d - 4) for 1 <= d <= 2
        return a * dr.fma(dr.fma(d - 5.0, d, 8.0), d, -4.0)

    return outer(t + 1.0), inner(t), inner(s), outer(s + 1.0)


def _axis(coordinate: Float, n: int, method: str):
    """Integer base index (clamped taps) and fraction along one axis of length n.

    The coordinate is first clamped to [-2, n + 1]: every tap there already reads the edge
    pixel, and far positions (beyond Int32, or float32 infinity) must not wrap around.
    """
    coordinate = dr.clip(coordinate, -2.0, float(n + 1))
    if method == "nearest":
        return (dr.clip(Int32(dr.floor(coordinate + 0.5)), 0, n - 1),), None
    base = dr.floor(coordinate)
    t = coordinate - base
    i0 = Int32(base)
    offsets = (0, 1) if method == "bilinear" else (-1, 0, 1, 2)
    return tuple(dr.clip(i0 + k, 0, n - 1) for k in offsets), t


def _clamp_pair(value: Float, v0: Float, v1: Float) -> Float:
    return dr.clip(value, dr.minimum(v0, v1), dr.maximum(v0, v1))


def _interpolate_1d(values: list[Float], t: Float | None, method: str, a: Float, clamp: bool) -> Float:
    if method == "nearest":
        return values[0]
    if method == "bilinear":
        return dr.fma(values[1] - values[0], t, values[0])
    w = _keys_weights(t, a)
    out = values[0] * w[0] + values[1] * w[1] + values[2] * w[2] + values[3] * w[3]
    return _clamp_pair(out, values[1], values[2]) if clamp else out


def _interpolate_2d(source: Float, H: int, W: int, C: int, x: Float, y: Float, channel: UInt32 | int,
                    method: str, a: Float, clamp: bool) -> Float:
    xs, tx = _axis(x, W, method)
    ys, ty = _axis(y, H, method)
    rows = []
    for iy in ys:
        taps = [dr.gather(Float, source, UInt32((iy * W + ix) * C) + channel) for ix in xs]
        rows.append(_interpolate_1d(taps, tx, method, a, clamp))
    return _interpolate_1d(rows, ty, method, a, clamp)


def _check_options(method, a, clamp):
    return _check_method(method), _check_a(a), checks.boolean(clamp, "clamp")


@eager_if_shared
def resize(image: Any, size: tuple[int, int], method: str = "bilinear", *, a: float = KEYS_A,
           clamp: bool = False) -> TensorXf:
    """Resize ``image`` to ``size = (width, height)`` by interpolation (pixel-centre convention).

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
    size : (int, int)
        Output width and height (like ``cv2.resize``'s ``dsize``), both >= 1, with
        width x height x channels at most :data:`MAX_RESIZE_VALUES` (ValueError otherwise).
    method : {"nearest", "bilinear", "bicubic"}
    a : float
        Keys' parameter for bicubic, in -3..0 (:data:`KEYS_A_RANGE`; default -0.5, -0.75
        reproduces OpenCV's INTER_CUBIC).
    clamp : bool
        Bicubic only: clamp the overshoot (see the module docstring). Off by default.

    Returns
    -------
    drjit.llvm.ad.TensorXf
        (height, width) or (height, width, C).

    Notes
    -----
    ============  ============================================  ==================================
    domain        range                                         edges
    ============  ============================================  ==================================
    any float     nearest/bilinear: within the input's range;   same size -> identity (finite
                  bicubic: may overshoot unless ``clamp``       values); 1x1 input -> constant;
                                                                NaN/inf spread to every output
                                                                pixel whose support holds them.
    ============  ============================================  ==================================

    Bicubic runs as two 1-D passes (rows, then columns), 4 taps each.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.resample import resize
    >>> np.asarray(resize(np.array([[0.0, 4.0]]), (4, 1))).tolist()
    [[0.0, 1.0, 3.0, 4.0]]
    """
    method, a, clamp = _check_options(method, a, clamp)
    width, height = checks.integers(size, "size", 2, low=1)  # (width, height)
    tensor = as_tensor(image)
    H, W = tensor.shape[0], tensor.shape[1]
    C = tensor.shape[2] if tensor.ndim == 3 else 1
    _check_resize_size(width, height, C, H if method == "bicubic" else 0)
    out_shape = (height, width) + ((C,) if tensor.ndim == 3 else ())
    a_value = dr.opaque(Float, a)
    if method == "bicubic":
        # Pass 1: along x, for every input row -> (H, width, C); pass 2: along y.
        middle = _pass_1d(tensor.array, H, W, C, width, axis=1, a=a_value, clamp=clamp)
        out = _pass_1d(middle, H, width, C, height, axis=0, a=a_value, clamp=clamp)
        return TensorXf(out, out_shape)
    index = dr.arange(UInt32, height * width * C)
    pixel = index // C if C > 1 else index
    channel = index - pixel * C if C > 1 else 0
    yo = pixel // width
    xo = pixel - yo * width
    if method == "nearest":   # floor((dst + 0.5) * n_in / n_out) in exact integer arithmetic
        ix = _nearest_index(xo, W, width)
        iy = _nearest_index(yo, H, height)
        out = dr.gather(Float, tensor.array, (iy * W + ix) * C + channel)
    else:
        x = dr.fma(Float(xo), W / width, 0.5 * W / width - 0.5)
        y = dr.fma(Float(yo), H / height, 0.5 * H / height - 0.5)
        out = _interpolate_2d(tensor.array, H, W, C, x, y, channel, method, a_value, clamp)
    dr.eval(out)
    return TensorXf(out, out_shape)


def _check_resize_size(width: int, height: int, channels: int, rows_in: int) -> None:
    """ValueError unless the output (and bicubic's (rows_in, width) first pass) holds at most
    :data:`MAX_RESIZE_VALUES` values."""
    for count in (height * width * channels, rows_in * width * channels):
        if count > MAX_RESIZE_VALUES:
            raise ValueError(f"size: {width}x{height} with {channels} channel(s) needs {count} values, more "
                             f"than one resize produces ({MAX_RESIZE_VALUES} = 2^31 - 1)")


def _nearest_index(out: UInt32, n_in: int, n_out: int) -> UInt32:
    """min(floor((2 out + 1) n_in / (2 n_out)), n_in - 1), in 64-bit integers where 32 could overflow."""
    if (2 * n_out - 1) * n_in < 2**32:
        return dr.minimum((2 * out + 1) * n_in // (2 * n_out), n_in - 1)
    wide = (2 * UInt64(out) + 1) * n_in // (2 * n_out)
    return UInt32(dr.minimum(wide, n_in - 1))


def _pass_1d(source: Float, H: int, W: int, C: int, n_out: int, *, axis: int, a: Float, clamp: bool) -> Float:
    """One separable Keys pass: resample axis ``axis`` (0 = rows/y, 1 = columns/x) to n_out."""
    rows_out = n_out if axis == 0 else H
    cols_out = W if axis == 0 else n_out
    index = dr.arange(UInt32, rows_out * cols_out * C)
    pixel = index // C if C > 1 else index
    channel = index - pixel * C if C > 1 else 0
    r = pixel // cols_out
    c = pixel - r * cols_out
    n_in = H if axis == 0 else W
    along = r if axis == 0 else c
    coordinate = dr.fma(Float(along), n_in / n_out, 0.5 * n_in / n_out - 0.5)
    taps_index, t = _axis(coordinate, n_in, "bicubic")
    if axis == 0:
        taps = [dr.gather(Float, source, UInt32((i * W + Int32(c)) * C) + channel) for i in taps_index]
    else:
        taps = [dr.gather(Float, source, UInt32((Int32(r) * W + i) * C) + channel) for i in taps_index]
    out = _interpolate_1d(taps, t, "bicubic", a, clamp)
    dr.eval(out)
    return out


@eager_if_shared
def sample(image: Any, x: Any, y: Any, method: str = "bilinear", *, a: float = KEYS_A,
           clamp: bool = False) -> TensorXf:
    """Interpolated values of ``image`` at real positions ``(x, y)`` (pixel centres at integers).

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
    x, y : float or array_like
        Column and row coordinates, broadcast against each other. Positions outside
        the image see the edge pixels repeated, however far out (any finite value).
    method, a, clamp
        As in :func:`resize`.

    Returns
    -------
    drjit.llvm.ad.TensorXf
        Shape ``broadcast(x, y).shape`` (+ ``(C,)`` for colour); a 0-d tensor for scalars.

    Examples
    --------
    The course's worked bilinear example: a 2x2 image, the point a quarter of the
    way across and half way down.

    >>> import numpy as np
    >>> from pointillist.imaging.resample import sample
    >>> img = np.array([[10.0, 20.0], [30.0, 40.0]])
    >>> float(np.asarray(sample(img, 0.25, 0.5)))     # 10 + 10*0.25 = 12.5; 32.5 below; mean
    22.5
    """
    method, a, clamp = _check_options(method, a, clamp)
    tensor = as_tensor(image)
    try:
        xs, ys = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
    except (TypeError, ValueError) as error:
        raise ValueError(f"x, y: expected numbers or arrays of broadcastable shapes ({error})") from None
    if not (np.all(np.isfinite(xs)) and np.all(np.isfinite(ys))):
        raise ValueError("x, y: expected finite coordinates")
    H, W = tensor.shape[0], tensor.shape[1]
    C = tensor.shape[2] if tensor.ndim == 3 else 1
    points = xs.size
    shape = xs.shape + ((C,) if tensor.ndim == 3 else ())
    if points == 0:
        return TensorXf(np.zeros(shape, dtype=np.float32))
    index = dr.arange(UInt32, points * C)
    point = index // C if C > 1 else index
    channel = index - point * C if C > 1 else 0
    # Clamped as in `_axis` already in float64, so that float32 cannot overflow to infinity.
    xs, ys = np.clip(xs, -2.0, W + 1.0), np.clip(ys, -2.0, H + 1.0)
    px = dr.gather(Float, Float(np.ascontiguousarray(xs.ravel(), dtype=np.float32)), point)
    py = dr.gather(Float, Float(np.ascontiguousarray(ys.ravel(), dtype=np.float32)), point)
    out = _interpolate_2d(tensor.array, H, W, C, px, py, channel, method, dr.opaque(Float, a), clamp)
    dr.eval(out)
    return TensorXf(out, shape)
