"""Helpers shared by pointillist's Python integrators that override ``render()``.

Not a plugin (the leading underscore keeps :func:`plugins.register` away).
Imported after the Mitsuba variant is set.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

__all__ = ["develop_film"]


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
