"""imaging.tone against numpy written from docs/conventions.md, OpenCV, colour-science and hand cases."""

from __future__ import annotations

import warnings

import colour
import cv2
import numpy as np
import pytest

from pointillist.imaging.filters import threshold
from pointillist.imaging.io import to_8bit
from pointillist.imaging.tone import (ACES_CONSTANTS, HABLE_CONSTANTS, NonFiniteWarning, contrast_stretch,
                                      dynamic_range, equalize_histogram, gamma, histogram, lut, quantize, tonemap)

RNG = np.random.default_rng(7)  # module-level data only (drawn once at import); tests use the `rng` fixture
GREY8 = RNG.integers(0, 256, (37, 53), dtype=np.uint8)          # odd size: not whole 32-bit words
GREY8_PACKED = RNG.integers(20, 200, (32, 48), dtype=np.uint8)  # whole words: the packed path
RGB8 = RNG.integers(0, 256, (16, 24, 3), dtype=np.uint8)


def a(x):
    return np.asarray(x)


def as_8bit(float_result):
    """What the 8-bit writers make of a float result (the reference for uint8 output)."""
    return to_8bit(a(float_result), srgb=False, max_value=255.0)


def assert_8bit(result, float_result):
    """uint8 in, uint8 out: ``result`` is uint8 and equals ``float_result`` as the writers round it."""
    assert a(result).dtype == np.uint8
    np.testing.assert_array_equal(a(result), as_8bit(float_result))


# ---------------------------------------------------------------------------- the conventions' reference formulas

def spec_equalize(levels_image: np.ndarray, levels: int) -> np.ndarray:
    """F(i) = max(0, round(L t(i) / (h w)) - 1), on integer levels (numpy rounds half to even)."""
    t = np.cumsum(np.bincount(levels_image.ravel(), minlength=levels))
    f = np.maximum(0, np.round(levels * t / levels_image.size) - 1)
    return f[levels_image]


def spec_stretch(x, r1, s1, r2, s2, top=255.0):
    x = np.clip(np.asarray(x, np.float64), 0, top)
    first = s1 / r1 * x if r1 else 0 * x
    middle = (s2 - s1) / (r2 - r1) * (x - r1) + s1 if r2 > r1 else 0 * x
    last = (top - s2) / (top - r2) * (x - r2) + s2 if r2 < top else 0 * x
    return np.where(x < r1, first, np.where(x <= r2, middle, last))


def warned(function, *args, **kwargs):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = function(*args, **kwargs)
    messages = [str(w.message) for w in caught if issubclass(w.category, NonFiniteWarning)]
    return result, messages


# ------------------------------------------------------------------------------------------ gamma

def test_gamma_formula_and_opencv(rng):
    x = rng.random((20, 30), dtype=np.float32) * 255
    expected = 255 * (x / 255.0) ** (1 / 2.2)
    np.testing.assert_allclose(a(gamma(x, 2.2)), expected, rtol=2e-6, atol=1e-4)
    np.testing.assert_allclose(a(gamma(x, 2.2)), cv2.pow(x / 255.0, 1 / 2.2) * 255, rtol=2e-6, atol=1e-4)
    np.testing.assert_allclose(a(gamma(x, 0.5, a=2.0)), 255 * (x / 255 / 2.0) ** 2, rtol=2e-6, atol=1e-4)
    np.testing.assert_allclose(a(gamma(x / 255, 2.0, max_value=1.0)), np.sqrt(x / 255), rtol=2e-6)
    np.testing.assert_allclose(a(gamma(x, 1.0)), x, rtol=2e-6)  # gamma 1: identity


def test_gamma_uint8_table_equals_float_path():
    assert_8bit(gamma(GREY8, 2.2), gamma(GREY8.astype(np.float32), 2.2))
    assert_8bit(gamma(RGB8, 0.45), gamma(RGB8.astype(np.float32), 0.45))
    assert_8bit(gamma(GREY8_PACKED, 3), gamma(GREY8_PACKED.astype(np.float32), 3))
    # and what OpenCV users write: cv2.LUT with the rounded table (no value of this table is a tie)
    table = np.round(255 * (np.arange(256) / 255) ** (1 / 2.2)).astype(np.uint8)
    np.testing.assert_array_equal(a(gamma(GREY8, 2.2)), cv2.LUT(GREY8, table))
    assert a(gamma(GREY8.astype(np.float32), 2.2)).dtype == np.float32  # float in, float out


def test_gamma_extremes():
    x = np.array([[0.0, 1.0, 128.0, 254.0, 255.0]], np.float32)
    low, high = a(gamma(x, 1e-3)), a(gamma(x, 1e3))
    assert low[0, 0] == 0 and low[0, -1] == 255 and np.all(low[0, 1:3] < 1e-3)
    np.testing.assert_allclose(low[0, 3], 255 * (254 / 255) ** 1000, rtol=1e-4)   # 5.01
    assert high[0, 0] == 0 and high[0, -1] == 255 and np.all(high[0, 1:4] > 250)
    np.testing.assert_allclose(high[0, 1], 255 * (1 / 255) ** 1e-3, rtol=1e-5)
    assert a(gamma(np.zeros((3, 3)), 2.2)).max() == 0            # all black
    np.testing.assert_allclose(a(gamma(np.full((3, 3), 255.0), 0.3)), 255, rtol=1e-6)  # all white
    assert a(gamma(np.array([[-5.0]]), 2)).item() == 0            # negative -> 0
    assert np.isfinite(a(gamma(np.array([[1e30]]), 2.2))).all()   # huge stays finite
    np.testing.assert_allclose(a(gamma(np.array([[100.0]]), 2.0)), [[255 * np.sqrt(100 / 255)]], rtol=1e-6)


def test_gamma_non_finite_policy():
    x = np.array([[np.nan, np.inf, -np.inf, 64.0]], np.float32)
    result, messages = warned(gamma, x, 2.0)
    np.testing.assert_allclose(a(result), [[0, 255, 0, 255 * np.sqrt(64 / 255)]], rtol=1e-6)
    assert len(messages) == 1 and "3 non-finite" in messages[0]
    _, none = warned(gamma, np.ones((2, 2)), 2.0)
    assert none == []


@pytest.mark.parametrize("g", [1e-45, 1e-300, 1e40, 1e300])
def test_gamma_beyond_float32_exponents_keeps_black_and_white(g):
    # 1/gamma overflows float32 (gamma < 3e-39) or underflows to 0 (gamma > 1e39): black stays 0
    # and white stays white (0^0 and 1^inf must not give NaN); in between the limits of the curve.
    x = np.array([[0.0, 1.0, 128.0, 254.0, 255.0]], np.float32)
    limit = [0, 0, 0, 0, 255] if g < 1 else [0, 255, 255, 255, 255]
    np.testing.assert_array_equal(a(gamma(x, g)), [limit])
    np.testing.assert_array_equal(a(gamma(x.astype(np.uint8), g)), [limit])


@pytest.mark.parametrize("bad", [0, -1.0, np.nan, np.inf])
def test_gamma_rejects_bad_gamma(bad):
    with pytest.raises(ValueError, match="gamma"):
        gamma(GREY8, bad)


def test_gamma_bad_types_and_shapes():
    with pytest.raises(TypeError, match="gamma"):
        gamma(GREY8, "2.2")
    with pytest.raises(ValueError, match="a:"):
        gamma(GREY8, 2.2, a=0)
    with pytest.raises(ValueError, match="image"):
        gamma(np.zeros(5), 2.2)
    with pytest.raises(ValueError, match="image"):
        gamma(np.zeros((2, 2, 2, 2), np.uint8), 2.2)


# ------------------------------------------------------------------------------------------ contrast stretch

@pytest.mark.parametrize("points", [(50, 20, 200, 235), (10, 100, 100, 120), (100, 200, 150, 20),
                                    (0, 30, 128, 200), (60, 0, 255, 240)])
def test_stretch_matches_spec(points):
    x = np.arange(256, dtype=np.float32).reshape(16, 16)
    np.testing.assert_allclose(a(contrast_stretch(x, *points)), spec_stretch(x, *points), atol=1e-4)
    assert_8bit(contrast_stretch(x.astype(np.uint8), *points), contrast_stretch(x, *points))


def test_stretch_hand_case_and_identity():
    x = np.array([[0, 25, 50, 100, 150, 200, 255]], np.float32)
    x = np.array([[0, 25, 50, 100, 155, 205, 255]], np.float32)
    # slopes 1/2, 2, 1/5 through (50, 25), (155, 235)
    np.testing.assert_allclose(a(contrast_stretch(x, 50, 25, 155, 235)), [[0, 12.5, 25, 125, 235, 245, 255]],
                               rtol=1e-6)
    np.testing.assert_allclose(a(contrast_stretch(x, 40, 40, 180, 180)), x, atol=1e-5)
    np.testing.assert_array_equal(a(contrast_stretch(RGB8, 0, 0, 255, 255)), RGB8)
    assert a(contrast_stretch(RGB8, 0, 0, 255, 255)).dtype == np.uint8
    # the module example's 127.5 is a tie: half to even, as the writers round it
    assert a(contrast_stretch(np.array([[0, 50, 100, 150, 255]], np.uint8), 50, 25, 150, 230)).tolist() == \
        [[0, 25, 128, 230, 255]]


def test_stretch_degenerate_breakpoints():
    x = np.arange(256, dtype=np.float32).reshape(1, -1)
    # r1 = r2: a step, at or above r -> last segment; s1 = 0, s2 = 255 is the conventions' threshold
    np.testing.assert_array_equal(a(contrast_stretch(x, 128, 0, 128, 255)), a(threshold(x, 128)))
    step = a(contrast_stretch(x, 100, 50, 100, 200))
    np.testing.assert_allclose(step[0, :100], x[0, :100] * 0.5, atol=1e-5)
    np.testing.assert_allclose(step[0, 100:], 200 + (x[0, 100:] - 100) * 55 / 155, atol=1e-4)
    # r1 = 0 and r2 = 255: only the middle segment; all three equal: everything -> last segment
    np.testing.assert_allclose(a(contrast_stretch(x, 0, 30, 255, 200)), 30 + x * 170 / 255, atol=1e-4)
    np.testing.assert_allclose(a(contrast_stretch(x, 0, 0, 0, 0)), x, atol=1e-5)
    np.testing.assert_allclose(a(contrast_stretch(x, 255, 255, 255, 255)), x, atol=1e-4)
    end = a(contrast_stretch(x, 255, 100, 255, 100))
    np.testing.assert_allclose(end[0, :255], x[0, :255] * 100 / 255, atol=1e-4)
    assert end[0, 255] == 100
    for result in (end, step, a(contrast_stretch(x, 0, 0, 0, 0))):
        assert np.all(np.isfinite(result))


def test_stretch_edges():
    constant = a(contrast_stretch(np.full((2, 2), 77.0), 50, 10, 200, 250))
    np.testing.assert_allclose(constant, np.full((2, 2), 10 + 27 * 240 / 150), rtol=1e-6)
    x = np.array([[-10.0, 1e30, np.nan, np.inf]], np.float32)
    result, messages = warned(contrast_stretch, x, 50, 10, 200, 250)
    assert a(result).tolist() == [[0.0, 255.0, 0.0, 255.0]] and "2 non-finite" in messages[0]
    assert a(contrast_stretch(np.array([[7]], np.uint8), 10, 20, 30, 40)).tolist() == [[14.0]]


@pytest.mark.parametrize("args, name", [((200, 0, 100, 255), "r1"), ((-1, 0, 100, 255), "r1"),
                                        ((0, 0, 300, 255), "r2"), ((10, 256, 100, 255), "s1"),
                                        ((10, 0, 100, -3), "s2"), ((10, np.nan, 100, 3), "s1")])
def test_stretch_rejects_bad_breakpoints(args, name):
    with pytest.raises(ValueError, match=name):
        contrast_stretch(GREY8, *args)


# ------------------------------------------------------------------------------------------ quantize

@pytest.mark.parametrize("levels", [2, 3, 4, 7, 16, 255, 256])
@pytest.mark.parametrize("mode", ["nearest", "bins"])
def test_quantize_definition(levels, mode):
    x = np.arange(256, dtype=np.float64)
    levels_out = np.arange(levels) * 255 / (levels - 1)
    if mode == "bins":
        expected = np.minimum(np.floor(x * levels / 255), levels - 1) * 255 / (levels - 1)
    else:  # the course's: the nearest of the levels (no exact ties among 0..255 here but at 2 levels' 127.5)
        expected = levels_out[np.abs(x[:, None] - levels_out[None, :]).argmin(axis=1)]
    got = a(quantize(x.reshape(16, 16), levels, mode=mode)).ravel()
    np.testing.assert_allclose(got, expected, rtol=1e-6)
    assert_8bit(quantize(x.astype(np.uint8).reshape(16, 16), levels, mode=mode),
                quantize(x.reshape(16, 16), levels, mode=mode))
    assert len(np.unique(got)) == levels


def test_quantize_modes_differ_as_the_issue_says():
    """at 4 levels, 42 of the 256 inputs get another level from the bins than the nearest
    one, by up to 63 (against at most 42.5 for the nearest level); the default is the nearest."""
    x = np.arange(256, dtype=np.float32).reshape(16, 16)
    nearest, bins = a(quantize(x, 4)), a(quantize(x, 4, mode="bins"))
    assert np.array_equal(nearest, a(quantize(x, 4, mode="nearest")))
    assert np.count_nonzero(nearest != bins) == 42
    assert np.abs(bins - x).max() == 63 and np.abs(nearest - x).max() == 42
    with pytest.raises(ValueError, match="mode"):
        quantize(x, 4, mode="round")


def test_quantize_edges():
    x = np.arange(256, dtype=np.float32).reshape(16, 16)
    np.testing.assert_array_equal(a(quantize(x, 256)), x)  # 256 levels on 8-bit: identity
    assert a(quantize(np.array([[0, 127, 128, 255]]), 2)).tolist() == [[0, 0, 255, 255]]
    assert np.unique(a(quantize(np.full((3, 3), 100.0), 4))).tolist() == [85.0]
    result, messages = warned(quantize, np.array([[np.nan, np.inf, -4, 1e30]]), 4)
    assert a(result).tolist() == [[0, 255, 0, 255]] and "2 non-finite" in messages[0]
    np.testing.assert_allclose(a(quantize(np.array([[0.2, 0.6, 1.0]]), 2, max_value=1.0)), [[0, 1, 1]])


@pytest.mark.parametrize("levels, error", [(1, ValueError), (0, ValueError), (2.5, TypeError),
                                           (True, TypeError), ("4", TypeError)])
def test_quantize_rejects_bad_levels(levels, error):
    with pytest.raises(error, match="levels"):
        quantize(GREY8, levels)


# ------------------------------------------------------------------------------------------ lut

def test_lut_matches_opencv(rng):
    table = rng.integers(0, 256, 256).astype(np.uint8)
    for image in (GREY8, GREY8_PACKED, RGB8):  # uint8 in, uint8 out, as cv2.LUT with a uint8 table
        assert a(lut(image, table)).dtype == np.uint8
        np.testing.assert_array_equal(a(lut(image, table)), cv2.LUT(image, table))
        np.testing.assert_array_equal(a(lut(image.astype(np.float32), table)),
                                      cv2.LUT(image, table).astype(np.float32))
    per_channel = rng.integers(0, 256, (256, 3)).astype(np.uint8)
    np.testing.assert_array_equal(a(lut(RGB8, per_channel)), cv2.LUT(RGB8, per_channel.reshape(256, 1, 3)))
    np.testing.assert_array_equal(a(lut(RGB8.astype(np.float32), per_channel)),
                                  cv2.LUT(RGB8, per_channel.reshape(256, 1, 3)).astype(np.float32))


def test_lut_float_input_rounds_and_clips():
    table = np.arange(256, dtype=np.float32) * 2
    x = np.array([[0.4, 0.5, 1.5, 2.6, -3, 300, 254.5]], np.float32)
    assert a(lut(x, table)).tolist() == [[0, 0, 4, 6, 0, 510, 508]]
    result, messages = warned(lut, np.array([[np.nan, np.inf]]), table)
    assert a(result).tolist() == [[0, 510]] and "2 non-finite" in messages[0]


def test_lut_rejects_bad_tables():
    with pytest.raises(ValueError, match="table"):
        lut(GREY8, np.arange(255))
    with pytest.raises(ValueError, match="table"):
        lut(GREY8, np.zeros((256, 3)))  # per-channel table on a grey image
    with pytest.raises(ValueError, match="table"):
        lut(GREY8, np.full(256, np.nan))
    with pytest.raises(TypeError, match="table"):
        lut(GREY8, ["a"] * 256)


# ------------------------------------------------------------------------------------------ equalisation

@pytest.mark.parametrize("image", [GREY8, GREY8_PACKED, np.array([[3]], np.uint8), np.zeros((5, 7), np.uint8)],
                         ids=["odd", "packed", "one-pixel", "black"])
def test_equalize_matches_spec_uint8(image):
    expected = spec_equalize(image, 256)
    np.testing.assert_array_equal(a(equalize_histogram(image)), expected)  # integral: bit-identical
    assert a(equalize_histogram(image)).dtype == np.uint8
    np.testing.assert_array_equal(a(equalize_histogram(image.astype(np.float32))), expected)
    assert a(equalize_histogram(image.astype(np.float32))).dtype == np.float32


@pytest.mark.parametrize("name", ["camera", "coins", "moon"])
def test_equalize_matches_spec_on_real_and_noisy_images(name):
    # scikit-image's 8-bit photographs and a noisy image of odd size (tail bytes after the packed
    # words): the pair histogram, folded on the host, and the host-side table give the conventions' levels
    from skimage import data

    noisy = np.random.default_rng(3).integers(0, 256, (999, 1003), dtype=np.uint8)
    for image in (getattr(data, name)(), noisy):
        expected = spec_equalize(image, 256)
        np.testing.assert_array_equal(a(equalize_histogram(image)), expected)
        np.testing.assert_array_equal(histogram(image), np.bincount(image.ravel(), minlength=256))
        np.testing.assert_array_equal(a(equalize_histogram(image.astype(np.float32))), expected)


def test_private_byte_histogram_is_exact_or_refused():
    # large 8-bit images take private sub-histograms (a table per work block, a column per SIMD lane):
    # exact on a tiled photograph and on noise with 1-3 tail bytes; small images fall back to the pair
    # table; if the tables were shared between threads (here: one table for every lane) updates could
    # be lost, which the total reveals: the result is then refused and the fallback is exact
    from skimage import data

    import pointillist.imaging.tone.equalisation as tone_equalisation
    from pointillist.imaging.arrays import TensorXu8

    noisy = np.random.default_rng(4).integers(0, 256, (1001, 1003), dtype=np.uint8)
    for image in (np.tile(data.camera(), (3, 3)), noisy):
        flat = image.reshape(-1)
        words, tail = tone_equalisation._packed(flat)
        expected = np.bincount(flat, minlength=256)
        assert np.array_equal(tone_equalisation._byte_histogram(words, tail), expected)
        np.testing.assert_array_equal(histogram(image), expected)
        np.testing.assert_array_equal(a(equalize_histogram(TensorXu8(image))), spec_equalize(image, 256))
    small = data.camera()[:200]
    assert tone_equalisation._byte_histogram(*tone_equalisation._packed(small.reshape(-1))) is None
    words, tail = tone_equalisation._packed(noisy.reshape(-1))
    for _ in range(3):
        shared = tone_equalisation._byte_histogram(words, tail, region=1 << 30)  # one table for every lane and thread
        assert shared is None or np.array_equal(shared, np.bincount(noisy.ravel(), minlength=256))


def test_equalize_levels_and_float_binning(rng):
    x = rng.random((21, 19), dtype=np.float32) * 255
    for levels in (2, 16, 256, 1000):
        bins = np.clip(np.round(x * (levels - 1) / 255.0), 0, levels - 1).astype(np.int64)
        expected = spec_equalize(bins, levels) * 255 / (levels - 1)
        np.testing.assert_allclose(a(equalize_histogram(x, levels)), expected, rtol=1e-6)


def test_equalize_properties(rng):
    flat = np.arange(256, dtype=np.uint8).reshape(16, 16)   # every level once: already flat
    np.testing.assert_array_equal(a(equalize_histogram(flat)), flat)
    assert np.unique(a(equalize_histogram(np.full((6, 6), 90.0)))).tolist() == [255.0]  # constant -> white
    assert a(equalize_histogram(np.full((4, 4), 255, np.uint8))).max() == 255
    # the result's cumulative distribution is the uniform one: P(out <= F) = (F + 1) / L to rounding
    skewed = (rng.random((64, 64)) ** 3 * 255).astype(np.uint8)
    out = a(equalize_histogram(skewed)).ravel().astype(np.int64)  # uint8 out: widen before arithmetic
    levels = np.unique(out)
    cdf = np.searchsorted(np.sort(out), levels, side="right") / out.size
    positive = levels > 0
    assert np.all(np.abs(cdf[positive] - (levels[positive] + 1) / 256) <= 0.5 / 256 + 1e-9)
    assert len(levels) > 100
    # OpenCV's variant (cdf - cdf_min) / (N - cdf_min) differs by at most a couple of levels
    assert np.abs(a(equalize_histogram(GREY8)).astype(int) - cv2.equalizeHist(GREY8)).max() <= 2
    # levels < 256 on uint8: F(i) 255 / (L - 1) rounded as the writers round it
    assert_8bit(equalize_histogram(GREY8, 6), equalize_histogram(GREY8.astype(np.float32), 6))


def test_equalize_colour_through_hsv_v():
    image = RGB8.astype(np.float32)
    hsv = cv2.cvtColor(image / 255.0, cv2.COLOR_RGB2HSV)
    v = np.round(hsv[..., 2] * 255).astype(np.int64)
    hsv[..., 2] = spec_equalize(v, 256) / 255.0
    expected = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB) * 255
    ours = a(equalize_histogram(image))
    np.testing.assert_allclose(ours, expected, atol=2e-3)
    assert_8bit(equalize_histogram(RGB8), ours)  # uint8 RGB: the same, rounded in the same pass
    ours_hsv = cv2.cvtColor(ours / 255, cv2.COLOR_RGB2HSV)
    orig_hsv = cv2.cvtColor(image / 255, cv2.COLOR_RGB2HSV)
    keep = (ours_hsv[..., 2] > 0.05) & (orig_hsv[..., 1] > 0.05)
    np.testing.assert_allclose(ours_hsv[..., 1][keep], orig_hsv[..., 1][keep], atol=1e-4)  # S kept


def test_equalize_non_finite_and_errors():
    x = np.array([[np.nan, np.inf, 10, 20]], np.float32)
    result, messages = warned(equalize_histogram, x)
    assert a(result).tolist() == [[spec_equalize(np.array([0, 255, 10, 20]), 256)[i] for i in range(4)]]
    assert "2 non-finite" in messages[0]
    with pytest.raises(ValueError, match="levels"):
        equalize_histogram(GREY8, 1)
    with pytest.raises(ValueError, match="levels"):
        equalize_histogram(GREY8, 70000)
    with pytest.raises(ValueError, match="channels"):
        equalize_histogram(np.zeros((4, 4, 2)))
    with pytest.raises(ValueError, match="channels"):
        equalize_histogram(np.zeros((4, 4, 2), np.uint8))
    for dtype in (np.float32, np.uint8):  # the same message whatever the dtype
        with pytest.raises(ValueError, match="image: expected 1 or 3 channels, got 4"):
            equalize_histogram(np.zeros((4, 4, 4), dtype))


def test_histogram_matches_bincount():
    for image in (GREY8, GREY8_PACKED, RGB8):
        np.testing.assert_array_equal(histogram(image), np.bincount(image.ravel(), minlength=256))
        np.testing.assert_array_equal(histogram(image.astype(np.float32)), np.bincount(image.ravel(), minlength=256))
    assert histogram(np.array([[0.0, 127.0, 128.0, 255.0]]), 2).tolist() == [2, 2]


# ------------------------------------------------------------------------------------------ tone mapping

def _srgb255(x):
    return colour.cctf_encoding(np.clip(x, 0, 1), function="sRGB") * 255


def _reference(x, operator, white=None):
    """Numpy versions of the operator formulas written from their sources (see imaging.tone)."""
    x = np.clip(np.asarray(x, np.float64), 0, None)
    lum = x @ np.array([0.2126, 0.7152, 0.0722]) if x.ndim == 3 else x
    if operator == "clip":
        return _srgb255(x)
    if operator in ("reinhard", "log"):
        w = white if white is not None else lum.max()
        mapped = lum * (1 + lum / w**2) / (1 + lum) if operator == "reinhard" else np.log1p(lum) / np.log1p(w)
        ratio = np.divide(mapped, lum, out=np.zeros_like(lum), where=lum > 0)
        return _srgb255(x * (ratio[..., None] if x.ndim == 3 else ratio))
    if operator == "reinhard_extended":
        w = white if white is not None else x.max()
        return _srgb255(x * (1 + x / w**2) / (1 + x))
    if operator == "hable":
        A, B, C, D, E, F, W = (HABLE_CONSTANTS[k] for k in "ABCDEFW")

        def f(v):
            return (v * (A * v + C * B) + D * E) / (v * (A * v + B) + D * F) - E / F

        return _srgb255(f(2.0 * x) / f(W))
    k = ACES_CONSTANTS
    return _srgb255(x * (k["a"] * x + k["b"]) / (x * (k["c"] * x + k["d"]) + k["e"]))


HDR = (RNG.random((12, 10, 3)) ** 4 * 20).astype(np.float32)


@pytest.mark.parametrize("operator", ["clip", "reinhard", "reinhard_extended", "hable", "aces", "log"])
def test_tonemap_operators_match_reference(operator):
    np.testing.assert_allclose(a(tonemap(HDR, operator)), _reference(HDR, operator), atol=5e-3)
    grey = HDR[..., 1]
    np.testing.assert_allclose(a(tonemap(grey, operator)), _reference(grey, operator), atol=5e-3)
    ramp = np.geomspace(1e-4, 1e4, 200, dtype=np.float32).reshape(10, 20)
    mapped = a(tonemap(ramp, operator)).ravel()
    assert np.all(np.diff(mapped) >= -1e-4)          # monotonic
    assert mapped[0] < 5 and mapped.min() >= 0 and mapped.max() <= 255
    assert a(tonemap(np.zeros((3, 3, 3)), operator)).max() == 0   # all black stays black
    assert a(tonemap(np.array([[np.float32(1e30)]]), operator)).item() > 200  # huge: no overflow


@pytest.mark.parametrize("operator", ["log", "reinhard", "reinhard_extended"])
@pytest.mark.parametrize("scale", [1e-34, 1e-30, 1e-20, 1e-12, 1e-9, 1e-6, 1e-3])
def test_tonemap_white_point_operators_on_a_dim_image(operator, scale):
    # The default white point w is the image's maximum, however small: log(1 + L) in float32
    # rounds to 0 for L < 6e-8 (the log ratio must not become 0/0, a dim image turned black), and
    # 1 / w^2 overflows for w < 1e-19 (Reinhard must not send every pixel to white).
    x = (np.maximum(HDR / HDR.max(), 0.1) * scale).astype(np.float32)
    assert np.all(x >= np.finfo(np.float32).tiny)              # normal floats: no flush to zero
    np.testing.assert_allclose(a(tonemap(x, operator)), _reference(x, operator), atol=5e-3)
    assert a(tonemap(x, operator)).max() == pytest.approx(255.0, abs=1e-3)


def test_tonemap_white_and_exposure():
    for operator in ("reinhard", "reinhard_extended", "log"):
        np.testing.assert_allclose(a(tonemap(HDR, operator, white=4.0)), _reference(HDR, operator, 4.0), atol=5e-3)
    np.testing.assert_allclose(a(tonemap(HDR, "aces", exposure=-1.5)), _reference(HDR * 2**-1.5, "aces"), atol=5e-3)
    np.testing.assert_allclose(a(tonemap(HDR, "reinhard", white=np.inf)), _srgb255(
        HDR * (1 / (1 + (HDR @ np.array([0.2126, 0.7152, 0.0722]))))[..., None]), atol=5e-3)
    # the default white point maps the brightest luminance to 1 (Reinhard's choice)
    assert a(tonemap(np.array([[0.5, 2.0, 8.0]]), "reinhard")).max() == pytest.approx(255.0, abs=1e-3)
    # clip agrees with the PNG preview of imaging.io (sRGB through colour-science, then rounding)
    np.testing.assert_array_equal(np.round(a(tonemap(HDR, "clip"))).astype(np.uint8), to_8bit(HDR))


def test_tonemap_non_finite_policy():
    x = HDR.copy()
    x[0, 0, 0], x[1, 1, 1], x[2, 2, 2] = np.nan, np.inf, -np.inf
    result, messages = warned(tonemap, x, "reinhard")
    result = a(result)
    assert result[0, 0, 0] == 0 and result[1, 1, 1] == 255 and result[2, 2, 2] == 0
    assert np.all(np.isfinite(result)) and len(messages) == 1 and "3 non-finite" in messages[0]
    # non-finite values do not move the default white point of the other pixels
    clean = x.copy()
    clean[0, 0, 0] = clean[1, 1, 1] = clean[2, 2, 2] = 0
    mask = np.ones(x.shape, bool)
    mask[[0, 1, 2], [0, 1, 2]] = False
    np.testing.assert_allclose(result[mask], a(tonemap(clean, "reinhard"))[mask], atol=1e-4)
    assert a(tonemap(np.array([[-1.0, -1e30]]), "hable")).tolist() == [[0.0, 0.0]]


@pytest.mark.parametrize("kwargs, name", [({"operator": "filmic"}, "operator"), ({"operator": 3}, "operator"),
                                          ({"operator": "aces", "white": 2}, "white"),
                                          ({"operator": "reinhard", "white": 0}, "white"),
                                          ({"operator": "reinhard", "white": np.nan}, "white"),
                                          ({"operator": "clip", "exposure": 1000}, "exposure"),
                                          ({"operator": "clip", "exposure": np.nan}, "exposure")])
def test_tonemap_rejects_bad_arguments(kwargs, name):
    with pytest.raises(ValueError, match=name):
        tonemap(HDR, **kwargs)


def test_tonemap_rejects_bad_shapes():
    with pytest.raises(ValueError, match="channels"):
        tonemap(np.zeros((4, 4, 2)), "clip")
    with pytest.raises(ValueError, match="image"):
        tonemap(np.zeros((4,)), "clip")


def test_dynamic_range():
    assert dynamic_range(np.array([[10, 200], [30, 40]])) == 190
    assert dynamic_range(np.full((3, 3), 5.0)) == 0
    assert dynamic_range(np.array([[np.nan, 1.0, np.inf, 4.0]])) == 3
    with pytest.raises(ValueError, match="finite"):
        dynamic_range(np.array([[np.nan]]))


# ------------------------------------------------------------------------------------------ fast paths (speed work)

@pytest.mark.parametrize("size", [1, 2, 3, 4, 5, 6, 7, 8, 13])
def test_equalize_and_histogram_every_word_tail(rng, size):
    """Packed words plus a tail of 0..3 bins (and images smaller than one word) count every pixel."""
    image = rng.integers(0, 256, (1, size), dtype=np.uint8)
    np.testing.assert_array_equal(histogram(image), np.bincount(image.ravel(), minlength=256))
    np.testing.assert_array_equal(a(equalize_histogram(image)), spec_equalize(image, 256))
    x = image.astype(np.float32) * (15 / 255)          # float input, 16 levels: UInt8 bins in one pass
    bins = np.clip(np.round(x * 255 / 255 * (255 / 15) * 15 / 255), 0, 15).astype(np.int64)
    np.testing.assert_allclose(a(equalize_histogram(x * 17, 16)), spec_equalize(bins, 16) * 17, rtol=1e-6)


def test_uint8_views_misaligned_and_strided(rng):
    """uint8 views that are not whole aligned words, or not contiguous, give the same results."""
    buffer = rng.integers(0, 256, 1 + 48 * 32, dtype=np.uint8)
    shifted = buffer[1:].reshape(48, 32)                 # data pointer not a multiple of 4
    assert shifted.ctypes.data % 4 != 0
    transposed = GREY8_PACKED.T                          # not C-contiguous
    table = (np.arange(256) * 7 % 256).astype(np.float32)
    for image in (shifted, transposed):
        np.testing.assert_array_equal(histogram(image), np.bincount(image.ravel(), minlength=256))
        np.testing.assert_array_equal(a(equalize_histogram(image)), spec_equalize(image, 256))
        np.testing.assert_array_equal(a(lut(image, table)), table[image])
        assert_8bit(gamma(image, 2.2), gamma(image.astype(np.float32), 2.2))


def test_uint8_result_does_not_alias_input():
    """The uint8 bytes are read in place; the result is new memory, evaluated before returning."""
    image = GREY8_PACKED.copy()
    table = (255 - np.arange(256)).astype(np.float32)
    result, equalized = lut(image, table), equalize_histogram(image)
    expected, expected_eq = table[image], spec_equalize(image, 256)
    image[:] = 0
    np.testing.assert_array_equal(a(result), expected)
    np.testing.assert_array_equal(a(equalized), expected_eq)


def test_equalize_many_levels_and_colour_odd_sizes(rng):
    """levels > 256 (UInt32 bins, direct histogram) and colour images of odd pixel counts."""
    x = rng.random((9, 11), dtype=np.float32) * 255
    bins = np.clip(np.round(x * 299 / 255.0), 0, 299).astype(np.int64)
    np.testing.assert_allclose(a(equalize_histogram(x, 300)), spec_equalize(bins, 300) * 255 / 299, rtol=1e-6)
    image = rng.integers(0, 256, (5, 7, 3), dtype=np.uint8).astype(np.float32)
    hsv = cv2.cvtColor(image / 255.0, cv2.COLOR_RGB2HSV)
    v = np.round(hsv[..., 2] * 255).astype(np.int64)
    hsv[..., 2] = spec_equalize(v, 256) / 255.0
    np.testing.assert_allclose(a(equalize_histogram(image)), cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB) * 255, atol=2e-3)


def _kernels(function):
    """Run ``function`` with Dr.Jit's kernel history on; return the JIT kernel launches."""
    import drjit as dr

    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()
        function()
        history = dr.kernel_history()
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    return [k for k in history if k["type"] == dr.KernelType.JIT]


def _hashes(function):
    """The hashes of the JIT kernels ``function`` launches (the same hash: no recompilation)."""
    return {k["hash"] for k in _kernels(function)}


def test_uint8_equalize_is_two_passes_and_nothing_recompiles(rng, aligned, monkeypatch):
    """Histogram pass (n/4 lanes) + table pass (n lanes); new arguments reuse the compiled kernels."""
    image = rng.integers(0, 256, (64, 96), dtype=np.uint8)
    equalize_histogram(image)
    kernels = _kernels(lambda: a(equalize_histogram(image)))
    per_pixel = sorted(k["size"] for k in kernels if k["size"] in (image.size // 4, image.size))
    assert per_pixel == [image.size // 4, image.size]
    assert all(k["size"] <= 65536 for k in kernels if k["size"] not in per_pixel)  # 256 x 256 pair table
    # Recompilation is checked by kernel hashes, not ``cache_hit`` (which also counts kernels
    # loaded from ~/.drjit and so depends on what ran on this machine before).
    # (The uint8 histogram pass reads the caller's bytes in place, and Dr.Jit compiles another
    # variant for a 64-byte aligned buffer: aligned inputs throughout.)
    compiled = _hashes(lambda: a(equalize_histogram(aligned(image))))
    for _ in range(3):
        other = aligned(rng.integers(0, 256, (64, 96), dtype=np.uint8))
        assert _hashes(lambda other=other: a(equalize_histogram(other))) <= compiled
    grey = rng.random((32, 32), dtype=np.float32) * 255
    grey, image = aligned(grey), aligned(image)
    pairs = ((lambda: gamma(grey, 2.2), lambda: gamma(grey, 0.7)),
             (lambda: contrast_stretch(grey, 10, 20, 200, 210), lambda: contrast_stretch(grey, 30, 5, 99, 250)),
             (lambda: lut(image, np.arange(256)), lambda: lut(image, np.arange(256)[::-1])),
             (lambda: gamma(image, 2.2), lambda: gamma(image, 1.9)))
    import pointillist.imaging.tone._shared as tone_module

    for first, then in pairs:
        # both build their 8-bit table (none cached by an earlier test): the same kernels
        monkeypatch.setattr(tone_module, "_BYTE_TABLES", {})
        compiled = _hashes(lambda first=first: a(first()))
        monkeypatch.setattr(tone_module, "_BYTE_TABLES", {})
        again = _hashes(lambda then=then: a(then()))
        assert again and again <= compiled


def test_tonemap_fixed_curves_are_one_pass(rng):
    """Sanitising, exposure, curve, sRGB and the +inf policy run in one kernel over the pixels."""
    hdr = rng.random((24, 40, 3), dtype=np.float32) * 8
    hdr[0, 0, 1] = np.inf
    for operator in ("clip", "aces", "hable"):
        warned(tonemap, hdr, operator)
        kernels = _kernels(lambda: warned(tonemap, hdr, operator))
        assert [k["size"] for k in kernels] == [24 * 40]
    result, messages = warned(tonemap, hdr, "aces")
    assert a(result)[0, 0, 1] == 255.0 and "1 non-finite" in messages[0]


# ------------------------------------------------------------------------------------------ 8-bit in, 8-bit out

def test_uint8_lut_rounds_table_as_the_writers():
    """A float table on uint8 input: entries rounded half to even and clipped, as to_8bit writes them."""
    table = np.arange(256) * 1.5 - 20.25          # below 0, ties (x.5), above 255
    table[:4] = [0.5, 1.5, 2.5, -0.5]
    assert_8bit(lut(GREY8, table), lut(GREY8.astype(np.float32), table))
    assert a(lut(np.array([[0, 1, 2, 3, 255]], np.uint8), table)).tolist() == [[0, 2, 2, 0, 255]]


def test_uint8_tensors_in_and_through_chains():
    """A TensorXu8 (what the 8-bit operations return) is 8-bit input too; float operations take it."""
    from drjit.llvm.ad import TensorXu8

    from pointillist.imaging.filters import sobel

    tensor = TensorXu8(GREY8)
    for op in (lambda x: gamma(x, 2.2), lambda x: contrast_stretch(x, 50, 20, 200, 235),
               lambda x: quantize(x, 5), lambda x: lut(x, 255 - np.arange(256)), equalize_histogram):
        from_tensor, from_numpy = op(tensor), op(GREY8)
        assert isinstance(from_tensor, TensorXu8) and a(from_tensor).dtype == np.uint8
        np.testing.assert_array_equal(a(from_tensor), a(from_numpy))
    # gamma (uint8) -> equalisation (uint8) -> sobel (float input, as_tensor widens the bytes)
    chained = equalize_histogram(gamma(GREY8, 2.2))
    np.testing.assert_array_equal(a(chained), a(equalize_histogram(a(gamma(GREY8, 2.2)))))
    np.testing.assert_array_equal(a(sobel(chained)), a(sobel(a(chained).astype(np.float32))))
    assert a(tonemap(TensorXu8(GREY8), "clip")).dtype == np.float32  # not an 8-bit operation: float out


def test_uint8_result_written_as_png(tmp_path):
    """A uint8 result written by the 8-bit writer is the float result written (the same bytes)."""
    from PIL import Image

    from pointillist.imaging.io import write_png

    for name, result, float_result in (("gamma", gamma(RGB8, 2.2), gamma(RGB8.astype(np.float32), 2.2)),
                                       ("quantize", quantize(GREY8, 3), quantize(GREY8.astype(np.float32), 3))):
        write_png(tmp_path / f"{name}8.png", result, srgb=False, max_value=255.0)
        write_png(tmp_path / f"{name}f.png", float_result, srgb=False, max_value=255.0)
        np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / f"{name}8.png")),
                                      np.asarray(Image.open(tmp_path / f"{name}f.png")))
        np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / f"{name}8.png")), a(result))


def test_uint8_tables_are_cached_by_curve_not_reused_across_parameters():
    """The byte tables are cached by the curve's code and captured values: another parameter (or
    operation) gets its own table; the same parameters reuse it."""
    import pointillist.imaging.tone._shared as tone_shared

    ramp = np.arange(256, dtype=np.uint8).reshape(16, 16)
    for first, second in ((lambda x: quantize(x, 3), lambda x: quantize(x, 4)),
                          (lambda x: gamma(x, 2.2), lambda x: gamma(x, 2.2, a=1.5)),
                          (lambda x: gamma(x, 2.2), lambda x: gamma(x, 2.2, max_value=200.0)),
                          (lambda x: contrast_stretch(x, 50, 20, 200, 235),
                           lambda x: contrast_stretch(x, 50, 20, 200, 236))):
        a, b = a_copy(first(ramp)), a_copy(second(ramp))
        assert not np.array_equal(a, b)
        assert_8bit(second(ramp), second(ramp.astype(np.float32)))
        assert_8bit(first(ramp), first(ramp.astype(np.float32)))
    size = len(tone_shared._BYTE_TABLES)
    gamma(ramp, 2.2)
    assert len(tone_shared._BYTE_TABLES) == size  # reused


def a_copy(x):
    return np.asarray(x).copy()
