"""Power spectra of images: the periodogram, its radial average, and the energy below a frequency.

Where an image's energy lies in spatial frequency: ``pointillist compare`` applies these to each
render's error image (render minus reference, luminance) to show whether a sampler leaves its
error as white noise (flat spectrum) or pushes it to high frequencies (blue noise), where the
eye and any blur forgive it.

Definitions, for an ``H x W`` image ``x`` with discrete Fourier transform ``X`` and
``N = H W``:

- frequencies in cycles per pixel, ``f = (k / W, l / H)`` with ``k, l`` as ``numpy.fft.fftfreq``
  lists them (``-1/2 <= f < 1/2``; Nyquist is :data:`NYQUIST` = 1/2); the radius is ``|f|``;
- the periodogram ``P(f) = |X(f)|^2 / N`` (:func:`power_spectrum`): its mean over all
  frequencies is ``mean(x^2)`` (Parseval), and white noise of variance ``sigma^2`` has
  ``E[P(f)] = sigma^2`` at every frequency: a flat spectrum at its variance;
- the radial average (:func:`radial_power_spectrum`): the mean of ``P`` over rings of width
  ``1 / max(H, W)`` around ``|f| = i / max(H, W)``, up to Nyquist;
- the low-frequency energy (:func:`low_frequency_energy`): ``(1/N) sum P(f)`` over ``|f| <=
  cutoff``, the part of ``mean(x^2)`` carried by those frequencies (white noise: about
  ``pi cutoff^2 sigma^2``). The default cutoff, :data:`LOW_FREQUENCY_CUTOFF`, is a quarter of
  Nyquist.

The transform is numpy's FFT (Dr.Jit has none); no window is applied, so ``x`` is taken as
periodic (for error images, noise with no structure at the borders, the seam is harmless).

Notes
-----
==============  ====================================  ========================================
argument        domain                                what happens
==============  ====================================  ========================================
``image``       (H, W) or (H, W, 1), real, numpy or   one pixel: all of it is the DC term;
                Dr.Jit; H, W >= 1                     constant: only DC; NaN or inf anywhere:
                                                      every power is NaN (as an RMSE would be)
``cutoff``      >= 0 cycles per pixel                 0: the DC term alone; >= sqrt(1/2):
                                                      all of ``mean(x^2)``
==============  ====================================  ========================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pointillist.core import checks

__all__ = ["NYQUIST", "LOW_FREQUENCY_CUTOFF", "RadialSpectrum", "power_spectrum", "frequency_radius",
           "radial_power_spectrum", "low_frequency_energy", "log_binned"]

#: Nyquist frequency of a pixel grid, in cycles per pixel.
NYQUIST = 0.5

#: Default cutoff of :func:`low_frequency_energy`: a quarter of Nyquist, 1/8 cycle per pixel
#: (wavelengths of 8 pixels and more).
LOW_FREQUENCY_CUTOFF = NYQUIST / 4


@dataclass(frozen=True)
class RadialSpectrum:
    """A radially averaged power spectrum (:func:`radial_power_spectrum`).

    Attributes
    ----------
    frequency : numpy.ndarray
        Ring centres ``i / max(H, W)`` in cycles per pixel, ``i = 0 ..`` up to Nyquist.
    power : numpy.ndarray
        Mean periodogram over each ring (NaN for a ring no frequency falls in: a thin image's
        coarse axis leaves gaps between its low rings).
    count : numpy.ndarray
        How many frequencies each ring averages (int).
    """

    frequency: np.ndarray
    power: np.ndarray
    count: np.ndarray


def _plane(image, name: str = "image") -> np.ndarray:
    """``image`` as a float64 (H, W) numpy array; ValueError for another shape or an empty one."""
    array = np.asarray(image)
    if array.ndim == 3 and array.shape[2] == 1:
        array = array[..., 0]
    if array.ndim != 2:
        raise ValueError(f"{name}: expected an (H, W) or (H, W, 1) image, got shape {array.shape}")
    if array.size == 0:
        raise ValueError(f"{name}: expected a non-empty image, got shape {array.shape}")
    if not (np.issubdtype(array.dtype, np.number) or array.dtype == bool) or np.iscomplexobj(array):
        raise TypeError(f"{name}: expected real numbers, got dtype {array.dtype}")
    return array.astype(np.float64, copy=False)


def power_spectrum(image) -> np.ndarray:
    """The periodogram ``|X(f)|^2 / N`` of a 2D image, in numpy's FFT order.

    Parameters
    ----------
    image : array_like, shape (H, W) or (H, W, 1)
        Real values (numpy or Dr.Jit).

    Returns
    -------
    numpy.ndarray
        float64 (H, W): entry ``[l, k]`` is the power at ``(numpy.fft.fftfreq(W)[k],
        numpy.fft.fftfreq(H)[l])``. Its mean is ``mean(image^2)``.

    Examples
    --------
    >>> power_spectrum(np.full((2, 2), 3.0)).tolist()   # a constant: all of it at DC, N x 3^2
    [[36.0, 0.0], [0.0, 0.0]]
    """
    x = _plane(image)
    spectrum = np.abs(np.fft.fft2(x)) ** 2 / x.size
    if not np.isfinite(x).all():
        spectrum[...] = np.nan
    return spectrum


def frequency_radius(shape: tuple[int, int]) -> np.ndarray:
    """``|f|`` in cycles per pixel for every entry of a (H, W) periodogram (numpy's FFT order).

    >>> frequency_radius((1, 4)).tolist()
    [[0.0, 0.25, 0.5, 0.25]]
    """
    height, width = checks.integers(shape, "shape", 2, low=0)
    return np.hypot(np.fft.fftfreq(height)[:, None], np.fft.fftfreq(width)[None, :])


def radial_power_spectrum(image, *, max_frequency: float = NYQUIST) -> RadialSpectrum:
    """The periodogram of ``image`` averaged over rings of equal frequency radius.

    Parameters
    ----------
    image : array_like, shape (H, W) or (H, W, 1)
        Real values (numpy or Dr.Jit).
    max_frequency : float, optional
        The last ring's centre, in cycles per pixel (default Nyquist, 1/2; the corners of the
        frequency square beyond it are left out, as is usual).

    Returns
    -------
    RadialSpectrum
        Ring ``i`` averages the frequencies with ``round(|f| max(H, W)) == i``.

    Examples
    --------
    White noise: flat at its variance (here 1), within the periodogram's own noise.

    >>> noise = np.random.default_rng(0).standard_normal((256, 256))
    >>> spectrum = radial_power_spectrum(noise)
    >>> spectrum.frequency[[0, 1, -1]].tolist(), len(spectrum.power)
    ([0.0, 0.00390625, 0.5], 129)
    >>> bool(abs(np.nanmean(spectrum.power[1:]) - 1) < 0.03)
    True
    """
    checks.real(max_frequency, "max_frequency", low=0.0, float32=False)
    spectrum = power_spectrum(image)
    n = max(spectrum.shape)
    ring = np.rint(frequency_radius(spectrum.shape) * n).astype(np.int64).ravel()
    rings = int(math.floor(max_frequency * n + 1e-9)) + 1
    keep = ring < rings
    count = np.bincount(ring[keep], minlength=rings)
    total = np.bincount(ring[keep], weights=spectrum.ravel()[keep], minlength=rings)
    with np.errstate(invalid="ignore", divide="ignore"):
        power = np.where(count > 0, total / np.maximum(count, 1), np.nan)
    return RadialSpectrum(frequency=np.arange(rings) / n, power=power, count=count)


def log_binned(spectrum: RadialSpectrum, *, per_decade: int = 12) -> RadialSpectrum:
    """The rings of ``spectrum`` merged into bins of equal width in log frequency, for log-log plots.

    Each bin's power is the mean periodogram over all the frequencies of its rings (rings weighted
    by ``count``), its frequency their mean radius; empty bins and the DC ring are dropped. Low
    rings hold few frequencies (ring ``i`` about ``2 pi i``), so their means are noisy; merging
    them evens the noise out along a log axis.

    Examples
    --------
    >>> s = RadialSpectrum(np.array([0, .1, .2, .3]), np.array([9., 1., 2., 4.]), np.array([1, 2, 2, 4]))
    >>> merged = log_binned(s, per_decade=4)   # bins [0.1, 0.178), [0.178, 0.316): 0.1 | 0.2 and 0.3
    >>> merged.frequency.round(4).tolist(), merged.power.round(4).tolist(), merged.count.tolist()
    ([0.1, 0.2667], [1.0, 3.3333], [2, 6])
    """
    checks.integer(per_decade, "per_decade", low=1)
    keep = (spectrum.frequency > 0) & (spectrum.count > 0)
    frequency, count = spectrum.frequency[keep], spectrum.count[keep]
    total = spectrum.power[keep] * count
    if not frequency.size:
        return RadialSpectrum(frequency=frequency, power=total, count=count)
    bins = np.floor(np.log10(frequency) * per_decade + 1e-9).astype(np.int64)
    bins -= bins.min()
    counts = np.bincount(bins, weights=count)
    used = counts > 0
    return RadialSpectrum(frequency=np.bincount(bins, weights=frequency * count)[used] / counts[used],
                          power=np.bincount(bins, weights=total)[used] / counts[used],
                          count=counts[used].astype(np.int64))


def low_frequency_energy(image, *, cutoff: float = LOW_FREQUENCY_CUTOFF) -> float:
    """The part of ``mean(image^2)`` carried by the frequencies with ``|f| <= cutoff``.

    ``(1/N) sum over |f| <= cutoff of |X(f)|^2 / N``: the mean square of the image low-passed by
    an ideal circular filter of radius ``cutoff``. With ``cutoff`` a quarter of Nyquist (the
    default) and an error image, it is the error's energy at wavelengths of 8 pixels and more.

    Parameters
    ----------
    image : array_like, shape (H, W) or (H, W, 1)
        Real values (numpy or Dr.Jit).
    cutoff : float, optional
        Radius in cycles per pixel, ``>= 0`` (default :data:`LOW_FREQUENCY_CUTOFF`, 1/8).

    Returns
    -------
    float
        Between 0 and ``mean(image^2)``; NaN when ``image`` holds NaN or inf.

    Examples
    --------
    A sinusoid of amplitude 2 puts all its mean square, 2, below the cutoff, or none of it:

    >>> x = np.arange(64)
    >>> slow = 2 * np.cos(2 * np.pi * 4 * x / 64)[None, :].repeat(64, 0)    # 1/16 cycle per pixel
    >>> fast = 2 * np.cos(2 * np.pi * 16 * x / 64)[None, :].repeat(64, 0)   # 1/4 cycle per pixel
    >>> round(low_frequency_energy(slow), 12), round(low_frequency_energy(fast), 12)
    (2.0, 0.0)
    """
    checks.real(cutoff, "cutoff", low=0.0, float32=False)
    spectrum = power_spectrum(image)
    inside = frequency_radius(spectrum.shape) <= cutoff + 1e-12
    return float(spectrum[inside].sum() / spectrum.size)
