"""The property readers every Python plugin uses (BSDFs, integrators, samplers).

Each reads one property of a :class:`mitsuba.Properties` with its default, checks its
type and range, and raises a ``TypeError`` (wrong type) or ``ValueError`` (out of range)
that names the property and what was expected. Imported after the Mitsuba variant is set.
"""

from __future__ import annotations

import math
import numbers

import mitsuba as mi
import numpy as np

from pointillist.core import checks

__all__ = ["texture_property", "spectrum_property", "string_property", "boolean_property", "number_property",
           "integer_property", "transform_property", "scalar_transform"]


def _as_triple(value, name: str) -> tuple[float, float, float] | None:
    """A constant colour property as three floats, or None when it is not a constant."""
    if isinstance(value, bool):
        raise TypeError(f"{name}: expected a float, an RGB colour or a texture, got a boolean")
    if isinstance(value, numbers.Real):
        return (float(value),) * 3
    if isinstance(value, (mi.ScalarColor3d, mi.ScalarColor3f)):
        return tuple(float(v) for v in value)
    if isinstance(value, (mi.Texture, str)) or not hasattr(value, "__len__"):
        return None
    try:  # lists, tuples and Dr.Jit scalar arrays (load_dict turns [r, g, b] into Array3f64)
        if len(value) == 3:
            return tuple(float(value[i]) for i in range(3))
    except (TypeError, ValueError):
        pass
    return None


def texture_property(props, name: str, default, *, kind: str = "rgb",
                     lower: float = 0.0, upper: float | None = 1.0):
    """Read property ``name`` as a :class:`mitsuba.Texture`.

    Mitsuba hands a ``<float>`` to Python as ``float``, an ``<rgb>`` as
    ``ScalarColor3d``, a ``<spectrum>`` or a nested ``<texture>`` as an object:
    this turns every form into a texture (``srgb`` for colours, ``uniform`` for
    grey values), so that the BSDF evaluates it the same way everywhere and its
    value is an opaque Dr.Jit variable (no recompilation when it changes).

    Constant values are checked against ``[lower, upper]`` (``upper=None``: no
    upper bound) and must be finite; a ValueError names the property. Textures
    are not checked (their range is only known when evaluated).
    """
    value = props.get(name, default) if name in props else default
    if isinstance(value, mi.Texture):
        return value
    triple = _as_triple(value, name)
    if kind == "float" and triple is not None and not isinstance(value, numbers.Real):
        raise TypeError(f"{name}: expected a float or a texture, got an RGB colour {list(triple)}")
    if triple is None:
        if hasattr(value, "is_uniform") and hasattr(value, "values"):
            # <spectrum value="0.4"/> arrives as a Properties.Spectrum
            if not value.is_uniform:
                raise TypeError(f"{name}: a sampled <spectrum> is not supported in RGB variants; "
                                "use <rgb> or a texture")
            triple = (float(value.values[0]),) * 3
    if triple is None:
        raise TypeError(f"{name}: expected a float, an RGB colour or a texture, got {type(value).__name__}")
    for v in triple:
        if not math.isfinite(v):
            raise ValueError(f"{name}: expected finite values, got {list(triple)}")
        if v < lower or (upper is not None and v > upper):
            bound = f"[{lower:g}, {upper:g}]" if upper is not None else f">= {lower:g}"
            raise ValueError(f"{name}: expected values in {bound}, got {list(triple)}")
    if kind == "float" or triple[0] == triple[1] == triple[2]:
        return mi.load_dict({"type": "uniform", "value": triple[0]})
    return mi.load_dict({"type": "srgb", "color": list(triple), "unbounded": True})


def spectrum_property(props, name: str, default) -> tuple[float, float, float]:
    """A constant colour property (float, RGB or uniform spectrum) as three finite floats."""
    value = props.get(name, default) if name in props else default
    triple = _as_triple(value, name)
    if triple is None and hasattr(value, "is_uniform") and value.is_uniform:
        triple = (float(value.values[0]),) * 3
    if triple is None:
        raise TypeError(f"{name}: expected a float or an RGB colour, got {type(value).__name__}")
    if not all(math.isfinite(v) for v in triple):
        raise ValueError(f"{name}: expected finite values, got {list(triple)}")
    return triple


def string_property(props, name: str, default: str, choices=None) -> str:
    """A string property; with ``choices``, one of them."""
    value = props.get(name, default) if name in props else default
    if not isinstance(value, str):
        raise TypeError(f"{name}: expected a string, got {type(value).__name__}")
    if choices is not None and value not in choices:
        raise ValueError(f"{name}: expected one of {', '.join(choices)}, got {value!r}")
    return value


def boolean_property(props, name: str, default: bool) -> bool:
    """A boolean property (``<boolean>``; no other type is taken for one)."""
    value = props[name] if name in props else default
    if not isinstance(value, bool):
        raise TypeError(f"{name}: expected a boolean, got {type(value).__name__}")
    return value


def number_property(props, name: str, default: float, *, minimum: float | None = None, strict: bool = False,
                    allow_inf: bool = False) -> float:
    """A real property as a float: finite (or +-inf with ``allow_inf``), never NaN, ``>= minimum``
    (``> minimum`` with ``strict``), and held by float32, in which the plugins compute
    (:func:`pointillist.core.checks.real`: 4e38 or a positive 1e-50 are refused)."""
    return checks.real(props[name] if name in props else default, name, low=minimum, low_open=strict,
                       allow_inf=allow_inf)


def integer_property(props, name: str, default: int, minimum: int, maximum: int, meaning: str = "") -> int:
    """An integer property in ``minimum..maximum``; ``meaning`` (e.g. what 0 does) is
    added to the range error."""
    value = checks.integer(props[name] if name in props else default, name)
    if not minimum <= value <= maximum:
        note = f" ({meaning})" if meaning else ""
        raise ValueError(f"{name}: expected an integer in {minimum}..{maximum}{note}, got {value}")
    return value


def scalar_transform(value, name: str = "to_world") -> mi.ScalarTransform4f:
    """A ``mi.ScalarTransform4f`` from any Mitsuba transform (float or double) or a 4x4 matrix:
    finite and not singular, else a ValueError naming ``name``."""
    try:
        matrix = np.array(value.matrix if hasattr(value, "matrix") else value, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError(f"{name}: expected a transform or a 4x4 matrix, got {type(value).__name__}") from None
    if matrix.shape != (4, 4) or not np.all(np.isfinite(matrix)):
        raise ValueError(f"{name}: expected a finite 4x4 transform, got shape {matrix.shape}")
    if abs(np.linalg.det(matrix[:3, :3])) < 1e-30:
        raise ValueError(f"{name}: the transform is singular (a zero scale?)")
    return mi.ScalarTransform4f(mi.ScalarMatrix4f(matrix.astype(np.float32)))


def transform_property(props, name: str = "to_world") -> mi.ScalarTransform4f:
    """A transform property (``<transform>``, or a 4x4 matrix from Python) as a checked
    ``mi.ScalarTransform4f`` (:func:`scalar_transform`); the identity when absent."""
    return scalar_transform(props[name] if name in props else mi.ScalarTransform4f(), name)
