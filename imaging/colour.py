"""Colour: RGB <-> HSV, Rec. 709 luminance and the sRGB transfer curves (:ref:`conventions-colour`).

Every function takes a numpy array or a Dr.Jit tensor and returns a
``drjit.llvm.ad.TensorXf``; the work is one fused Dr.Jit kernel per call (no
Python loop over pixels), and per-call scalars are opaque so that kernels are
compiled once and then reused.

Notes
-----
=================  ===========================  ================================
Function           Domain                       Range
=================  ===========================  ================================
``rgb_to_hsv``     RGB, any real (0..1 usual)    H [0, 360), S [0, 1] for RGB >= 0,
                                                 V = max(R, G, B) (input units)
``hsv_to_rgb``     H any (wrapped mod 360),      RGB in V's units
                   S [0, 1], V any
``luminance``      RGB linear, any real          Y = 0.2126 R + 0.7152 G + 0.0722 B
``srgb_encode``    linear [0, 1]                 encoded [0, 1]
``srgb_decode``    encoded [0, 1]                linear [0, 1]
=================  ===========================  ================================

Non-finite input follows the rule of every imaging function (as in
:mod:`pointillist.imaging.tone`): NaN becomes 0, +inf becomes white
(``max_value``: 1 by default, 255 for 0..255 intensities), -inf becomes 0, and
one :class:`~pointillist.imaging.arrays.NonFiniteWarning` gives the count. In
``hsv_to_rgb`` the rule applies per channel with white = 0 for H (360 wrapped),
1 for S and ``max_value`` for V. The per-value helpers (``*_values``) only read
NaN as 0 where they say so.
"""

from __future__ import annotations

import sys
from typing import Any, Callable

import drjit as dr
import numpy as np
from drjit.llvm.ad import Array3f, Float, UInt8, UInt32

from pointillist.core import checks
from pointillist.imaging.arrays import (TensorXf, as_tensor, check_shape, eager_if_shared, is_uint8, opaque_scalar,
                                        replace_non_finite, uint8_array, warn_non_finite)

__all__ = [
    "REC709_LUMINANCE_WEIGHTS",
    "rgb_to_hsv",
    "hsv_to_rgb",
    "luminance",
    "adjust_hsv",
    "srgb_encode",
    "srgb_decode",
    "srgb_encode_values",
    "srgb_decode_values",
    "hsv_from_rgb_values",
    "rgb_from_hsv_values",
]

_FLOAT32_MAX = checks.FLOAT32_MAX

#: Rec. 709 / sRGB luminance weights of linear R, G, B (ITU-R BT.709-6, item 3.3).
REC709_LUMINANCE_WEIGHTS: tuple[float, float, float] = (0.2126, 0.7152, 0.0722)

#: sRGB transfer function constants (IEC 61966-2-1:1999, as in colour-science's ``eotf_inverse_sRGB``).
SRGB_LINEAR_THRESHOLD = 0.0031308
SRGB_ENCODED_THRESHOLD = 0.04045
SRGB_SLOPE = 12.92
SRGB_SCALE = 1.055
SRGB_OFFSET = 0.055
SRGB_EXPONENT = 2.4


def _rgb_tensor(image: Any, name: str = "image") -> TensorXf:
    tensor = as_tensor(image, name)
    if tensor.ndim != 3 or tensor.shape[2] != 3:
        raise ValueError(f"{name}: expected an RGB image of shape (H, W, 3), got shape {tuple(tensor.shape)}")
    return tensor


Triple = tuple[Float, Float, Float]


def _map_pixels(tensor: TensorXf, function: Callable[[Float, Float, Float], Triple]) -> TensorXf:
    """Apply ``function`` (3 channels -> 3 channels) to every pixel of an (H, W, 3) tensor (lazy: one
    kernel with what follows)."""
    rgb = dr.unravel(Array3f, tensor.array)
    return TensorXf(dr.ravel(Array3f(*function(rgb.x, rgb.y, rgb.z))), tensor.shape)


def _white(max_value: Any) -> float:
    """``max_value`` checked: the value of white (+inf becomes it), > 0 and finite in float32."""
    return checks.real(max_value, "max_value", low=0.0, low_open=True)


def _clean_rgb(white: float, counter: list) -> Callable[[Float, Float, Float], Triple]:
    """R, G, B -> the same with the non-finite rule applied, counted in ``counter[0]``."""
    def clean(r: Float, g: Float, b: Float) -> Triple:
        out = []
        for c in (r, g, b):
            c, counter[0] = replace_non_finite(c, white, counter[0])
            out.append(c)
        return tuple(out)

    return clean


def hsv_from_rgb_values(r: Float, g: Float, b: Float) -> tuple[Float, Float, Float]:
    """HSV of R, G, B Dr.Jit arrays (OpenCV's float formula; ties resolve R, then G, then B).

    The per-value formula behind :func:`rgb_to_hsv` (no NaN/inf handling): H in degrees
    0..360, S 0..1, V = max(R, G, B).

    Examples
    --------
    >>> from drjit.llvm import Float
    >>> from pointillist.imaging.colour import hsv_from_rgb_values
    >>> [float(c[0]) for c in hsv_from_rgb_values(Float(0.5), Float(1.0), Float(0.5))]
    [120.0, 0.5, 1.0]
    """
    v = dr.maximum(dr.maximum(r, g), b)
    delta = v - dr.minimum(dr.minimum(r, g), b)
    s = dr.select(v > 0.0, delta / v, 0.0)
    inv = dr.select(delta > 0.0, 60.0 / delta, 0.0)
    h = dr.select(v == r, (g - b) * inv,
                  dr.select(v == g, 120.0 + (b - r) * inv, 240.0 + (r - g) * inv))
    h = dr.select(delta > 0.0, h, 0.0)
    h = dr.select(h < 0.0, h + 360.0, h)
    return h, s, v


def rgb_from_hsv_values(h: Float, s: Float, v: Float) -> tuple[Float, Float, Float]:
    """R, G, B of H (degrees, wrapped), S, V Dr.Jit arrays (the hexcone sectors).

    The per-value formula behind :func:`hsv_to_rgb`, inverse of :func:`hsv_from_rgb_values`.

    Examples
    --------
    >>> from drjit.llvm import Float
    >>> from pointillist.imaging.colour import rgb_from_hsv_values
    >>> [float(c[0]) for c in rgb_from_hsv_values(Float(120.0), Float(0.5), Float(1.0))]
    [0.5, 1.0, 0.5]
    """
    h = h * (1.0 / 60.0)
    h = h - 6.0 * dr.floor(h * (1.0 / 6.0))  # wrap to [0, 6)
    sector = dr.floor(h)
    f = h - sector
    sector = dr.select(sector >= 6.0, 0.0, sector)
    p = v * (1.0 - s)
    q = v * (1.0 - s * f)
    t = v * (1.0 - s * (1.0 - f))
    # sector:   0  1  2  3  4  5
    # R:        v  q  p  p  t  v
    # G:        t  v  v  q  p  p
    # B:        p  p  t  v  v  q
    r = dr.select(sector < 1.0, v, dr.select(sector < 2.0, q, dr.select(sector < 4.0, p,
                  dr.select(sector < 5.0, t, v))))
    g = dr.select(sector < 1.0, t, dr.select(sector < 3.0, v, dr.select(sector < 4.0, q, p)))
    b = dr.select(sector < 2.0, p, dr.select(sector < 3.0, t, dr.select(sector < 5.0, v, q)))
    return r, g, b


@eager_if_shared
def rgb_to_hsv(image: Any, *, max_value: float = 1.0) -> TensorXf:
    """Convert an RGB image to HSV (hue in degrees, saturation, value).

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W, 3)
        RGB values, usually 0..1 (0..255 works too: V keeps the input's units).
    max_value : float
        White, which +inf becomes (NaN and -inf become 0, with one ``NonFiniteWarning``).

    Returns
    -------
    drjit.llvm.ad.TensorXf
        (H, W, 3): H in [0, 360) degrees, S = (max - min) / max in [0, 1],
        V = max(R, G, B). Greys (max = min) have H = 0 and S = 0; black has
        S = 0. This is OpenCV's ``cvtColor(..., COLOR_RGB2HSV)`` for float32
        input. Negative components are allowed (S may then exceed 1).

    Raises
    ------
    ValueError
        If ``image`` is not (H, W, 3).

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.colour import rgb_to_hsv
    >>> np.asarray(rgb_to_hsv(np.array([[[1.0, 0.5, 0.0]]]))).round(3).tolist()
    [[[30.0, 1.0, 1.0]]]
    """
    tensor = _rgb_tensor(image)
    counter: list = [None]
    clean = _clean_rgb(_white(max_value), counter)
    result = _map_pixels(tensor, lambda r, g, b: hsv_from_rgb_values(*clean(r, g, b)))
    return warn_non_finite(result, counter[0], "rgb_to_hsv")


@eager_if_shared
def hsv_to_rgb(image: Any, *, max_value: float = 1.0) -> TensorXf:
    """Convert an HSV image (hue in degrees) back to RGB.

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W, 3)
        H in degrees (any value: wrapped modulo 360, so 360 is 0 and -60 is
        300), S in [0, 1] (not clipped), V in the RGB units wanted.
    max_value : float
        White: +inf in V becomes it (in S, 1; in H, 0 = 360); NaN and -inf become 0, with
        one ``NonFiniteWarning``.

    Returns
    -------
    drjit.llvm.ad.TensorXf
        (H, W, 3) RGB; the inverse of :func:`rgb_to_hsv` (round trip to float32
        rounding). S = 0 gives grey (V, V, V); V = 0 gives black.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.colour import hsv_to_rgb
    >>> np.asarray(hsv_to_rgb(np.array([[[240.0, 1.0, 0.5]]]))).tolist()
    [[[0.0, 0.0, 0.5]]]
    """
    tensor = _rgb_tensor(image)
    white = _white(max_value)
    counter: list = [None]

    def convert(h: Float, s: Float, v: Float) -> Triple:
        h, counter[0] = replace_non_finite(h, 0.0, counter[0])
        s, counter[0] = replace_non_finite(s, 1.0, counter[0])
        v, counter[0] = replace_non_finite(v, white, counter[0])
        return rgb_from_hsv_values(h, s, v)

    return warn_non_finite(_map_pixels(tensor, convert), counter[0], "hsv_to_rgb")


@eager_if_shared
def adjust_hsv(image: Any, *, hue: float = 0.0, saturation: float = 1.0, value: float = 1.0,
               max_value: float = 1.0) -> TensorXf:
    """Shift the hue and scale the saturation and value of an RGB image (through HSV).

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W, 3)
        RGB values (any units: V keeps them).
    hue : float
        Degrees added to H (wrapped modulo 360 in float64 first: any hue float32 holds shifts as
        its remainder does).
    saturation : float
        >= 0, factor on S; the result is clipped to S <= 1 (0 gives grey).
    value : float
        >= 0, factor on V (not clipped: display steps clip when writing; a V beyond float32's
        range becomes its largest value, 3.4e38, never inf).
    max_value : float
        White, which +inf becomes (NaN and -inf become 0, with one ``NonFiniteWarning``).

    Returns
    -------
    drjit.llvm.ad.TensorXf
        (H, W, 3) RGB. hue = 0, saturation = value = 1 is the identity (to float32
        rounding); greys keep S = 0 whatever the hue shift.

    Raises
    ------
    TypeError
        If a parameter is not a number.
    ValueError
        If a factor is negative or a parameter is not finite in float32 (``|x| <= 3.4e38``).

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.colour import adjust_hsv
    >>> np.asarray(adjust_hsv(np.array([[[1.0, 0.0, 0.0]]]), hue=120)).tolist()
    [[[0.0, 1.0, 0.0]]]
    """
    hue = checks.real(hue, "hue")
    saturation = checks.real(saturation, "saturation", low=0.0)
    value = checks.real(value, "value", low=0.0)
    # The shift is wrapped here, in float64 (exact): added in float32, a hue of 1e30 would swamp H.
    checked = [opaque_scalar(Float, hue % 360.0), opaque_scalar(Float, saturation), opaque_scalar(Float, value)]
    shift, s_scale, v_scale = checked
    counter: list = [None]
    clean = _clean_rgb(_white(max_value), counter)

    def adjust(r: Float, g: Float, b: Float) -> Triple:
        h, s, v = hsv_from_rgb_values(*clean(r, g, b))
        # V at most float32's largest value: an overflow to inf would make V (1 - S) = inf * 0 = NaN
        return rgb_from_hsv_values(h + shift, dr.minimum(s * s_scale, 1.0), dr.minimum(v * v_scale, _FLOAT32_MAX))

    return warn_non_finite(_map_pixels(_rgb_tensor(image), adjust), counter[0], "adjust_hsv")


@eager_if_shared
def luminance(image: Any, *, max_value: float = 1.0) -> TensorXf:
    """Rec. 709 luminance Y = 0.2126 R + 0.7152 G + 0.0722 B.

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W), (H, W, 1) or (H, W, 3)
        Linear RGB (on display-encoded values this gives luma, the usual
        "convert to grey"). Grey input is returned unchanged as (H, W).
    max_value : float
        White, which +inf components become.

    Returns
    -------
    drjit.llvm.ad.TensorXf
        (H, W). NaN and -inf components count as 0, +inf as ``max_value``, with one
        ``NonFiniteWarning``. 8-bit input (numpy ``uint8``, ``TensorXu8``) gives the values of its
        float32 conversion, read from the bytes without a float32 copy.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.colour import luminance
    >>> np.asarray(luminance(np.ones((1, 2, 3)))).round(6).tolist()
    [[1.0, 1.0]]
    """
    white = _white(max_value)
    if is_uint8(image):
        return _luminance_bytes(image)
    tensor = as_tensor(image, channels=(1, 3))
    height, width = tensor.shape[:2]
    if tensor.ndim == 2 or tensor.shape[2] == 1:
        grey, counter = replace_non_finite(tensor.array, white)
        return warn_non_finite(TensorXf(grey, (height, width)), counter, "luminance")
    counter: list = [None]
    rgb = dr.unravel(Array3f, tensor.array)
    r, g, b = _clean_rgb(white, counter)(rgb.x, rgb.y, rgb.z)
    wr, wg, wb = REC709_LUMINANCE_WEIGHTS
    return warn_non_finite(TensorXf(wr * r + wg * g + wb * b, (height, width)), counter[0], "luminance")


def _luminance_bytes(image: Any) -> TensorXf:
    """:func:`luminance` of 8-bit input: the same float32 values, read from the bytes in the kernel
    that uses them (no float32 copy of the image, and no non-finite rule: bytes are finite).

    R, G and B of pixel p are bytes 3p, 3p + 1, 3p + 2, gathered as the 32-bit words holding them
    (LLVM scalarises a gather of single bytes) when the bytes can be viewed as words. Lazy: the
    grey values are computed in the kernel that consumes them (a ``post`` chain's next step).
    """
    array = uint8_array(image)
    check_shape(array.shape, "image", (1, 3))
    height, width = array.shape[:2]
    flat = array.reshape(-1)
    if array.ndim == 2 or array.shape[2] == 1:
        grey = Float(UInt8(flat))
    else:
        if flat.size % 4 == 0 and flat.ctypes.data % 4 == 0 and sys.byteorder == "little":
            words = UInt32(flat.view(np.uint32))
            first = dr.arange(UInt32, height * width) * 3

            def channel(c: int) -> Float:
                byte = first + c
                return Float((dr.gather(UInt32, words, byte >> 2) >> ((byte & 3) << 3)) & 0xFF)

            r, g, b = channel(0), channel(1), channel(2)
        else:
            rgb = dr.unravel(Array3f, Float(UInt8(flat)))
            r, g, b = rgb.x, rgb.y, rgb.z
        wr, wg, wb = REC709_LUMINANCE_WEIGHTS
        grey = wr * r + wg * g + wb * b
    return TensorXf(grey, (height, width))


def srgb_encode_values(values: Float) -> Float:
    """sRGB encoding of linear values (any Dr.Jit float array or Python float), NaN -> 0.

    colour-science calls it ``eotf_inverse_sRGB``."""
    values = dr.select(dr.isnan(values), 0.0, values)
    # 1.055 p - 0.055 written as 1.055 (p - 1) + 1 (1.055 - 0.055 = 1): white encodes to exactly 1
    power = SRGB_SCALE * (dr.power(dr.maximum(values, SRGB_LINEAR_THRESHOLD), 1.0 / SRGB_EXPONENT) - 1.0) + 1.0
    return dr.select(values <= SRGB_LINEAR_THRESHOLD, values * SRGB_SLOPE, power)


def srgb_decode_values(values: Float) -> Float:
    """sRGB decoding of encoded values (any Dr.Jit float array or Python float), NaN -> 0.

    colour-science calls it ``eotf_sRGB``."""
    values = dr.select(dr.isnan(values), 0.0, values)
    # a division, not a product with 1 / 1.055 (which rounds): 1 + 0.055 and 1.055 are the same float32,
    # so white decodes to exactly 1
    base = (dr.maximum(values, SRGB_ENCODED_THRESHOLD) + SRGB_OFFSET) / SRGB_SCALE
    return dr.select(values <= SRGB_ENCODED_THRESHOLD, values * (1.0 / SRGB_SLOPE), dr.power(base, SRGB_EXPONENT))


@eager_if_shared
def srgb_encode(image: Any) -> TensorXf:
    """Apply the sRGB encoding curve (linear light -> display values), per component.

    V = 12.92 L for L <= 0.0031308, else 1.055 L^(1/2.4) - 0.055 (IEC 61966-2-1),
    the same piecewise curve as ``colour.cctf_encoding(L, function="sRGB")``.

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
        Linear values, 0..1 for the display range.

    Returns
    -------
    drjit.llvm.ad.TensorXf
        Same shape, encoded values (0 -> 0, 1 -> 1). Outside 0..1 the curve
        is extended as colour-science does: negative values stay on the linear
        segment, values above 1 follow the power segment. NaN and -inf become 0,
        +inf white (1), with one ``NonFiniteWarning``.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.colour import srgb_encode
    >>> np.asarray(srgb_encode(np.array([[0.0, 0.18, 1.0]])), dtype=float).round(4).tolist()
    [[0.0, 0.4614, 1.0]]
    """
    tensor = as_tensor(image)
    clean, counter = replace_non_finite(tensor.array, 1.0)
    return warn_non_finite(TensorXf(srgb_encode_values(clean), tensor.shape), counter, "srgb_encode")


@eager_if_shared
def srgb_decode(image: Any) -> TensorXf:
    """Apply the sRGB decoding curve (display values -> linear light); inverse of :func:`srgb_encode`.

    L = V / 12.92 for V <= 0.04045, else ((V + 0.055) / 1.055)^2.4, as
    ``colour.cctf_decoding(V, function="sRGB")``.

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
        Encoded values, 0..1 for the display range.

    Returns
    -------
    drjit.llvm.ad.TensorXf
        Same shape, linear values; negative values stay on the linear segment.
        NaN and -inf become 0, +inf white (1), with one ``NonFiniteWarning``.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.colour import srgb_decode
    >>> np.asarray(srgb_decode(np.array([[0.0, 0.5, 1.0]])), dtype=float).round(4).tolist()
    [[0.0, 0.214, 1.0]]
    """
    tensor = as_tensor(image)
    clean, counter = replace_non_finite(tensor.array, 1.0)
    return warn_non_finite(TensorXf(srgb_decode_values(clean), tensor.shape), counter, "srgb_decode")
