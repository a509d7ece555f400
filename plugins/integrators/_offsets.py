"""Scale-invariant ray offsets from floating-point error bounds (pbrt-v4 style), for Mitsuba 3.9.

Not a plugin (the leading underscore keeps :func:`plugins.register` away). Imported after the
Mitsuba variant is set.

Mitsuba 3.9.1's ``spawn_ray`` / ``spawn_ray_to`` move a new ray's origin off its surface by
``(1 + max|p|) * RayEpsilon`` (``RayEpsilon`` = 1500 x 2^-24, about 8.9e-5) and shorten shadow
rays by 10 RayEpsilon of their length. Below magnitude 1 that offset is an absolute length
(9e-5 whatever the unit), so a scene modelled in millimetres or micrometres gets shadow and
refraction rays that start far off their surface. Here the offset is a bound on the rounding
error of the hit point instead, as in pbrt-v4 (``OffsetRayOrigin``): the computed hit ``p`` is
within ``p_err`` (per component) of the true surface, so moving it by ``dot(|n_g|, p_err)`` along
the geometric normal ``n_g``, to the side the new ray leaves from, puts the origin on that side.

The bound of a hit on shape ``S`` is isotropic, ``p_err = gamma(n_S) * M_S`` in each component:
``M_S`` the largest coordinate magnitude of the shape's world bounding box (it bounds ``|p|``
and every magnitude the shape's computations involve) and ``n_S`` a number of float32 roundings
per shape kind (:data:`ERROR_ULPS`). Mitsuba 3.9.1 computes ``si.p`` as: spheres, re-projected
onto the surface, ``p = c + r n`` (error within a few roundings of ``|c| + r``, the bounding
box's magnitude); meshes and rectangles, ``p = sum b_k p_k`` (pbrt: ``gamma(7) sum |b_k p_k|``,
within the box); disks, re-projected onto their plane through their transform. The bound also
has to cover the error of the *next* intersection routine, which decides whether a ray leaving
the surface meets it again (Embree's triangle test, Mitsuba's float32 sphere and plane tests):
``benchmarks/stiff.py --offsets`` measures, per shape kind, the smallest ``n`` with no
self-intersection over rays leaving at grazing to normal angles, for radii 1e-5 .. 1e4 and
centres 0 .. 3e4 radii from the origin; :data:`ERROR_ULPS` is 2.7 to 4 times that. Everything is
relative: scaling a scene by ``s`` scales every offset by ``s`` (no absolute floor tied to a
unit of length).

Each hit reads its shape's ``gamma(n_S) M_S`` from a table indexed by the shape's registry id
(one gather). Shapes not in the table (inside a ``shapegroup``, reached through an
``instance``) get the largest kind factor times the whole scene's magnitude, which bounds theirs.

Shadow rays: the target point on a light is moved off the light's surface the same way (by its
shape's bound, toward the shading point; a point light has no surface and bound 0), and the ray
stops ``gamma(SHADOW_ULPS)`` of its length short of it.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from pointillist.core import checks

__all__ = ["ERROR_ULPS", "DEFAULT_ULPS", "SHADOW_ULPS", "UNIT_ROUNDOFF", "gamma", "magnitude",
           "shape_offset_scale", "ErrorBounds"]

#: Unit roundoff of float32 (half an ulp of 1): pbrt's ``MachineEpsilon``.
UNIT_ROUNDOFF = 2.0 ** -24

#: Roundings ``n_S`` per ``mi.ShapeType`` name: 2.7 to 4 times the smallest that left no
#: self-intersection among 300 000 rays per kind in ``benchmarks/stiff.py --offsets --rays 20000``
#: (rectangle and triangle mesh: 3; sphere: 6; disk: 8; cylinder: 16).
ERROR_ULPS = {"Sphere": 16, "Rectangle": 8, "Mesh": 8, "Disk": 32, "Cylinder": 64}

#: Roundings for the shape kinds not measured (curves, SDF grids, ellipsoids) and instances.
DEFAULT_ULPS = 64

#: Shadow rays stop ``gamma(SHADOW_ULPS)`` of their length short of their target.
SHADOW_ULPS = 16


def gamma(n: int) -> float:
    """pbrt's ``gamma(n) = n u / (1 - n u)``: the bound of ``n`` float32 roundings (u = 2^-24).

    >>> round(gamma(1) / 2.0 ** -24, 6)
    1.0
    """
    n = checks.integer(n, "n", low=0)
    return n * UNIT_ROUNDOFF / (1.0 - n * UNIT_ROUNDOFF)


def magnitude(bbox) -> float:
    """Largest coordinate magnitude of a bounding box (0 for an invalid / empty box).

    >>> import pointillist
    >>> mi = pointillist.setup("llvm_ad_rgb")
    >>> magnitude(mi.ScalarBoundingBox3f([-3, 0, 1], [2, 0.5, 1]))
    3.0
    """
    lo = [float(bbox.min[i]) for i in range(3)]
    hi = [float(bbox.max[i]) for i in range(3)]
    if not all(math.isfinite(v) for v in lo + hi) or any(a > b for a, b in zip(lo, hi)):
        return 0.0
    return max(abs(v) for v in lo + hi)


def _kind_ulps(shape) -> int:
    kind = int(shape.shape_type())
    for name, n in ERROR_ULPS.items():
        if kind == int(getattr(mi.ShapeType, name)):
            return n
    return DEFAULT_ULPS


def shape_offset_scale(shape) -> float:
    """``gamma(n_S) * M_S``: the per-component error bound of a hit on ``shape`` (world units).

    >>> import pointillist
    >>> mi = pointillist.setup("llvm_ad_rgb")
    >>> s = mi.load_dict({"type": "sphere", "center": [0, 0, 1e3], "radius": 1.0})
    >>> round(shape_offset_scale(s) / (1001 * 2.0 ** -24), 3)          # 16 roundings of 1001
    16.0
    """
    return gamma(_kind_ulps(shape)) * magnitude(shape.bbox())


def _registry_id(ptr) -> int:
    return int(dr.reinterpret_array(mi.UInt32, ptr)[0])


def _table(entries: list[tuple[int, float]], fallback: float) -> tuple[mi.Float, int]:
    table = np.full(max((i for i, _ in entries), default=0) + 2, fallback, np.float32)
    for i, value in entries:
        table[i] = value
    return mi.Float(table), len(table) - 1


class ErrorBounds:
    """Per-scene tables of error bounds, and ray spawners that offset by them.

    Build one per render (``ErrorBounds(scene)``: a Python loop over the scene's shapes and
    emitters, before tracing); its methods are traced into the kernel. Replaces
    ``si.spawn_ray(d)`` by ``bounds.spawn_ray(si, d, length)`` and ``si.spawn_ray_to(ds.p)`` by
    ``bounds.spawn_ray_to(si, length, ds)``, with ``length = bounds.hit_offset(si)`` once per hit.

    Examples
    --------
    >>> import pointillist
    >>> mi = pointillist.setup("llvm_ad_rgb")
    >>> scene = mi.load_dict({"type": "scene",
    ...                       "s": {"type": "sphere", "center": [0, 0, 0], "radius": 1e-6}})
    >>> bounds = ErrorBounds(scene)
    >>> si = scene.ray_intersect(mi.Ray3f([0, 0, 1], [0, 0, -1]))
    >>> length = bounds.hit_offset(si)
    >>> ray = bounds.spawn_ray(si, mi.Vector3f(0, 0, 1), length)      # leaves the top, upwards
    >>> off = float(ray.o.z[0]) - float(si.p.z[0])
    >>> 5e-13 < off < 2e-12                # 16 roundings of 1e-6 (Mitsuba 3.9.1: 9e-5)
    True
    >>> bool(scene.ray_test(ray)[0]), bool(scene.ray_test(bounds.spawn_ray(si, mi.Vector3f(0, 0, -1), length))[0])
    (False, True)
    """

    def __init__(self, scene) -> None:
        if not isinstance(scene, mi.Scene):
            raise TypeError(f"scene: expected a mitsuba Scene, got {type(scene).__name__}")
        #: bound for shapes not listed (instanced): the largest kind factor x the scene's magnitude
        self.fallback = gamma(max(DEFAULT_ULPS, *ERROR_ULPS.values())) * magnitude(scene.bbox())
        shapes = [s for s in scene.shapes() if s.class_name() not in ("Instance", "ShapeGroup")]
        self.shape_table, self._last_shape = _table(
            [(_registry_id(mi.ShapePtr(s)), shape_offset_scale(s)) for s in shapes], self.fallback)
        emitters = list(scene.emitters())
        self._emitter_scales = {id(e): self.emitter_offset_scale(e) for e in emitters}
        self.emitter_table, self._last_emitter = _table(
            [(_registry_id(mi.EmitterPtr(e)), self._emitter_scales[id(e)]) for e in emitters], self.fallback)
        self.shadow = dr.opaque(mi.Float, 1.0 - gamma(SHADOW_ULPS))

    @staticmethod
    def emitter_offset_scale(emitter) -> float:
        """Error bound of points sampled on an emitter: its shape's (area lights), else 0."""
        shape = emitter.get_shape()
        return shape_offset_scale(shape) if shape is not None else 0.0

    def emitter_bound_of(self, emitter):
        """:meth:`emitter_offset_scale` as an opaque value (no kernel recompiled per scene), or
        None for an emitter without a surface (point, spot, directional, environment): its
        sampled points need no offset."""
        if emitter.get_shape() is None:
            return None
        scale = self._emitter_scales.get(id(emitter))
        return dr.opaque(mi.Float, self.emitter_offset_scale(emitter) if scale is None else scale)

    # ------------------------------------------------------------- traced code
    def shape_bound(self, si, active=True) -> mi.Float:
        """``gamma(n_S) M_S`` of each hit's shape (a gather by registry id)."""
        idx = dr.minimum(dr.reinterpret_array(mi.UInt32, si.shape), self._last_shape)
        return dr.gather(mi.Float, self.shape_table, idx, active)

    def emitter_bound(self, ds, active=True) -> mi.Float:
        """Error bound of each direction sample's point on its emitter (a gather by ``ds.emitter``)."""
        idx = dr.minimum(dr.reinterpret_array(mi.UInt32, ds.emitter), self._last_emitter)
        return dr.gather(mi.Float, self.emitter_table, idx, active)

    @staticmethod
    def offset_length(bound, n) -> mi.Float:
        """``dot(|n|, p_err)`` for ``p_err`` = ``bound`` in each component: how far to move."""
        return bound * (dr.abs(n.x) + dr.abs(n.y) + dr.abs(n.z))

    def hit_offset(self, si, active=True) -> mi.Float:
        """How far rays leaving hit ``si`` start off its surface (once per hit, for all its rays)."""
        return self.offset_length(self.shape_bound(si, active), si.n)

    @staticmethod
    def offset(p, n, length, d) -> mi.Point3f:
        """``p`` moved by ``length`` along ``n``, to the side of ``d``."""
        return dr.fma(dr.mulsign(length, dr.dot(n, d)), n, p)

    def spawn_ray(self, si, d, length) -> mi.Ray3f:
        """A ray from hit ``si`` along ``d`` (as ``si.spawn_ray(d)``); ``length``: the hit's
        :meth:`hit_offset`."""
        return mi.Ray3f(self.offset(si.p, si.n, length, d), d, dr.largest(mi.Float), si.time, si.wavelengths)

    def spawn_ray_to(self, si, length, ds, target_bound="gather", active=True) -> mi.Ray3f:
        """A shadow ray from hit ``si`` (its :meth:`hit_offset` ``length``) to the point of
        direction sample ``ds`` on an emitter.

        ``target_bound``: that point's error bound: a Float (:meth:`emitter_bound_of`, when the
        emitter is known while tracing), None (a point without a surface: no offset) or
        "gather" (from ``ds.emitter``, when the emitter was chosen per lane).
        """
        o = self.offset(si.p, si.n, length, ds.p - si.p)
        target = ds.p
        if isinstance(target_bound, str):
            target_bound = self.emitter_bound(ds, active)
        if target_bound is not None:
            target = self.offset(ds.p, ds.n, self.offset_length(target_bound, ds.n), o - ds.p)
        d = target - o
        dist = dr.norm(d)
        return mi.Ray3f(o, d / dist, dist * self.shadow, si.time, si.wavelengths)
