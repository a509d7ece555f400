"""Tests of the ``whitted`` integrator.

Evidence: agreement with Mitsuba's ``path`` (max_depth 2 on diffuse scenes with
point lights: same camera rays, so equal up to rounding; within noise for area
and environment lights and for every built-in BSDF kind), analytic results
(two emitting mirrors: L = E (max_depth + 1); rays trapped by total internal
reflection in a glass sphere: L = E sum F^k with F from ``mi.fresnel``), and the
stiff cases (max_depth 0 and 50, 1e5 translation, 1e-4 scale, grazing: the ray offsets of the
documentation's ``conventions-rendering``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

RES = 32


def _look_at(mi, origin, target, up=(0, 1, 0)):
    return mi.ScalarTransform4f().look_at(origin=list(origin), target=list(target), up=list(up))


def _sensor(mi, origin=(0, 1.5, 5), target=(0, 0.5, 0), res=RES, spp=16, fov=40):
    return {"type": "perspective", "fov": fov, "to_world": _look_at(mi, origin, target),
            "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
            "sampler": {"type": "independent", "sample_count": spp}}


def _diffuse_scene(mi, integrator, *, floor_bsdf=None, sphere_bsdf=None, lights=None, transform=None,
                   spp=16, res=RES, extra=None):
    """A sphere over a floor: the small test scene. ``transform`` moves everything (camera included)."""
    T = transform if transform is not None else mi.ScalarTransform4f()
    origin, target = T @ mi.ScalarPoint3f(0, 1.5, 5), T @ mi.ScalarPoint3f(0, 0.5, 0)
    up = T @ mi.ScalarVector3f(0, 1, 0)
    sensor = _sensor(mi, res=res, spp=spp)
    scale = math.sqrt(sum(float(x) ** 2 for x in T @ mi.ScalarVector3f(1, 0, 0)))
    sensor["near_clip"] = 1e-2 * scale
    sensor["to_world"] = mi.ScalarTransform4f().look_at(origin=origin, target=target, up=dr_normalize(up))
    scene = {
        "type": "scene",
        "integrator": integrator,
        "sensor": sensor,
        "floor": {"type": "rectangle",
                  "to_world": T @ mi.ScalarTransform4f().rotate([1, 0, 0], -90).scale(4),
                  "bsdf": floor_bsdf or {"type": "lambert", "reflectance": {
                      "type": "checkerboard", "to_uv": mi.ScalarTransform4f().scale([6, 6, 1])}}},
        "ball": {"type": "sphere", "to_world": T @ mi.ScalarTransform4f().translate([0.3, 0.7, 0]).scale(0.7),
                 "bsdf": sphere_bsdf or {"type": "diffuse",
                                         "reflectance": {"type": "rgb", "value": [0.7, 0.3, 0.2]}}},
    }
    if lights is None:
        lights = {"light": {"type": "point", "position": [2.0, 4.0, 3.0],
                            "intensity": {"type": "rgb", "value": [30.0, 28.0, 25.0]}}}
    for name, light in lights.items():
        light = dict(light)
        if "position" in light:
            light["position"] = list(T @ mi.ScalarPoint3f(*light["position"]))
        scene[name] = light
    scene.update(extra or {})
    return mi.load_dict(scene)


def dr_normalize(v):
    n = math.sqrt(sum(float(x) ** 2 for x in v))
    return [float(x) / n for x in v]


def _render(mi, scene, spp=None, seed=0):
    kwargs = {"seed": seed}
    if spp:
        kwargs["spp"] = spp
    return np.asarray(mi.render(scene, **kwargs))[..., :3].astype(np.float64)


def _blocks(img, k=8):
    h, w, c = img.shape
    return img.reshape(h // k, k, w // k, k, c).mean(axis=(1, 3))


# ----------------------------------------------------------- versus path
def test_diffuse_point_light_equals_path_max_depth_2(mi):
    """Diffuse surfaces + point lights: Whitted is exactly path at max_depth 2 (same camera rays)."""
    for sphere in ({"type": "diffuse"}, {"type": "lambert", "reflectance": 0.6},
                   {"type": "phong", "exponent": 20.0}):
        ours = _render(mi, _diffuse_scene(mi, {"type": "whitted"}, sphere_bsdf=sphere), seed=7)
        ref = _render(mi, _diffuse_scene(mi, {"type": "path", "max_depth": 2}, sphere_bsdf=sphere), seed=7)
        assert ours.mean() > 0.05
        np.testing.assert_allclose(ours, ref, rtol=1e-4, atol=1e-5)


def test_area_and_environment_light_agree_with_path(mi):
    lights = {"area": {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([-1, 3, 1])
                       .rotate([1, 0, 0], 90).scale(0.5),
                       "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [12.0, 12.0, 10.0]}}},
              "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.3, 0.35, 0.5]}},
              "sun": {"type": "directional", "direction": [-0.3, -1, -0.4],
                      "irradiance": {"type": "rgb", "value": [1.5, 1.4, 1.2]}},
              "spot": {"type": "spot", "to_world": mi.ScalarTransform4f().look_at(
                  origin=[1.5, 3, 2], target=[0, 0, 0], up=[0, 1, 0]), "cutoff_angle": 30.0,
                  "intensity": {"type": "rgb", "value": [20.0, 20.0, 20.0]}}}
    ours = _render(mi, _diffuse_scene(mi, {"type": "whitted"}, lights=lights, spp=128), seed=1)
    ref = _render(mi, _diffuse_scene(mi, {"type": "path", "max_depth": 2}, lights=lights, spp=512), seed=2)
    assert abs(ours.mean() / ref.mean() - 1) < 0.01
    np.testing.assert_allclose(_blocks(ours), _blocks(ref), rtol=0.04, atol=0.01)


@pytest.mark.parametrize("bsdf, depth", [
    ({"type": "plastic"}, 1),
    ({"type": "roughplastic", "alpha": 0.2}, 1),
    ({"type": "conductor", "material": "Au"}, 1),
    ({"type": "roughconductor", "alpha": 0.3}, 1),
    ({"type": "dielectric"}, 8),
    ({"type": "thindielectric"}, 8),
    ({"type": "phong", "exponent": 10.0, "specular_reflectance": 0.5}, 1),
])
def test_any_mitsuba_bsdf_agrees_with_path(mi, bsdf, depth):
    """A convex object in a constant sky + point light: Whitted(max_depth=d) == path(max_depth=d+1)."""
    def scene(integrator):
        return mi.load_dict({
            "type": "scene", "integrator": integrator,
            "sensor": _sensor(mi, origin=(0, 0, 4), target=(0, 0, 0), fov=35, spp=64),
            "ball": {"type": "sphere", "bsdf": bsdf},
            "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.4, 0.5, 0.6]}},
            "light": {"type": "point", "position": [2, 3, 3], "intensity": {"type": "rgb", "value": 10.0}},
        })
    ours = _render(mi, scene({"type": "whitted", "max_depth": depth}), spp=128, seed=3)
    ref = _render(mi, scene({"type": "path", "max_depth": depth + 1, "rr_depth": 100}), spp=512, seed=4)
    assert np.all(np.isfinite(ours))
    assert abs(ours.mean() / ref.mean() - 1) < 0.015
    np.testing.assert_allclose(_blocks(ours), _blocks(ref), rtol=0.05, atol=0.01)


# ------------------------------------------------------- recursion cut-off
def _two_mirrors(mi, integrator, emit=1.0, reflect=1.0):
    """Two facing emissive perfect mirrors, an orthographic camera looking straight at one."""
    mirror = {"type": "conductor", "material": "none",
              "specular_reflectance": {"type": "rgb", "value": reflect}}
    emitter = {"type": "area", "radiance": {"type": "rgb", "value": emit}}
    return mi.load_dict({
        "type": "scene", "integrator": integrator,
        "sensor": {"type": "orthographic",
                   "to_world": _look_at(mi, (0, 0, 0), (0, 0, -1)) @ mi.ScalarTransform4f().scale([0.5, 0.5, 1]),
                   "film": {"type": "hdrfilm", "width": 4, "height": 4, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": 4}},
        # mirror A at z = -1 facing +z, mirror B at z = +1 facing -z
        "a": {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, 0, -1]).scale(10),
              "bsdf": mirror, "emitter": emitter},
        "b": {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, 0, 1])
              .rotate([1, 0, 0], 180).scale(10), "bsdf": mirror, "emitter": emitter},
    })


@pytest.mark.parametrize("max_depth", [0, 1, 2, 5, 50])
def test_two_mirrors_stop_exactly_at_max_depth(mi, max_depth):
    ours = _render(mi, _two_mirrors(mi, {"type": "whitted", "max_depth": max_depth}))
    # every vertex of the mirror chain adds E = 1: max_depth + 1 of them
    np.testing.assert_allclose(ours, max_depth + 1, rtol=1e-5)
    ref = _render(mi, _two_mirrors(mi, {"type": "path", "max_depth": max_depth + 1, "rr_depth": 1000}))
    np.testing.assert_allclose(ours, ref, rtol=1e-5)


def test_mirror_reflectance_geometric_series(mi):
    r, m = 0.5, 6
    ours = _render(mi, _two_mirrors(mi, {"type": "whitted", "max_depth": m}, emit=2.0, reflect=r))
    np.testing.assert_allclose(ours, 2.0 * (1 - r ** (m + 1)) / (1 - r), rtol=1e-5)


def test_max_depth_zero_shows_only_emitters(mi):
    lights = {"area": {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, 0.7, 0.8])
                       .scale(0.4), "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 5.0}}},
              "point": {"type": "point", "position": [2.0, 4.0, 3.0]}}
    ours = _render(mi, _diffuse_scene(mi, {"type": "whitted", "max_depth": 0, "ambient": 0.5},
                                      lights=lights, spp=8), seed=2)
    ref = _render(mi, _diffuse_scene(mi, {"type": "path", "max_depth": 1}, lights=lights, spp=8), seed=2)
    assert ours.max() > 1.0                    # the area light is in view
    assert np.count_nonzero(ours.sum(-1) == 0) > 0.5 * RES * RES   # everything else is black
    np.testing.assert_allclose(ours, ref, rtol=1e-5, atol=1e-6)


# ------------------------------------------------- total internal reflection
def test_total_internal_reflection_preserves_energy(mi, dr):
    """Camera inside an emissive glass sphere (normals flipped inward, so the glass is the
    "exterior": ext_ior 1.5, int_ior 1). A ray keeps one incidence angle inside a sphere, so
    every vertex adds E and the path continues with probability F(theta): the expected value
    is E (1 - F^(M+1)) / (1 - F); under TIR (F = 1) it is exactly E (M + 1), with no noise.
    """
    E, M, eta = 1.0, 6, 1.5
    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": "whitted", "max_depth": M},
        "glass": {"type": "sphere", "radius": 1.0, "flip_normals": True,
                  "bsdf": {"type": "dielectric", "int_ior": 1.0, "ext_ior": eta},
                  "emitter": {"type": "area", "radiance": {"type": "rgb", "value": E}}},
    })
    n_angles, reps = 64, 4096
    # rays from (0.5, 0, 0) in the xy-plane at angles covering the full range of incidence
    angles = np.linspace(0.01, np.pi - 0.01, n_angles)
    ang = np.repeat(angles, reps)
    o = np.array([0.85, 0.0, 0.0])
    d = np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], -1)
    ray = mi.Ray3f(mi.Point3f(*[np.full(len(ang), v, np.float32) for v in o]),
                   mi.Vector3f(*[d[:, i].astype(np.float32) for i in range(3)]))
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(5, len(ang))
    from pointillist.plugins.integrators._common import sample_radiance
    L, valid, _ = sample_radiance(scene.integrator(), scene, sampler, ray)
    L = np.asarray(L)[:, 0] if np.asarray(L).shape[0] == len(ang) else np.asarray(L)[0]
    L = L.reshape(n_angles, reps)
    assert np.all(np.asarray(valid))
    # incidence angle from the impact parameter b = |o x d|, sin(theta) = b / R
    b = np.abs(o[0] * np.sin(angles))
    cos_t = np.sqrt(1 - b ** 2)
    F = np.asarray(mi.fresnel(mi.Float(cos_t.astype(np.float32)), mi.Float(1.0 / eta))[0], np.float64)
    expected = np.where(F >= 1, E * (M + 1), E * (1 - F ** (M + 1)) / np.maximum(1 - F, 1e-12))
    # F(theta) is steep at the critical angle: leave out a margin where float32 normals decide
    near = np.abs(b - 1 / eta) < 5e-3
    tir = (b > 1 / eta) & ~near
    partial = (b < 1 / eta) & ~near
    assert tir.sum() > 5 and partial.sum() > 5
    # TIR: exact, every sample
    np.testing.assert_allclose(L[tir], E * (M + 1), rtol=1e-5)
    # partial reflection: right in expectation
    mean, err = L.mean(axis=1), L.std(axis=1) / math.sqrt(reps)
    assert np.all(np.abs(mean - expected)[partial] <= 5 * err[partial] + 1e-3)


# ------------------------------------------------------- stiff / extreme cases
@pytest.mark.parametrize("transform", ["translate", "scale"])
def test_far_and_tiny_scenes_have_no_acne(mi, transform):
    """The test scene moved to 1e5 or shrunk to 1e-4, all of it (camera and light too).

    Self-intersection acne would speckle lit surfaces with self-shadowing. A lit floor on
    its own must render as before. With the sphere, whitted's offsets come from error
    bounds of each hit (tests/test_stiff.py has the full set of scales), so it
    changes fewer pixels than Mitsuba's ``path``, whose ``(1 + max|p|) RayEpsilon`` offsets
    are 9e-5 at the scale of 1e-4 and 9 far from the origin (path at scale 1 renders this
    scene exactly as whitted does).
    """
    if transform == "translate":
        T, power = mi.ScalarTransform4f().translate([1e5, -1e5, 1e5]), 1.0
    else:
        T, power = mi.ScalarTransform4f().scale(1e-4), 1e-8     # I / d^2 stays the same

    def lights(p):
        return {"light": {"type": "point", "position": [2.0, 4.0, 3.0],
                          "intensity": {"type": "rgb", "value": 30.0 * p}}}

    far = {"ball": {"type": "sphere", "center": [0, -50, 0], "radius": 0.1}}   # out of the way
    ref = _render(mi, _diffuse_scene(mi, {"type": "whitted"}, lights=lights(1.0), extra=far), seed=4)
    far = {"ball": {"type": "sphere", "to_world": T @ mi.ScalarTransform4f().translate([0, -50, 0]).scale(0.1)}}
    moved = _render(mi, _diffuse_scene(mi, {"type": "whitted"}, lights=lights(power), transform=T,
                                       extra=far), seed=4)
    assert ref.mean() > 0.02 and np.all(np.isfinite(moved))
    lit = ref.sum(-1) > 0
    assert np.all(moved.sum(-1)[lit] > 0)                   # no black speckles
    np.testing.assert_allclose(moved.mean(), ref.mean(), rtol=0.01)
    assert (np.abs(moved - ref).max(-1) > 0.05 * ref.max()).mean() < 0.01

    ref = _render(mi, _diffuse_scene(mi, {"type": "whitted"}, lights=lights(1.0)), seed=4)
    moved = _render(mi, _diffuse_scene(mi, {"type": "whitted"}, lights=lights(power), transform=T), seed=4)
    path = _render(mi, _diffuse_scene(mi, {"type": "path", "max_depth": 2}, lights=lights(power),
                                      transform=T), seed=4)
    path_ref = _render(mi, _diffuse_scene(mi, {"type": "path", "max_depth": 2}, lights=lights(1.0)), seed=4)
    np.testing.assert_allclose(ref, path_ref, rtol=1e-4, atol=1e-6)

    def changed(img):
        return (np.abs(img - ref).max(-1) > 0.05 * ref.max()).mean()

    # measured: whitted 0.2 % (translated) and 0 % (scaled); Mitsuba 3.9.1 path 2.9 % and 3.2 %
    assert changed(moved) < 0.005
    assert changed(moved) <= changed(path)


def test_hide_emitters_and_ambient(mi):
    lights = {"sky": {"type": "constant", "radiance": {"type": "rgb", "value": 0.5}}}
    shown = _render(mi, _diffuse_scene(mi, {"type": "whitted"}, lights=lights), seed=1)
    hidden = _render(mi, _diffuse_scene(mi, {"type": "whitted", "hide_emitters": True}, lights=lights), seed=1)
    # the fraction of each pixel's camera rays that miss: path at max_depth 1 under a unit sky
    # (camera rays depend only on the seed, so these are the same rays)
    miss = _render(mi, _diffuse_scene(mi, {"type": "path", "max_depth": 1}, lights={
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": 1.0}}}), seed=1)
    assert (miss == 1).any() and (miss == 0).any()
    np.testing.assert_allclose(shown - hidden, 0.5 * miss, atol=1e-5)
    assert np.all(hidden[miss == 1] == 0) and hidden[miss == 0].mean() > 0.05

    # ambient only (no emitters): L = ambient x diffuse reflectance, exactly
    amb = _render(mi, _diffuse_scene(mi, {"type": "whitted", "ambient": [0.5, 1.0, 2.0]}, lights={},
                                     sphere_bsdf={"type": "phong", "diffuse_reflectance": [0.5, 0.4, 0.2]},
                                     floor_bsdf={"type": "lambert", "reflectance": 0.3}))
    values = {tuple(np.round(v, 5)) for v in amb.reshape(-1, 3)}
    assert (0.15, 0.3, 0.6) in values                       # floor: 0.3 * ambient
    mixed = values - {(0.15, 0.3, 0.6), (0.0, 0.0, 0.0), (0.25, 0.4, 0.4)}
    # pixels straddling an edge are averages; all values stay within the two pure ones
    assert all(0 <= v[0] <= 0.25 + 1e-6 for v in mixed)
    assert (0.25, 0.4, 0.4) in values                       # sphere: Kd * ambient


def test_grazing_rays_are_finite(mi, dr):
    scene = _diffuse_scene(mi, {"type": "whitted"}, sphere_bsdf={"type": "dielectric"})
    n = 2000
    x = np.linspace(-3, 3, n).astype(np.float32)
    # rays skimming the floor (y = 1e-6) and tangent to the sphere's top (y = 1.4)
    for y in (1e-6, 1.4):
        ray = mi.Ray3f(mi.Point3f(x, np.full(n, y, np.float32), np.full(n, 5.0, np.float32)),
                       mi.Vector3f(0.0, 0.0, -1.0))
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(0, n)
        from pointillist.plugins.integrators._common import sample_radiance
        L, _, _ = sample_radiance(scene.integrator(), scene, sampler, ray)
        assert np.all(np.isfinite(np.asarray(L)))
        assert np.asarray(L).min() >= 0


# --------------------------------------------- leave out what is not needed
def _kernel_ops(mi, dr, scene, integrator=None):
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()
    img = mi.render(scene, integrator=integrator, seed=0)
    dr.eval(img)
    dr.sync_thread()
    hist = dr.kernel_history()
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    return np.asarray(img), max(k.get("operation_count", 0) for k in hist)


def test_scene_inspection_shrinks_the_kernel(mi, dr):
    from pointillist.plugins.integrators.whitted import inspect_scene

    diffuse = _diffuse_scene(mi, {"type": "whitted"})
    glass = _diffuse_scene(mi, {"type": "whitted"}, sphere_bsdf={"type": "dielectric"})
    f = inspect_scene(diffuse)
    assert not f.reflection and not f.transmission and len(f.emitters) == 1
    g = inspect_scene(glass)
    assert g.reflection and g.transmission
    m = inspect_scene(_diffuse_scene(mi, {"type": "whitted"}, sphere_bsdf={"type": "conductor"}))
    assert m.reflection and not m.transmission
    dark = inspect_scene(_diffuse_scene(mi, {"type": "whitted"}, lights={}))
    assert dark.emitters == () and not dark.emission

    general = mi.load_dict({"type": "whitted", "specialize": False})
    img_s, ops_s = _kernel_ops(mi, dr, diffuse)
    img_g, ops_g = _kernel_ops(mi, dr, diffuse, general)
    _, ops_glass = _kernel_ops(mi, dr, glass)
    _, ops_dark = _kernel_ops(mi, dr, _diffuse_scene(mi, {"type": "whitted"}, lights={}))
    np.testing.assert_allclose(img_s, img_g, rtol=1e-5, atol=1e-6)   # same image
    assert ops_s < 0.8 * ops_g           # measurably smaller without the recursion loop
    assert ops_s < ops_glass
    assert ops_dark < ops_s              # no shadow rays without emitters


@pytest.mark.parametrize("props, word", [
    ({"max_depth": -1}, "max_depth"),
    ({"ambient": -0.5}, "ambient"),
    ({"ambient": [0.1, float("inf"), 0.1]}, "ambient"),
    ({"specialize": 3}, "specialize"),
    ({"max_dpeth": 3}, "max_dpeth"),
    ({"max_depth": 2 ** 32}, "max_depth: expected an integer"),   # beyond the UInt32 depth counter
])
def test_bad_parameters_are_rejected(mi, props, word):
    with pytest.raises(Exception, match=word):
        mi.load_dict({"type": "whitted", **props})


# ------------------------------------------------------------------- scenes
@pytest.mark.parametrize("name", ["whitted.xml", "cornell_phong.xml", "default.xml"])
def test_project_scenes_render(mi, name):
    from pointillist.scene import load_scene
    from tests.conftest import SCENES

    scene = load_scene(SCENES / name, {"res": "32", "spp": "2", "integrator": "whitted"})
    img = _render(mi, scene)
    assert img.shape == (32, 32, 3) and np.all(np.isfinite(img)) and img.mean() > 0.02


@pytest.mark.parametrize("name", ["whitted.xml", "cornell_phong.xml", "default.xml", "edges.xml"])
def test_scene_parameters_in_the_header_are_accepted(mi, name):
    """Every parameter a scene's header comment lists ("Parameters (override with -D): ...")
    has a <default> and is accepted by ``-D`` (Mitsuba refuses unused parameters)."""
    import re

    from pointillist.scene import load_scene
    from tests.conftest import SCENES

    text = (SCENES / name).read_text()
    listed = re.search(r"Parameters \(override with -D\):([^.]*)\.", text)
    assert listed, f"{name}: no parameter list in the header"
    names = [p.strip() for p in listed.group(1).replace("\n", " ").split(",") if p.strip()]
    defaults = dict(re.findall(r'<default name="(\w+)" value="([^"]*)"', text))
    assert set(names) == set(defaults), name
    for param in names:
        params = {"res": "8", "spp": "1", param: defaults[param]}
        load_scene(SCENES / name, params)        # raises on an unknown / unused parameter


def test_an_integrator_outliving_its_scene_keeps_nothing_of_it(tmp_path):
    """An integrator object used on one scene, which is then freed, and a render of another scene:
    the integrator kept the first scene's emitters (SceneFeatures on ``self``) past their shapes,
    and the next trace of a virtual call to the emitters (Dr.Jit traces every registered emitter)
    read a freed shape and crashed the process. In a subprocess: a crash must fail the test, not
    the suite."""
    import subprocess
    import sys

    from conftest import ROOT

    script = tmp_path / "outlive.py"
    script.write_text(f"""
import gc, sys
sys.path.insert(0, {str(ROOT)!r})
import drjit as dr, numpy as np, pointillist
mi = pointillist.setup()
kept = mi.load_dict({{"type": "adaptive", "threshold": 20.0, "max_depth": 2, "nested": {{"type": "whitted"}}}})
first = mi.load_file({str(ROOT / "scenes" / "default.xml")!r}, res="48", spp="1")
np.asarray(mi.render(first, integrator=kept, seed=0))
del first
gc.collect()
second = mi.load_file({str(ROOT / "scenes" / "default.xml")!r}, res="48")
params = mi.traverse(second)
key = "ball.bsdf.diffuse_reflectance.value"
theta = mi.Float(0.0)
dr.enable_grad(theta)
params[key] = mi.Color3f(params[key]) + theta
params.update()
dr.forward(theta, dr.ADFlag.ClearEdges)
image = second.integrator().render_forward(second, theta, seed=1, spp=4)
print("ok", float(np.asarray(image).sum()) > 0)
""")
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, (done.returncode, done.stderr[-2000:])
    assert done.stdout.split()[-2:] == ["ok", "True"]
