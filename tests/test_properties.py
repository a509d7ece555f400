"""Property-based tests (hypothesis) of the imaging operations that take arbitrary arrays.

Every operation, given an array of any shape (1 x 1 and 1 x N included), dtype (uint8, int16,
float32, float64, bool) and values (NaN, +-inf and huge included), returns an image of the
documented shape and dtype (float32; uint8 for uint8 input to the 8-bit operations, as OpenCV and
Pillow do) or raises ``ValueError``/``TypeError``: never a hang, an abort or a raw Dr.Jit
error. Then invariants of each operation's definition on the inputs it accepts.

Examples are derandomised (the same examples in every run and alone) and kept few
(``max_examples`` 30) so the file stays fast; ``database=None`` keeps no state between runs.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from pointillist.imaging import colour, dither, filters, resample, tone

SETTINGS = settings(max_examples=30, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
DTYPES = [np.uint8, np.int16, np.float32, np.float64, np.bool_]


def image_shapes(channels=(1, 3, 4)):
    """(H, W) or (H, W, C) with small H, W (1 included) and C from ``channels``."""
    sides = st.integers(1, 9)
    return st.one_of(st.tuples(sides, sides), st.tuples(sides, sides, st.sampled_from(channels)))


def arrays(shapes=None, dtypes=DTYPES, finite=False, low=None, high=None):
    """Arrays of the given shapes and dtypes; floats include NaN, +-inf and huge values."""
    def elements(dtype):
        if np.dtype(dtype).kind == "f":
            width = 32 if dtype == np.float32 else 64
            if finite or low is not None:
                return st.floats(low if low is not None else -1e30, high if high is not None else 1e30,
                                 allow_nan=False, allow_infinity=False, width=width)
            special = st.sampled_from([np.nan, np.inf, -np.inf, 1e30, -1e30, 0.0, 255.0])
            return st.one_of(st.floats(width=width), special)
        return None  # hypothesis' own full range of the integer / bool dtype

    return st.sampled_from(dtypes).flatmap(
        lambda dtype: hnp.arrays(dtype, shapes if shapes is not None else image_shapes(), elements=elements(dtype)))


#: name -> (function, allowed channel counts)
OPERATIONS = {
    "threshold": (filters.threshold, (1, 3, 4)),
    "correlate": (lambda x: filters.correlate(x, filters.GAUSSIAN_3, border="reflect"), (1, 3, 4)),
    "sobel": (filters.sobel, (1, 3, 4)),
    "laplacian": (filters.laplacian, (1, 3, 4)),
    "median": (filters.median, (1, 3, 4)),
    "normalize": (filters.normalize, (1, 3, 4)),
    "zero_crossings": (filters.zero_crossings, (1, 3, 4)),
    "gamma": (lambda x: tone.gamma(x, 2.2), (1, 3, 4)),
    "contrast_stretch": (lambda x: tone.contrast_stretch(x, 50, 20, 200, 230), (1, 3, 4)),
    "quantize": (lambda x: tone.quantize(x, 5), (1, 3, 4)),
    "lut": (lambda x: tone.lut(x, np.arange(256)[::-1]), (1, 3, 4)),
    "equalize_histogram": (tone.equalize_histogram, (1, 3, 4)),
    "tonemap_reinhard": (lambda x: tone.tonemap(x, "reinhard"), (3,)),
    "srgb_encode": (colour.srgb_encode, (1, 3, 4)),
    "rgb_to_hsv": (colour.rgb_to_hsv, (3,)),
    "luminance": (colour.luminance, (3,)),
    "resize_bilinear": (lambda x: resample.resize(x, (5, 3), "bilinear"), (1, 3, 4)),
    "resize_bicubic": (lambda x: resample.resize(x, (2, 7), "bicubic"), (1, 3, 4)),
    "floyd_steinberg": (dither.floyd_steinberg, (1, 3, 4)),
    "jjn_serpentine": (lambda x: dither.diffuse(x, "jarvis_judice_ninke", serpentine=True), (1, 3, 4)),
    "error_diffusion": (dither.error_diffusion, (1, 3, 4)),
    "ordered": (dither.ordered, (1, 3, 4)),
    "pattern": (dither.pattern, (1, 3, 4)),
    "halftone": (lambda x: dither.halftone(x, 2), (1, 3, 4)),
}


#: The operations that keep 8-bit input 8-bit (imaging.tone and imaging.dither's tables).
EIGHT_BIT = {"threshold", "gamma", "contrast_stretch", "quantize", "lut", "equalize_histogram", "floyd_steinberg",
             "jjn_serpentine", "error_diffusion", "ordered", "pattern", "halftone"}


def _rounded_like(expected: np.ndarray, image: np.ndarray) -> tuple[np.ndarray, float]:
    """The float ``expected`` as an operation gives it for ``image``'s dtype: uint8 input gets the
    value rounded to the nearest integer, a tie to even (numpy's ``rint``, as ``to_8bit`` and the
    8-bit writers round float32 values), with its tolerance."""
    if image.dtype == np.uint8:
        return np.rint(np.asarray(expected, np.float32)).astype(np.float64), 1e-9
    return np.asarray(expected, np.float64), 1e-3


@pytest.mark.parametrize("name", OPERATIONS)
@SETTINGS
@given(data=st.data())
def test_any_array_gives_an_image_or_a_clear_error(name, data):
    function, channels = OPERATIONS[name]
    shape = data.draw(st.one_of(image_shapes(channels), image_shapes((2, 5)),  # also refused channel counts
                                st.tuples(st.integers(0, 4)), st.tuples(st.integers(0, 2), st.integers(0, 3)),
                                st.tuples(*[st.integers(1, 2)] * 4)), label="shape")
    image = data.draw(arrays(st.just(shape)), label="image")
    try:
        result = function(image)
    except (ValueError, TypeError) as error:
        assert str(error).strip(), "an error must say what is wrong"
        return
    assert len(shape) in (2, 3) and 0 not in shape, f"accepted an image of shape {shape}"
    result = result[0] if isinstance(result, tuple) else result
    array = np.asarray(result)
    dtype = np.uint8 if image.dtype == np.uint8 and name in EIGHT_BIT else np.float32
    assert array.dtype == dtype and array.ndim == (2 if name == "luminance" else len(shape))  # luminance: (H, W)


@SETTINGS
@given(image=arrays(), level=st.floats(-300, 300))
def test_threshold_output_is_exactly_zero_or_max(image, level):
    got = np.asarray(filters.threshold(image, level))
    expected = np.where(image.astype(np.float32) >= np.float32(level), 255.0, 0.0)  # NaN compares false
    np.testing.assert_array_equal(got, expected)


@SETTINGS
@given(values=hnp.arrays(np.float64, st.integers(2, 40), elements=st.floats(0, 255)),
       g=st.floats(0.1, 10), uint8=st.booleans())
def test_gamma_is_monotone_and_fixes_the_ends(values, g, uint8):
    ramp = np.sort(values)[None, :]
    ramp = np.round(ramp).astype(np.uint8) if uint8 else ramp
    out = np.asarray(tone.gamma(ramp, g), dtype=np.float64)[0]
    assert np.all(np.diff(out) >= 0)
    ends = np.asarray(tone.gamma(np.array([[0, 255]], ramp.dtype), g))
    np.testing.assert_allclose(ends, [[0.0, 255.0]], atol=1e-3)
    exact = 255 * (ramp[0].astype(np.float64) / 255) ** (1 / g)
    if uint8:  # uint8 out: the rounded value (within float32 rounding of the exact one at a tie)
        assert np.all(np.abs(out - exact) <= 0.5 + 1e-3)
    else:
        np.testing.assert_allclose(out, exact, rtol=1e-4, atol=2e-3)


@SETTINGS
@given(image=arrays(dtypes=[np.uint8]), table=hnp.arrays(np.int64, 256, elements=st.integers(0, 255)))
def test_lut_is_the_table_lookup_and_keeps_order_for_sorted_tables(image, table):
    np.testing.assert_array_equal(np.asarray(tone.lut(image, table)), table[image].astype(np.float32))
    ramp = np.arange(256, dtype=np.uint8)[None, :]
    assert np.all(np.diff(np.asarray(tone.lut(ramp, np.sort(table)))[0]) >= 0)


@SETTINGS
@given(image=arrays(), levels=st.integers(2, 300))
def test_quantize_gives_at_most_levels_values_on_the_grid(image, levels):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # +-inf input warns (documented)
        out = np.asarray(tone.quantize(image, levels), dtype=np.float64)
    assert np.isfinite(out).all() and len(np.unique(out)) <= levels  # NaN -> 0, +inf -> white
    grid, atol = _rounded_like(np.arange(levels) * 255 / (levels - 1), image)
    assert np.all(np.min(np.abs(out.reshape(-1, 1) - grid.reshape(1, -1)), axis=1) <= atol)
    assert out.min() >= 0 and out.max() <= 255


@SETTINGS
@given(image=arrays(shapes=image_shapes((1, 3))),
       kernel=st.sampled_from(sorted(dither.KERNELS)), serpentine=st.booleans())
def test_diffusion_outputs_only_black_and_white(image, kernel, serpentine):
    out = np.asarray(dither.diffuse(image, kernel, serpentine=serpentine))
    assert out.shape == image.shape and np.isin(out, [0.0, 255.0]).all()


@SETTINGS
@given(image=arrays(shapes=image_shapes((1,)), dtypes=[np.float32, np.float64, np.uint8, np.int16]))
def test_simple_error_diffusion_total_error_is_one_carried_error(image):
    # 100 % of each error goes to the next pixel of the serpentine scan, so the total output minus
    # the total (NaN -> 0, clipped) input is minus the last pixel's error, which lies in [-128, 127].
    clipped = np.clip(np.nan_to_num(image.astype(np.float32).astype(np.float64), nan=0.0), 0, 255)
    out = np.asarray(dither.error_diffusion(image), dtype=np.float64)
    assert np.isin(out, [0.0, 255.0]).all()
    assert -127.0 - 1e-6 <= out.sum() - clipped.sum() <= 128.0 + 1e-6


@SETTINGS
@given(image=arrays(shapes=image_shapes((1,)), finite=True, low=0.0, high=255.0, dtypes=[np.float32, np.float64]))
def test_floyd_steinberg_mean_error_comes_only_from_the_edges(image):
    # Floyd-Steinberg conserves error except what leaves the image: 7/16 at the right column, 3/16
    # at the left column, everything at the bottom row. Each pixel's error is at most 255 here.
    height, width = image.shape[:2]
    out = np.asarray(dither.floyd_steinberg(image), dtype=np.float64)
    edge_pixels = width + 2 * (height - 1)
    assert abs(out.sum() - image.astype(np.float32).astype(np.float64).sum()) <= 255 * edge_pixels + 1e-3


@SETTINGS
@given(image=arrays(dtypes=[np.float32, np.float64, np.uint8]), levels=st.integers(2, 9))
def test_ordered_dithering_output_is_on_the_levels(image, levels):
    out = np.asarray(dither.ordered(image, levels=levels), dtype=np.float64)
    grid, atol = _rounded_like(np.arange(levels) * 255 / (levels - 1), image)
    assert np.all(np.min(np.abs(out.reshape(-1, 1) - grid.reshape(1, -1)), axis=1) <= atol)
    assert out.shape == image.shape


@SETTINGS
@given(image=arrays(finite=True, low=-1e3, high=1e3, dtypes=[np.float32, np.float64]),
       width=st.integers(1, 12), height=st.integers(1, 12), method=st.sampled_from(["nearest", "bilinear"]))
def test_resize_shape_and_range(image, width, height, method):
    out = np.asarray(resample.resize(image, (width, height), method))
    assert out.shape == (height, width, *image.shape[2:])
    values = image.astype(np.float32)
    tolerance = 1e-4 * max(1.0, float(np.abs(values).max()))
    assert out.min() >= values.min() - tolerance and out.max() <= values.max() + tolerance
