"""Stiff scenes: the same image whatever the scene's scale or distance from the origin (issue 21).

One small scene (a Phong sphere, a mirror sphere, a glass sphere on a diffuse floor, one point
light, 80x80 at 4 spp, box filter, fixed seed) is scaled by 1e-6 .. 1e6 (camera, clip planes and
light included; the light's intensity by s^2, so irradiance is unchanged) or moved 1e3 from the
origin, and compared pixel by pixel with the scene at scale 1 rendered with the same seed: the
camera rays are then the same up to rounding, so any difference is numerical. Variants add a thin
sphere (radius 1e-3 of the scene's size) resting on the floor and a grazing light.

Evidence: the image at scale 1 (an independent rendering of the same rays), and Mitsuba's own
``path`` integrator on the same scenes (it offsets rays by ``(1 + max|p|) * 1500 ulp``, so a tiny
scene's shadow and refraction rays start far off their surface: measured 33 % of pixels off at
1e-4 with Mitsuba 3.9.1; a release with mitsuba3 pull request 1962, "A better ray epsilon",
should pass the same check, and ``test_mitsuba_path_at_small_scale`` will then show it).
"""

from __future__ import annotations

import numpy as np
import pytest

RES, SPP, SEED = 80, 4, 3
SCALES = (1e-6, 1e-4, 1e4, 1e6)
SHIFT = 1e3

#: Goals of issue 21: fraction of pixels off by more than 1 %.
GOAL_SCALED, GOAL_MOVED = 0.005, 0.02


def stiff_scene(mi, integrator, *, scale: float = 1.0, shift: float = 0.0, thin: bool = False,
                grazing: bool = False, res: int = RES, spp: int = SPP):
    """The test scene scaled by ``scale`` about the origin, then moved by ``shift`` along (1, 1, 1).

    ``thin`` adds a sphere of radius 4e-3 (1e-3 of the 4-unit floor's size... of the scene's
    8-unit floor: 5e-4 of it) resting on the floor; ``grazing`` puts the point light 2 degrees
    above the floor's plane, far to the side, so shadows are long and the floor is lit at grazing
    incidence. Light intensity scales with ``scale**2`` (unchanged irradiance).
    """
    T = mi.ScalarTransform4f().translate([shift] * 3) @ mi.ScalarTransform4f().scale(scale)

    def at(x, y, z):
        return T @ mi.ScalarPoint3f(x, y, z)

    def sphere(c, r, bsdf):
        return {"type": "sphere", "center": list(at(*c)), "radius": r * scale, "bsdf": bsdf}

    light_pos = (6.0, 0.2, 2.0) if grazing else (2.0, 4.0, 3.0)
    light_pow = 600.0 if grazing else 40.0
    scene = {
        "type": "scene",
        "integrator": integrator,
        "sensor": {"type": "perspective", "fov": 40,
                   "near_clip": 1e-2 * scale, "far_clip": 1e3 * scale,
                   "to_world": mi.ScalarTransform4f().look_at(origin=at(0, 1.6, 5.5), target=at(0, 0.4, 0),
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
        scene["thin"] = sphere((0.3, 4e-3, 1.6), 4e-3, {"type": "diffuse",
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
