"""Helpers shared by pointillist's Python integrators that override ``render()``.

Not a plugin (the leading underscore keeps :func:`plugins.register` away).
Imported after the Mitsuba variant is set.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

__all__ = ["develop_film", "film_sample", "sample_radiance"]


def develop_film(film, develop: bool, evaluate: bool) -> mi.TensorXf:
    """The end of ``Integrator.render()``, as Mitsuba's own: an empty tensor when
    ``develop`` is false (the film keeps the blocks), else the developed image,
    evaluated when ``evaluate`` is true."""
    if not develop:
        return mi.TensorXf()
    image = film.develop()
    if evaluate:
        dr.eval(image)
    return image


def film_sample(film, position: mi.Vector2f) -> mi.Vector2f:
    """The sensor's position sample (``sample2`` of ``Sensor.sample_ray``) of a film position in
    pixels (the crop offset included), as Mitsuba's ``ADIntegrator.sample_rays`` computes it:
    relative to the film's crop window, ``(position - crop_offset) / crop_size``. A sensor maps
    [0, 1]^2 onto its crop window, so dividing by the whole film's size instead shifts and scales
    every ray of a cropped film (a tiled render)."""
    scale = dr.rcp(mi.ScalarVector2f(film.crop_size()))
    offset = -mi.ScalarVector2f(film.crop_offset()) * scale
    return dr.fma(position, scale, offset)


def sample_radiance(integrator, scene, sampler, ray, medium=None, active=True):
    """One sample of ``integrator`` along ``ray``: ``(L, valid, aovs)``, whichever of Mitsuba's two
    Python interfaces it has. A plain sampling integrator (``path``, ``direct``) takes
    ``sample(scene, sampler, ray, medium, active)``; a differentiable one (``whitted``, ``prb``:
    subclasses of ``CppADIntegrator``) takes ``sample(mode=, scene=, sampler=, ray=, ...)``
    and returns a fourth value, its state for the derivative passes."""
    if isinstance(integrator, mi.CppADIntegrator):
        L, valid, aovs, _ = integrator.sample(
            mode=dr.ADMode.Primal, scene=scene, sampler=sampler, ray=ray, depth=mi.UInt32(0),
            δL=None, δaovs=None, state_in=None, active=mi.Bool(active))
        return L, valid, aovs
    return integrator.sample(scene, sampler, ray, medium, active)
