"""Derivatives of renders with the ``whitted`` integrator and the ``lambert``/``phong`` BSDFs.

Evidence: at a fixed seed a render is a smooth function of every material and light
parameter (whitted's random numbers do not depend on them), so reverse mode, forward mode and
central differences of the same render must agree; forward and reverse mode to rounding, central
differences within 1 %. The replay's gradients equal those of evaluated (unrolled) loops, and
those of Mitsuba's ``prb`` where both compute the same image (direct light from a point light).
Parameters that move geometry are refused by name.
"""

from __future__ import annotations

import numpy as np
import pytest

RES, SPP, SEED = 32, 8, 5


def _scene(mi, integrator=None, *, textured_floor=True):
    T = mi.ScalarTransform4f
    texels = np.random.default_rng(1).uniform(0.2, 0.8, (4, 4, 3)).astype(np.float32)
    floor = ({"type": "bitmap", "data": mi.TensorXf(texels), "raw": True, "filter_type": "nearest"}
             if textured_floor else {"type": "rgb", "value": [0.6, 0.5, 0.4]})
    return mi.load_dict({
        "type": "scene",
        "integrator": integrator or {"type": "whitted", "max_depth": 4},
        "sensor": {"type": "perspective", "fov": 40,
                   "to_world": T().look_at(origin=[0, 1.5, 5], target=[0, 0.5, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": RES, "height": RES, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": SPP}},
        "floor": {"type": "rectangle", "to_world": T().rotate([1, 0, 0], -90).scale(4),
                  "bsdf": {"type": "lambert", "reflectance": floor}},
        "ball": {"type": "sphere", "to_world": T().translate([0.8, 0.7, 0]).scale(0.7),
                 "bsdf": {"type": "phong", "diffuse_reflectance": {"type": "rgb", "value": [0.5, 0.3, 0.2]},
                          "specular_reflectance": {"type": "rgb", "value": [0.2, 0.2, 0.2]},
                          "exponent": 20.0}},
        "mirror": {"type": "sphere", "to_world": T().translate([-0.9, 0.6, 0.3]).scale(0.6),
                   "bsdf": {"type": "conductor", "material": "none",
                            "specular_reflectance": {"type": "rgb", "value": [0.8, 0.8, 0.8]}}},
        "glass": {"type": "sphere", "to_world": T().translate([0.0, 0.35, 1.2]).scale(0.35),
                  "bsdf": {"type": "dielectric",
                           "specular_transmittance": {"type": "rgb", "value": [0.9, 0.9, 0.9]}}},
        "lamp": {"type": "rectangle", "to_world": T().translate([0, 3.5, 0]).rotate([1, 0, 0], 90).scale(0.5),
                 "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [6, 6, 6]}}},
        "light": {"type": "point", "position": [2.0, 4.0, 3.0],
                  "intensity": {"type": "rgb", "value": [20.0, 18.0, 15.0]}},
    })


def _weights(shape):
    return np.random.default_rng(0).uniform(0.0, 1.0, shape)


def _loss(image) -> float:
    """A fixed random linear functional of the image, in float64."""
    array = np.asarray(image).astype(np.float64)
    return float((array * _weights(array.shape)).sum())


def _reverse(mi, dr, scene, key, **kwargs) -> np.ndarray:
    params = mi.traverse(scene)
    dr.enable_grad(params[key])
    params.update()
    weights = mi.TensorXf(_weights((RES, RES, 3)).astype(np.float32))
    scene.integrator().render_backward(scene, params, weights, seed=SEED, spp=SPP, **kwargs)
    grad = np.asarray(dr.grad(params[key])).astype(np.float64).ravel()
    dr.disable_grad(params[key])
    params.update()
    return grad


def _forward(mi, dr, scene, key) -> float:
    """The derivative of the loss along all-ones (every component of ``key`` moved alike)."""
    params = mi.traverse(scene)
    start = type(params[key])(params[key])
    theta = mi.Float(0.0)
    dr.enable_grad(theta)
    params[key] = start + theta
    params.update()
    dr.forward(theta, dr.ADFlag.ClearEdges)
    image = scene.integrator().render_forward(scene, theta, seed=SEED, spp=SPP)
    params[key] = start
    params.update()
    return _loss(image)


def _central_difference(mi, scene, key, h) -> float:
    params = mi.traverse(scene)
    start = type(params[key])(params[key])
    values = []
    for sign in (1, -1):
        params[key] = start + sign * h
        params.update()
        values.append(_loss(mi.render(scene, seed=SEED, spp=SPP)))
    params[key] = start
    params.update()
    return (values[0] - values[1]) / (2 * h)


#: Every differentiable parameter of the scene and the step of its central difference.
PARAMETERS = [
    ("floor.bsdf.reflectance.data", 0.05),          # lambert, a bitmap's texels
    ("ball.bsdf.diffuse_reflectance.value", 0.05),  # phong Kd
    ("ball.bsdf.specular_reflectance.value", 0.05),  # phong Ks
    ("ball.bsdf.exponent.value", 0.2),             # phong n (curved: a small step)
    ("mirror.bsdf.specular_reflectance.value", 0.05),  # a delta reflection's weight
    ("glass.bsdf.specular_transmittance.value", 0.05),  # a delta refraction's weight
    ("lamp.emitter.radiance.value", 0.5),           # an area light
    ("light.intensity.value", 1.0),                 # a point light
]


@pytest.mark.parametrize("key, h", PARAMETERS, ids=[key for key, _ in PARAMETERS])
def test_reverse_equals_forward_and_central_differences(mi, dr, key, h):
    scene = _scene(mi)
    reverse = _reverse(mi, dr, scene, key).sum()
    forward = _forward(mi, dr, scene, key)
    difference = _central_difference(mi, scene, key, h)
    assert abs(difference) > 1e-4, "the parameter must change this image"
    assert forward == pytest.approx(reverse, rel=1e-5)
    assert reverse == pytest.approx(difference, rel=0.01)


def test_texel_gradients_each_match_central_differences(mi, dr):
    """Per texel, not only their sum: each of the 48 texel channels' derivative."""
    scene = _scene(mi)
    key = "floor.bsdf.reflectance.data"
    reverse = _reverse(mi, dr, scene, key)
    params = mi.traverse(scene)
    start = np.asarray(params[key]).copy()
    h = 0.05
    for index in (0, 7, 20, 33, 47):
        values = []
        for sign in (1, -1):
            moved = start.copy().ravel()
            moved[index] += sign * h
            params[key] = mi.TensorXf(moved.reshape(start.shape))
            params.update()
            values.append(_loss(mi.render(scene, seed=SEED, spp=SPP)))
        difference = (values[0] - values[1]) / (2 * h)
        assert reverse[index] == pytest.approx(difference, rel=0.01, abs=1e-3 * abs(reverse).max())
    params[key] = mi.TensorXf(start)
    params.update()


def test_replay_gradients_equal_evaluated_loops(mi, dr):
    """The symbolic loop's replay against the same loop evaluated iteration by iteration, for the
    parameters reached only through delta bounces too (the mirror, the glass)."""
    scene = _scene(mi)
    keys = ["mirror.bsdf.specular_reflectance.value", "glass.bsdf.specular_transmittance.value",
            "ball.bsdf.diffuse_reflectance.value"]
    symbolic = [_reverse(mi, dr, scene, key) for key in keys]
    with dr.scoped_set_flag(dr.JitFlag.SymbolicLoops, False):
        evaluated = [_reverse(mi, dr, scene, key) for key in keys]
    for a, b in zip(symbolic, evaluated):
        assert np.all(a != 0)
        np.testing.assert_allclose(a, b, rtol=1e-5)


def test_gradients_agree_with_mitsubas_prb(mi, dr):
    """Direct light from a point light on diffuse surfaces: whitted (max_depth 1) and Mitsuba's
    ``prb`` (max_depth 2) render the same image from the same camera rays, so the derivative
    with respect to the texels is the same up to rounding."""
    T = mi.ScalarTransform4f
    texels = np.random.default_rng(2).uniform(0.2, 0.8, (4, 4, 3)).astype(np.float32)

    def scene(integrator):
        return mi.load_dict({
            "type": "scene", "integrator": integrator,
            "sensor": {"type": "perspective", "fov": 40,
                       "to_world": T().look_at(origin=[0, 2, 4], target=[0, 0, 0], up=[0, 1, 0]),
                       "film": {"type": "hdrfilm", "width": RES, "height": RES, "rfilter": {"type": "box"}},
                       "sampler": {"type": "independent", "sample_count": 4}},
            "floor": {"type": "rectangle", "to_world": T().rotate([1, 0, 0], -90).scale(3),
                      "bsdf": {"type": "diffuse", "reflectance": {
                          "type": "bitmap", "data": mi.TensorXf(texels), "raw": True, "filter_type": "nearest"}}},
            "light": {"type": "point", "position": [1.0, 3.0, 1.0], "intensity": {"type": "rgb", "value": [10, 9, 8]}},
        })

    key = "floor.bsdf.reflectance.data"
    ours = _reverse(mi, dr, scene({"type": "whitted", "max_depth": 1}), key)
    theirs = _reverse(mi, dr, scene({"type": "prb", "max_depth": 2}), key)
    assert np.abs(ours).max() > 0
    np.testing.assert_allclose(ours, theirs, rtol=1e-4, atol=1e-6 * np.abs(theirs).max())


@pytest.mark.parametrize("key", ["ball.to_world", "light.position", "sensor.to_world", "sensor.x_fov"])
def test_geometry_gradients_are_refused(mi, dr, key):
    scene = _scene(mi, textured_floor=False)
    params = mi.traverse(scene)
    dr.enable_grad(params[key])
    params.update()
    weights = mi.TensorXf(np.ones((RES, RES, 3), np.float32))
    with pytest.raises(ValueError, match=rf"^{key}: the whitted integrator does not differentiate geometry"):
        scene.integrator().render_backward(scene, params, weights, seed=SEED, spp=1)
    with pytest.raises(ValueError, match=rf"^{key}: "):
        scene.integrator().render_forward(scene, params, seed=SEED, spp=1)
    dr.disable_grad(params[key])
    params.update()


def test_reflectance_recovered_by_inverse_rendering(mi, dr):
    """Recover the ball's diffuse colour from a target image: 80 Adam steps, RMSE below 0.01."""
    scene = _scene(mi, textured_floor=False)
    key = "ball.bsdf.diffuse_reflectance.value"
    params = mi.traverse(scene)
    truth = np.asarray(params[key]).copy()
    target = mi.render(scene, seed=100, spp=64)
    optimizer = mi.ad.Adam(lr=0.05)
    optimizer[key] = mi.Color3f(0.1, 0.8, 0.6)
    params.update(optimizer)
    for step in range(80):
        image = mi.render(scene, params, seed=step, spp=4)
        loss = dr.mean(dr.square(image - target), axis=None)
        dr.backward(loss)
        optimizer.step()
        optimizer[key] = dr.clip(optimizer[key], 0.0, 1.0)
        params.update(optimizer)
    found = np.asarray(params[key]).ravel()
    assert np.sqrt(np.mean((found - truth.ravel()) ** 2)) < 0.01
