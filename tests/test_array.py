"""Array conventions shared by every imaging operation (imaging/arrays.py)."""

from __future__ import annotations

import math
import warnings

import drjit as dr
import numpy as np
import pytest
from drjit.llvm.ad import TensorXf

from pointillist.imaging import as_tensor, colour, dither, filters, resample, tone



def _rgb(rng):
    return rng.random((16, 17, 3)).astype(np.float32)


def _grey(rng):
    return (rng.random((16, 17)) * 255).astype(np.float32)


def _u8(rng):
    return (rng.random((16, 17)) * 255).astype(np.uint8)


OPERATIONS = {
    "rgb_to_hsv": (colour.rgb_to_hsv, _rgb),
    "hsv_to_rgb": (colour.hsv_to_rgb, _rgb),
    "adjust_hsv": (lambda x: colour.adjust_hsv(x, hue=10), _rgb),
    "luminance": (colour.luminance, _rgb),
    "srgb_encode": (colour.srgb_encode, _rgb),
    "srgb_decode": (colour.srgb_decode, _rgb),
    "gamma": (lambda x: tone.gamma(x, 2.2), _grey),
    "gamma_uint8": (lambda x: tone.gamma(x, 2.2), _u8),
    "contrast_stretch": (lambda x: tone.contrast_stretch(x, 50, 20, 200, 230), _grey),
    "quantize": (lambda x: tone.quantize(x, 4), _grey),
    "lut": (lambda x: tone.lut(x, np.arange(256)[::-1]), _u8),
    "equalize_histogram": (tone.equalize_histogram, _grey),
    "tonemap": (lambda x: tone.tonemap(x, "reinhard"), _rgb),
    "correlate": (lambda x: filters.correlate(x, filters.GAUSSIAN_3), _grey),
    "correlate_normalize": (lambda x: filters.correlate(x, filters.SOBEL_X, normalize=True), _grey),
    "sobel": (filters.sobel, _grey),
    "prewitt": (filters.prewitt, _grey),
    "laplacian": (filters.laplacian, _grey),
    "zero_crossings": (filters.zero_crossings, _grey),
    "median": (filters.median, _grey),
    "median_size1": (lambda x: filters.median(x, 1), _grey),
    "threshold": (filters.threshold, _grey),
    "normalize": (filters.normalize, _grey),
    "resize_nearest": (lambda x: resample.resize(x, (30, 20), "nearest"), _grey),
    "resize_bilinear": (lambda x: resample.resize(x, (30, 20), "bilinear"), _grey),
    "resize_bicubic": (lambda x: resample.resize(x, (30, 20), "bicubic"), _grey),
    "sample": (lambda x: resample.sample(x, [1.5, 2.25], [3.0, 4.5]), _grey),
    "floyd_steinberg": (dither.floyd_steinberg, _grey),
    "error_diffusion": (dither.error_diffusion, _grey),
    "ordered": (dither.ordered, _grey),
    "pattern": (dither.pattern, _grey),
    "halftone": (lambda x: dither.halftone(x, 3), _grey),
    "blue_noise": (dither.blue_noise, _grey),
}


@pytest.mark.parametrize("name", OPERATIONS)
def test_result_does_not_change_when_the_numpy_input_does(rng, name):
    # as_tensor shares numpy memory with Dr.Jit; a lazy result must not read the caller's array
    # after the call returns.
    function, make = OPERATIONS[name]
    image = make(rng)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        expected = np.array(function(image.copy()))
        result = function(image)
        image[...] = 7
        got = np.array(result)
    np.testing.assert_array_equal(got, expected)


def test_numpy_float32_is_shared_and_other_dtypes_convert():
    image = np.arange(6, dtype=np.float32).reshape(2, 3)
    tensor = as_tensor(image)
    assert isinstance(tensor, TensorXf) and tensor.shape == (2, 3)
    np.testing.assert_array_equal(np.asarray(tensor), image)
    converted = as_tensor(np.array([[200, 3]], dtype=np.uint8))
    assert np.asarray(converted).tolist() == [[200.0, 3.0]]


def test_drjit_inputs_stay_lazy_and_ad_tensors_keep_their_gradients():
    import drjit.llvm
    import mitsuba as mi

    import pointillist

    pointillist.setup()
    ad = mi.TensorXf(np.ones((2, 2, 3), np.float32))
    dr.enable_grad(ad)
    assert as_tensor(ad) is ad and dr.grad_enabled(as_tensor(ad))     # Mitsuba's tensor is ours
    float64 = drjit.llvm.ad.TensorXf64(np.ones((2, 2), np.float64))
    dr.enable_grad(float64)
    cast = as_tensor(float64)
    assert type(cast) is TensorXf and dr.grad_enabled(cast)              # the cast is differentiated
    dr.backward(dr.sum(cast * 3.0, axis=None))
    np.testing.assert_array_equal(np.asarray(dr.grad(float64)), np.full((2, 2), 3.0))
    plain = drjit.llvm.TensorXf(np.ones((2, 2, 3), np.float32))   # no AD: converted, values kept
    tensor = as_tensor(plain)
    assert type(tensor) is TensorXf and not dr.grad_enabled(tensor)
    np.testing.assert_array_equal(np.asarray(tensor), np.ones((2, 2, 3), np.float32))


@pytest.mark.parametrize("bad, kind, message", [
    (np.zeros(3), ValueError, r"expected an image of shape \(H, W\) or \(H, W, C\), got shape \(3,\)"),
    (np.zeros((0, 3)), ValueError, "expected a non-empty image"),
    (np.array([["a"]]), TypeError, "expected a numeric array"),
    (np.zeros((2, 2), complex), TypeError, "expected a real-valued array"),
    (object(), TypeError, "expected a numeric array"),
])
def test_bad_input_names_the_argument(bad, kind, message):
    with pytest.raises(kind, match=message):
        as_tensor(bad, "picture")
    with pytest.raises(kind, match="^picture: "):
        as_tensor(bad, "picture")


def test_channel_restriction():
    with pytest.raises(ValueError, match="image: expected 1 or 3 channels, got 2"):
        as_tensor(np.zeros((2, 2, 2)), channels=(1, 3))


def test_shared_helpers():
    from drjit.llvm import Float, UInt32

    from pointillist.imaging import arrays

    # the opaque-scalar cache keeps -0.0 and 0.0 apart (equal as keys of a dict) and reuses a value
    assert math.copysign(1.0, float(arrays.opaque_scalar(Float, -0.0)[0])) == -1.0
    assert math.copysign(1.0, float(arrays.opaque_scalar(Float, 0.0)[0])) == 1.0
    assert arrays.opaque_scalar(UInt32, 7) is arrays.opaque_scalar(UInt32, 7)
    assert arrays.is_uint8(np.zeros(2, np.uint8)) and not arrays.is_uint8(np.zeros(2, np.int8))
    assert not arrays.is_uint8([1, 2])
    with pytest.raises(ValueError, match="^frame: expected 1 or 3 channels, got 4$"):
        arrays.check_shape((2, 2, 4), "frame", (1, 3))
