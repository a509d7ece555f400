"""imaging.colour against OpenCV (HSV), colour-science (sRGB curves, Rec. 709 weights) and hand cases."""

from __future__ import annotations

import colour
import cv2
import numpy as np
import pytest

from pointillist.imaging.arrays import NonFiniteWarning
from pointillist.imaging.colour import (REC709_LUMINANCE_WEIGHTS, adjust_hsv, hsv_to_rgb, luminance, rgb_to_hsv,
                                        srgb_decode, srgb_encode)


def _rgb_samples() -> np.ndarray:
    rng = np.random.default_rng(5)
    image = rng.random((24, 20, 3), dtype=np.float32)
    special = np.array([[0, 0, 0], [1, 1, 1], [0.5, 0.5, 0.5], [1, 0, 0], [0, 1, 0], [0, 0, 1],
                        [1, 1, 0], [0, 1, 1], [1, 0, 1], [0.2, 0.2, 0.7], [0.7, 0.2, 0.7],
                        [0.3, 0.9, 0.3]], np.float32)
    image.reshape(-1, 3)[: len(special)] = special
    return image


def test_rgb_to_hsv_matches_opencv():
    image = _rgb_samples()
    ours = np.asarray(rgb_to_hsv(image))
    ref = cv2.cvtColor(image, cv2.COLOR_RGB2HSV)
    # hue: OpenCV rounds 60/delta differently; a thousandth of a degree is float32 noise here
    np.testing.assert_allclose(ours[..., 0], ref[..., 0], atol=2e-3)
    np.testing.assert_allclose(ours[..., 1:], ref[..., 1:], atol=2e-6)


def test_hsv_hand_cases():
    cases = {(1.0, 0.5, 0.0): (30.0, 1.0, 1.0), (0.0, 0.0, 0.5): (240.0, 1.0, 0.5),
             (0.5, 0.5, 0.5): (0.0, 0.0, 0.5), (0.0, 0.0, 0.0): (0.0, 0.0, 0.0),
             (1.0, 0.0, 0.5): (330.0, 1.0, 1.0), (0.25, 0.5, 0.5): (180.0, 0.5, 0.5),
             # OpenCV divides by V + FLT_EPSILON and gives S = 0.456 here; S = (max - min) / max = 1
             (1e-7, 0.0, 0.0): (0.0, 1.0, 1e-7)}
    rgb = np.array([[list(k) for k in cases]], np.float32)
    expected = np.array([[list(v) for v in cases.values()]], np.float32)
    np.testing.assert_allclose(np.asarray(rgb_to_hsv(rgb)), expected, atol=1e-5)
    np.testing.assert_allclose(np.asarray(hsv_to_rgb(expected)), rgb, atol=1e-6)


def test_hsv_to_rgb_matches_opencv_and_round_trips():
    image = _rgb_samples()
    hsv = cv2.cvtColor(image, cv2.COLOR_RGB2HSV)
    np.testing.assert_allclose(np.asarray(hsv_to_rgb(hsv)), cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB), atol=2e-6)
    back = np.asarray(hsv_to_rgb(rgb_to_hsv(image)))
    np.testing.assert_allclose(back, image, atol=2e-6)
    # 0..255 input keeps its units in V
    np.testing.assert_allclose(np.asarray(hsv_to_rgb(rgb_to_hsv(image * 255))), image * 255, atol=5e-4)


def test_hue_wraps_modulo_360():
    base = np.array([[[0.0, 1.0, 1.0], [300.0, 0.5, 0.8]]], np.float32)
    shifted = base + np.array([360.0, 0, 0], np.float32)
    negative = base - np.array([360.0, 0, 0], np.float32)
    ref = np.asarray(hsv_to_rgb(base))
    np.testing.assert_allclose(np.asarray(hsv_to_rgb(shifted)), ref, atol=1e-6)
    np.testing.assert_allclose(np.asarray(hsv_to_rgb(negative)), ref, atol=1e-6)
    np.testing.assert_allclose(ref[0, 0], [1.0, 0.0, 0.0])


def test_hsv_non_finite_and_one_pixel():
    hsv = np.asarray(rgb_to_hsv(np.array([[[np.nan, 0.5, 0.25]]], np.float32)))
    np.testing.assert_allclose(hsv, cv2.cvtColor(np.array([[[0, 0.5, 0.25]]], np.float32), cv2.COLOR_RGB2HSV),
                               atol=1e-4)
    inf = np.asarray(rgb_to_hsv(np.array([[[np.inf, 0.0, 0.0]]], np.float32)))
    assert np.all(np.isfinite(inf)) and inf[0, 0, 0] == 0 and inf[0, 0, 1] == 1
    assert np.asarray(rgb_to_hsv(np.zeros((1, 1, 3)))).tolist() == [[[0.0, 0.0, 0.0]]]


def test_adjust_hsv():
    image = _rgb_samples()
    np.testing.assert_allclose(np.asarray(adjust_hsv(image)), image, atol=2e-6)
    hsv = cv2.cvtColor(image, cv2.COLOR_RGB2HSV)
    hsv[..., 0] = (hsv[..., 0] + 90) % 360
    hsv[..., 1] = np.minimum(hsv[..., 1] * 1.5, 1)
    hsv[..., 2] *= 0.5
    np.testing.assert_allclose(np.asarray(adjust_hsv(image, hue=90, saturation=1.5, value=0.5)),
                               cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB), atol=1e-5)
    grey = np.asarray(adjust_hsv(image, saturation=0))
    np.testing.assert_allclose(grey, np.repeat(image.max(axis=2, keepdims=True), 3, axis=2), atol=1e-6)
    with pytest.raises(ValueError, match="saturation"):
        adjust_hsv(image, saturation=-1)
    with pytest.raises(ValueError, match="hue"):
        adjust_hsv(image, hue=np.inf)
    for bad in ("10", np.array([1.0, 2.0]), [3.0]):        # not one number: named in a TypeError
        with pytest.raises(TypeError, match="value: expected a number"):
            adjust_hsv(image, value=bad)


def test_luminance_uses_rec709_weights():
    matrix = colour.RGB_COLOURSPACES["sRGB"].matrix_RGB_to_XYZ
    np.testing.assert_allclose(REC709_LUMINANCE_WEIGHTS, matrix[1], atol=2e-4)
    image = _rgb_samples()
    np.testing.assert_allclose(np.asarray(luminance(image)), image @ np.array(REC709_LUMINANCE_WEIGHTS),
                               rtol=1e-6, atol=1e-7)
    assert np.asarray(luminance(np.ones((2, 2, 3)))).shape == (2, 2)
    grey = np.arange(6, dtype=np.float32).reshape(2, 3)
    np.testing.assert_array_equal(np.asarray(luminance(grey)), grey)
    np.testing.assert_array_equal(np.asarray(luminance(grey[..., None])), grey)
    with pytest.warns(NonFiniteWarning, match="luminance: replaced 1 non-finite"):
        y = np.asarray(luminance(np.array([[[np.nan, 1, 1]]]))).item()
    assert y == pytest.approx(0.7152 + 0.0722)   # the NaN component counts as 0


def test_non_finite_rule():
    """NaN -> 0, +inf -> white (max_value), -inf -> 0, one NonFiniteWarning with the count (the hostile-input round:
    rgb_to_hsv gave V = 1e30, hsv_to_rgb -1e30, luminance passed +-inf, none warned)."""
    rgb = np.array([[[np.inf, 0.5, 0.0], [np.nan, -np.inf, 1.0]]], np.float32)
    clean = np.array([[[1.0, 0.5, 0.0], [0.0, 0.0, 1.0]]], np.float32)
    cases = [(rgb_to_hsv, rgb, clean, 3), (luminance, rgb, clean, 3), (srgb_encode, rgb, clean, 3),
             (srgb_decode, rgb, clean, 3), (lambda x: adjust_hsv(x, hue=30), rgb, clean, 3),
             (hsv_to_rgb, np.array([[[np.inf, np.inf, np.inf], [np.nan, -np.inf, 0.5]]], np.float32),
              np.array([[[0.0, 1.0, 1.0], [0.0, 0.0, 0.5]]], np.float32), 5)]
    for function, dirty, same, count in cases:
        with pytest.warns(NonFiniteWarning) as caught:
            got = np.asarray(function(dirty))
        messages = [str(w.message) for w in caught if issubclass(w.category, NonFiniteWarning)]
        assert len(messages) == 1 and f"replaced {count} non-finite" in messages[0], messages
        np.testing.assert_array_equal(got, np.asarray(function(same)))
    with pytest.warns(NonFiniteWarning):
        assert np.asarray(rgb_to_hsv(rgb, max_value=255.0))[0, 0].tolist() == pytest.approx([60 * 0.5 / 255, 1, 255])
    with pytest.warns(NonFiniteWarning):
        assert np.asarray(luminance(np.array([[np.inf, -np.inf]]), max_value=255.0)).tolist() == [[255.0, 0.0]]
    with pytest.raises(ValueError, match="max_value"):
        luminance(rgb, max_value=0)


def test_srgb_curves_match_colour_science():
    values = np.concatenate([np.linspace(-0.5, 2.0, 2001), [0.0031308, 0.04045, 1e-6, 1e4]]).astype(np.float32)
    image = values.reshape(5, -1)
    ref = colour.cctf_encoding(image.astype(np.float64), function="sRGB")
    np.testing.assert_allclose(np.asarray(srgb_encode(image)), ref, rtol=2e-6, atol=2e-7)
    ref = colour.cctf_decoding(image.astype(np.float64), function="sRGB")
    np.testing.assert_allclose(np.asarray(srgb_decode(image)), ref, rtol=5e-6, atol=2e-7)
    unit = np.linspace(0, 1, 257, dtype=np.float32).reshape(1, -1)
    np.testing.assert_allclose(np.asarray(srgb_decode(srgb_encode(unit))), unit, atol=1e-6)
    with pytest.warns(NonFiniteWarning, match="replaced 2 non-finite"):   # the imaging rule: +inf -> white
        ends = np.asarray(srgb_encode(np.array([[0.0, 1.0, np.nan, np.inf]])))
    assert ends.tolist() == [[0.0, 1.0, 0.0, 1.0]]
    # black and white decode to exactly 0 and 1 (white was 0.99999988: a product with 1 / 1.055)
    assert np.asarray(srgb_decode(np.array([[0.0, 1.0]], np.float32))).tolist() == [[0.0, 1.0]]


@pytest.mark.parametrize("function", [rgb_to_hsv, hsv_to_rgb, adjust_hsv])
def test_hsv_needs_three_channels(function):
    with pytest.raises(ValueError, match="image"):
        function(np.zeros((4, 4)))
    with pytest.raises(ValueError, match="image"):
        function(np.zeros((4, 4, 4)))
    with pytest.raises(TypeError, match="image"):
        function("not an image")


def test_luminance_of_bytes_equals_that_of_their_float_conversion():
    # 8-bit input is read as bytes (32-bit word gathers; odd pixel counts fall back to a float
    # unravel): the float32 values of the float path, bit for bit, on real and noisy images
    from skimage import data

    from pointillist.imaging.arrays import TensorXu8

    rng = np.random.default_rng(8)
    for image in (data.astronaut(), data.coffee(), rng.integers(0, 256, (17, 13, 3), dtype=np.uint8),
                  rng.integers(0, 256, (16, 12, 3), dtype=np.uint8), data.camera(), data.camera()[..., None]):
        expected = np.asarray(luminance(image.astype(np.float32), max_value=255.0))
        for given in (image, TensorXu8(image)):
            got = np.asarray(luminance(given, max_value=255.0))
            assert got.dtype == np.float32 and got.shape == image.shape[:2]
            assert np.array_equal(got.view(np.uint32), expected.view(np.uint32))


def test_luminance_rejects_two_channels():
    with pytest.raises(ValueError, match="channels"):
        luminance(np.zeros((2, 2, 2)))


# ------------------------------------------------------------------------------------------ whatever the input's memory

def _routes(image: np.ndarray):
    """The same pixels as aligned numpy, a lazy Dr.Jit tensor and an 8-byte-misaligned view."""
    import drjit as dr
    from drjit.llvm import TensorXf

    lazy = TensorXf(dr.llvm.Float(image.reshape(-1)) * 1.0, image.shape)   # unevaluated
    buffer = np.empty(image.size + 1, np.float32)
    misaligned = buffer[1:].reshape(image.shape)
    misaligned[...] = image
    assert misaligned.ctypes.data % 8 == 4
    return image, lazy, misaligned


@pytest.mark.parametrize("function", [rgb_to_hsv, hsv_to_rgb, lambda x: adjust_hsv(x, hue=40, saturation=0.5)],
                         ids=["rgb_to_hsv", "hsv_to_rgb", "adjust_hsv"])
def test_the_result_does_not_depend_on_the_input_s_memory(function):
    image = _rgb_samples()
    image[0, 1] = [np.nan, np.inf, -np.inf]
    if function is hsv_to_rgb:
        image = cv2.cvtColor(np.nan_to_num(image, posinf=1, neginf=0), cv2.COLOR_RGB2HSV)
    results = [np.asarray(function(x)) for x in _routes(image)]
    for other in results[1:]:
        np.testing.assert_array_equal(results[0], other)
    odd = image[:, :19]                                   # 24 x 19: an odd pixel count
    np.testing.assert_array_equal(np.asarray(function(np.ascontiguousarray(odd))), results[0][:, :19])


def test_one_kernel_and_no_aliasing(aligned):
    import drjit as dr

    image = aligned(_rgb_samples())  # aligned like the warm-up copy: Dr.Jit has a variant per alignment
    expected = cv2.cvtColor(image, cv2.COLOR_RGB2HSV)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()
        np.asarray(rgb_to_hsv(aligned(image)))
        compiled = {k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT}
        result = rgb_to_hsv(image)
        kernels = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert [k["size"] for k in kernels] == [image.shape[0] * image.shape[1]]   # one lane a pixel
    assert {k["hash"] for k in kernels} <= compiled  # no recompilation (hashes: not ~/.drjit's cache_hit)
    image[...] = 0                                        # the result is already computed
    np.testing.assert_allclose(np.asarray(result)[..., 1:], expected[..., 1:], atol=2e-6)


def _boundary_inputs() -> np.ndarray:
    """Every float32 in 0..1 within 64 ulps of a linear value whose sRGB encoding x 255 is k + 1/2
    (where rounding to 8 bits can go either way), plus 2^20 evenly spaced values."""
    linear = colour.cctf_decoding((np.arange(256) + 0.5) / 255.0, function="sRGB")
    bits = np.float32(linear).view(np.uint32).astype(np.int64)[:, None] + np.arange(-64, 65)
    near = np.clip(bits, 0, None).astype(np.uint32).view(np.float32).ravel()
    x = np.unique(np.concatenate([near, np.linspace(0, 1, 1 << 20, dtype=np.float32), [0.0, 1.0]]))
    return x[(x >= 0) & (x <= 1)].astype(np.float32)


def test_one_srgb_curve_for_the_png_and_the_adaptive_integrator(dr):
    """The PNG's bytes (``to_8bit``, the imaging module's curve in float64) equal colour-science's
    encoding rounded, at every float32 input near a rounding boundary; the adaptive integrator's
    display value (the same curve in float32) rounds to the same byte except within float32
    rounding of a half step, and never more than 1 apart."""
    from drjit.llvm import Float

    from pointillist.imaging.io import to_8bit
    from pointillist.plugins.integrators.adaptive import srgb_display

    x = _boundary_inputs()
    reference = np.round(colour.cctf_encoding(x.astype(np.float64), function="sRGB") * 255.0).astype(np.uint8)
    png = to_8bit(x.reshape(1, -1))[0]
    np.testing.assert_array_equal(png, reference)
    shown = np.clip(np.rint(srgb_display(Float(x)).numpy()), 0, 255).astype(np.uint8)
    differ = shown != png
    exact = colour.cctf_encoding(x[differ].astype(np.float64), function="sRGB") * 255.0
    assert np.abs(shown.astype(int) - png).max() <= 1
    assert np.all(np.abs(exact - np.floor(exact) - 0.5) < 1e-4)            # only at half steps
    assert 0 < differ.sum() < len(x) / 1000
