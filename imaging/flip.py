"""FLIP on Dr.Jit: the LDR-FLIP and HDR-FLIP error maps, computed as flip-evaluator computes them.

FLIP (Andersson et al., "FLIP: A Difference Evaluator for Alternating Images", HPG 2020)
compares a test image with a reference as a viewer flipping between them would see the
difference; HDR-FLIP (Andersson et al., "Visualizing Errors in Rendered High Dynamic Range
Images", Eurographics 2021) takes the largest LDR-FLIP over a range of exposures of the two
tone-mapped images. :func:`flip` follows NVIDIA's implementation, the ``flip-evaluator``
package 1.7 (``FLIP.h``), step by step and in float32:

1. HDR only: each exposure ``c`` scales both images by ``2^c`` (``c`` from ``start`` to
   ``stop`` in equal steps, :func:`hdr_exposure_range`), tone-maps them (ACES by default,
   :data:`TONEMAPPERS`) and clamps to [0, 1]. LDR input is sRGB-decoded (``srgb``) and clamped.
2. Linear RGB -> XYZ (D65) -> YCxCz (the opponent space of the paper).
3. Colour pipeline: each channel blurred by the contrast sensitivity filters (a Gaussian for
   Y and Cx, a sum of two for Cz: :data:`CSF_CONSTANTS`; separable, radius
   ``ceil(3 sqrt(0.04 / (2 pi^2)) ppd)``: 10 pixels at the default 67 pixels per degree),
   back to linear RGB clamped to [0, 1], to CIELab with the Hunt adjustment
   (a, b scaled by 0.01 L), HyAB distance raised to ``qc = 0.7`` and mapped to [0, 1]
   (the distance between Hunt-adjusted green and blue is the maximum, ``pc``/``pt`` bend it).
4. Feature pipeline: the normalised luminance ``y = (Y + 16) / 116`` filtered with the first
   and second derivatives of a Gaussian of standard deviation ``0.5 w ppd`` (``w = 0.082``
   degrees; radius ``ceil(3 sigma)``, 9 pixels by default), giving edge and point strengths;
   their largest difference ``(max(|de|, |dp|) / sqrt 2)^qf``, ``qf = 0.5``.
5. ``error = colour^(1 - feature)``; HDR-FLIP keeps the largest over the exposures.

Every convolution reads outside the image as the nearest edge pixel (flip-evaluator clamps
its indices), so any size, one pixel included, is defined.

Implementation: the whole computation is three Dr.Jit kernels for a batch of exposures,
whatever the image size: (1) expose, tone-map and convert every pixel of a frame padded by the
filter radius (edge pixels repeated), for all exposures of the batch at once; (2) the
horizontal pass of the four colour filters and the three feature filters on both images;
(3) the vertical pass, the colour and feature differences and the error. The taps of (2) and
(3) are contiguous zero-copy views of the previous pass's evaluated output (shifted by one
element, or by one padded row), so no tap is a gather; the padded row length is a multiple of
16 floats, so every row view is 64-byte aligned and no kernel depends on the image size.
The largest error over the exposures is one numpy reduction. Image sizes, exposure scales
and batch counts are opaque or data, the filter weights kernel constants: the kernels compile
once per tone mapper and pixels-per-degree value.

Precision: the same float32 operations in flip-evaluator's order (a product then a sum per
filter tap, the colour transforms as written there, the filter weights and constants rounded
as its host code rounds them), so that the maps agree to the last bits; only the transcendental
functions differ. That matters most for the cube root of CIELab: where the two images are
nearly equal, HyAB is a difference of nearly equal colours, and any disagreement in their last
bit adds (its absolute value is positive) a bias to the error. ``powf(t, 1/3)`` is therefore
reproduced correctly rounded (a float32 cube root refined in float64); the other powers use
Dr.Jit's float32 ``power`` (within a few ulp, unbiased). Measured on the project's renders:
maps within 1.3e-6 of flip-evaluator's at the 99th percentile and 4e-5 at most, means within
1e-8 (tests/test_flip.py).

Notes
-----
==================  =================================  =========================================
argument            domain                             what happens
==================  =================================  =========================================
``image``,          (H, W), (H, W, 1) or (H, W, 3),    grey is compared as RGB; non-finite values
``reference``       same shape; HDR: finite, >= 0;     are refused (ValueError), as are negative
                    LDR: finite (clamped to [0, 1]     ones in HDR (tone mappers are undefined
                    after sRGB decoding, as            there); a 1x1 image is fine (every tap
                    flip-evaluator does)               reads the one pixel)
exposures (HDR)     computed from the reference, or    start > stop is refused (flip-evaluator
                    given (``start_exposure`` <=       exits the process there): a reference
                    ``stop_exposure``)                 whose largest luminance is below float32's
                                                       epsilon has no range of its own
``ppd``             finite, > 0                        pixels per degree; the radii follow it
==================  =================================  =========================================

Range: the map is in [0, 1]; identical images give 0 everywhere.
"""

from __future__ import annotations

import functools
import math
from typing import Any, NamedTuple

import drjit as dr
import numpy as np
from drjit.llvm.ad import Float, Float64, UInt32

from pointillist.core import checks
from pointillist.imaging.arrays import TensorXf, as_tensor, divmod_u32, opaque_scalar, refuse_gradients, to_numpy
from pointillist.imaging.colour import REC709_LUMINANCE_WEIGHTS, srgb_decode
from pointillist.imaging.neighbourhood import select_max, select_min
from pointillist.imaging.tone import ACES_CONSTANTS

__all__ = ["FLIP_CONSTANTS", "CSF_CONSTANTS", "TONEMAPPERS", "DEFAULT_PPD", "FlipResult", "flip",
           "pixels_per_degree", "hdr_exposure_range", "tonemapper_x_max"]

_f32 = np.float32

#: FLIP's constants (Andersson et al. 2020, table 1): colour difference exponent ``qc``, the
#: colour error's knee ``pc`` and the value ``pt`` it maps to, the feature filter's width ``w``
#: in degrees and the feature difference exponent ``qf``.
FLIP_CONSTANTS = {"qc": 0.7, "pc": 0.4, "pt": 0.95, "w": 0.082, "qf": 0.5}

#: The contrast sensitivity functions (Andersson et al. 2020, eq. 2 and table 1): per channel
#: (Y, Cx, Cz), weights ``a1, a2`` and scales ``b1, b2`` of a sum of two Gaussians
#: ``a sqrt(pi / b) exp(-pi^2 x^2 / b)`` (x in degrees; only Cz uses the second one).
CSF_CONSTANTS = {"a1": (1.0, 1.0, 34.1), "b1": (0.0047, 0.0053, 0.04),
                 "a2": (0.0, 0.0, 13.5), "b2": (1.0e-5, 1.0e-5, 0.025)}

#: HDR-FLIP's tone mappers as flip-evaluator writes them: per channel (or for Reinhard, on the
#: luminance) ``(c0 x^2 + c1 x + c2) / (c3 x^2 + c4 x + c5)``. ACES is Narkowicz's fit with a
#: pre-exposure of 0.6 cancelled (0.6^2 on the squares, 0.6 on the linear terms); Hable's is
#: his filmic curve in the same form.
TONEMAPPERS: dict[str, tuple[float, ...]] = {
    "reinhard": (0.0, 1.0, 0.0, 0.0, 1.0, 1.0),
    "aces": tuple(float(v) for v in (
        _f32(0.6) * _f32(0.6) * _f32(ACES_CONSTANTS["a"]), _f32(0.6) * _f32(ACES_CONSTANTS["b"]), _f32(0.0),
        _f32(0.6) * _f32(0.6) * _f32(ACES_CONSTANTS["c"]), _f32(0.6) * _f32(ACES_CONSTANTS["d"]),
        _f32(ACES_CONSTANTS["e"]))),
    "hable": (0.231683, 0.013791, 0.0, 0.18, 0.3, 0.018),
}

#: The reference white of the D65 illuminant in XYZ, and its inverse, as flip-evaluator has them.
_D65 = (0.950428545, 1.0, 1.088900371)
_INV_D65 = (1.052156925, 1.0, 0.918357670)


def pixels_per_degree(distance: float = 0.7, resolution_x: float = 3840.0, monitor_width: float = 0.7) -> float:
    """Pixels per degree of visual angle for a monitor ``monitor_width`` metres wide showing
    ``resolution_x`` pixels seen from ``distance`` metres: ``distance resolution_x / width * pi / 180``
    (small-angle form, float32 as in flip-evaluator). The defaults give :data:`DEFAULT_PPD`.

    Examples
    --------
    >>> round(pixels_per_degree(), 4)
    67.0206
    """
    for name, value in (("distance", distance), ("resolution_x", resolution_x), ("monitor_width", monitor_width)):
        checks.real(value, name, low=0.0, low_open=True)
    pi = _f32(3.14159265358979)
    return float(_f32(distance) * (_f32(resolution_x) / _f32(monitor_width)) * (pi / _f32(180.0)))


#: flip-evaluator's default viewing condition: a 0.7 m wide 4K monitor seen from 0.7 m (67.02 ppd).
DEFAULT_PPD = pixels_per_degree()


class FlipResult(NamedTuple):
    """What :func:`flip` returns."""

    #: The FLIP error map, (H, W) float32 in [0, 1].
    map: TensorXf
    #: Its mean (float64 sum of the map / H W).
    mean: float
    #: HDR-FLIP's exposures ``(start, stop, count)`` (stops); ``None`` for LDR-FLIP.
    exposures: tuple[float, float, int] | None


def _exp32(x: Any) -> np.float32:
    """``expf``: exp of a float32, correctly rounded (computed in float64), as glibc's is in practice."""
    return _f32(np.exp(np.float64(x)))


def _pow32(x: Any, y: Any) -> np.float32:
    """``powf``, correctly rounded in the same way."""
    return _f32(np.float64(x) ** np.float64(y))


def _check_tonemapper(tonemapper: Any) -> str:
    if not isinstance(tonemapper, str) or tonemapper.lower() not in TONEMAPPERS:
        raise ValueError(f"tonemapper: expected one of {', '.join(map(repr, TONEMAPPERS))}, got {tonemapper!r}")
    return tonemapper.lower()


def tonemapper_x_max(tonemapper: str = "aces", t: float = 0.85) -> float:
    """The linear value the tone mapper takes to ``t``: HDR-FLIP's ``x_max`` (Andersson et al. 2021,
    sec. 4.1), the larger root of ``(c0 - t c3) x^2 + (c1 - t c4) x + (c2 - t c5) = 0``, in float32
    as flip-evaluator solves it (about 2.12 for ACES).

    Examples
    --------
    >>> round(tonemapper_x_max("aces"), 4), round(tonemapper_x_max("reinhard"), 4)
    (2.1189, 5.6667)
    """
    c = [_f32(v) for v in TONEMAPPERS[_check_tonemapper(tonemapper)]]
    t = _f32(checks.real(t, "t", low=0.0, high=1.0, low_open=True, high_open=True))
    a, b, c0 = c[0] - t * c[3], c[1] - t * c[4], c[2] - t * c[5]
    if a == 0:
        return float(-c0 / b)
    d1 = _f32(-0.5) * (b / a)
    d2 = np.sqrt(d1 * d1 - c0 / a, dtype=np.float32)
    return float(d1 + d2)


def _luminance_f32(rgb: np.ndarray) -> np.ndarray:
    """flip-evaluator's luminance, float32 in its order: (0.2126 R + 0.7152 G) + 0.0722 B."""
    wr, wg, wb = (_f32(w) for w in REC709_LUMINANCE_WEIGHTS)
    return (wr * rgb[..., 0] + wg * rgb[..., 1]) + wb * rgb[..., 2]


def hdr_exposure_range(reference: Any, tonemapper: str = "aces") -> tuple[float, float]:
    """HDR-FLIP's exposure range ``(start, stop)`` in stops, from the reference, as flip-evaluator 1.7
    computes it: ``log2(x_max / Y_max)`` and ``log2(x_max / max(Y_median, eps))``.

    ``Y`` is the Rec. 709 luminance of the linear reference (float32), ``Y_median`` its
    ``H W // 2``-th smallest value, ``eps`` float32's machine epsilon (so that a reference more
    than half black still has a range) and ``x_max`` :func:`tonemapper_x_max`. The start exceeds
    the stop (an empty range, which :func:`flip` refuses) when ``Y_max`` is below ``eps``: a
    black reference, or a constant one of 1e-7.

    Examples
    --------
    >>> import numpy as np
    >>> start, stop = hdr_exposure_range(np.full((2, 2, 3), 0.5, np.float32))
    >>> round(start, 4), round(stop, 4)   # a constant reference: one exposure, log2(2.119 / 0.5)
    (2.0833, 2.0833)
    """
    rgb = _rgb_array(reference, "reference")
    return _exposure_range(rgb, _check_tonemapper(tonemapper))


def _exposure_range(rgb: np.ndarray, tonemapper: str) -> tuple[float, float]:
    luminance = _luminance_f32(rgb).reshape(-1)
    middle = luminance.size // 2
    y_max = luminance.max()
    y_median = max(np.partition(luminance, middle)[middle], np.finfo(np.float32).eps)
    x_max = _f32(tonemapper_x_max(tonemapper))
    with np.errstate(divide="ignore"):   # a black reference: x_max / 0 = inf, start = inf
        start, stop = (float(_f32(np.log2(np.float64(x_max / y)))) for y in (y_max, y_median))
    return start, stop


def _rgb_array(image: Any, name: str) -> np.ndarray:
    """``image`` as a C-contiguous float32 (H, W, 3) numpy array (grey repeated), finite values only."""
    refuse_gradients(image, "flip (computed partly on the host)")
    tensor = as_tensor(image, name, channels=(1, 3))
    array = to_numpy(tensor)
    if array.ndim == 2:
        array = array[..., None]
    if array.shape[2] == 1:
        array = np.repeat(array, 3, axis=2)
    array = np.ascontiguousarray(array, dtype=np.float32)
    if not np.isfinite(array).all():
        raise ValueError(f"{name}: expected finite values, got NaN or infinity (replace them first, "
                         "e.g. with numpy.nan_to_num)")
    return array


# --------------------------------------------------------------------------- filters (host, float32)
@functools.lru_cache(maxsize=8)
def _filters(ppd: float) -> dict[str, Any]:
    """The separable filters at ``ppd``, float32 as flip-evaluator builds them (sums in tap order)."""
    pi = _f32(3.14159265358979)
    pi_sq = pi * pi
    a1, b1 = [_f32(v) for v in CSF_CONSTANTS["a1"]], [_f32(v) for v in CSF_CONSTANTS["b1"]]
    a2, b2 = [_f32(v) for v in CSF_CONSTANTS["a2"]], [_f32(v) for v in CSF_CONSTANTS["b2"]]
    ppd32 = _f32(ppd)
    largest = max(max(b1), max(b2))
    radius = int(math.ceil(_f32(3.0) * np.sqrt(largest / (_f32(2.0) * pi_sq), dtype=np.float32) * ppd32))

    def gaussian(x2, a, b):  # a sqrt(pi / b) exp(-pi^2 x^2 / b)
        return a * np.sqrt(pi / b, dtype=np.float32) * _exp32(-pi_sq * x2 / b)

    def gaussian_sqrt(x2, a, b):  # the square root of the weight: one factor of the separated 2-D filter
        return np.sqrt(a * np.sqrt(pi / b, dtype=np.float32), dtype=np.float32) * _exp32(-pi_sq * x2 / b)

    dx = _f32(1.0) / ppd32
    taps = {"y": [], "cx": [], "cz1": [], "cz2": []}
    sums = dict.fromkeys(taps, _f32(0.0))
    for x in range(2 * radius + 1):
        ix = _f32(x - radius) * dx
        ix2 = ix * ix
        values = {"y": gaussian(ix2, a1[0], b1[0]), "cx": gaussian(ix2, a1[1], b1[1]),
                  "cz1": gaussian_sqrt(ix2, a1[2], b1[2]), "cz2": gaussian_sqrt(ix2, a2[2], b2[2])}
        for key, value in values.items():
            taps[key].append(_f32(value))
            sums[key] = _f32(sums[key] + _f32(value))
    norm_cz = _f32(1.0) / np.sqrt(sums["cz1"] * sums["cz1"] + sums["cz2"] * sums["cz2"], dtype=np.float32)
    spatial = {"y": [w * (_f32(1.0) / sums["y"]) for w in taps["y"]],
               "cx": [w * (_f32(1.0) / sums["cx"]) for w in taps["cx"]],
               "cz1": [w * norm_cz for w in taps["cz1"]], "cz2": [w * norm_cz for w in taps["cz2"]]}

    sigma = _f32(0.5) * _f32(FLIP_CONSTANTS["w"]) * ppd32
    feature_radius = int(math.ceil(_f32(3.0) * sigma))
    g, dg, ddg = [], [], []
    g_sum = dg_pos = dg_neg = ddg_pos = ddg_neg = _f32(0.0)
    for x in range(2 * feature_radius + 1):
        xx = _f32(x - feature_radius)
        gv = _exp32(-(xx * xx) / (_f32(2.0) * sigma * sigma))
        g_sum = _f32(g_sum + gv)
        dgv = -xx * gv
        if dgv > 0:
            dg_pos = _f32(dg_pos + dgv)
        else:
            dg_neg = _f32(dg_neg - dgv)
        ddgv = (xx * xx / (sigma * sigma) - _f32(1.0)) * gv
        if ddgv > 0:
            ddg_pos = _f32(ddg_pos + ddgv)
        else:
            ddg_neg = _f32(ddg_neg - ddgv)
        g.append(gv); dg.append(dgv); ddg.append(ddgv)
    feature = {"g": [v / g_sum for v in g],
               "dg": [v / (dg_pos if v > 0 else dg_neg) for v in dg],
               "ddg": [v / (ddg_pos if v > 0 else ddg_neg) for v in ddg]}
    return {"radius": radius, "spatial": {k: [float(v) for v in w] for k, w in spatial.items()},
            "feature_radius": feature_radius, "feature": {k: [float(v) for v in w] for k, w in feature.items()}}


# ------------------------------------------------------------------------- colour (device, float32)
def _f(value: float) -> float:
    """A constant as float32 computes it (a Python float the Dr.Jit literal keeps exactly)."""
    return float(_f32(value))


#: Linear sRGB -> XYZ (D65), flip-evaluator's fractions rounded to float32.
_RGB_TO_XYZ = tuple(tuple(float(_f32(n) / _f32(d)) for n, d in row) for row in (
    ((10135552.0, 24577794.0), (8788810.0, 24577794.0), (4435075.0, 24577794.0)),
    ((2613072.0, 12288897.0), (8788810.0, 12288897.0), (887015.0, 12288897.0)),
    ((1425312.0, 73733382.0), (8788810.0, 73733382.0), (70074185.0, 73733382.0))))

#: XYZ -> linear sRGB (D65), as flip-evaluator writes it.
_XYZ_TO_RGB = ((3.241003275, -1.537398934, -0.498615861),
               (-0.969224334, 1.875930071, 0.041554224),
               (0.055639423, -0.204011202, 1.057148933))


#: flip-evaluator's cube root is powf(t, 1.0f / 3.0f), and 1.0f / 3.0f = 1/3 + 9.9e-9: t^(1/3 + e) =
#: cbrt(t) t^e = cbrt(t) (1 + e ln t) to float32 precision (|e ln t| < 5e-8 over CIELab's cube-root range).
#: Leaving the e out (plain cbrt) biased mean FLIP by 7e-7 on a render; the power in float64 would
#: cost 3x the whole vertical pass.
_THIRD_EXCESS_LOG2 = (float(np.float32(1.0) / np.float32(3.0)) - 1.0 / 3.0) * math.log(2.0)


def _powf_third(t: Float) -> Float:
    """``powf(t, 1.0f / 3.0f)`` for t > 0, correctly rounded (see :data:`_THIRD_EXCESS_LOG2`): the float32
    cube root (within an ulp), one Newton step in float64 (the step's reciprocal slope in float32 is
    plenty: it scales a residual of 1e-7), the excess exponent, then one rounding. NaN or inf for t <= 0."""
    root = dr.cbrt(t)
    slope = Float64(1.0 / (3.0 * root * root))
    y = Float64(root)
    y = y - (y * y * y - Float64(t)) * slope
    return Float(dr.fma(y, Float64(_THIRD_EXCESS_LOG2 * dr.log2(t)), y))


def _matrix(m, a, b, c):
    return [m[i][0] * a + m[i][1] * b + m[i][2] * c for i in range(3)]


def _ycxcz(r, g, b):
    """Linear RGB -> YCxCz (XYZ relative to D65, then Y = 116 y - 16, Cx = 500 (x - y), Cz = 200 (y - z))."""
    x, y, z = _matrix(_RGB_TO_XYZ, r, g, b)
    x, z = x * _f(_INV_D65[0]), z * _f(_INV_D65[2])
    return 116.0 * y - 16.0, 500.0 * (x - y), 200.0 * (y - z)


def _lab_values(x, y, z):
    """XYZ relative to the white (already divided) -> CIE L*a*b*."""
    delta = _f32(6.0) / _f32(29.0)
    cube = delta * delta * delta
    factor = _f32(1.0) / (_f32(3.0) * delta * delta)
    term = _f32(4.0) / _f32(29.0)

    def f(t):
        return dr.select(t > float(cube), _powf_third(t), float(factor) * t + float(term))

    fx, fy, fz = f(x), f(y), f(z)
    return 116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)


_ONE_OVER_116 = float(_f32(1.0) / _f32(116.0))
_SIXTEEN_OVER_116 = float(_f32(16.0) / _f32(116.0))


def _clamp01(value):
    return select_min(select_max(value, 0.0), 1.0)


def _hunt_lab(Y, Cx, Cz):
    """Filtered YCxCz -> linear RGB clamped to [0, 1] -> CIELab with the Hunt adjustment (a, b x 0.01 L)."""
    y = (Y + 16.0) / 116.0
    x, z = y + Cx / 500.0, y - Cz / 200.0
    x, z = x * _f(_D65[0]), z * _f(_D65[2])
    r, g, b = (_clamp01(v) for v in _matrix(_XYZ_TO_RGB, x, y, z))
    x, y, z = _matrix(_RGB_TO_XYZ, r, g, b)
    L, a, b_ = _lab_values(x * _f(_INV_D65[0]), y, z * _f(_INV_D65[2]))
    return L, 0.01 * L * a, 0.01 * L * b_


def _hyab(p, q):
    return dr.abs(p[0] - q[0]) + dr.sqrt(dr.square(p[1] - q[1]) + dr.square(p[2] - q[2]))


@functools.lru_cache(maxsize=1)
def _colour_limits() -> tuple[float, float]:
    """``(cmax, pc cmax)``: the Hunt-adjusted HyAB distance between green and blue raised to ``qc``
    (the largest colour difference), float32 on the host as flip-evaluator computes it."""
    def lab(rgb):
        m = np.array(_RGB_TO_XYZ, np.float32)
        xyz = (m @ np.array(rgb, np.float32)).astype(np.float32) * np.array(_INV_D65, np.float32)
        delta = _f32(6.0) / _f32(29.0)
        third, factor = _f32(1.0) / _f32(3.0), _f32(1.0) / (_f32(3.0) * delta * delta)
        f = [_pow32(t, third) if t > delta * delta * delta else t * factor + _f32(4.0) / _f32(29.0) for t in xyz]
        L, a, b = _f32(116.0) * f[1] - _f32(16.0), _f32(500.0) * (f[0] - f[1]), _f32(200.0) * (f[1] - f[2])
        return L, _f32(0.01) * L * a, _f32(0.01) * L * b

    green, blue = lab((0.0, 1.0, 0.0)), lab((0.0, 0.0, 1.0))
    distance = abs(green[0] - blue[0]) + np.sqrt((green[1] - blue[1]) ** 2 + (green[2] - blue[2]) ** 2,
                                                 dtype=np.float32)
    cmax = _pow32(distance, _f32(FLIP_CONSTANTS["qc"]))
    return float(cmax), float(_f32(FLIP_CONSTANTS["pc"]) * cmax)


# ------------------------------------------------------------------------------ the three passes
#: Lanes of one batch of exposures (the padded frame times the exposures in it): bounds the
#: memory of the passes (about 25 floats a lane: some 200 MB) whatever the exposure count.
_BATCH_LANES = 1 << 21


class _Frame:
    """The padded frame: the image with ``R`` edge pixels repeated on every side, rows ``Pw`` long."""

    def __init__(self, height: int, width: int, radius: int):
        self.H, self.W, self.R = height, width, radius
        self.Ph = height + 2 * radius
        self.Pw = -(-(width + 2 * radius) // 16) * 16     # a multiple of 16 floats: 64-byte aligned rows
        self.P = self.Ph * self.Pw


def _pass_colour(images: list[Float], frame: _Frame, lanes: int, batch: int, scales: Float | None,
                 tonemapper: str | None) -> list[np.ndarray]:
    """Pass 1: every lane of the padded frames (``batch`` exposures, then a margin) -> (Y, Cx, Cz) of both
    images: exposed by ``scales`` and tone-mapped (HDR) or as they are (LDR), clamped to [0, 1]."""
    R, H, W = frame.R, frame.H, frame.W
    u = functools.partial(opaque_scalar, UInt32)
    i = dr.minimum(dr.arange(UInt32, lanes), u(batch * frame.P - 1))
    bound = max(_BATCH_LANES, batch * frame.P) + 1
    exposure, rest = divmod_u32(i, frame.P, bound)
    row, column = divmod_u32(rest, frame.Pw, frame.P + 1)
    y = dr.minimum(dr.maximum(row, u(R)) - u(R), u(H - 1))
    x = dr.minimum(dr.maximum(column, u(R)) - u(R), u(W - 1))
    pixel = (y * u(W) + x) * u(3)
    scale = dr.gather(Float, scales, exposure) if scales is not None else None
    outputs = []
    for image in images:
        rgb = [dr.gather(Float, image, pixel + u(c)) for c in range(3)]
        if scale is not None:
            rgb = [v * scale for v in rgb]
            c0, c1, c2, c3, c4, c5 = TONEMAPPERS[tonemapper]
            if tonemapper == "reinhard":
                wr, wg, wb = (_f(w) for w in REC709_LUMINANCE_WEIGHTS)
                factor = 1.0 / (1.0 + (wr * rgb[0] + wg * rgb[1] + wb * rgb[2]))
                rgb = [v * factor for v in rgb]
            else:
                rgb = [((v * v) * _f(c0) + v * _f(c1) + _f(c2)) / ((v * v) * _f(c3) + v * _f(c4) + _f(c5))
                       for v in rgb]
        outputs += list(_ycxcz(*(_clamp01(v) for v in rgb)))
    dr.eval(*outputs)
    return [o.numpy() for o in outputs]   # before the views die: their release waits for the kernel


def _taps(filters: dict, frame_radius: int) -> list[tuple[dict[str, float], dict[str, float]]]:
    """Per tap ``j`` of a window of radius ``frame_radius``: the colour and the feature filters' weights
    there (empty where the narrower filter has no tap). The weights are kernel literals: the kernels
    compile once per ``ppd``."""
    rs, rf = filters["radius"], filters["feature_radius"]
    taps = []
    for j in range(2 * frame_radius + 1):
        ks, kf = j - frame_radius + rs, j - frame_radius + rf
        spatial = {name: w[ks] for name, w in filters["spatial"].items()} if 0 <= ks <= 2 * rs else {}
        feature = {name: w[kf] for name, w in filters["feature"].items()} if 0 <= kf <= 2 * rf else {}
        taps.append((spatial, feature))
    return taps


def _pass_horizontal(ycxcz: list[np.ndarray], filters: dict, frame: _Frame, lanes: int) -> list[np.ndarray]:
    """Pass 2, per image: the horizontal colour filters (Y, Cx, and Cz by both of its Gaussians) and the
    feature filters (dg, ddg, g) of the normalised luminance ``y = (Y + 16) / 116``; tap ``j`` of lane
    ``i`` reads element ``i + j``."""
    outputs = []
    for image in range(2):
        source = ycxcz[3 * image:3 * image + 3]
        sums = [Float(0.0) for _ in range(7)]
        for j, (spatial, feature) in enumerate(_taps(filters, frame.R)):
            Y, Cx, Cz = (Float(channel[j:j + lanes]) for channel in source)
            if spatial:                  # a product then a sum, in tap order, as flip-evaluator adds
                sums[0] = sums[0] + spatial["y"] * Y
                sums[1] = sums[1] + spatial["cx"] * Cx
                sums[2] = sums[2] + spatial["cz1"] * Cz
                sums[3] = sums[3] + spatial["cz2"] * Cz
            if feature:
                y = Y * _ONE_OVER_116 + _SIXTEEN_OVER_116
                sums[4] = sums[4] + feature["dg"] * y
                sums[5] = sums[5] + feature["ddg"] * y
                sums[6] = sums[6] + feature["g"] * y
        outputs += sums
    dr.eval(*outputs)
    return [o.numpy() for o in outputs]   # before the views die: their release waits for the kernel


def _pass_vertical(rows: list[np.ndarray], filters: dict, frame: _Frame, lanes: int) -> np.ndarray:
    """Pass 3: the vertical filters (tap ``j`` of lane ``i`` reads element ``i + j Pw``), the colour
    difference (Hunt-adjusted HyAB), the feature difference and the FLIP error."""
    lab, edges, points = [], [], []
    for image in range(2):
        source = rows[7 * image:7 * image + 7]
        s = [Float(0.0) for _ in range(8)]
        for j, (spatial, feature) in enumerate(_taps(filters, frame.R)):
            start = j * frame.Pw
            if spatial:
                for c, name in enumerate(("y", "cx", "cz1", "cz2")):
                    s[c] = s[c] + spatial[name] * Float(source[c][start:start + lanes])
            if feature:
                dx, ddx, gx = (Float(source[c][start:start + lanes]) for c in (4, 5, 6))
                s[4] = s[4] + feature["g"] * dx          # d/dx: dg across, g down
                s[5] = s[5] + feature["g"] * ddx         # d2/dx2
                s[6] = s[6] + feature["dg"] * gx         # d/dy: g across, dg down
                s[7] = s[7] + feature["ddg"] * gx        # d2/dy2
        lab.append(_hunt_lab(s[0], s[1], s[2] + s[3]))
        edges.append(dr.sqrt(s[4] * s[4] + s[6] * s[6]))
        points.append(dr.sqrt(s[5] * s[5] + s[7] * s[7]))
    cmax, pccmax = (_f32(v) for v in _colour_limits())
    pt = _f32(FLIP_CONSTANTS["pt"])
    colour = dr.power(_hyab(*lab), _f(FLIP_CONSTANTS["qc"]))
    colour = dr.select(colour < float(pccmax), colour * float(pt / pccmax),
                       float(pt) + ((colour - float(pccmax)) / float(cmax - pccmax)) * float(_f32(1.0) - pt))
    difference = select_max(dr.abs(edges[0] - edges[1]), dr.abs(points[0] - points[1]))
    normalisation = float(_f32(1.0) / np.sqrt(_f32(2.0), dtype=np.float32))
    feature_error = dr.sqrt(normalisation * difference)
    error = dr.power(colour, 1.0 - feature_error)
    dr.eval(error)
    return error.numpy()


def _ldr_flip_batch(test: Float, reference: Float, frame: _Frame, filters: dict, batch: int,
                    scales: Float | None, tonemapper: str | None) -> np.ndarray:
    """LDR-FLIP of ``batch`` exposures: (batch, H, W) float32."""
    n3 = batch * frame.P
    n2 = n3 + 2 * frame.R * frame.Pw
    n1 = n2 + 2 * frame.R
    ycxcz = _pass_colour([reference, test], frame, n1, batch, scales, tonemapper)
    rows = _pass_horizontal(ycxcz, filters, frame, n2)
    del ycxcz
    error = _pass_vertical(rows, filters, frame, n3)
    del rows
    return error.reshape(batch, frame.Ph, frame.Pw)[:, :frame.H, :frame.W]


# ------------------------------------------------------------------------------------ public
def flip(image: Any, reference: Any, *, dynamic_range: str = "hdr", ppd: float = DEFAULT_PPD,
         start_exposure: float | None = None, stop_exposure: float | None = None,
         num_exposures: int | None = None, tonemapper: str = "aces", srgb: bool | None = None) -> FlipResult:
    """The FLIP error map of ``image`` against ``reference`` (HDR-FLIP by default), as flip-evaluator computes it.

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W), (H, W, 1) or (H, W, 3)
        The test image: linear RGB for HDR-FLIP, display values in [0, 1] for LDR-FLIP.
    reference : array_like or Dr.Jit tensor
        The reference, same shape. HDR-FLIP's exposures come from it.
    dynamic_range : {"hdr", "ldr"}
        HDR-FLIP (Andersson et al. 2021) or LDR-FLIP (Andersson et al. 2020).
    ppd : float
        Pixels per degree of visual angle (:func:`pixels_per_degree`; default 67.02, a 0.7 m
        4K monitor at 0.7 m). The filter radii grow with it.
    start_exposure, stop_exposure : float, optional
        HDR-FLIP's exposure range in stops; each one not given is computed from the reference
        (:func:`hdr_exposure_range`). ``start_exposure <= stop_exposure``.
    num_exposures : int, optional
        HDR-FLIP's number of exposures, from start to stop in equal steps; default
        ``max(2, ceil(stop - start))``. With 1, the start exposure alone (flip-evaluator divides
        by zero there).
    tonemapper : {"aces", "hable", "reinhard"}
        HDR-FLIP's tone mapper (:data:`TONEMAPPERS`).
    srgb : bool, optional
        The inputs are sRGB-encoded and are decoded first. Default: True for LDR-FLIP, False for
        HDR-FLIP (linear input), flip-evaluator's defaults.

    Returns
    -------
    FlipResult
        ``map`` ((H, W) ``TensorXf`` in [0, 1]), ``mean`` and, for HDR-FLIP, ``exposures``
        ``(start, stop, count)``.

    Raises
    ------
    ValueError
        Shapes that differ or are not images, NaN or infinite values, negative values in HDR,
        an empty exposure range (start > stop), a ``ppd`` that is not finite and positive, an
        unknown ``dynamic_range`` or ``tonemapper``, ``num_exposures < 1``.

    Notes
    -----
    See the module's notes for the domain. Agreement with flip-evaluator 1.7 (its tests): on
    renders and photographs, means within 1e-3 and per-pixel maps within 1e-2 at the 99th
    percentile (float32 rounding of the two implementations differs; the filters, borders,
    exposures and constants are the same).

    Examples
    --------
    >>> import numpy as np
    >>> reference = np.full((16, 16, 3), 0.5, np.float32)
    >>> flip(reference, reference).mean
    0.0
    >>> test = reference.copy(); test[6:10, 6:10] = 2.0        # a bright square
    >>> result = flip(test, reference)
    >>> result.exposures                    # a constant reference: one exposure, taken twice
    (2.0832972526550293, 2.0832972526550293, 2)
    >>> round(float(np.asarray(result.map)[8, 8]), 3), round(float(np.asarray(result.map)[0, 0]), 3)
    (0.27, 0.0)
    """
    if not isinstance(dynamic_range, str) or dynamic_range.lower() not in ("hdr", "ldr"):
        raise ValueError(f"dynamic_range: expected 'hdr' or 'ldr', got {dynamic_range!r}")
    hdr = dynamic_range.lower() == "hdr"
    checks.real(ppd, "ppd", low=0.0, low_open=True)
    tonemapper = _check_tonemapper(tonemapper)
    if srgb is not None:
        checks.boolean(srgb, "srgb")
    srgb = (not hdr) if srgb is None else bool(srgb)
    for name, value in (("start_exposure", start_exposure), ("stop_exposure", stop_exposure)):
        if value is not None:
            checks.real(value, name)
    if num_exposures is not None:
        checks.integer(num_exposures, "num_exposures", low=1)
    test = _rgb_array(image, "image")
    ref = _rgb_array(reference, "reference")
    if test.shape != ref.shape:
        raise ValueError(f"image: expected the reference's shape {ref.shape[:2]}, got {test.shape[:2]}")
    if hdr and ((test < 0).any() or (ref < 0).any()):
        name = "image" if (test < 0).any() else "reference"
        raise ValueError(f"{name}: expected linear values >= 0 for HDR-FLIP, got negative values")

    if srgb:   # flip-evaluator decodes on the host, before anything else (the exposures included)
        test, ref = (np.asarray(srgb_decode(a)) for a in (test, ref))
    H, W = ref.shape[:2]
    filters = _filters(float(ppd))
    frame = _Frame(H, W, max(filters["radius"], filters["feature_radius"]))
    test_f, ref_f = Float(test.reshape(-1)), Float(ref.reshape(-1))
    result = np.zeros((H, W), np.float32)
    exposures = None
    if not hdr:
        result = np.maximum(result, _ldr_flip_batch(test_f, ref_f, frame, filters, 1, None, None)[0])
    else:
        start, stop = start_exposure, stop_exposure
        if start is None or stop is None:
            computed = _exposure_range(ref, tonemapper)
            start = computed[0] if start is None else start
            stop = computed[1] if stop is None else stop
        start, stop = _f32(start), _f32(stop)
        if not start <= stop:
            raise ValueError(
                f"start_exposure: HDR-FLIP's exposure range is empty (start {float(start):.6g} > stop "
                f"{float(stop):.6g}); a reference whose largest luminance is below float32's epsilon (black or "
                "nearly black) has no range of its own: pass start_exposure and stop_exposure")
        count = int(num_exposures) if num_exposures is not None else int(max(_f32(2.0), np.ceil(stop - start)))
        step = (stop - start) / _f32(count - 1) if count > 1 else _f32(0.0)
        levels = [start + _f32(i) * step for i in range(count)]
        scales = np.array([_pow32(2.0, level) for level in levels], np.float32)
        batch = max(1, _BATCH_LANES // frame.P)
        for first in range(0, count, batch):
            chunk = scales[first:first + batch]
            maps = _ldr_flip_batch(test_f, ref_f, frame, filters, chunk.size, Float(chunk), tonemapper)
            np.maximum(result, maps.max(axis=0), out=result)
        exposures = (float(start), float(stop), count)
    return FlipResult(TensorXf(result), float(result.mean(dtype=np.float64)), exposures)
