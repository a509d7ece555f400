"""Tone mapping: linear HDR renders to display values through a table of operators."""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import drjit as dr
import numpy as np
from drjit.llvm import Array3f, Float, UInt32

from pointillist.core import checks
from pointillist.imaging.arrays import TensorXf, as_tensor, eager_if_shared, opaque_scalar
from pointillist.imaging.colour import REC709_LUMINANCE_WEIGHTS, srgb_encode_values
from pointillist.imaging.tone._shared import _finish

__all__ = ["TONEMAP_OPERATORS", "TONEMAP_TABLE", "TonemapOperator", "HABLE_CONSTANTS", "ACES_CONSTANTS", "tonemap"]

#: Hable's filmic curve (J. Hable, "Uncharted 2: HDR Lighting", GDC 2010): shoulder strength A,
#: linear strength B, linear angle C, toe strength D, toe numerator E, toe denominator F,
#: linear white point W, and the exposure bias applied before the curve.
HABLE_CONSTANTS = {"A": 0.15, "B": 0.50, "C": 0.10, "D": 0.20, "E": 0.02, "F": 0.30,
                   "W": 11.2, "exposure_bias": 2.0}

#: K. Narkowicz, "ACES Filmic Tone Mapping Curve" (2016): x (a x + b) / (x (c x + d) + e).
ACES_CONSTANTS = {"a": 2.51, "b": 0.03, "c": 2.43, "d": 0.59, "e": 0.14}

#: The smallest default white point: float32's smallest normal number (an all-black image).
_TINY = float(np.finfo(np.float32).tiny)

#: Linear values are clamped here after exposure: every operator is saturated far below, and
#: the curves' squares stay finite in float32.
_HDR_MAX = 1e15


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


# --------------------------------------------------------------------------- the operators' curves
# Each takes the exposed, clamped channels (one, or R, G, B) and the checked ``white`` (None: the
# operator's default) and returns the mapped channels, to be clipped to 0..1 and sRGB-encoded.

def _white_point(values: Float, white: float | None) -> Float:
    """``white`` (opaque), or the largest of ``values`` (at least float32's smallest normal)."""
    if white is not None:
        return opaque_scalar(Float, min(white, _HDR_MAX))
    return dr.maximum(dr.max(values), _TINY)  # its own reduction pass


def _clip(channels: list[Float], white: float | None) -> list[Float]:
    return channels


def _on_luminance(curve: Callable[[Float, Float], Float]) -> Callable[[list[Float], float | None], list[Float]]:
    """An operator that maps the luminance L to L_d and scales every channel by L_d / L (hue kept)."""
    def mapped(channels: list[Float], white: float | None) -> list[Float]:
        lum = _luminance(channels)
        mapped_l = curve(lum, _white_point(lum, white))
        ratio = dr.select(lum > 0.0, mapped_l / lum, 0.0)
        return [c * ratio for c in channels]
    return mapped


def _reinhard_curve(lum: Float, w: Float) -> Float:
    # L (1 + L / w^2) / (1 + L) as (L + (L / w)^2) / (1 + L): 1 / w^2 overflows for w < 1e-19
    relative = lum / w  # w = inf -> 0
    return (lum + relative * relative) / (1.0 + lum)


def _log_curve(lum: Float, w: Float) -> Float:
    return _log1p(lum) / _log1p(w)


def _reinhard_extended(channels: list[Float], white: float | None) -> list[Float]:
    brightest = channels[0] if len(channels) == 1 else dr.maximum(dr.maximum(channels[0], channels[1]), channels[2])
    w = _white_point(brightest, white)
    return [(c + (c / w) * (c / w)) / (1.0 + c) for c in channels]


def _hable(channels: list[Float], white: float | None) -> list[Float]:
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
    return [f(k["exposure_bias"] * c) * norm for c in channels]


def _aces(channels: list[Float], white: float | None) -> list[Float]:
    k = ACES_CONSTANTS
    return [(c * (k["a"] * c + k["b"])) / (c * (k["c"] * c + k["d"]) + k["e"]) for c in channels]


class TonemapOperator(NamedTuple):
    """A tone-mapping operator: the keyword parameters it takes and its curve
    (``curve(channels, white) -> channels``, linear to 0..1 before clipping and the sRGB encoding)."""

    parameters: tuple[str, ...]
    curve: Callable[[list[Float], float | None], list[Float]]


#: The tone-mapping operators of :func:`tonemap` by name (their curves are described there).
TONEMAP_TABLE: dict[str, TonemapOperator] = {
    "clip": TonemapOperator((), _clip),
    "reinhard": TonemapOperator(("white",), _on_luminance(_reinhard_curve)),
    "reinhard_extended": TonemapOperator(("white",), _reinhard_extended),
    "hable": TonemapOperator(("white",), _hable),
    "aces": TonemapOperator((), _aces),
    "log": TonemapOperator(("white",), _on_luminance(_log_curve)),
}

#: Tone-mapping operators and the extra keyword parameters each accepts (from :data:`TONEMAP_TABLE`).
TONEMAP_OPERATORS: dict[str, tuple[str, ...]] = {name: op.parameters for name, op in TONEMAP_TABLE.items()}


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
    if not isinstance(operator, str) or operator not in TONEMAP_TABLE:
        raise ValueError(f"operator: expected one of {', '.join(TONEMAP_OPERATORS)}, got {operator!r}")
    exposure = checks.real(exposure, "exposure", low=-100.0, high=100.0)
    unknown = set(params) - set(TONEMAP_TABLE[operator].parameters)
    if unknown:
        allowed = ", ".join(TONEMAP_TABLE[operator].parameters) or "none"
        raise ValueError(f"{sorted(unknown)[0]}: not a parameter of tonemap operator {operator!r} "
                         f"(it takes: {allowed})")
    white = params.get("white")
    if white is not None:
        white = checks.real(white, "white", low=0.0, low_open=True, allow_inf=True)

    tensor = as_tensor(image, channels=(1, 3))
    count = dr.zeros(UInt32, 1)
    scale = opaque_scalar(Float, 2.0 ** exposure)

    def prepare(values: Float) -> tuple[Float, Float]:
        """Sanitised, exposed, clamped channel and its +inf mask (counted); per pixel, so that
        the whole operator is one pass over the (H, W, 3) data, not one per step."""
        bad = ~dr.isfinite(values)
        dr.scatter_add(count, 1, UInt32(0), active=bad)
        return dr.clip(dr.select(bad, 0.0, values) * scale, 0.0, _HDR_MAX), bad & (values > 0)

    if tensor.ndim == 3 and tensor.shape[2] == 3:
        rgb = dr.unravel(Array3f, tensor.array)
        prepared = [prepare(c) for c in (rgb.x, rgb.y, rgb.z)]
    else:
        prepared = [prepare(tensor.array)]
    channels = [c for c, _ in prepared]
    posinf = [p for _, p in prepared]

    mapped = TONEMAP_TABLE[operator].curve(channels, white)

    display = [dr.select(inf, 255.0, srgb_encode_values(dr.clip(m, 0.0, 1.0)) * 255.0)
               for m, inf in zip(mapped, posinf)]
    values = dr.ravel(Array3f(*display)) if len(display) == 3 else display[0]
    return _finish(TensorXf(values, tensor.shape), count, "tonemap")

