"""Spatial filters: cross-correlation, edges, median and thresholding (:ref:`conventions-filters`).

Every window operation here (:func:`correlate`, :func:`sobel`, :func:`prewitt`,
:func:`laplacian`, :func:`zero_crossings`, :func:`median`) runs as one Dr.Jit
kernel over all pixels through the padded-window engine of
:mod:`pointillist.imaging.neighbourhood`, which also documents the ``border``
modes (:data:`BORDERS`): ``zero`` (the course's choice, the default), ``crop``,
``keep``, ``clamp``, ``reflect``, ``mirror``, ``wrap`` and ``constant``.

Colour images (H, W, C) are filtered per channel. Intensities are on 0..255 by
convention, but any float values (negative, HDR) are accepted.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from types import SimpleNamespace
from typing import Any, NamedTuple

import drjit as dr
import numpy as np
from drjit.llvm.ad import Bool, Float, UInt8, UInt32

from pointillist.core import checks
from pointillist.imaging.arrays import (TensorXf, TensorXu8, as_tensor, eager_if_shared, held_extreme, is_uint8,
                                        opaque_scalar, refuse_gradients, to_uint8, uint8_array)
from pointillist.imaging.median_networks import median_of
from pointillist.imaging.neighbourhood import (BORDERS, PADDED_BORDERS, Taps, Window, check_border, finite_extrema,
                                               select_max, select_min, window_apply, window_result)
from pointillist.imaging.rank import radix_median

__all__ = [
    "SOBEL_X", "SOBEL_Y", "PREWITT_X", "PREWITT_Y", "GAUSSIAN_3", "LOW_PASS", "HIGH_PASS",
    "LAPLACIAN", "KERNELS", "BORDERS", "correlate", "normalize", "sobel", "prewitt", "gradient", "Gradient",
    "GRADIENT_KERNELS",
    "laplacian", "zero_crossings", "threshold", "median", "MEDIAN_NETWORK_MAX_SIZE", "MEDIAN_MAX_LOADS",
]

# --- Kernel constants (cross-correlation; conventions: filters) -----------------------------
#: Sobel x (:ref:`conventions-filters`): responds to intensity increasing to the right; = OpenCV ``Sobel(dx=1)``.
SOBEL_X = np.array([[-1, 0, 1], [-2, 0, 2], [-1, 0, 1]], dtype=np.float32)
#: Sobel y (:ref:`conventions-filters`): responds to intensity increasing *upwards* (= -OpenCV ``Sobel(dy=1)``).
SOBEL_Y = np.array([[1, 2, 1], [0, 0, 0], [-1, -2, -1]], dtype=np.float32)
#: Prewitt x (:ref:`conventions-filters`, ``[[1, 0, -1]] * 3`` rows): note the sign is opposite to SOBEL_X.
PREWITT_X = np.array([[1, 0, -1], [1, 0, -1], [1, 0, -1]], dtype=np.float32)
#: Prewitt y (:ref:`conventions-filters`).
PREWITT_Y = np.array([[1, 1, 1], [0, 0, 0], [-1, -1, -1]], dtype=np.float32)
#: The course's 3x3 Gaussian (:ref:`conventions-filters`), unnormalised (sum 25).
GAUSSIAN_3 = np.array([[1, 3, 1], [3, 9, 3], [1, 3, 1]], dtype=np.float32)
#: Low pass (:ref:`conventions-filters`): all ones, unnormalised (sum 9).
LOW_PASS = np.ones((3, 3), dtype=np.float32)
#: High pass (:ref:`conventions-filters`): 8 at the centre, -1 around (sum 0).
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

# --- Argument checks ---------------------------------------------------------------------------
def _check_kernel(kernel: Any) -> np.ndarray:
    if isinstance(kernel, str):
        if kernel not in KERNELS:
            raise ValueError(f"kernel: unknown kernel name {kernel!r}; known: {', '.join(KERNELS)}")
        return KERNELS[kernel]
    array = checks.real_array(kernel, "kernel")
    if array.ndim == 1:
        array = array[None, :]
    if array.ndim != 2 or array.size == 0:
        raise ValueError(f"kernel: expected a non-empty 2-D array, got shape {array.shape}")
    if array.shape[0] % 2 == 0 or array.shape[1] % 2 == 0:
        raise ValueError(f"kernel: expected odd height and width (a centre tap), got shape {array.shape}")
    return array.astype(np.float32)


def _check_size(size: Any) -> int:
    checks.integer(size, "size")
    if size <= 0 or size % 2 == 0:
        raise ValueError(f"size: expected an odd positive int, got {size}")
    return int(size)


def _extremes_differentiably(values: Float, low: float, high: float, scale: float,
                             mask: Bool | None) -> tuple[Float, Float]:
    """``min`` and ``255 / (max - min)`` with the values computed on the host (the same image as
    without gradients) and the derivatives of the pixels holding them (:func:`held_extreme`), as
    numpy's ``(v - v.min()) * 255 / (v.max() - v.min())`` would differentiate."""
    usable = np.isfinite(np.asarray(dr.detach(values)))
    if mask is not None:
        usable &= np.asarray(mask)
    v_min, v_max = held_extreme(values, low, usable), held_extreme(values, high, usable)
    return (dr.replace_grad(dr.opaque(Float, low), v_min),
            dr.replace_grad(dr.opaque(Float, scale), 255.0 / (v_max - v_min)))


def _rescale(values: Float, bounds: tuple[float, float] | None, mask: Bool | None,
             fill: Float | None) -> Float:
    """(v - min) * 255 / (max - min) where ``mask``; non-finite and constant cases per `normalize`."""
    low, high = bounds if bounds is not None else (0.0, 0.0)
    scale = 255.0 / (high - low) if high > low else 0.0
    if not math.isfinite(scale):       # max - min underflows to a subnormal
        scale = 255.0 / (np.float64(high) - np.float64(low))
    low_v, scale_v = dr.opaque(Float, low), dr.opaque(Float, scale)
    if dr.grad_enabled(values) and high > low:
        low_v, scale_v = _extremes_differentiably(values, low, high, scale, mask)
    shifted = (values - low_v) * scale_v
    scaled = select_min(select_max(shifted, Float(0.0)), Float(255.0))
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
    """Cross-correlate ``image`` with an odd-sized ``kernel`` (:ref:`conventions-filters`).

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
        ``"mirror"``, ``"wrap"`` or ``"constant"`` (module docstring). The default differs
        from the ecosystem's: ``scipy.ndimage`` and scikit-image reflect by default
        (``border="reflect"`` here), OpenCV mirrors without repeating the edge
        (``BORDER_REFLECT_101``: ``border="mirror"`` here); ``"zero"`` sets the ring where the
        kernel does not fit to 0.
    normalize : bool
        Make the result positive (absolute value) and stretch it to 0..255:
        ``(|I| - min) * 255 / (max - min)``, min and max over the computed pixels only
        (for ``zero``/``keep`` the ring stays 0 / keeps the input and does not count).

    Returns
    -------
    drjit.llvm.ad.TensorXf
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
    border = check_border(border)
    checks.boolean(normalize, "normalize")
    tensor = as_tensor(image)
    ry, rx = kernel.shape[0] // 2, kernel.shape[1] // 2
    offsets, combine = _weighted_sum(kernel)
    if not offsets:                                    # an all-zero kernel
        offsets = [(0, 0)]
        combine = lambda taps: (taps[(0, 0)] * 0.0,)  # noqa: E731
    (out,), window, bounds = window_apply(tensor, ry, rx, border, offsets, combine,
                                           absolute=normalize, reduce=normalize)
    if normalize:
        padded = border in PADDED_BORDERS
        fill = window.tap(0, 0) if border == "keep" else Float(0.0)
        out = _rescale(out, bounds, None if padded else window.inside, fill)
        dr.eval(out)
    return window_result(out, window, border)


@eager_if_shared
def normalize(image: Any, *, absolute: bool = True, ring: int | tuple[int, int] = 0) -> TensorXf:
    """Min-max normalise to 0..255: ``(|I| - min) * 255 / (max - min)``, min and max over the
    computed pixels (:ref:`conventions-filters`).

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
        Any float values; min and max are taken over all channels together.
    absolute : bool
        Make negative values positive first (absolute value), as the conventions ask for
        correlation results (default True). With False the signed values are stretched.
    ring : int or (int, int)
        Width ``r`` or ``(ry, rx)`` of a border ring that was not computed: the ring a
        window operation with ``border="zero"`` (or ``"keep"``) leaves, ``ry = kh // 2`` rows
        and ``rx = kw // 2`` columns on each side (1 for the 3x3 kernels). The ring's
        pixels do not count in min and max and are returned as they are, so
        ``normalize(correlate(img, k), ring=1)`` equals ``correlate(img, k, normalize=True)``
        (default 0: every pixel counts, as for any image).

    Returns
    -------
    drjit.llvm.ad.TensorXf
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
    >>> img = np.zeros((5, 5)); img[2, 2] = 1.0      # the course's 5x5 example, Gaussian then normalise
    >>> np.asarray(normalize(correlate(img, GAUSSIAN_3), ring=1))[1:4, 1:4].tolist()
    [[0.0, 63.75, 0.0], [63.75, 255.0, 63.75], [0.0, 63.75, 0.0]]
    """
    checks.boolean(absolute, "absolute")
    ry, rx = _check_ring(ring)
    tensor = as_tensor(image)
    source = tensor.array
    dr.eval(source)
    values = dr.abs(source) if absolute else source  # computed again in the output's kernel
    inside = None
    if ry or rx:
        H, W = tensor.shape[0], tensor.shape[1]
        C = tensor.shape[2] if tensor.ndim == 3 else 1
        pixel = dr.arange(UInt32, H * W * C) // C
        y, x = pixel // W, pixel % W
        inside = (y >= ry) & (y + ry < H) & (x >= rx) & (x + rx < W)
    # one pass over the source for min and max, the absolute value and the ring left out in it
    bounds = finite_extrema(source, absolute=absolute, shape=tuple(tensor.shape), ring=(ry, rx))
    out = _rescale(values, bounds, inside, source if inside is not None else None)
    out = dr.select(values == -math.inf, 0.0, out) if inside is None else \
        dr.select(inside & (values == -math.inf), 0.0, out)
    return TensorXf(out, tensor.shape)


def _check_ring(ring: Any) -> tuple[int, int]:
    values = ring if isinstance(ring, (tuple, list)) else (ring, ring)
    if len(values) != 2:
        raise ValueError(f"ring: expected a width >= 0 or (rows, columns), got {ring!r}")
    return checks.integer(values[0], "ring", low=0), checks.integer(values[1], "ring", low=0)


class Gradient(NamedTuple):
    """What :func:`gradient` returns: the magnitude ``sqrt(gx^2 + gy^2)`` and the two correlations."""

    magnitude: TensorXf
    gx: TensorXf
    gy: TensorXf


#: The kernel pairs of :func:`gradient` by name: (x kernel, y kernel).
GRADIENT_KERNELS = {"sobel": (SOBEL_X, SOBEL_Y), "prewitt": (PREWITT_X, PREWITT_Y)}


def _gradient(image: Any, kx: np.ndarray, ky: np.ndarray, border: str, components: bool):
    border = check_border(border)
    tensor = as_tensor(image)
    offsets_x, combine_x = _weighted_sum(kx)
    offsets_y, combine_y = _weighted_sum(ky)
    offsets = sorted(set(offsets_x) | set(offsets_y))

    def combine(taps: Taps) -> tuple[Float, Float, Float]:
        (gx,), (gy,) = combine_x(taps), combine_y(taps)
        return dr.sqrt(dr.fma(gx, gx, gy * gy)), gx, gy

    outs, window, _ = window_apply(tensor, 1, 1, border, offsets, combine if components else
                                    (lambda taps: combine(taps)[:1]))
    results = tuple(window_result(o, window, border) for o in outs)
    return Gradient(*results) if components else results[0]


def gradient(image: Any, operator: str = "sobel", *, border: str = "zero") -> Gradient:
    """The gradient by ``operator`` (``"sobel"`` or ``"prewitt"``, :data:`GRADIENT_KERNELS`):
    ``(magnitude, gx, gy)``, one pass over the image.

    ``gx`` and ``gy`` are the correlations with the operator's x and y kernels (signs as in
    :func:`sobel` and :func:`prewitt`), ``magnitude`` what those functions return.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.filters import gradient
    >>> step = np.array([[0, 0, 10, 10]] * 3, dtype=float)
    >>> g = gradient(step, "sobel")
    >>> np.asarray(g.gx)[1].tolist(), np.asarray(g.gy)[1].tolist()
    ([0.0, 40.0, 40.0, 0.0], [0.0, 0.0, 0.0, 0.0])
    """
    operator = checks.choice(operator, "operator", tuple(GRADIENT_KERNELS))
    return _gradient(image, *GRADIENT_KERNELS[operator], border, True)


def sobel(image: Any, *, border: str = "zero") -> TensorXf:
    """Sobel gradient magnitude ``sqrt(gx^2 + gy^2)`` with the conventions' SOBEL_X and SOBEL_Y.

    ``gy`` is positive where intensity grows *upwards* (towards row 0): the opposite sign of
    OpenCV's ``Sobel(dy=1)`` and of ``scipy.ndimage.sobel(axis=0)``; ``gx`` has their sign.
    The magnitude is the same either way.

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
    border : str
        As in :func:`correlate` (default ``"zero"``: the 1-pixel ring is 0).

    Returns
    -------
    drjit.llvm.ad.TensorXf
        The magnitude (:func:`gradient` gives ``gx`` and ``gy`` too).

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
    return _gradient(image, SOBEL_X, SOBEL_Y, border, False)


def prewitt(image: Any, *, border: str = "zero") -> TensorXf:
    """Prewitt gradient magnitude ``sqrt(gx^2 + gy^2)`` with the conventions' PREWITT_X and PREWITT_Y.

    Same parameters, returns and edge cases as :func:`sobel`. Note PREWITT_X is
    ``[[1, 0, -1]] * 3``, so ``gx`` is positive where intensity grows to the *left*: the
    opposite sign of SOBEL_X, of ``scipy.ndimage.prewitt(axis=1)`` and of scikit-image's
    ``prewitt_v``; ``gy`` is positive upwards, as SOBEL_Y. The magnitude is the same either way.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.filters import prewitt
    >>> step = np.array([[0, 0, 10, 10]] * 3, dtype=float)
    >>> np.asarray(prewitt(step))[1].tolist()
    [0.0, 30.0, 30.0, 0.0]
    """
    return _gradient(image, PREWITT_X, PREWITT_Y, border, False)


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
    """Zero crossings of a second derivative: a pixel above zero with a neighbour below zero.

    As :ref:`conventions-filters` defines it.

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
    drjit.llvm.ad.TensorXf
        Same shape, values in {0, max_value}. A constant image (or all zeros) has no
        crossings; NaN is neither above nor below zero.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.filters import zero_crossings
    >>> np.asarray(zero_crossings(np.array([[1.0, -1.0, 0.0, 2.0]]))).tolist()
    [[255.0, 0.0, 0.0, 0.0]]
    """
    refuse_gradients(image, "zero_crossings")
    connectivity = checks.choice(connectivity, "connectivity", (4, 8))
    max_value = checks.real(max_value, "max_value")
    tensor = as_tensor(image)
    window = Window(tensor, 1, 1)
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
def threshold(image: Any, level: float = 128, *, max_value: float = 255.0) -> TensorXf | TensorXu8:
    """Threshold: values below ``level`` become 0, values at or above it ``max_value``.

    8-bit in, 8-bit out (as ``cv2.threshold``): uint8 input (numpy or ``TensorXu8``) gives a
    ``TensorXu8`` with ``max_value`` rounded half to even and clipped to 0..255.

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
        Intensities (0..255 by convention; any real values are accepted).
    level : float
        The threshold (the conventions: 128 for dithering). A value equal to ``level`` becomes ``max_value``.
    max_value : float
        The value of "on" pixels (default 255).

    Returns
    -------
    drjit.llvm.ad.TensorXf or drjit.llvm.ad.TensorXu8
        Same shape as ``image``, values in {0, max_value}. NaN compares false and becomes 0.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.filters import threshold
    >>> np.asarray(threshold(np.array([[0, 127], [128, 255]]))).tolist()
    [[0.0, 0.0], [255.0, 255.0]]
    >>> np.asarray(threshold(np.array([[0, 127], [128, 255]], np.uint8))).tolist()
    [[0, 0], [255, 255]]
    """
    refuse_gradients(image, "threshold")
    level = checks.real(level, "level")
    max_value = checks.real(max_value, "max_value")
    if is_uint8(image):  # the bytes widened in the kernel, the result written as bytes
        array = uint8_array(image)
        on = to_uint8(Float(float(max_value)))[0]
        up = Float(UInt8(array.reshape(-1))) >= opaque_scalar(Float, float(level))
        return TensorXu8(dr.select(up, opaque_scalar(UInt8, on), opaque_scalar(UInt8, 0)), array.shape)
    tensor = as_tensor(image)
    values = dr.select(tensor.array >= dr.opaque(Float, float(level)), dr.opaque(Float, float(max_value)), 0.0)
    return TensorXf(values, tensor.shape)


# --- Median: a sorting network held in registers (median_networks.py) or radix selection (rank.py)
#: The largest window :func:`median` sorts with a network (9x9: 81 values through a Batcher network,
#: about 2 s to compile the first time); larger windows use radix selection.
MEDIAN_NETWORK_MAX_SIZE = 9

#: The most key loads one radix-selection median may take (32 x window values x image values for
#: float data): about half a minute here. Larger requests are refused.
MEDIAN_MAX_LOADS = 2**34


def median(image: Any, size: int = 3, *, border: str = "clamp") -> TensorXf:
    """Median filter: the ``size`` x ``size`` window sorted, the middle value replaces the centre.

    As :ref:`conventions-filters` defines it.

    The window's values are held in registers and pass through a sorting network
    (Devillard's 19-exchange network for 3x3 and 99-exchange network for 5x5, Batcher's
    odd-even merge sort otherwise; only the exchanges that lead to the middle value are
    compiled). An exchange is one compare and two selects.

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
        Channels are filtered independently.
    size : int
        Odd window size (1 returns the image). Up to :data:`MEDIAN_NETWORK_MAX_SIZE` (9) a
        sorting network (:mod:`pointillist.imaging.median_networks`); above, radix selection
        (:mod:`pointillist.imaging.rank`): the network grows as n log^2 n in the n = size^2
        values and is compiled as one kernel, the selection's kernel does not grow (8 or 32
        loads per window value; compile and run times in ``benchmarks/RESULTS.md``). A call
        needing more than :data:`MEDIAN_MAX_LOADS` loads is refused with a ValueError. A
        window larger than the image is defined by the border mode (``"crop"`` refuses it:
        nothing is left).
    border : str
        As in :func:`correlate`; the default ``"clamp"`` matches ``cv2.medianBlur``
        (the course only defines border handling for correlation).

    Returns
    -------
    drjit.llvm.ad.TensorXf

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
    refuse_gradients(image, "median")
    size = _check_size(size)
    border = check_border(border)
    tensor = as_tensor(image)
    r = size // 2
    if size > MEDIAN_NETWORK_MAX_SIZE:
        loads = 32 * size * size * int(np.prod(tensor.shape))
        if loads > MEDIAN_MAX_LOADS:
            raise ValueError(f"size: a {size}x{size} median of a {'x'.join(map(str, tensor.shape))} image needs up to "
                             f"{loads:.3g} loads, more than {MEDIAN_MAX_LOADS:.3g} (MEDIAN_MAX_LOADS, about half a "
                             "minute); use a smaller window")
        values, _ = radix_median(tensor, size, border)
        shape = tuple(tensor.shape)
        frame = SimpleNamespace(shape=shape, H=shape[0], W=shape[1], ry=r, rx=r)  # what window_result reads
        return window_result(values, frame, border)
    if r == 0:   # the identity, as a copy: numpy input shares the caller's memory
        values = Float(tensor.array) if dr.is_array_v(image) else Float(np.array(tensor.array, dtype=np.float32))
        return window_result(values, Window(tensor, 0, 0), border)
    offsets = [(dy, dx) for dy in range(-r, r + 1) for dx in range(-r, r + 1)]

    def combine(taps: Taps) -> tuple[Float]:
        return (median_of([taps[d] for d in offsets]),)

    (out,), window, _ = window_apply(tensor, r, r, border, offsets, combine)
    return window_result(out, window, border)
