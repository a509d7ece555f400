"""Stiff scenes: the same image whatever the scene's scale or distance from the origin.

One small scene (a Phong sphere, a mirror sphere, a glass sphere on a diffuse floor, one point
light, 80x80 at 4 spp, box filter, fixed seed) is scaled by 1e-6 .. 1e6 (camera, clip planes and
light included; the light's intensity by s^2, so irradiance is unchanged) or moved 1e3 from the
origin, and compared pixel by pixel with the scene at scale 1 rendered with the same seed: the
camera rays are then the same up to rounding, so any difference is numerical. Variants add a thin
sphere (radius 1e-3 of the scene's size) resting on the floor and a grazing light.

Evidence: the image at scale 1 (an independent rendering of the same rays), and Mitsuba's own
``path`` integrator on the same scenes (it offsets rays by ``(1 + max|p|) * 1500 * 2^-24``, so a
tiny scene's shadow and refraction rays start far off their surface: 19 % of pixels off at 1e-4
with Mitsuba 3.9.1, measured; a release with mitsuba3 pull request 1962, "A better ray epsilon",
should pass the same check, and ``test_mitsuba_path_at_small_scale`` will then show it). The
error bounds themselves: rays leaving spheres, rectangles, disks, meshes and cylinders at grazing
to normal angles, at radii 1e-5 .. 1e4, do not meet their own surface again.
"""

from __future__ import annotations

import numpy as np
import pytest

RES, SPP, SEED = 80, 4, 3
SCALES = (1e-6, 1e-4, 1e4, 1e6)
SHIFT = 1e3

#: Goal: fraction of pixels off by more than 1 %.
GOAL_SCALED, GOAL_MOVED = 0.005, 0.02


def stiff_scene(mi, integrator, *, scale: float = 1.0, shift: float = 0.0, thin: bool = False,
                grazing: bool = False, res: int = RES, spp: int = SPP):
    """The test scene scaled by ``scale`` about the origin, then moved by ``shift`` along (1, 1, 1).

    Floor: a diffuse rectangle 8 x 8 at y = 0; spheres of radius 0.5-0.6 resting on it (Phong,
    mirror, glass), camera 5.5 away (field of view 40 degrees). ``thin`` adds a sphere of radius 8e-3 (1e-3 of
    the scene's size, the floor's 8) resting on the floor 3.4 from the camera, and narrows the
    camera's view to 1.7 degrees around it (the sphere is 13 pixels wide; its contact with the
    floor and its shadow in view); ``grazing`` puts the point light 2 degrees above the floor's
    plane, far to the side, so the shadows are long and the floor is lit at grazing incidence.
    Light intensity scales with ``scale**2`` (unchanged irradiance).
    """
    T = mi.ScalarTransform4f().translate([shift] * 3) @ mi.ScalarTransform4f().scale(scale)

    def at(x, y, z):
        return T @ mi.ScalarPoint3f(x, y, z)

    def sphere(c, r, bsdf):
        return {"type": "sphere", "center": list(at(*c)), "radius": r * scale, "bsdf": bsdf}

    light_pos = (6.0, 0.2, 2.0) if grazing else (2.0, 4.0, 3.0)
    light_pow = 600.0 if grazing else 40.0
    thin_centre = (0.2, 8e-3, 2.5)
    scene = {
        "type": "scene",
        "integrator": integrator,
        "sensor": {"type": "perspective", "fov": 1.7 if thin else 40,
                   "near_clip": 1e-2 * scale, "far_clip": 1e3 * scale,
                   "to_world": mi.ScalarTransform4f().look_at(origin=at(0, 1.6, 5.5),
                                                              target=at(*(thin_centre if thin else (0, 0.4, 0))),
                                                              up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": spp}},
        "floor": {"type": "rectangle",
                  "to_world": T @ mi.ScalarTransform4f().rotate([1, 0, 0], -90).scale(4),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.6, 0.6, 0.55]}}},
        "phong": sphere((-1.2, 0.5, 0.2), 0.5, {"type": "phong", "exponent": 30.0,
                                                "diffuse_reflectance": [0.6, 0.2, 0.15],
                                                "specular_reflectance": 0.3}),
        "mirror": sphere((0.0, 0.6, -0.8), 0.6, {"type": "conductor", "material": "none"}),
        "glass": sphere((1.1, 0.5, 0.6), 0.5, {"type": "dielectric", "int_ior": 1.5}),
        "light": {"type": "point", "position": list(at(*light_pos)),
                  "intensity": {"type": "rgb", "value": light_pow * scale ** 2}},
    }
    if thin:
        scene["thin"] = sphere(thin_centre, 8e-3, {"type": "diffuse",
                                                        "reflectance": {"type": "rgb", "value": [0.2, 0.5, 0.8]}})
    return mi.load_dict(scene)


def render(mi, scene, seed: int = SEED) -> np.ndarray:
    """The rendered image as float64 (H, W, 3)."""
    return np.asarray(mi.render(scene, seed=seed))[..., :3].astype(np.float64)


def fraction_off(img: np.ndarray, ref: np.ndarray, rel: float = 0.01, floor: float = 1e-3) -> float:
    """Fraction of pixels where some channel differs from ``ref`` by more than ``rel`` (relative),
    with an absolute floor of ``floor`` times the reference image's mean."""
    tol = rel * np.abs(ref) + floor * ref.mean()
    return float(np.mean(np.any(np.abs(img - ref) > tol, axis=-1)))


def test_fraction_off_counts_pixels():
    ref = np.ones((4, 4, 3))
    img = ref.copy()
    img[0, 0, 1] = 1.02            # 2 % off in one channel: counted
    img[1, 1] = 1.005              # 0.5 % off: not counted
    img[2, 2, 0] = 0.0             # black: counted
    assert fraction_off(img, ref) == 2 / 16
    assert fraction_off(ref, ref) == 0.0


# ------------------------------------------------------------ error bounds
def test_gamma_and_magnitude(mi):
    from pointillist.plugins.integrators._offsets import gamma, magnitude

    u = 2.0 ** -24
    assert gamma(0) == 0.0
    assert gamma(8) == 8 * u / (1 - 8 * u)
    with pytest.raises(ValueError, match="^n: expected an integer >= 0, got -1$"):
        gamma(-1)
    for bad in (1.5, True):
        with pytest.raises(TypeError, match="^n: expected an integer, got "):
            gamma(bad)
    assert magnitude(mi.ScalarBoundingBox3f([-3, 0, 1], [2, 0.5, 1])) == 3.0
    assert magnitude(mi.ScalarBoundingBox3f()) == 0.0          # empty box


def test_shape_bounds_follow_the_shapes_magnitude(mi):
    from pointillist.plugins.integrators._offsets import ERROR_ULPS, ErrorBounds, gamma, shape_offset_scale

    sphere = mi.load_dict({"type": "sphere", "center": [0, -2e3, 5], "radius": 10.0})
    assert shape_offset_scale(sphere) == pytest.approx(gamma(ERROR_ULPS["Sphere"]) * 2010, rel=1e-6)
    rect = mi.load_dict({"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([1, 2, 3]).scale(0.5)})
    assert shape_offset_scale(rect) == pytest.approx(gamma(ERROR_ULPS["Rectangle"]) * 3.0, rel=1e-6)
    disk = mi.load_dict({"type": "disk", "to_world": mi.ScalarTransform4f().scale(1e-5)})
    assert shape_offset_scale(disk) == pytest.approx(gamma(ERROR_ULPS["Disk"]) * 1e-5, rel=1e-6)
    with pytest.raises(TypeError, match="scene: expected a mitsuba Scene"):
        ErrorBounds(sphere)


def _unit(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _vec(mi, a, cls):
    return cls(*[a[:, i].astype(np.float32) for i in range(3)])


def _leaving_rays(mi, kind, r, ratio, n, rng):
    """Hits on one shape (radius r, centre ratio * r from the origin) and two directions at each:
    back to the side the camera ray came from and through the surface, at angles from grazing
    (cos 1e-4) to normal. Returns (scene, si, valid, out, into, cos)."""
    c = _unit(rng, 1)[0] * ratio * r
    if kind == "sphere":
        shape = {"type": "sphere", "center": c.tolist(), "radius": r}
    else:
        shape = {"type": kind, "to_world": mi.ScalarTransform4f().translate(c.tolist())
                 @ mi.ScalarTransform4f().rotate(_unit(rng, 1)[0].tolist(), float(rng.uniform(0, 360)))
                 @ mi.ScalarTransform4f().scale(r)}
    scene = mi.load_dict({"type": "scene", "s": shape})
    aim = c + 0.6 * r * rng.uniform(-1, 1, (n, 3))
    o = (aim if kind in ("rectangle", "disk") else c) + 3 * r * _unit(rng, n)
    d = aim - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    si = scene.ray_intersect(mi.Ray3f(_vec(mi, o, mi.Point3f), _vec(mi, d, mi.Vector3f)))
    nrm = np.asarray(si.n)
    nrm = nrm.T if nrm.shape[0] == 3 else nrm
    cos = 10 ** rng.uniform(-4, 0, n)
    t = _unit(rng, n)
    t -= (t * nrm).sum(1, keepdims=True) * nrm
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    side = -np.sign((d * nrm).sum(1, keepdims=True))
    sin = np.sqrt(1 - cos ** 2)[:, None]
    out = side * cos[:, None] * nrm + sin * t
    into = -side * cos[:, None] * nrm + sin * t
    return scene, si, np.asarray(si.is_valid()), out, into, cos


@pytest.mark.parametrize("kind", ["sphere", "rectangle", "disk", "cube", "cylinder"])
@pytest.mark.parametrize("r", [1e-5, 1.0, 1e4])
def test_rays_leaving_a_surface_do_not_meet_it_again(mi, kind, r):
    """Rays leaving a hit at grazing to normal angles: to the side they came from they miss the
    (convex) shape (cylinder: its outside); through a plane they miss it; into a sphere they meet its far side at the
    chord length 2 r cos. Shapes of radius 1e-5 .. 1e4 at 0 .. 1e3 radii from the origin."""
    from pointillist.plugins.integrators._offsets import ErrorBounds

    rng = np.random.default_rng(21)
    for ratio in (0.0, 30.0, 1e3):
        scene, si, valid, out, into, cos = _leaving_rays(mi, kind, r, ratio, 3000, rng)
        if kind == "cylinder":        # open: only hits on its outside (convex there) count
            normal = np.asarray(si.n)
            valid &= (out * (normal.T if normal.shape[0] == 3 else normal)).sum(1) > 0
        assert valid.mean() > 0.25
        bounds = ErrorBounds(scene)
        leaving = bounds.spawn_ray(si, _vec(mi, out, mi.Vector3f), bounds.hit_offset(si))
        assert not np.any(np.asarray(scene.ray_test(leaving)) & valid), (kind, r, ratio)
        entering = bounds.spawn_ray(si, _vec(mi, into, mi.Vector3f), bounds.hit_offset(si))
        if kind in ("rectangle", "disk"):
            assert not np.any(np.asarray(scene.ray_test(entering)) & valid), (kind, r, ratio)
        # the origin moved off the surface by a few float32 roundings of the shape's size, no more
        moved = np.linalg.norm(np.asarray(leaving.o) - np.asarray(si.p), axis=0)[valid]
        assert moved.max() < 1e-5 * (ratio + 1) * r
        if kind == "sphere":
            # the far side: chord 2 r cos from the surface; the offset origin is moved / cos off that
            # along the ray (so a self-hit, t ~ 0, fails wherever the chord is longer than that)
            t = np.asarray(scene.ray_intersect(entering).t)[valid]
            chord = 2 * r * cos[valid]
            assert np.all(np.abs(t - chord) <= 0.01 * chord + 4 * moved / cos[valid]), (kind, r, ratio)
            if ratio < 100:                      # mostly a real check (far away, offsets are long)
                assert np.mean(chord > 100 * moved / cos[valid]) > 0.25     # cos is log-uniform


def test_offsets_scale_exactly_with_the_scene(mi):
    """Scaling by a power of two scales every float exactly: the spawned rays scale exactly too
    (no absolute floor). Mitsuba 3.9.1's own spawn_ray does not (its offset is 9e-5 below 1)."""
    from pointillist.plugins.integrators._offsets import ErrorBounds

    rays = {}
    for s in (1.0, 2.0 ** -20):
        scene = mi.load_dict({"type": "scene", "s": {"type": "sphere", "center": [0.25 * s, 0, 0], "radius": s}})
        rng = np.random.default_rng(5)
        o = _unit(rng, 64) * 3
        d = -o / 3
        si = scene.ray_intersect(mi.Ray3f(_vec(mi, o * s, mi.Point3f), _vec(mi, d, mi.Vector3f)))
        bounds = ErrorBounds(scene)
        ours = bounds.spawn_ray(si, si.n, bounds.hit_offset(si))
        theirs = si.spawn_ray(si.n)
        rays[s] = [np.asarray(ours.o), np.asarray(theirs.o) - np.asarray(si.p)]
    small = 2.0 ** -20
    np.testing.assert_array_equal(rays[small][0], rays[1.0][0] * small)
    # Mitsuba's offset: the same length (about 9e-5) at both scales
    np.testing.assert_allclose(np.linalg.norm(rays[small][1], axis=0), 1500 * 2.0 ** -24, rtol=0.01)


# ---------------------------------------------------------------- images
VARIANTS = {"main": {}, "thin": {"thin": True}, "grazing": {"thin": True, "grazing": True}}


@pytest.fixture(scope="module")
def references(mi):
    """Scale-1 whitted images of each variant (same seed as the stiff ones)."""
    return {name: render(mi, stiff_scene(mi, {"type": "whitted"}, **kw)) for name, kw in VARIANTS.items()}


@pytest.mark.parametrize("variant", list(VARIANTS))
@pytest.mark.parametrize("scale", SCALES)
def test_scaled_scene_renders_the_same_image(mi, references, variant, scale):
    ref = references[variant]
    assert ref.mean() > 0.03 and np.all(np.isfinite(ref))
    img = render(mi, stiff_scene(mi, {"type": "whitted"}, scale=scale, **VARIANTS[variant]))
    assert fraction_off(img, ref) <= GOAL_SCALED          # measured: 0 at every scale


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_moved_scene_renders_nearly_the_same_image(mi, references, variant):
    """1e3 from the origin float32 positions are 6e-5 apart: edges and the thin sphere move by that
    much, and a few pixels change (measured 0.1-0.2 %)."""
    img = render(mi, stiff_scene(mi, {"type": "whitted"}, shift=SHIFT, **VARIANTS[variant]))
    assert fraction_off(img, references[variant]) <= GOAL_MOVED


def test_whitted_no_worse_than_mitsuba_path(mi, references):
    """At scale 1e-4 and moved 1e3, whitted changes no more pixels than Mitsuba's ``path`` does
    (path's reference: path at scale 1; with max_depth 6 it follows the same delta chains)."""
    path = {"type": "path", "max_depth": 6}
    path_ref = render(mi, stiff_scene(mi, path))
    for kw in ({"scale": 1e-4}, {"shift": SHIFT}):
        ours = fraction_off(render(mi, stiff_scene(mi, {"type": "whitted"}, **kw)), references["main"])
        theirs = fraction_off(render(mi, stiff_scene(mi, path, **kw)), path_ref)
        assert ours <= theirs, kw


@pytest.mark.xfail(strict=False, reason="Mitsuba 3.9.1 offsets rays by (1 + max|p|) * 9e-5: 19 % of pixels off "
                   "at scale 1e-4 (measured); a release with mitsuba3 PR 1962 ('A better ray epsilon') "
                   "should pass, and this test then shows XPASS")
def test_mitsuba_path_at_small_scale(mi):
    path = {"type": "path", "max_depth": 6}
    ref = render(mi, stiff_scene(mi, path))
    assert fraction_off(render(mi, stiff_scene(mi, path, scale=1e-4)), ref) <= GOAL_SCALED


def test_many_emitters_and_area_lights_at_small_scale(mi):
    """More than MAX_UNROLLED_EMITTERS emitters (one chosen per hit, ``ds.emitter`` gathers the
    light's bound) and an area light close to the floor: shadow rays that end on a light's
    surface must reach it at any scale."""
    def scene(s):
        T = mi.ScalarTransform4f().scale(s)
        lights = {f"p{i}": {"type": "point", "position": list(T @ mi.ScalarPoint3f(-3 + 0.4 * i, 3.0, 2.0)),
                            "intensity": {"type": "rgb", "value": 3.0 * s * s}} for i in range(16)}
        lights["area"] = {"type": "rectangle", "to_world": T @ mi.ScalarTransform4f().translate([0.5, 0.05, 0.8])
                          .rotate([1, 0, 0], 90).scale(0.3),
                          "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 4.0}}}
        return mi.load_dict({
            "type": "scene", "integrator": {"type": "whitted"},
            "sensor": {"type": "perspective", "fov": 40, "near_clip": 1e-2 * s, "far_clip": 1e3 * s,
                       "to_world": mi.ScalarTransform4f().look_at(origin=T @ mi.ScalarPoint3f(0, 1.6, 5.5),
                                                                  target=T @ mi.ScalarPoint3f(0, 0.4, 0), up=[0, 1, 0]),
                       "film": {"type": "hdrfilm", "width": 40, "height": 40, "rfilter": {"type": "box"}},
                       "sampler": {"type": "independent", "sample_count": 4}},
            "floor": {"type": "rectangle", "to_world": T @ mi.ScalarTransform4f().rotate([1, 0, 0], -90).scale(4),
                      "bsdf": {"type": "diffuse"}},
            "ball": {"type": "sphere", "center": list(T @ mi.ScalarPoint3f(-0.5, 0.5, 0)), "radius": 0.5 * s,
                     "bsdf": {"type": "phong"}},
            **lights})

    from pointillist.plugins.integrators.whitted import MAX_UNROLLED_EMITTERS, inspect_scene

    unit = scene(1.0)
    assert inspect_scene(unit).sample_one_emitter and len(unit.emitters()) == 17 > MAX_UNROLLED_EMITTERS
    ref = render(mi, unit)
    assert ref.mean() > 0.02
    for s in (1e-5, 1e5):
        assert fraction_off(render(mi, scene(s)), ref) <= GOAL_SCALED, s


def test_offsets_docstring_examples_run(mi):
    import doctest

    from pointillist.plugins.integrators import _offsets

    result = doctest.testmod(_offsets, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted >= 8 and result.failed == 0
