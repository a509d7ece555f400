"""The ``whitted`` integrator: classic recursive (Whitted-style) ray tracing, in Python on Dr.Jit."""

from __future__ import annotations

from typing import NamedTuple

import drjit as dr
import mitsuba as mi

from pointillist.core.checks import UINT32_MAX
from pointillist.plugins.integrators._offsets import ErrorBounds
from pointillist.plugins.properties import boolean_property, integer_property, spectrum_property

__all__ = ["WhittedIntegrator", "SceneFeatures", "inspect_scene", "refuse_geometry_gradients", "PLUGIN_CLASS"]

#: A scene with more emitters than this gets one randomly chosen emitter per
#: vertex (``Scene.sample_emitter_direction``, unbiased) instead of one shadow
#: ray per emitter: the per-emitter code is unrolled into the kernel, so its
#: size grows with the emitter count.
MAX_UNROLLED_EMITTERS = 16

#: Largest ``max_depth``: the depth counter is a ``UInt32`` that counts up to
#: ``max_depth + 1`` (a chain that long never ends in practice: two facing mirrors).
MAX_DEPTH_LIMIT = UINT32_MAX - 1

#: Mitsuba's base class of differentiable integrators that replay their paths (as ``prb``).
RBIntegrator = mi.ad.integrators.common.RBIntegrator

_DELTA_LOBES = (mi.BSDFFlags.DeltaReflection | mi.BSDFFlags.DeltaTransmission | mi.BSDFFlags.Null)


class SceneFeatures:
    """What a scene needs from the integrator (see :func:`inspect_scene`).

    ``delta_flags``: union of the delta lobes (``DeltaReflection``,
    ``DeltaTransmission``, ``Null``) of the scene's BSDFs: which recursive rays
    exist at all. ``smooth``: some BSDF has a non-delta lobe (only those
    receive direct light). ``emitters``: the emitters that get shadow rays.
    ``emission``: something in the scene emits (area light or environment).
    ``sample_one_emitter``: more than :data:`MAX_UNROLLED_EMITTERS` emitters.

    A plain class on purpose: Dr.Jit traverses dataclasses passed through
    symbolic loops as loop state.
    """

    def __init__(self, delta_flags: int = int(_DELTA_LOBES), smooth: bool = True, emitters: tuple = (),
                 emission: bool = True, sample_one_emitter: bool = False) -> None:
        self.delta_flags = int(delta_flags)
        self.smooth = bool(smooth)
        self.emitters = tuple(emitters)
        self.emission = bool(emission)
        self.sample_one_emitter = bool(sample_one_emitter)

    def __repr__(self) -> str:
        return f"SceneFeatures({self.summary()})"

    @property
    def reflection(self) -> bool:
        return bool(self.delta_flags & int(mi.BSDFFlags.DeltaReflection))

    @property
    def transmission(self) -> bool:
        return bool(self.delta_flags & int(mi.BSDFFlags.DeltaTransmission | mi.BSDFFlags.Null))

    def summary(self) -> dict:
        return {"reflection": self.reflection, "transmission": self.transmission,
                "smooth": self.smooth, "emitters": len(self.emitters), "emission": self.emission,
                "sample_one_emitter": self.sample_one_emitter}


def inspect_scene(scene, *, specialize: bool = True) -> SceneFeatures:
    """Find which parts of the Whitted algorithm ``scene`` needs.

    Reads the flags of every shape's BSDF and the scene's emitters (Python
    side, before tracing). With ``specialize=False`` (or when the scene holds
    instances, whose BSDFs are not listed) every lobe kind is assumed present.
    """
    emitters = tuple(scene.emitters())
    emission = any(not mi.has_flag(e.flags(), mi.EmitterFlags.Delta) for e in emitters)
    many = len(emitters) > MAX_UNROLLED_EMITTERS
    if not specialize:
        return SceneFeatures(emitters=emitters, emission=bool(emitters), sample_one_emitter=many)
    delta, smooth = 0, False
    for shape in scene.shapes():
        if shape.class_name() in ("Instance", "ShapeGroup"):
            return SceneFeatures(emitters=emitters, emission=emission, sample_one_emitter=many)
        bsdf = shape.bsdf()
        if bsdf is None:
            continue
        flags = int(bsdf.flags())
        delta |= flags & int(_DELTA_LOBES)
        smooth |= bool(flags & int(mi.BSDFFlags.Smooth))
    return SceneFeatures(delta_flags=delta, smooth=smooth, emitters=emitters, emission=emission,
                         sample_one_emitter=many)


#: The parameter names of a light's placement (its other parameters, radiance, intensity and
#: their textures, are differentiated).
_PLACEMENT_KEYS = ("to_world", "position", "direction")


def refuse_geometry_gradients(scene) -> None:
    """Raise ``ValueError`` if a parameter that places something in ``scene`` has gradients enabled.

    Whitted's derivatives are those of the ray tree's weights along fixed rays: a shape's or
    sensor's parameters (vertex positions, ``to_world``, field of view), and a light's placement
    (``to_world``, ``position``, ``direction``) also move visibility boundaries (silhouettes,
    shadow edges), whose derivative needs the boundary sampling of Mitsuba's projective
    integrators (``direct_projective``, ``prb_projective``). Without it the gradient would be
    silently wrong (zero at best), so it is refused, naming the parameter.
    """
    params = mi.traverse(scene)
    for key in params.keys():
        node = params.properties[key][2]
        geometric = isinstance(node, (mi.Shape, mi.Sensor)) or (
            isinstance(node, mi.Emitter) and key.rsplit(".", 1)[-1] in _PLACEMENT_KEYS)
        if geometric and dr.grad_enabled(params[key]):
            raise ValueError(
                f"{key}: the whitted integrator does not differentiate geometry (shape, sensor and "
                "light placement: their derivatives come from moving visibility boundaries, which it "
                "does not sample); disable gradients on it, or use Mitsuba's 'direct_projective' or "
                "'prb_projective' integrator for this parameter")


class _Trace(NamedTuple):
    """What one call of :meth:`WhittedIntegrator.sample` traces with (read-only in its loop)."""

    mode: dr.ADMode              # Primal, or Forward/Backward for the replay
    features: SceneFeatures      # which parts of the algorithm the scene needs
    bounds: ErrorBounds          # ray offsets from the hits' floating-point error


class _Vertex(NamedTuple):
    """One vertex of a ray tree: what it adds and where the tree goes on."""

    L: mi.Spectrum               # radiance it adds, throughput included (differentiable in the replay)
    ray: mi.Ray3f                # the delta ray leaving it
    beta: mi.Spectrum            # throughput of that ray
    depth: mi.UInt32             # depth after this vertex
    active: mi.Bool              # the tree goes on
    hit: mi.Bool                 # the ray found a surface
    weight: mi.Spectrum          # the delta sample's weight (differentiable in the replay)


class WhittedIntegrator(RBIntegrator):
    r"""Whitted-style recursive ray tracer (:monosp:`whitted`)

    .. pluginparameters::

     * - max_depth
       - |int|
       - Recursive cut-off (default: 5), the number of surface hits that are
         shaded along a chain of mirror/refraction rays. 0 renders only
         emitters seen directly by the camera (no shading at all); 1 shades the
         first hit (local illumination) and lets a mirror show what emits
         behind it; ``k`` follows at most ``k`` delta bounces. This counts the
         same light paths as ``path`` with ``max_depth = k + 1``. Must be in
         0 .. 2^32 - 2 (the depth counter is 32-bit): there is no "unlimited"
         (two facing mirrors would never stop).
     * - ambient
       - |spectrum|
       - Ambient radiance :math:`I_a` (default: 0); each shaded hit adds
         :math:`I_a K_d` with :math:`K_d` the BSDF's diffuse reflectance
         (``eval_diffuse_reflectance``).
     * - hide_emitters
       - |bool|
       - Hide emitters (area lights, environment) seen directly by the camera
         (default: false); they still light the scene and show in mirrors.
     * - specialize
       - |bool|
       - Inspect the scene and leave out what it does not need (default:
         true); false builds the general kernel (for comparisons).

    At each hit: emitted radiance; the ambient term; direct light from every
    emitter through a shadow ray (``Emitter.sample_direction`` then
    ``Scene.ray_test``): point, spot and directional lights exactly, area and
    environment lights by one emitter sample per camera sample (above
    :data:`MAX_UNROLLED_EMITTERS` emitters one emitter is chosen at random per
    hit); reflected light is ``bsdf.eval``,
    which is zero for delta lobes. Then the ray continues along the BSDF's
    delta lobes (mirror reflection, refraction with Snell's law, Fresnel
    weights and total internal reflection, null transmission) drawn with
    ``bsdf.sample`` restricted to delta components. Where a BSDF has both a
    reflected and a refracted delta ray, one of them is followed with the
    BSDF's Fresnel probability and weight: an unbiased estimate of the two-ray
    Whitted tree whose average over the pixel samples converges to it (a
    vectorised wavefront cannot branch). Works with any Mitsuba BSDF; smooth
    (diffuse/glossy) lobes get direct light only, as in Whitted's algorithm.
    Participating media are ignored.

    Leave out what a scene does not need: on each render the scene is
    inspected (:func:`inspect_scene`): without delta lobes there is no
    recursion loop at all, the BSDF context only enables the delta lobes
    present (no refraction sampling without refractive BSDFs), without
    emitters there are no shadow rays and no emission lookups; ambient 0 skips
    the ambient term, and ``max_depth`` 0 skips all shading.

    Edges: reflected, refracted and shadow rays leave a surface from a point
    moved off it by a bound on the floating-point error of the hit, along the
    geometric normal, to the side the ray leaves from (pbrt-v4's method; see
    :mod:`pointillist.plugins.integrators._offsets`): a few float32 roundings
    of the hit shape's magnitude, so the offsets scale with the scene, with no
    absolute floor (Mitsuba 3.9.1's ``spawn_ray`` adds 9e-5 whatever the
    unit). Shadow rays end just short of their target, itself moved off the
    light's surface. Scenes scaled by 1e-6 .. 1e6 render the same image, and
    scenes far from the origin are loaded camera-relative (the documentation's
    page "Numerical robustness" gives the figures). Normals facing away are handled by each BSDF (one-sided
    BSDFs return black). A ray whose throughput becomes 0 stops early.

    **Derivatives.** A differentiable Mitsuba integrator (Mitsuba's ``RBIntegrator``, as
    ``prb``): ``mi.render(scene, params)`` then ``dr.backward``, or ``render_forward``, gives the
    derivatives of the image with respect to every material and light parameter: the BSDFs'
    parameters and textures (``lambert``'s reflectance; ``phong``'s Kd, Ks and exponent; a
    mirror's or glass's ``specular_reflectance``/``specular_transmittance``, the weight of a delta
    bounce), emitters' radiance and intensity (bitmap texels included). The derivative pass
    replays each ray tree with the same random numbers and, at each vertex, re-evaluates what
    the vertex adds and the weight of its delta bounce with gradients on: the rest of the tree's
    radiance (the primal total minus what the earlier vertices added) times the weight's
    relative derivative. Nothing is kept across bounces, so memory does not grow with the depth.
    Geometry is refused (:func:`refuse_geometry_gradients`: shape and sensor parameters and
    light placement with gradients enabled raise ValueError naming the parameter), as its
    derivative comes from moving visibility boundaries that this integrator does not sample;
    Mitsuba's ``direct_projective`` and ``prb_projective`` do.

    .. code-block:: xml

        <integrator type="whitted">
            <integer name="max_depth" value="5"/>
            <rgb name="ambient" value="0.02, 0.02, 0.02"/>
        </integrator>
    """

    def __init__(self, props: mi.Properties) -> None:
        # Mitsuba's ADIntegrator reads max_depth (-1 for infinite) and rr_depth, neither of which
        # is whitted's: the C++ base reads hide_emitters, the properties are read and checked here.
        mi.CppADIntegrator.__init__(self, props)
        self.max_depth = integer_property(props, "max_depth", 5, 0, MAX_DEPTH_LIMIT,
                                          "0 shows only emitters seen directly")
        ambient = spectrum_property(props, "ambient", 0.0)
        if min(ambient) < 0:
            raise ValueError(f"ambient: expected non-negative radiance, got {list(ambient)}")
        self.ambient_value = ambient
        self.m_ambient = dr.opaque(mi.Color3f, ambient)
        self.m_max_depth = dr.opaque(mi.UInt32, self.max_depth)
        self.specialize = boolean_property(props, "specialize", True)
        # Nothing about a scene is kept on the integrator between calls: a SceneFeatures holds the
        # scene's emitters, and an emitter kept alive past its scene (its shape freed) crashes the
        # next trace of any virtual call to the emitters (Dr.Jit traces every registered one).

    # ------------------------------------------------------------ derivatives
    def render_forward(self, scene, params, sensor=0, seed=0, spp=0):
        refuse_geometry_gradients(scene)
        return super().render_forward(scene, params, sensor, seed, spp)

    def render_backward(self, scene, params, grad_in, sensor=0, seed=0, spp=0):
        refuse_geometry_gradients(scene)
        return super().render_backward(scene, params, grad_in, sensor, seed, spp)

    # ------------------------------------------------------------------ sample
    def sample(self, mode, scene, sampler, ray, δL, state_in, active, **kwargs):
        """One ray tree per lane (the interface of Mitsuba's ``ADIntegrator.sample``).

        Primal mode returns the radiance. Forward and backward modes replay the same tree
        (the sampler repeats its numbers) with ``state_in``, the primal radiance, and
        propagate derivatives vertex by vertex: forward mode returns the derivative of the
        radiance, backward mode accumulates ``δL`` times it into the parameters' gradients.
        """
        trace = _Trace(mode, inspect_scene(scene, specialize=self.specialize), ErrorBounds(scene))
        ray = mi.Ray3f(ray)
        active = mi.Bool(active)
        if self.max_depth >= 1 and trace.features.delta_flags:
            L, valid = self._trace_recursive(trace, scene, sampler, ray, δL, state_in, active)
        else:
            vertex = self._vertex(trace, scene, sampler, ray, mi.Spectrum(1.0), mi.UInt32(0), active,
                                  recurse=False)
            L, valid = vertex.L, vertex.hit
            if mode != dr.ADMode.Primal:
                L = self._propagate(mode, vertex.L, None, None, δL)
        return L, valid, [], (L if mode == dr.ADMode.Primal else state_in)

    @dr.syntax
    def _trace_recursive(self, trace, scene, sampler, ray, δL, state_in, active):
        primal = trace.mode == dr.ADMode.Primal
        width = dr.width(ray)
        # --------------------- loop state (full width: see Dr.Jit's reverse-mode loops) ---
        L = dr.zeros(mi.Spectrum, width) if primal else mi.Spectrum(state_in)  # primal: radiance so far;
        #                                                  replay: radiance still to come from this vertex on
        δL = dr.zeros(mi.Spectrum, width) if trace.mode != dr.ADMode.Backward else mi.Spectrum(δL)
        #                                                  forward: derivative so far; backward: adjoint
        beta = dr.full(mi.Spectrum, 1.0, width)          # throughput of the current ray
        depth = dr.zeros(mi.UInt32, width)               # hits shaded so far
        valid = dr.full(mi.Bool, False, width)           # the camera ray hit a surface
        while dr.hint(active, max_iterations=min(self.max_depth + 1, UINT32_MAX),
                      label=f"Whitted ray tree ({trace.mode.name})"):
            vertex = self._vertex(trace, scene, sampler, ray, beta, depth, active, recurse=True)
            if dr.hint(primal, mode="scalar"):
                L += vertex.L
            else:
                L -= dr.detach(vertex.L)                 # what the rest of the tree adds
                δL = self._propagate(trace.mode, vertex.L, L, vertex.weight, δL)
            valid |= vertex.hit & (depth == 0)
            ray, beta, depth, active = vertex.ray, vertex.beta, vertex.depth, vertex.active
        return (L if primal else δL), valid

    @staticmethod
    def _propagate(mode, L_vertex, L_rest, weight, δL):
        """Derivatives of one vertex: of what it adds (``L_vertex``, differentiable) and, through
        the delta sample's ``weight``, of everything the tree adds after it (``L_rest``, detached;
        its relative derivative is the weight's). Forward mode returns ``δL`` plus that
        derivative; backward mode accumulates ``δL`` times it into the parameters, returns ``δL``."""
        with dr.resume_grad():
            L_o = L_vertex if L_rest is None else L_vertex + L_rest * dr.relative_grad(weight)
            if mode == dr.ADMode.Backward:
                dr.backward_from(δL * L_o)
                return δL
            forward = dr.forward_to(L_o)
            return forward if δL is None else δL + forward

    # ------------------------------------------------------------------ helpers
    def _vertex(self, trace, scene, sampler, ray, beta, depth, active, *, recurse):
        """Trace ``ray`` and shade its hit (differentiably in the replay): a :class:`_Vertex`."""
        features, bounds = trace.features, trace.bounds
        si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=(depth == 0), active=active)
        hit = active & si.is_valid()
        depth_next = dr.select(active, depth + 1, depth)
        with dr.resume_grad(when=trace.mode != dr.ADMode.Primal):
            L = mi.Spectrum(0.0)
            if features.emission:
                emit = active & (depth > 0) if self.hide_emitters else active
                L += beta * si.emitter(scene).eval(si, emit)
            if self.max_depth == 0:
                return _Vertex(L, ray, beta, depth_next, mi.Bool(False), hit, mi.Spectrum(1.0))
            shade = hit & (depth_next <= self.m_max_depth)
            bsdf = si.bsdf(ray)

            if any(self.ambient_value):
                L += beta * self.m_ambient * bsdf.eval_diffuse_reflectance(si, shade)

            offset = bounds.hit_offset(si, shade)     # from the hit's error bound, for every ray it spawns
            if features.emitters and features.smooth:
                lit = shade & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
                L += beta * self._direct(scene, sampler, si, offset, bsdf, lit, trace)

            if not recurse:
                return _Vertex(L, ray, beta, depth_next, mi.Bool(False), hit, mi.Spectrum(1.0))
            ctx = mi.BSDFContext()
            ctx.type_mask = features.delta_flags
            bounce = shade & ((bsdf.flags() & mi.UInt32(features.delta_flags)) != 0)
            bs, weight = bsdf.sample(ctx, si, sampler.next_1d(bounce), sampler.next_2d(bounce), bounce)
            bs = dr.detach(bs)
            bounce &= dr.any(dr.detach(weight) != 0.0) & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
            weight_followed = dr.select(bounce, weight, 1.0)
        beta = beta * dr.detach(weight)
        ray = bounds.spawn_ray(si, si.to_world(bs.wo), offset)
        return _Vertex(L, ray, beta, depth_next, bounce, hit, weight_followed)

    def _direct(self, scene, sampler, si, offset, bsdf, active, trace):
        """Light reflected at ``si`` straight from the emitters, with shadow rays."""
        features, bounds = trace.features, trace.bounds
        ctx = mi.BSDFContext()
        if features.sample_one_emitter:
            ds, weight = scene.sample_emitter_direction(si, sampler.next_2d(active), False, active)
            ok = active & (ds.pdf != 0.0)
            ok &= ~scene.ray_test(bounds.spawn_ray_to(si, offset, dr.detach(ds), active=ok), ok)
            return dr.select(ok, bsdf.eval(ctx, si, si.to_local(ds.d), ok) * weight, 0.0)
        Ld = mi.Spectrum(0.0)
        table = scene.emitters_dr()
        for index, emitter in enumerate(features.emitters):
            if mi.has_flag(emitter.flags(), mi.EmitterFlags.Delta):
                sample = mi.Point2f(0.5)       # point / spot / directional: exact, no randomness
            else:
                sample = sampler.next_2d(active)
            # Called through the scene's emitter table (a one-target virtual call), not on the Python
            # object: Dr.Jit 1.5 inlines each direct call, and two emitters whose radiance is a
            # bitmap then define the same texture helper twice in one kernel ("invalid
            # redefinition of function": LLVM refuses the kernel and the process aborts).
            pointer = dr.gather(mi.EmitterPtr, table, mi.UInt32(index), active)
            ds, weight = pointer.sample_direction(si, sample, active)
            ok = active & dr.any(weight != 0.0)
            shadow_ray = bounds.spawn_ray_to(si, offset, dr.detach(ds), bounds.emitter_bound_of(emitter), ok)
            visible = ok & ~scene.ray_test(shadow_ray, ok)
            f = bsdf.eval(ctx, si, si.to_local(ds.d), visible)
            Ld += dr.select(visible, f * weight, 0.0)
        return Ld

    def aov_names(self):
        return []

    def to_string(self) -> str:
        return (f"WhittedIntegrator[\n  max_depth = {self.max_depth},\n  ambient = {list(self.ambient_value)},\n"
                f"  hide_emitters = {self.hide_emitters},\n  specialize = {self.specialize}\n]")


#: The plugin's class, which pointillist.plugins registers with Mitsuba under this file's name.
PLUGIN_CLASS = WhittedIntegrator
