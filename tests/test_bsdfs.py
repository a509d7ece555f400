"""Tests of the ``lambert`` and ``phong`` BSDF plugins.

Evidence: Mitsuba's chi-square test of sampling against pdf (``mitsuba.chi2``),
exact agreement with Mitsuba's built-in ``diffuse``, an independent NumPy
implementation of the Phong formula, analytic albedos (white furnace,
normal-incidence Phong albedo = Ks), and stiff scenes (tiny and huge scales, far from the
origin, grazing light; the ray offsets of the documentation's ``conventions-rendering``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

PHONG_EXPONENTS = [1, 10, 100, 1000]
ANGLES = [0.0, 45.0, 85.0, 89.5]          # incident zenith angles in degrees, 89.5 = grazing


def _wi(angle_deg):
    t = math.radians(angle_deg)
    return [math.sin(t), 0.0, math.cos(t)]


def _chi2(mi, plugin, params, angle, *, res=101, ires=4):
    from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain

    sample_func, pdf_func = BSDFAdapter(plugin, dict(type=plugin, **params), wi=_wi(angle))
    test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample_func, pdf_func=pdf_func,
                         sample_dim=3, sample_count=1_000_000, res=res, ires=ires)
    ok = test.run(0.01, test_count=1, quiet=True)
    assert ok, f"{plugin} {params} at {angle} deg: {test.messages[-400:]}"


def _si(mi, dr, wi):
    wi = np.asarray(wi, dtype=np.float32).reshape(-1, 3)
    si = dr.zeros(mi.SurfaceInteraction3f, len(wi))
    si.wi = mi.Vector3f(wi[:, 0], wi[:, 1], wi[:, 2])
    si.uv = mi.Point2f(0.3, 0.6)
    return si


def _vec(mi, v):
    v = np.asarray(v, dtype=np.float32).reshape(-1, 3)
    return mi.Vector3f(v[:, 0], v[:, 1], v[:, 2])


def _unit(rng, n, hemisphere=False):
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    if hemisphere:
        v[:, 2] = np.abs(v[:, 2])
    return v.astype(np.float32)


def _np(x):
    return np.asarray(x).T if np.asarray(x).ndim == 2 else np.asarray(x)


# ----------------------------------------------------------------------- chi2
@pytest.mark.parametrize("angle", ANGLES)
def test_lambert_chi2(mi, angle):
    _chi2(mi, "lambert", {"reflectance": 0.7}, angle)


@pytest.mark.parametrize("exponent", PHONG_EXPONENTS)
@pytest.mark.parametrize("angle", ANGLES)
def test_phong_chi2(mi, exponent, angle):
    # Narrow lobes need finer pdf integration (the pole of the spherical grid).
    res = 301 if exponent >= 1000 else 101
    ires = 16 if exponent >= 100 else 4
    params = {"diffuse_reflectance": 0.3, "specular_reflectance": 0.6, "exponent": float(exponent)}
    _chi2(mi, "phong", params, angle, res=res, ires=ires)


@pytest.mark.parametrize("exponent", [10, 1000])
def test_phong_chi2_specular_only(mi, exponent):
    params = {"diffuse_reflectance": 0.0, "specular_reflectance": 0.8, "exponent": float(exponent)}
    _chi2(mi, "phong", params, 30.0, res=301 if exponent >= 1000 else 101, ires=16)


# ------------------------------------------------------- lambert == diffuse
def test_lambert_matches_builtin_diffuse_pointwise(mi, dr):
    rng = np.random.default_rng(1)
    n = 4096
    wi, wo = _unit(rng, n), _unit(rng, n)          # both hemispheres: normals facing away too
    wi[:8, 2] = 1e-6                               # grazing incidence
    refl = [0.2, 0.5, 0.9]
    ours = mi.load_dict({"type": "lambert", "reflectance": refl})
    ref = mi.load_dict({"type": "diffuse", "reflectance": {"type": "rgb", "value": refl}})
    ctx = mi.BSDFContext()
    si = _si(mi, dr, wi)
    wo_v = _vec(mi, wo)
    np.testing.assert_allclose(_np(ours.eval(ctx, si, wo_v)), _np(ref.eval(ctx, si, wo_v)), rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(_np(ours.pdf(ctx, si, wo_v)), _np(ref.pdf(ctx, si, wo_v)), rtol=1e-6, atol=1e-7)
    s1 = mi.Float(rng.random(n).astype(np.float32))
    s2 = mi.Point2f(rng.random(n).astype(np.float32), rng.random(n).astype(np.float32))
    bs_a, w_a = ours.sample(ctx, si, s1, s2)
    bs_b, w_b = ref.sample(ctx, si, s1, s2)
    np.testing.assert_allclose(_np(bs_a.wo), _np(bs_b.wo), atol=1e-6)
    np.testing.assert_allclose(_np(w_a), _np(w_b), rtol=1e-6, atol=1e-7)
    # normals facing away (cos theta_i <= 0): black, like diffuse
    away = wi[:, 2] <= 0
    assert np.all(_np(w_a)[away] == 0) and np.all(_np(ours.eval(ctx, si, wo_v))[away] == 0)
    # grazing: the weight is still exactly Kd
    np.testing.assert_allclose(_np(w_a)[:8], np.tile(refl, (8, 1)), rtol=1e-6)


def _small_cornell(mi, bsdf_white):
    scene = mi.cornell_box()
    scene["white"] = bsdf_white
    scene["sensor"]["film"]["width"] = scene["sensor"]["film"]["height"] = 32
    scene["sensor"]["film"]["rfilter"] = {"type": "box"}
    scene["integrator"] = {"type": "path", "max_depth": 4}
    return mi.load_dict(scene)


def test_lambert_renders_like_diffuse(mi):
    white = [0.885809, 0.698859, 0.666422]
    a = np.asarray(mi.render(_small_cornell(mi, {"type": "lambert", "reflectance": white}), spp=16, seed=3))
    b = np.asarray(mi.render(_small_cornell(mi, {"type": "diffuse", "reflectance": {"type": "rgb", "value": white}}),
                             spp=16, seed=3))
    assert a.mean() > 0.05
    # same model, same random numbers: equal up to float rounding
    np.testing.assert_allclose(a, b, rtol=1e-3, atol=1e-4)


def test_phong_without_specular_is_lambert(mi, dr):
    rng = np.random.default_rng(2)
    wi, wo = _unit(rng, 1000, True), _unit(rng, 1000, True)
    phong = mi.load_dict({"type": "phong", "diffuse_reflectance": 0.6, "specular_reflectance": 0.0})
    lamb = mi.load_dict({"type": "lambert", "reflectance": 0.6})
    ctx, si, wo_v = mi.BSDFContext(), _si(mi, dr, wi), _vec(mi, wo)
    np.testing.assert_allclose(_np(phong.eval(ctx, si, wo_v)), _np(lamb.eval(ctx, si, wo_v)), rtol=1e-6)
    np.testing.assert_allclose(_np(phong.pdf(ctx, si, wo_v)), _np(lamb.pdf(ctx, si, wo_v)), rtol=1e-6)


# --------------------------------------------------------- phong vs formula
def _phong_reference(wi, wo, kd, ks, n):
    """Independent NumPy implementation of the modified Phong BSDF times cos(theta_o)."""
    kd, ks = np.asarray(kd, float), np.asarray(ks, float)
    scale = 1.0 / np.maximum(kd + ks, 1.0)
    kd, ks = kd * scale, ks * scale
    r = wi * np.array([-1.0, -1.0, 1.0])
    cos_a = np.clip(np.sum(r * wo, axis=1), 0.0, None)
    lobe = np.where(cos_a > 0, cos_a ** n, 0.0)
    f = kd[None] / np.pi + ks[None] * ((n + 2) / (2 * np.pi) * lobe)[:, None]
    ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    return np.where(ok[:, None], f * wo[:, 2:3], 0.0)


@pytest.mark.parametrize("exponent", [0.0, 1.0, 7.5, 100.0])
def test_phong_eval_matches_formula(mi, dr, exponent):
    rng = np.random.default_rng(3)
    wi, wo = _unit(rng, 2000), _unit(rng, 2000)
    # add exact mirror directions, where the lobe peaks
    wo[:50] = wi[:50] * np.array([-1, -1, 1], dtype=np.float32)
    kd, ks = [0.5, 0.2, 0.1], [0.3, 0.3, 0.3]
    bsdf = mi.load_dict({"type": "phong", "diffuse_reflectance": kd, "specular_reflectance": ks,
                         "exponent": exponent})
    got = _np(bsdf.eval(mi.BSDFContext(), _si(mi, dr, wi), _vec(mi, wo)))
    np.testing.assert_allclose(got, _phong_reference(wi.astype(float), wo.astype(float), kd, ks, exponent),
                               rtol=2e-4, atol=1e-6)


def test_phong_rescales_kd_plus_ks_above_one(mi, dr):
    bsdf = mi.load_dict({"type": "phong", "diffuse_reflectance": [0.8, 0.2, 0.5],
                         "specular_reflectance": 0.6, "exponent": 5.0})
    si = _si(mi, dr, [[0, 0, 1]])
    kd = _np(bsdf.eval_diffuse_reflectance(si))[0]
    np.testing.assert_allclose(kd, [0.8 / 1.4, 0.2, 0.5 / 1.1], rtol=1e-6)
    rng = np.random.default_rng(4)
    wi, wo = _unit(rng, 500, True), _unit(rng, 500, True)
    got = _np(bsdf.eval(mi.BSDFContext(), _si(mi, dr, wi), _vec(mi, wo)))
    ref = _phong_reference(wi.astype(float), wo.astype(float), [0.8, 0.2, 0.5], [0.6] * 3, 5.0)
    np.testing.assert_allclose(got, ref, rtol=2e-4, atol=1e-6)


# ------------------------------------------------------------ energy tests
def _albedo_quadrature(bsdf, mi, dr, wi, n_theta=400, n_phi=400):
    """Integral of eval (which includes cos theta_o) over the hemisphere, midpoint rule."""
    theta = (np.arange(n_theta) + 0.5) * (np.pi / 2) / n_theta
    phi = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    t, p = np.meshgrid(theta, phi, indexing="ij")
    wo = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    dw = (np.sin(t) * (np.pi / 2 / n_theta) * (2 * np.pi / n_phi)).reshape(-1)
    si = _si(mi, dr, np.tile(np.asarray(wi, np.float32), (len(wo), 1)))
    f = _np(bsdf.eval(mi.BSDFContext(), si, _vec(mi, wo)))
    return (f * dw[:, None]).sum(axis=0)


def _albedo_sampled(bsdf, mi, dr, wi, n=200_000, seed=0):
    rng = np.random.default_rng(seed)
    si = _si(mi, dr, np.tile(np.asarray(wi, np.float32), (n, 1)))
    s1 = mi.Float(rng.random(n).astype(np.float32))
    s2 = mi.Point2f(rng.random(n).astype(np.float32), rng.random(n).astype(np.float32))
    _, w = bsdf.sample(mi.BSDFContext(), si, s1, s2)
    w = _np(w)
    assert np.all(np.isfinite(w))
    return w.mean(axis=0), w.std(axis=0) / math.sqrt(n)


def test_lambert_white_furnace_weights(mi, dr):
    bsdf = mi.load_dict({"type": "lambert", "reflectance": 1.0})
    for angle in ANGLES:
        mean, _ = _albedo_sampled(bsdf, mi, dr, _wi(angle), n=10_000)
        np.testing.assert_allclose(mean, 1.0, atol=1e-6)
        np.testing.assert_allclose(_albedo_quadrature(bsdf, mi, dr, _wi(angle)), 1.0, atol=1e-3)


def test_lambert_white_furnace_render(mi):
    """A reflectance-1 lambert sphere in a radiance-1 environment is invisible (L = 1)."""
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 8},
        "sensor": {"type": "perspective", "fov": 30,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 24, "height": 24, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": 256}},
        "sphere": {"type": "sphere", "bsdf": {"type": "lambert", "reflectance": 1.0}},
        "env": {"type": "constant", "radiance": {"type": "rgb", "value": 1.0}},
    })
    img = np.asarray(mi.render(scene, seed=1))[..., :3]
    assert abs(img.mean() - 1.0) < 1e-3
    assert np.abs(img - 1.0).max() < 0.05


@pytest.mark.parametrize("exponent", [0.0, 1.0, 10.0, 100.0, 1e4])
def test_phong_never_reflects_more_than_arrives(mi, dr, exponent):
    bsdf = mi.load_dict({"type": "phong", "diffuse_reflectance": 0.3, "specular_reflectance": 0.7,
                         "exponent": exponent})
    for angle in [0.0, 30.0, 60.0, 85.0, 89.9]:
        mean, err = _albedo_sampled(bsdf, mi, dr, _wi(angle))
        assert np.all(mean <= 1.0 + 4 * err + 1e-6), (angle, mean)


@pytest.mark.parametrize("exponent", [1.0, 10.0, 50.0])
def test_phong_normal_incidence_albedo_is_ks(mi, dr, exponent):
    """Energy normalisation (n + 2) / (2 pi): the lobe reflects exactly Ks at normal incidence."""
    bsdf = mi.load_dict({"type": "phong", "diffuse_reflectance": 0.0, "specular_reflectance": 1.0,
                         "exponent": exponent})
    np.testing.assert_allclose(_albedo_quadrature(bsdf, mi, dr, [0, 0, 1]), 1.0, atol=2e-3)
    mean, err = _albedo_sampled(bsdf, mi, dr, [0, 0, 1])
    np.testing.assert_allclose(mean, 1.0, atol=5 * err.max() + 1e-4)
    # and less than Ks away from normal incidence (the horizon clips the lobe)
    assert np.all(_albedo_quadrature(bsdf, mi, dr, _wi(80.0)) < 0.999)


# ----------------------------------------------------------- stiff cases
@pytest.mark.parametrize("exponent", [0.0, 1e4, 1e6])
def test_phong_extreme_exponents_are_finite(mi, dr, exponent):
    rng = np.random.default_rng(5)
    n = 20000
    wi, wo = _unit(rng, n), _unit(rng, n)
    wi[:10] = [0, 0, 1]                       # normal incidence
    wi[10:20, 2] = 1e-7                       # grazing
    wo[:20] = wi[:20] * np.array([-1, -1, 1], dtype=np.float32)   # exactly the mirror direction
    bsdf = mi.load_dict({"type": "phong", "diffuse_reflectance": 0.2, "specular_reflectance": 0.8,
                         "exponent": exponent})
    ctx, si, wo_v = mi.BSDFContext(), _si(mi, dr, wi), _vec(mi, wo)
    value, pdf = bsdf.eval_pdf(ctx, si, wo_v)
    s1 = mi.Float(rng.random(n).astype(np.float32))
    s2 = mi.Point2f(rng.random(n).astype(np.float32), rng.random(n).astype(np.float32))
    bs, weight = bsdf.sample(ctx, si, s1, s2)
    for arr in (value, pdf, weight, bs.wo, bs.pdf):
        assert np.all(np.isfinite(_np(arr)))
    assert np.all(_np(value) >= 0) and np.all(_np(pdf) >= 0)
    if exponent == 0.0:
        # n = 0: the specular lobe is the constant Ks / pi on the hemisphere about the mirror direction
        v = _np(value)[30:, 0]
        w_i, w_o = wi[30:].astype(float), wo[30:].astype(float)
        cos_a = np.sum(w_i * np.array([-1, -1, 1]) * w_o, axis=1)
        up = (w_i[:, 2] > 0) & (w_o[:, 2] > 0) & (np.abs(cos_a) > 1e-4)
        expected = (0.2 + 0.8 * (cos_a > 0)) / np.pi * w_o[:, 2]
        np.testing.assert_allclose(v[up], expected[up], rtol=1e-5)
    else:
        # at the mirror direction at normal incidence: Kd/pi + Ks (n+2)/(2 pi)
        np.testing.assert_allclose(_np(value)[:10], 0.2 / np.pi + 0.8 * (exponent + 2) / (2 * np.pi), rtol=1e-4)


def test_normals_facing_away_are_black(mi, dr):
    rng = np.random.default_rng(6)
    wi = _unit(rng, 1000)
    wi[:, 2] = -np.abs(wi[:, 2])
    wi[:10] = [0, 0, -1]
    wo = _unit(rng, 1000, True)
    for params in ({"type": "lambert"}, {"type": "phong", "exponent": 0.0}, {"type": "phong"}):
        bsdf = mi.load_dict(params)
        ctx, si, wo_v = mi.BSDFContext(), _si(mi, dr, wi), _vec(mi, wo)
        assert np.all(_np(bsdf.eval(ctx, si, wo_v)) == 0)
        assert np.all(_np(bsdf.pdf(ctx, si, wo_v)) == 0)
        _, w = bsdf.sample(ctx, si, mi.Float(0.3), mi.Point2f(0.4, 0.7))
        assert np.all(_np(w) == 0)


def test_textures_are_evaluated(mi, dr):
    checker = {"type": "checkerboard", "color0": {"type": "rgb", "value": [0.1, 0.2, 0.3]},
               "color1": {"type": "rgb", "value": [0.9, 0.8, 0.7]}}
    bsdf = mi.load_dict({"type": "lambert", "reflectance": checker})
    phong = mi.load_dict({"type": "phong", "diffuse_reflectance": checker, "specular_reflectance": 0.0})
    tex = mi.load_dict(checker)
    si = _si(mi, dr, [[0, 0, 1]] * 4)
    si.uv = mi.Point2f([0.25, 0.75, 0.25, 0.75], [0.25, 0.25, 0.75, 0.75])
    expected = _np(tex.eval(si))
    np.testing.assert_allclose(_np(bsdf.eval_diffuse_reflectance(si)), expected)
    np.testing.assert_allclose(_np(phong.eval_diffuse_reflectance(si)), expected)
    assert len(np.unique(expected[:, 0])) == 2
    assert mi.has_flag(bsdf.flags(), mi.BSDFFlags.SpatiallyVarying)


def test_flags_and_traversal(mi):
    lamb = mi.load_dict({"type": "lambert"})
    phong = mi.load_dict({"type": "phong"})
    assert mi.has_flag(lamb.flags(), mi.BSDFFlags.DiffuseReflection)
    assert not mi.has_flag(lamb.flags(), mi.BSDFFlags.Glossy)
    assert phong.component_count() == 2
    assert mi.has_flag(phong.flags(), mi.BSDFFlags.GlossyReflection)
    params = mi.traverse(phong)
    assert "exponent.value" in params and "diffuse_reflectance.value" in params


@pytest.mark.parametrize("params, word", [
    ({"type": "lambert", "reflectance": -0.1}, "reflectance"),
    ({"type": "lambert", "reflectance": [0.2, 1.5, 0.1]}, "reflectance"),
    ({"type": "lambert", "reflectance": float("nan")}, "reflectance"),
    ({"type": "phong", "exponent": -1.0}, "exponent"),
    ({"type": "phong", "specular_reflectance": -0.5}, "specular_reflectance"),
    ({"type": "phong", "exponent": [1.0, 2.0, 3.0]}, "exponent"),
])
def test_bad_parameters_are_rejected(mi, params, word):
    with pytest.raises(Exception, match=word):
        mi.load_dict(params)


def _phong_eval_sum(mi, dr, bsdf, wi, wo):
    value = bsdf.eval(mi.BSDFContext(), _si(mi, dr, wi), _vec(mi, wo))
    return dr.sum(value.x + value.y + value.z)


@pytest.mark.parametrize("key, base, step", [
    ("exponent.value", 12.0, 1e-2),
    ("diffuse_reflectance.value", [0.3, 0.2, 0.1], 1e-3),
    ("specular_reflectance.value", [0.4, 0.35, 0.3], 1e-3),
])
def test_phong_parameters_are_differentiable_and_their_gradients_are_differences(mi, dr, key, base, step):
    """Every continuous phong parameter is flagged differentiable, and forward-mode AD of eval
    matches central differences (the exponent's too: it was flagged non-differentiable)."""
    rng = np.random.default_rng(11)
    wi, wo = _unit(rng, 400), _unit(rng, 400)
    wo[:100] = wi[:100] * np.array([-1, -1, 1], dtype=np.float32)   # near the lobe's peak
    wo[100:200] = 0.9 * wo[100:200] + 0.1 * wi[100:200] * np.array([-1, -1, 1], dtype=np.float32)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    bsdf = mi.load_dict({"type": "phong", "exponent": 12.0, "diffuse_reflectance": [0.3, 0.2, 0.1],
                         "specular_reflectance": [0.4, 0.35, 0.3]})
    params = mi.traverse(bsdf)
    assert params.flags(key) & int(mi.ParamFlags.NonDifferentiable) == 0
    value = params[key]
    dr.enable_grad(value)
    params.update()
    total = _phong_eval_sum(mi, dr, bsdf, wi, wo)
    dr.set_grad(value, type(value)(1.0))   # a colour: along (1, 1, 1)
    dr.forward_to(total)
    grad = float(dr.grad(total)[0])

    def at(shift):
        fresh = mi.load_dict({"type": "phong", "exponent": 12.0, "diffuse_reflectance": [0.3, 0.2, 0.1],
                              "specular_reflectance": [0.4, 0.35, 0.3]})
        p = mi.traverse(fresh)
        b = np.asarray(base, dtype=np.float64) + shift
        p[key] = type(p[key])(*b.tolist()) if np.ndim(b) else type(p[key])(float(b))
        p.update()
        return float(_phong_eval_sum(mi, dr, fresh, wi, wo)[0])

    difference = (at(step) - at(-step)) / (2 * step)
    assert abs(grad) > 1e-3
    assert grad == pytest.approx(difference, rel=2e-3)


def test_phong_rescale_derivative_at_the_kink_is_the_one_from_below(mi, dr):
    """At Kd + Ks = 1 exactly the rescale has a kink: the documented derivative is the one-sided
    one from below (unscaled branch), not the one from above (where Kd + Ks are divided by their sum)."""
    rng = np.random.default_rng(12)
    wi, wo = _unit(rng, 300), _unit(rng, 300)

    def bsdf_at(kd):
        return mi.load_dict({"type": "phong", "exponent": 8.0, "diffuse_reflectance": [kd, 0.5, 0.5],
                             "specular_reflectance": [0.25, 0.25, 0.25]})

    bsdf = bsdf_at(0.75)                                     # red: 0.75 + 0.25 = 1 exactly
    params = mi.traverse(bsdf)
    value = params["diffuse_reflectance.value"]
    dr.enable_grad(value)
    params.update()
    total = _phong_eval_sum(mi, dr, bsdf, wi, wo)
    dr.set_grad(value, type(value)(1.0, 0.0, 0.0))
    dr.forward_to(total)
    grad = float(dr.grad(total)[0])
    f = {kd: float(_phong_eval_sum(mi, dr, bsdf_at(kd), wi, wo)[0]) for kd in (0.74, 0.75, 0.76)}
    below, above = (f[0.75] - f[0.74]) / 0.01, (f[0.76] - f[0.75]) / 0.01
    assert abs(below - above) > 0.1 * abs(below)             # a real kink
    assert grad == pytest.approx(below, rel=1e-3)
