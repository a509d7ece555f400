"""Errors of an image against a reference: RMSE, relative MSE and HDR-FLIP, with their per-pixel maps,
and where the error lies in spatial frequency.

The measures ``pointillist compare`` reports (and ``pointillist render``'s progressive
estimate imitates without a reference):

- ``rmse = sqrt(mean((x - r)^2))`` over all pixels and RGB channels;
- ``relmse = mean((x - r)^2 / (r^2 + epsilon))``, epsilon = :data:`RELMSE_EPSILON`;
- ``flip``: the mean of HDR-FLIP (Andersson et al. 2021), linear sRGB input, computed on Dr.Jit by
  :func:`pointillist.imaging.flip.flip` (``flip_backend="flip-evaluator"`` runs NVIDIA's package
  instead: the reference the tests hold the Dr.Jit implementation to);
- ``lowfreq``: the mean square of the luminance error ``e = Y(x) - Y(r)`` (Rec. 709 weights)
  carried by spatial frequencies up to a quarter of Nyquist
  (:func:`pointillist.imaging.spectrum.low_frequency_energy`); :func:`error_spectrum` is the
  radially averaged power spectrum of ``e``. White-noise error keeps about 5 % of its mean
  square there (pi / 64); blue-noise error less.

Notes
-----
==============  ===============================  ===================================
argument        domain                           what happens
==============  ===============================  ===================================
``image``       (H, W) or (H, W, C), any float   NaN/inf make RMSE/relMSE non-finite
``reference``   same shape, any float            a black or constant reference gets
                                                 FLIP's single exposure (no abort)
==============  ===============================  ===================================
"""

from __future__ import annotations

import math

import numpy as np

from pointillist.imaging.colour import REC709_LUMINANCE_WEIGHTS
from pointillist.imaging.flip import flip as _flip_drjit
from pointillist.imaging.flip import tonemapper_x_max
from pointillist.imaging.spectrum import RadialSpectrum, low_frequency_energy, radial_power_spectrum

__all__ = ["RELMSE_EPSILON", "FLIP_MIN_LUMINANCE", "FLIP_BACKENDS", "image_errors", "error_maps", "as_rgb",
           "luminance_error", "error_spectrum"]

#: Epsilon of the relative MSE, mean((x - ref)^2 / (ref^2 + eps)).
RELMSE_EPSILON = 0.01


#: HDR-FLIP's exposure range runs from log2(x / max Y) to log2(x / max(median Y, FLT_EPSILON)) (Y the
#: reference's luminance, Rec. 709 weights): flip-evaluator exits the process when the start exceeds the
#: stop, which happens for every reference whose max Y is below FLT_EPSILON (measured: one pixel of 1e-30
#: on black). Below twice that, :func:`_flip_exposures` passes the exposure itself.
FLIP_MIN_LUMINANCE = 2.0 * float(np.finfo(np.float32).eps)

#: The implementations of FLIP: ``"drjit"`` (:func:`pointillist.imaging.flip.flip`, the default) and
#: ``"flip-evaluator"`` (NVIDIA's package, the reference that the tests check the first against).
FLIP_BACKENDS = ("drjit", "flip-evaluator")


def as_rgb(image: np.ndarray) -> np.ndarray:
    """``image`` as float64 (H, W, 3): grey (H, W) repeated into RGB, extra channels (alpha) dropped."""
    image = np.asarray(image, dtype=np.float64)
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, axis=2)
    return image[..., :3]


def image_errors(image: np.ndarray, reference: np.ndarray, *, flip: bool = True,
                 maps: dict[str, np.ndarray] | None = None, flip_backend: str = "drjit") -> dict[str, float]:
    """RMSE, relative MSE, HDR-FLIP and low-frequency error of ``image`` against ``reference``.

    - ``rmse = sqrt(mean((x - r)^2))`` over all pixels and RGB channels;
    - ``relmse = mean((x - r)^2 / (r^2 + 0.01))`` (:data:`RELMSE_EPSILON`);
    - ``flip``: mean HDR-FLIP (linear sRGB input, default viewing conditions), NaN
      values and negatives set to 0 and values above 1e4 to 1e4 first, computed by
      ``flip_backend`` (:data:`FLIP_BACKENDS`: ``"drjit"``, :func:`pointillist.imaging.flip.flip`,
      or ``"flip-evaluator"``). Where the reference has no exposure range of its own (a
      black, constant or nearly black one: flip-evaluator would exit the process) the
      exposure is passed explicitly (:func:`_flip_exposures`), so every reference gets a value;
    - ``lowfreq``: the part of the mean square of the luminance error (:func:`luminance_error`)
      at spatial frequencies up to a quarter of Nyquist
      (:func:`pointillist.imaging.spectrum.low_frequency_energy`).

    Non-finite pixels of ``image`` make RMSE, relative MSE and ``lowfreq`` non-finite (they
    are reported, not hidden). Grey (H, W) images are compared as RGB. A ``maps`` dict
    receives the per-pixel maps whose means these are (:func:`error_maps`), at no
    extra cost.

    Examples
    --------
    >>> import numpy as np
    >>> ref = np.full((4, 4, 3), 0.5, np.float32)
    >>> e = image_errors(ref + 0.1, ref, flip=False)
    >>> round(e["rmse"], 6), round(e["relmse"], 6), round(e["lowfreq"], 6)   # a constant error is all DC
    (0.1, 0.038462, 0.01)
    """
    if flip_backend not in FLIP_BACKENDS:
        raise ValueError(f"flip_backend: expected one of {', '.join(map(repr, FLIP_BACKENDS))}, got {flip_backend!r}")
    x, r = _pair(image, reference)
    diff2 = (x - r) ** 2
    relative = diff2 / (r * r + RELMSE_EPSILON)
    result = {"rmse": float(np.sqrt(diff2.mean())), "relmse": float(relative.mean()), "flip": math.nan,
              "lowfreq": low_frequency_energy(_luminance(x - r))}
    if maps is not None:
        maps["relmse"] = relative.mean(axis=2).astype(np.float32)
    if flip:
        flip_map, result["flip"] = _flip(x, r, flip_backend)
        if maps is not None:
            maps["flip"] = flip_map
    return result


def error_maps(image: np.ndarray, reference: np.ndarray, *, flip: bool = True,
               flip_backend: str = "drjit") -> dict[str, np.ndarray]:
    """Per-pixel errors of ``image`` against ``reference``: (H, W) float32 maps.

    - ``relmse``: ``mean over RGB of (x - r)^2 / (r^2 + 0.01)``; its mean over the
      pixels is :func:`image_errors`' ``relmse``;
    - ``flip`` (with ``flip``): the HDR-FLIP error map in [0, 1] (by ``flip_backend``, the
      input cleaned as in :func:`image_errors`); its mean is the ``flip`` there.

    Examples
    --------
    >>> import numpy as np
    >>> ref = np.zeros((1, 2, 3), np.float32)
    >>> error_maps(ref + [[[0.1, 0.1, 0.1], [0.0, 0.0, 0.3]]], ref, flip=False)["relmse"].tolist()
    [[1.0, 3.0]]
    """
    maps: dict[str, np.ndarray] = {}
    image_errors(image, reference, flip=flip, maps=maps, flip_backend=flip_backend)
    return maps


def luminance_error(image: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """The error image ``Y(image) - Y(reference)``: float64 (H, W), Y with Rec. 709 weights.

    Examples
    --------
    >>> luminance_error(np.ones((1, 1, 3)), np.zeros((1, 1, 3))).round(6).tolist()
    [[1.0]]
    """
    x, r = _pair(image, reference)
    return _luminance(x - r)


def error_spectrum(image: np.ndarray, reference: np.ndarray) -> RadialSpectrum:
    """The radially averaged power spectrum of the luminance error (:func:`luminance_error`).

    White-noise error is flat at its variance; blue-noise error rises with frequency
    (:func:`pointillist.imaging.spectrum.radial_power_spectrum`).
    """
    return radial_power_spectrum(luminance_error(image, reference))


def _luminance(rgb: np.ndarray) -> np.ndarray:
    return rgb @ np.array(REC709_LUMINANCE_WEIGHTS)


def _pair(image: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x, r = as_rgb(image), as_rgb(reference)
    if x.shape != r.shape:
        raise ValueError(f"image: expected the reference's shape {r.shape[:2]}, got {x.shape[:2]}")
    if r.ndim != 3 or r.size == 0:
        raise ValueError(f"reference: expected a non-empty (H, W) or (H, W, C) image, got shape {r.shape}")
    return x, r


def _flip(x: np.ndarray, r: np.ndarray, backend: str) -> tuple[np.ndarray, float]:
    """HDR-FLIP of ``x`` against ``r`` by ``backend``: the (H, W) map and its mean."""
    def clean(a):
        return np.ascontiguousarray(np.clip(np.nan_to_num(a, nan=0.0, posinf=1e4), 0.0, 1e4), dtype=np.float32)

    reference, test = clean(r), clean(x)
    exposure = _flip_exposures(reference)
    if backend == "flip-evaluator":
        import flip_evaluator

        parameters = {} if exposure is None else {"startExposure": exposure, "stopExposure": exposure}
        error_map, mean, _ = flip_evaluator.evaluate(reference, test, "HDR", applyMagma=False, parameters=parameters)
        return np.asarray(error_map, np.float32).reshape(x.shape[:2]), float(mean)
    result = _flip_drjit(test, reference, dynamic_range="hdr", start_exposure=exposure, stop_exposure=exposure)
    return np.asarray(result.map), result.mean


def _flip_exposures(reference: np.ndarray) -> float | None:
    """None (HDR-FLIP's own exposure range), or the one exposure to use where there is none.

    HDR-FLIP takes start = log2(x_max / Y_max) and stop = log2(x_max / max(Y_median, FLT_EPSILON))
    from the reference's luminance; flip-evaluator calls ``exit`` ("Start exposure must be smaller
    than stop exposure!") when start exceeds stop (a constant reference of 1e-7, a black one), and
    :func:`pointillist.imaging.flip.flip` raises. Where the median luminance is the maximum
    (rounding may put the start above the stop) or the maximum is below :data:`FLIP_MIN_LUMINANCE`,
    the one exposure log2(x_max / Y_max) (0 for a black reference) is passed as both start and stop,
    which is what HDR-FLIP uses when they tie.
    """
    luminance = reference @ np.array(REC709_LUMINANCE_WEIGHTS, np.float32)
    y_max, y_median = float(luminance.max()), float(np.median(luminance))
    if y_median < y_max * (1 - 1e-5) and y_max >= FLIP_MIN_LUMINANCE:
        return None
    return math.log2(tonemapper_x_max("aces") / y_max) if y_max > 0 else 0.0
