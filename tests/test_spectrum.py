"""imaging.spectrum (periodogram, radial average, low-frequency energy) and the error spectrum of
imaging.metrics: analytic cases (white noise, sinusoids, constants), numpy's own FFT conventions,
and properties over arbitrary arrays."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from pointillist.imaging.metrics import error_spectrum, image_errors, luminance_error
from pointillist.imaging.spectrum import (LOW_FREQUENCY_CUTOFF, NYQUIST, RadialSpectrum, frequency_radius,
                                          log_binned, low_frequency_energy, power_spectrum, radial_power_spectrum)


def test_white_noise_is_flat_at_its_variance(rng):
    """E[P(f)] = sigma^2 at every frequency: averaged over 20 images of 128 x 96, each ring's mean
    is within 4 standard errors of sigma^2 (P is exponential with mean sigma^2, so a ring of n
    frequencies over 20 images has standard error sigma^2 / sqrt(20 n))."""
    sigma = 0.3
    spectra = [radial_power_spectrum(rng.normal(0.0, sigma, (96, 128))) for _ in range(20)]
    power = np.mean([s.power for s in spectra], axis=0)
    count = spectra[0].count
    ok = count > 0
    standard_error = sigma ** 2 / np.sqrt(20 * count[ok])
    assert np.all(np.abs(power[ok] - sigma ** 2) < 4 * standard_error)
    assert spectra[0].frequency[-1] == NYQUIST and len(spectra[0].frequency) == 128 // 2 + 1
    # the low-frequency energy of white noise: the share of the frequencies inside the disk (about pi / 64)
    inside = (frequency_radius((96, 128)) <= LOW_FREQUENCY_CUTOFF).mean()
    assert math.pi / 64 == pytest.approx(inside, rel=0.05)
    energies = [low_frequency_energy(rng.normal(0.0, sigma, (96, 128))) for _ in range(50)]
    assert np.mean(energies) == pytest.approx(sigma ** 2 * inside, rel=0.05)


def test_sinusoid_peaks_at_its_radius():
    """A cos(2 pi (k0 x / W + l0 y / H)): all of its mean square A^2 / 2 sits at +-(k0/W, l0/H)."""
    height, width, amplitude = 64, 64, 1.5
    y, x = np.mgrid[0:height, 0:width]
    for k0, l0 in ((8, 0), (0, 5), (6, 8)):
        image = amplitude * np.cos(2 * np.pi * (k0 * x / width + l0 * y / height))
        spectrum = radial_power_spectrum(image)
        radius = math.hypot(k0 / width, l0 / height)
        peak = int(np.nanargmax(spectrum.power))
        assert spectrum.frequency[peak] == pytest.approx(round(radius * 64) / 64)
        # the ring's total periodogram is 2 x (A N / 2)^2 / N = A^2 N / 2; every other ring is empty
        total = spectrum.power * spectrum.count
        assert total[peak] == pytest.approx(amplitude ** 2 * height * width / 2, rel=1e-9)
        assert np.nansum(np.delete(total, peak)) == pytest.approx(0, abs=1e-9)
        expected = amplitude ** 2 / 2 if radius <= LOW_FREQUENCY_CUTOFF else 0.0
        assert low_frequency_energy(image) == pytest.approx(expected, abs=1e-12)
    # the cutoff is inclusive: 8 cycles over 64 pixels is exactly 1/8 cycle per pixel
    image = np.cos(2 * np.pi * 8 * x / width)
    assert low_frequency_energy(image) == pytest.approx(0.5)
    assert low_frequency_energy(image, cutoff=0.12) == pytest.approx(0.0, abs=1e-12)


def test_periodogram_matches_numpy_and_parseval(rng):
    image = rng.random((7, 10))
    expected = np.abs(np.fft.fft2(image)) ** 2 / image.size
    np.testing.assert_allclose(power_spectrum(image), expected, rtol=1e-12)
    assert power_spectrum(image).mean() == pytest.approx((image ** 2).mean(), rel=1e-12)
    # (H, W, 1), Dr.Jit tensors and integers are taken as the plane they hold
    import drjit as dr

    np.testing.assert_allclose(power_spectrum(image[..., None]), expected, rtol=1e-12)
    tensor = dr.llvm.TensorXf(image.astype(np.float32))
    np.testing.assert_allclose(power_spectrum(tensor), np.abs(np.fft.fft2(image.astype(np.float32))) ** 2 / 70,
                               rtol=1e-5)
    assert power_spectrum(np.ones((2, 2), np.uint8))[0, 0] == 4.0


def test_edges_of_the_domain():
    # one pixel: its square is the DC term, and all of the energy whatever the cutoff
    one = radial_power_spectrum(np.array([[3.0]]))
    assert one.frequency.tolist() == [0.0] and one.power.tolist() == [9.0] and one.count.tolist() == [1]
    assert low_frequency_energy(np.array([[3.0]]), cutoff=0.0) == 9.0
    # a constant: only DC, N c^2
    constant = radial_power_spectrum(np.full((8, 8), 2.0))
    assert constant.power[0] == 4.0 * 64 and np.all(constant.power[1:] == 0)
    assert low_frequency_energy(np.full((8, 8), 2.0)) == 4.0
    # cutoff 0: the mean squared; a cutoff past the corner of the frequency square: everything
    image = np.arange(12.0).reshape(3, 4)
    assert low_frequency_energy(image, cutoff=0) == pytest.approx(image.mean() ** 2)
    assert low_frequency_energy(image, cutoff=1.0) == pytest.approx((image ** 2).mean())
    # a thin image: the coarse axis leaves rings empty (NaN), never a division by zero
    thin = radial_power_spectrum(np.random.default_rng(1).random((2, 16)))
    assert np.all(np.isnan(thin.power[thin.count == 0])) and np.all(np.isfinite(thin.power[thin.count > 0]))
    assert thin.count.sum() == (frequency_radius((2, 16)) * 16 < 8.5).sum()
    # NaN or inf anywhere: every power is NaN (reported as an RMSE would be), never a partial result
    for bad in (np.nan, np.inf):
        image = np.zeros((4, 4))
        image[1, 2] = bad
        assert np.isnan(power_spectrum(image)).all() and math.isnan(low_frequency_energy(image))
    # huge values do not overflow in float64
    assert low_frequency_energy(np.full((4, 4), 1e30), cutoff=0) == pytest.approx(1e60)


def test_bad_input_names_the_argument():
    with pytest.raises(ValueError, match=r"image: expected an \(H, W\) or \(H, W, 1\) image, got shape \(4, 4, 3\)"):
        power_spectrum(np.zeros((4, 4, 3)))
    with pytest.raises(ValueError, match="image: expected a non-empty image"):
        radial_power_spectrum(np.zeros((0, 4)))
    with pytest.raises(TypeError, match="image: expected real numbers"):
        low_frequency_energy(np.zeros((2, 2), complex))
    for bad in (-0.1, math.nan, math.inf):
        with pytest.raises(ValueError, match="cutoff: expected a (finite )?number"):
            low_frequency_energy(np.zeros((2, 2)), cutoff=bad)
        with pytest.raises(ValueError, match="max_frequency: expected a (finite )?number"):
            radial_power_spectrum(np.zeros((2, 2)), max_frequency=bad)
    for bad in ("0.1", True):
        with pytest.raises(TypeError, match="cutoff: expected a number"):
            low_frequency_energy(np.zeros((2, 2)), cutoff=bad)
        with pytest.raises(TypeError, match="max_frequency: expected a number"):
            radial_power_spectrum(np.zeros((2, 2)), max_frequency=bad)


@settings(max_examples=60, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(1, 12), st.integers(1, 12)),
              elements=st.floats(-1e3, 1e3, allow_nan=False)),
       st.floats(0.0, 0.8))
def test_properties_over_arbitrary_images(image, cutoff):
    mean_square = float((image ** 2).mean())
    tolerance = 1e-9 * max(mean_square, 1.0)
    # Parseval, and the low-frequency part lies between the DC term and everything
    assert power_spectrum(image).mean() == pytest.approx(mean_square, rel=1e-9, abs=1e-9)
    low = low_frequency_energy(image, cutoff=cutoff)
    assert image.mean() ** 2 - tolerance <= low <= mean_square + tolerance
    # it grows with the cutoff
    assert low_frequency_energy(image, cutoff=cutoff / 2) <= low + tolerance
    # every frequency up to Nyquist lands in exactly one ring
    spectrum = radial_power_spectrum(image)
    n = max(image.shape)
    assert spectrum.count.sum() == (np.rint(frequency_radius(image.shape) * n) <= n // 2).sum()
    assert np.all(spectrum.power[spectrum.count > 0] >= 0)


def test_log_binned_keeps_the_energy_of_the_rings(rng):
    spectrum = radial_power_spectrum(rng.normal(size=(64, 48)))
    merged = log_binned(spectrum, per_decade=5)
    ring = spectrum.count > 0
    ring[0] = False  # DC is dropped
    assert merged.count.sum() == spectrum.count[ring].sum()
    assert (merged.power * merged.count).sum() == pytest.approx((spectrum.power * spectrum.count)[ring].sum())
    assert np.all(np.diff(merged.frequency) > 0) and np.all(np.diff(np.log10(merged.frequency)) > 0.1)
    empty = log_binned(RadialSpectrum(np.array([0.0]), np.array([4.0]), np.array([1])))
    assert empty.frequency.size == 0 and empty.power.size == 0
    with pytest.raises(ValueError, match="per_decade: expected an integer >= 1"):
        log_binned(spectrum, per_decade=0)


def test_error_spectrum_is_the_luminance_errors(rng):
    reference = rng.random((16, 24, 3))
    image = reference + rng.normal(0, 0.1, reference.shape)
    error = luminance_error(image, reference)
    np.testing.assert_allclose(error, (image - reference) @ [0.2126, 0.7152, 0.0722], rtol=1e-12)
    spectrum = error_spectrum(image, reference)
    np.testing.assert_allclose(spectrum.power, radial_power_spectrum(error).power, rtol=1e-12)
    assert image_errors(image, reference, flip=False)["lowfreq"] == pytest.approx(low_frequency_energy(error))
    # an error in the chroma only (zero luminance) has no luminance error at all
    chroma = reference.copy()
    chroma[..., 0] += 0.7152
    chroma[..., 1] -= 0.2126
    assert image_errors(chroma, reference, flip=False)["lowfreq"] == pytest.approx(0, abs=1e-20)
    assert math.isnan(image_errors(np.full((4, 4, 3), np.nan), np.zeros((4, 4, 3)), flip=False)["lowfreq"])
