"""Derivatives through the imaging module: AD tensors in, AD tensors out.

Evidence: for every operation whose mathematics is differentiable, the reverse-mode gradient of a
fixed random linear functional of its output matches central differences (float64 sums, steps
away from the kinks) within 0.1 %; the primal result is the same with and without gradient
tracking; the piecewise-constant operations refuse an input that tracks gradients.
"""

from __future__ import annotations

import numpy as np
import pytest

SHAPE = (8, 9, 3)


def _image():
    """Values in 0.1 .. 0.9, one pixel at 0.86 .. 0.97 and one at 0.06 .. 0.14 (channels apart: no
    ties): extremes (the white points, normalize's range) apart from the rest by more than the
    difference step, so no step changes which pixel is extreme."""
    image = np.random.default_rng(0).uniform(0.1, 0.9, SHAPE).astype(np.float32)
    image[2, 3] = (0.97, 0.91, 0.86)
    image[5, 6] = (0.06, 0.14, 0.10)
    return image


def _differentiable():
    from pointillist.imaging import colour, filters, resample
    from pointillist.imaging.tone import TONEMAP_OPERATORS, contrast_stretch, gamma, tonemap

    cases = {f"tonemap-{op}": lambda x, op=op: tonemap(x, op) for op in TONEMAP_OPERATORS}
    cases.update({
        "gamma": lambda x: gamma(x * 255.0, 2.2),
        "contrast_stretch": lambda x: contrast_stretch(x * 255.0, 40.0, 20.0, 200.0, 240.0),
        "srgb_encode": colour.srgb_encode,
        "srgb_decode": colour.srgb_decode,
        "rgb_to_hsv": colour.rgb_to_hsv,
        "luminance": colour.luminance,
        "adjust_hsv": lambda x: colour.adjust_hsv(x, saturation=1.2, value=0.9),
        "resize-bicubic": lambda x: resample.resize(x, (12, 5)),
        "normalize": filters.normalize,
        "sobel": filters.sobel,
        "correlate-normalize": lambda x: filters.correlate(x, filters.SOBEL_X, normalize=True),
    })
    for border in ("zero", "crop", "keep", "clamp", "reflect", "mirror", "wrap", "constant"):
        cases[f"correlate-{border}"] = lambda x, border=border: filters.correlate(x, filters.GAUSSIAN_3, border=border)
    return cases


CASES = sorted(_differentiable())


@pytest.mark.parametrize("name", CASES)
def test_gradients_match_central_differences(name):
    import drjit as dr
    from drjit.llvm.ad import TensorXf

    function = _differentiable()[name]
    image = _image()
    x = TensorXf(image)
    dr.enable_grad(x)
    y = function(x)
    assert isinstance(y, TensorXf) and dr.grad_enabled(y)
    plain = function(TensorXf(image))
    assert not dr.grad_enabled(plain)
    np.testing.assert_array_equal(np.asarray(dr.detach(y)), np.asarray(plain))  # the same image either way
    weights = np.random.default_rng(1).uniform(0.0, 1.0, tuple(y.shape))
    dr.backward(dr.sum(y * TensorXf(weights.astype(np.float32)), axis=None))
    grad = np.asarray(dr.grad(x)).astype(np.float64)
    assert np.abs(grad).max() > 0

    def loss(array):
        return float((np.asarray(function(TensorXf(array.astype(np.float32)))).astype(np.float64) * weights).sum())

    flat = image.reshape(-1)
    points = {0, 31, 100, 200, int(np.argmax(flat)), int(np.argmin(flat))}  # the extremes included
    for point in sorted(points):
        index = np.unravel_index(point, SHAPE)
        h = min(2e-3, float(image[index]) / 20)      # small: the curves bend (unaffected outputs cancel)
        plus, minus = image.astype(np.float64), image.astype(np.float64)
        plus[index] += h
        minus[index] -= h
        difference = (loss(plus) - loss(minus)) / (2 * h)
        assert grad[index] == pytest.approx(difference, rel=1e-3, abs=1e-3 * np.abs(grad).max()), point


def test_an_ad_render_keeps_its_gradient_through_a_tone_map(mi, dr):
    """render -> tone map -> loss: the gradient reaches the scene parameter, and equals the
    central difference of the same chain (reinhard's white point is the image's own maximum, so
    brightening the ball also darkens it: a negative component is right)."""
    from pointillist.imaging.tone import tonemap

    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": "whitted"},
        "sensor": {"type": "perspective", "film": {"type": "hdrfilm", "width": 8, "height": 8},
                   "sampler": {"type": "independent", "sample_count": 4}},
        "ball": {"type": "sphere", "to_world": mi.ScalarTransform4f().translate([0, 0, 3]),
                 "bsdf": {"type": "lambert", "reflectance": {"type": "rgb", "value": [0.5, 0.4, 0.3]}}},
        "light": {"type": "point", "position": [0, 1, 0], "intensity": {"type": "rgb", "value": [5, 5, 5]}},
    })
    params = mi.traverse(scene)
    key = "ball.bsdf.reflectance.value"
    dr.enable_grad(params[key])
    params.update()
    image = mi.render(scene, params, seed=1, spp=4)     # Mitsuba differentiates with another seed (2)
    dr.backward(dr.mean(tonemap(image, "reinhard"), axis=None))
    through_render = np.asarray(dr.grad(params[key])).ravel()
    dr.disable_grad(params[key])
    params.update()

    # The same chain rule at one seed: the tone map's gradient image into the render's adjoint.
    image = mi.TensorXf(mi.render(scene, seed=1, spp=4))
    dr.enable_grad(image)
    dr.backward(dr.mean(tonemap(image, "reinhard"), axis=None))
    grad_image = dr.grad(image)
    dr.enable_grad(params[key])
    params.update()
    scene.integrator().render_backward(scene, params, grad_image, seed=1, spp=4)
    grad = np.asarray(dr.grad(params[key])).ravel()
    dr.disable_grad(params[key])
    start = np.asarray(params[key]).ravel().copy()
    h = 1e-3                          # 1e-2 already moves the white point to another pixel
    for channel in range(3):
        values = []
        for sign in (1, -1):
            moved = start.copy()
            moved[channel] += sign * h
            params[key] = mi.Color3f(*[float(v) for v in moved])
            params.update()
            tone_mapped = np.asarray(tonemap(mi.render(scene, seed=1, spp=4), "reinhard")).astype(np.float64)
            values.append(tone_mapped.mean())
        difference = (values[0] - values[1]) / (2 * h)
        assert grad[channel] == pytest.approx(difference, rel=1e-2)
        assert through_render[channel] == pytest.approx(difference, rel=0.1)   # another seed's noise


@pytest.mark.parametrize("name", ["quantize", "lut", "equalize_histogram", "histogram", "threshold", "median",
                                  "zero_crossings", "floyd_steinberg", "ordered", "dither", "flip"])
def test_piecewise_constant_operations_refuse_gradients(name):
    import drjit as dr
    from drjit.llvm.ad import TensorXf

    from pointillist.imaging import dither, filters, flip, tone

    functions = {
        "quantize": lambda x: tone.quantize(x, 4), "lut": lambda x: tone.lut(x, np.arange(256.0)),
        "equalize_histogram": tone.equalize_histogram, "histogram": tone.histogram,
        "threshold": filters.threshold, "median": filters.median, "zero_crossings": filters.zero_crossings,
        "floyd_steinberg": dither.floyd_steinberg, "ordered": dither.ordered, "dither": dither.dither,
        "flip": lambda x: flip.flip(x, np.asarray(_image())),
    }
    x = TensorXf(_image() * 255.0)
    functions[name](TensorXf(_image() * 255.0))        # fine without gradients
    dr.enable_grad(x)
    with pytest.raises(TypeError, match="is not differentiable .* the input tracks gradients"):
        functions[name](x)
