"""The fast code paths of imaging.filters / imaging.resample that only large images take.

tests/test_filters.py and tests/test_resample.py use small images; the speed work added
paths that switch on with size (the 16-way min/max fold, the two-pass 5x5 median, ...).
These tests run them on images big enough to take those paths, against numpy, scipy and
OpenCV.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import scipy.ndimage as ndi

import pointillist.imaging  # noqa: F401  (libLLVM first)
from pointillist.imaging import filters as F
from pointillist.imaging import median_networks as N
from pointillist.imaging.neighbourhood import finite_extrema



def out(x):
    return np.asarray(x)


def test_finite_extrema_fold_matches_numpy(rng):
    from drjit.llvm import Float

    for n in (16 * 1024, 16 * 1024 + 7, 40_000):
        values = (rng.standard_normal(n) * 100).astype(np.float32)
        values[rng.integers(0, n, 50)] = np.nan
        values[rng.integers(0, n, 5)] = np.inf
        values[rng.integers(0, n, 5)] = -np.inf
        finite = values[np.isfinite(values)]
        assert finite_extrema(Float(values)) == (float(finite.min()), float(finite.max()))
        # the extremes placed in the tail (past the 16 folded views) and at the very start
        tail = values.copy()
        tail[-1] = 1e6
        tail[0] = -1e6
        assert finite_extrema(Float(tail)) == (-1e6, 1e6)
    assert finite_extrema(Float(np.full(20_000, np.nan, np.float32))) is None


@pytest.mark.parametrize("shape, ring", [((150, 130), (1, 1)), ((301, 203, 3), (2, 3)), ((70, 1100), (0, 4)),
                                         ((40, 40), (5, 0)), ((9, 4000), (1, 1))])
def test_finite_extrema_of_absolute_values_inside_a_ring_matches_numpy(rng, shape, ring):
    # one pass over the source: |values|, the ring left out, 16 bands of whole interior rows + the
    # rows left over (and, for 9 x 4000, too few rows per band: numpy alone)
    from drjit.llvm import Float

    values = (rng.standard_normal(shape) * 100).astype(np.float32)
    values.reshape(-1)[rng.integers(0, values.size, 40)] = np.nan
    ry, rx = ring
    values[:ry] = 1e6                       # huge values in the ring must not count
    values[:, :rx] = -1e6
    values[-1, -1] = np.inf
    interior = np.abs(values[ry:shape[0] - ry, rx:shape[1] - rx])
    finite = interior[np.isfinite(interior)]
    expected = (float(finite.min()), float(finite.max()))
    assert finite_extrema(Float(values.ravel()), absolute=True, shape=shape, ring=ring) == expected
    signed = values[ry:shape[0] - ry, rx:shape[1] - rx]
    signed = signed[np.isfinite(signed)]
    assert finite_extrema(Float(values.ravel()), shape=shape, ring=ring) == (float(signed.min()), float(signed.max()))
    assert finite_extrema(Float(values.ravel()), shape=shape, ring=(shape[0], 0)) is None


def test_normalize_large_image_matches_numpy(rng):
    img = (rng.standard_normal((150, 130)) * 50).astype(np.float32)
    img[3, 4] = np.nan
    img[7, 9] = np.inf
    a = np.abs(img)
    finite = a[np.isfinite(a)]
    expected = np.clip((a - finite.min()) * (255 / (finite.max() - finite.min())), 0, 255)
    expected[7, 9] = 255
    got = out(F.normalize(img))
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-3)
    assert np.isnan(got[3, 4])


@pytest.mark.parametrize("border", ["zero", "keep", "clamp", "wrap"])
def test_correlate_normalize_large_image_ignores_the_ring(rng, border):
    img = (rng.random((160, 140)) * 255).astype(np.float32)
    img[0, :] = 1e4          # a huge row on the border: in the ring for zero/keep, computed otherwise
    mode = {"zero": "constant", "keep": "constant", "clamp": "nearest", "wrap": "wrap"}[border]
    ref = np.abs(ndi.correlate(img.astype(np.float64), F.SOBEL_X.astype(np.float64), mode=mode))
    computed = ref[1:-1, 1:-1] if border in ("zero", "keep") else ref
    low, high = computed.min(), computed.max()
    expected = (ref - low) * 255 / (high - low)
    got = out(F.correlate(img, F.SOBEL_X, border=border, normalize=True))
    if border in ("zero", "keep"):
        np.testing.assert_allclose(got[1:-1, 1:-1], expected[1:-1, 1:-1], atol=2e-2)
        ring = np.ones(img.shape, bool)
        ring[1:-1, 1:-1] = False
        np.testing.assert_array_equal(got[ring], 0 if border == "zero" else img[ring])
    else:
        np.testing.assert_allclose(got, expected, atol=2e-2)
    assert got[1:-1, 1:-1].min() == 0 or border not in ("zero", "keep")


def test_median_large_images_match_opencv_and_scipy(rng):
    img = (rng.random((70, 90)) * 255).astype(np.float32)
    img[rng.random(img.shape) < 0.05] = 255       # salt
    for size in (3, 5):
        np.testing.assert_array_equal(out(F.median(img, size)), cv2.medianBlur(img, size))
        for border, mode in (("reflect", "reflect"), ("wrap", "wrap"), ("constant", "constant")):
            np.testing.assert_array_equal(out(F.median(img, size, border=border)),
                                          ndi.median_filter(img, size=size, mode=mode))
    colour = (rng.random((40, 33, 3)) * 255).astype(np.float32)
    np.testing.assert_array_equal(out(F.median(colour, 5, border="mirror")),
                                  ndi.median_filter(colour, size=(5, 5, 1), mode="mirror"))


def _bit_sliced_wires(n):
    """Wire i of all 2^n 0-1 inputs, bit-sliced: bit t of the uint64 words is bit i of t."""
    words = np.arange(2 ** max(n - 6, 0), dtype=np.uint64)
    low = [np.uint64(sum(1 << t for t in range(64) if (t >> i) & 1)) for i in range(6)]
    wires = []
    for i in range(n):
        if i < 6:
            wires.append(np.full(words.size, low[i], dtype=np.uint64))
        else:
            wires.append(np.where((words >> np.uint64(i - 6)) & np.uint64(1), ~np.uint64(0), np.uint64(0)))
    return wires


@pytest.mark.parametrize("n", [9, 25])
def test_fixed_median_networks_on_every_0_1_input(n):
    """0-1 principle: a comparator network that selects the median of every 0-1 input selects
    the median of every input. Compared against Batcher's full sorting network."""
    network, middle = N.MEDIAN_NETWORKS[n]
    wires = _bit_sliced_wires(n)
    for i, j in network:
        wires[i], wires[j] = wires[i] & wires[j], wires[i] | wires[j]
    reference = _bit_sliced_wires(n) + [None] * ((1 << (n - 1).bit_length()) - n)   # None = all ones
    for i, j in N.batcher(n):
        if reference[j] is None:
            continue
        if reference[i] is None:
            reference[i], reference[j] = reference[j], None
            continue
        reference[i], reference[j] = reference[i] & reference[j], reference[i] | reference[j]
    mask = np.uint64((1 << min(2 ** n, 64)) - 1) if n < 6 else ~np.uint64(0)
    np.testing.assert_array_equal(wires[middle] & mask, reference[n // 2] & mask)


@pytest.mark.parametrize("shape", [(3, 2), (40, 3), (2, 50, 3), (33, 47, 2)])
def test_clamp_border_without_a_ring_pass_matches_scipy(rng, shape):
    """``clamp`` computes every pixel in the main kernel (replicated rows, column selects)."""
    img = (rng.random(shape) * 255).astype(np.float32)
    kernel = rng.standard_normal((5, 7)).astype(np.float32)
    weights = kernel if img.ndim == 2 else kernel[..., None]
    expected = ndi.correlate(img.astype(np.float64), weights.astype(np.float64), mode="nearest")
    np.testing.assert_allclose(out(F.correlate(img, kernel, border="clamp")), expected, atol=2e-3)
    size = (5, 5) if img.ndim == 2 else (5, 5, 1)
    np.testing.assert_array_equal(out(F.median(img, 5)), ndi.median_filter(img, size=size, mode="nearest"))


def test_results_do_not_follow_later_changes_of_a_numpy_input(rng):
    """Results are evaluated before returning: numpy inputs are shared with Dr.Jit, not copied."""
    img = (rng.random((64, 48)) * 255).astype(np.float32)
    keep = img.copy()
    results = [F.normalize(img, absolute=False), F.threshold(img, 128), F.median(img, 3),
               F.correlate(img, F.GAUSSIAN_3, normalize=True)]
    img[:] = 0.0
    expected = [F.normalize(keep, absolute=False), F.threshold(keep, 128), F.median(keep, 3),
                F.correlate(keep, F.GAUSSIAN_3, normalize=True)]
    for got, want in zip(results, expected):
        np.testing.assert_array_equal(out(got), out(want))
