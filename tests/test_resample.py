"""imaging.resample: hand-worked interpolation, OpenCV's resize, an independent Keys implementation."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import pointillist.imaging  # noqa: F401  (libLLVM first)
from pointillist.imaging.resample import keys_kernel, resize, sample

SHAPES = [(1, 1), (2, 2), (7, 9), (5, 4, 3)]
SIZES = [(1, 1), (3, 5), (4, 3), (13, 11), (10, 7)]


def image(rng, shape):
    return (rng.random(shape) * 255).astype(np.float32)


def out(x):
    return np.asarray(x)


def reference_resize(img, width, height, method, a=-0.5):
    """Independent float64 numpy resize: separable weights per output row/column, clamped taps."""
    def matrix(n_in, n_out):
        src = (np.arange(n_out) + 0.5) * n_in / n_out - 0.5
        m = np.zeros((n_out, n_in))
        if method == "nearest":
            idx = np.minimum(((2 * np.arange(n_out) + 1) * n_in) // (2 * n_out), n_in - 1)
            m[np.arange(n_out), idx] = 1
            return m
        base = np.floor(src)
        taps = (0, 1) if method == "bilinear" else (-1, 0, 1, 2)
        for k in taps:
            pos = base + k
            w = (1 - np.abs(src - pos)) if method == "bilinear" else keys_kernel(src - pos, a)
            np.add.at(m, (np.arange(n_out), np.clip(pos, 0, n_in - 1).astype(int)), w)
        return m

    my, mx = matrix(img.shape[0], height), matrix(img.shape[1], width)
    return np.einsum("yi,ij...,xj->yx...", my, img.astype(np.float64), mx)


# --- hand-worked cases ----------------------------------------------------------------------------
def test_linear_and_bilinear_by_hand():
    # course example: v = v1 + (v2 - v1)(x - x1)/(x2 - x1) between x1 = 0 (v1 = 10) and x2 = 1 (v2 = 20)
    row = np.array([[10.0, 20.0, 40.0]], np.float32)
    assert out(sample(row, [0.0, 0.3, 1.0, 1.75], 0.0)).tolist() == pytest.approx([10, 13, 20, 35])
    img = np.array([[10.0, 20.0], [30.0, 40.0]], np.float32)
    # x = 0.25: top 12.5, bottom 32.5; y = 0.5 -> 22.5.  (0.5, 0.25): top 15, bottom 35 -> 20
    assert out(sample(img, [0.25, 0.5], [0.5, 0.25])).tolist() == pytest.approx([22.5, 20.0])
    assert float(out(sample(img, 1, 1))) == 40.0                 # on a pixel centre: the pixel
    assert float(out(sample(img, -3.0, 9.0))) == 30.0           # outside: edge pixels repeat
    assert out(sample(img, 0.5, 0.5, "nearest")).item() == 40.0   # ties go right/down
    assert out(sample(img, 0.49, 0.2, "nearest")).item() == 10.0


def test_resize_pixel_centre_convention_by_hand():
    # 2 -> 4: centres at -0.25, 0.25, 0.75, 1.25 -> clamp, 0.25, 0.75, clamp
    assert out(resize(np.array([[0.0, 4.0]]), (4, 1))).tolist() == [[0.0, 1.0, 3.0, 4.0]]
    # 4 -> 2: src = 0.5 and 2.5: averages of pairs
    assert out(resize(np.array([[0.0, 2.0, 4.0, 8.0]]), (2, 1))).tolist() == [[1.0, 6.0]]
    assert out(resize(np.array([[1.0, 2.0, 3.0]]), (6, 1), "nearest")).tolist() == [[1, 1, 2, 2, 3, 3]]


def test_keys_kernel_values():
    # a = -0.5: W(0.5) = 1.5/8 - 2.5/4 + 1 = 0.5625 ; W(1.5) = -0.5(3.375 - 11.25 + 12 - 4) = -0.0625
    assert keys_kernel([0, 0.5, 1, 1.5, 2, 3]).tolist() == [1, 0.5625, 0, -0.0625, 0, 0]
    t = np.linspace(0, 1, 11)
    for a in (-0.5, -0.75, -1.0):   # partition of unity
        total = sum(keys_kernel(t - k, a) for k in (-1, 0, 1, 2))
        np.testing.assert_allclose(total, 1.0, atol=1e-12)


def test_bicubic_sample_by_hand():
    # Keys a=-0.5 at t=0.5 between 20 and 40 with neighbours 10 and 80: weights -1/16, 9/16, 9/16, -1/16
    row = np.array([[10.0, 20.0, 40.0, 80.0]], np.float32)
    expected = (-10 + 9 * 20 + 9 * 40 - 80) / 16
    assert out(sample(row, 1.5, 0.0, "bicubic")).item() == pytest.approx(expected)
    # it reproduces a quadratic exactly inside (third-order accuracy of a = -0.5)
    x = np.arange(8, dtype=np.float32)
    quad = np.tile(x**2, (3, 1))
    assert out(sample(quad, [2.5, 3.25], [1, 1], "bicubic")).tolist() == pytest.approx([6.25, 3.25**2], abs=1e-4)


# --- against OpenCV and the reference ------------------------------------------------------------
@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("size", SIZES)
def test_resize_matches_opencv(rng, shape, size):
    img = image(rng, shape)
    for method, flag, kwargs in (("bilinear", cv2.INTER_LINEAR, {}),
                                 ("bicubic", cv2.INTER_CUBIC, {"a": -0.75})):
        expected = cv2.resize(img, size, interpolation=flag)
        if expected.ndim < img.ndim:
            expected = expected[..., None]
        np.testing.assert_allclose(out(resize(img, size, method, **kwargs)), expected, atol=2e-2)


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("size", SIZES)
@pytest.mark.parametrize("method", ["nearest", "bilinear", "bicubic"])
def test_resize_matches_reference(rng, shape, size, method):
    img = image(rng, shape)
    np.testing.assert_allclose(out(resize(img, size, method)), reference_resize(img, *size, method),
                               rtol=1e-5, atol=2e-3)


def test_nearest_matches_opencv_exact_away_from_ties(rng):
    img = image(rng, (10, 12, 3))
    for size in ((7, 5), (25, 23), (5, 3)):
        np.testing.assert_array_equal(out(resize(img, size, "nearest")),
                                      cv2.resize(img, size, interpolation=cv2.INTER_NEAREST_EXACT))


def test_sample_matches_resize_grid(rng):
    img = image(rng, (6, 8, 3))
    width, height = 11, 5
    xs = (np.arange(width) + 0.5) * 8 / width - 0.5
    ys = (np.arange(height) + 0.5) * 6 / height - 0.5
    gx, gy = np.meshgrid(xs, ys)
    for method in ("nearest", "bilinear", "bicubic"):
        got = out(sample(img, gx, gy, method))
        assert got.shape == (height, width, 3)
        np.testing.assert_allclose(got, out(resize(img, (width, height), method)), atol=1e-3)


# --- properties and edges ----------------------------------------------------------------------
@pytest.mark.parametrize("method", ["nearest", "bilinear", "bicubic"])
def test_same_size_is_identity(rng, method):
    img = image(rng, (9, 7, 3))
    np.testing.assert_array_equal(out(resize(img, (7, 9), method)), img)


def test_bicubic_overshoot_clamped_only_when_asked():
    step = np.zeros((1, 8), np.float32)
    step[:, 4:] = 255
    free = out(resize(step, (32, 1), "bicubic"))
    held = out(resize(step, (32, 1), "bicubic", clamp=True))
    assert free.min() < 0 and free.max() > 255        # Keys rings at a step edge
    assert held.min() == 0 and held.max() == 255
    np.testing.assert_array_equal(free[(free >= 0) & (free <= 255)], held[(free >= 0) & (free <= 255)])
    assert out(sample(step, 4.25, 0, "bicubic")).item() > 255
    assert out(sample(step, 4.25, 0, "bicubic", clamp=True)).item() == 255


def test_constant_and_one_pixel_images():
    for method in ("nearest", "bilinear", "bicubic"):
        got = out(resize(np.array([[7.0]]), (5, 3), method))
        assert got.shape == (3, 5)
        np.testing.assert_allclose(got, 7.0, rtol=0 if method != "bicubic" else 1e-6)  # Keys weights sum to 1 +- ulp
        const = out(resize(np.full((4, 6), 100.0), (9, 2), method))
        np.testing.assert_allclose(const, 100.0, rtol=1e-6)


def test_nan_and_huge_values():
    img = np.full((4, 4), 1e30, np.float32)
    np.testing.assert_allclose(out(resize(img, (7, 7), "bicubic")), 1e30, rtol=1e-5)
    img[1, 1] = np.nan
    got = out(resize(img, (8, 8)))
    assert np.isnan(got).any() and np.isfinite(got[-1, -1])


def test_bad_arguments():
    img = np.ones((4, 4))
    for size in ((0, 3), (3, -1), (3,)):
        with pytest.raises(ValueError, match="^size: "):
            resize(img, size)
    for size in ((2.5, 3), "ab", 3):  # not integers: a TypeError (the argument contract)
        with pytest.raises(TypeError, match="^size: expected "):
            resize(img, size)
    with pytest.raises(ValueError, match="method"):
        resize(img, (3, 3), "lanczos")
    with pytest.raises(ValueError, match="method"):
        sample(img, 1, 1, "area")
    with pytest.raises(ValueError, match="a"):
        resize(img, (3, 3), "bicubic", a=float("inf"))
    with pytest.raises(ValueError, match="x, y"):
        sample(img, [1, 2], [1, 2, 3])
    with pytest.raises(ValueError, match="finite"):
        sample(img, np.nan, 1)
    with pytest.raises(ValueError, match="image"):
        resize(np.ones((0, 3)), (2, 2))


@pytest.mark.parametrize("method", ["nearest", "bilinear", "bicubic"])
def test_far_positions_see_the_nearest_edge(method):
    # Positions far outside the image (beyond Int32, or beyond float32's range) repeat the edge
    # pixel on THEIR side: the right edge for huge x, the bottom edge for huge y.
    img = np.array([[10.0, 20.0, 30.0], [40.0, 50.0, 60.0]], np.float32)
    xs = [1e10, 3e38, 1e39, -1e10, -1e39, 2.5e9]
    got = out(sample(img, xs, 0.0, method))
    np.testing.assert_array_equal(got, [30.0, 30.0, 30.0, 10.0, 10.0, 30.0])
    got = out(sample(img, 0.0, [1e12, -1e12, 1e40], method))
    np.testing.assert_array_equal(got, [40.0, 10.0, 40.0])


def test_nearest_resize_of_a_wide_row_is_exact():
    # (2 x + 1) W overflows 32 bits when W * width > 2^31: the identity and a 2x upscale must hold.
    row = np.arange(50000, dtype=np.float32)[None, :]
    np.testing.assert_array_equal(out(resize(row, (50000, 1), "nearest")), row)
    np.testing.assert_array_equal(out(resize(row.T, (1, 50000), "nearest")), row.T)
    np.testing.assert_array_equal(out(resize(row, (100000, 1), "nearest")), np.repeat(row, 2, axis=1))
