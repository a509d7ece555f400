"""Tone mapping: linear HDR renders to display values through a table of operators.

Each operator is a module of this package that ends with ``register(TonemapOperator(...))``;
importing the package imports every module in it, so a new operator is one new module (and its
tests): :func:`tonemap`, its documentation, ``pointillist post --steps tonemap:...`` and the
checks of its parameters take it from :data:`TONEMAP_TABLE`.
"""

from __future__ import annotations

import importlib
import pkgutil
from typing import Any

import drjit as dr
from drjit.llvm.ad import Array3f, Float, UInt32

from pointillist.core import checks
from pointillist.imaging.arrays import TensorXf, as_tensor, eager_if_shared, opaque_scalar
from pointillist.imaging.colour import srgb_encode_values
from pointillist.imaging.tone._shared import _finish
from pointillist.imaging.tone.operators._curves import HDR_MAX
from pointillist.imaging.tone.operators._registry import TONEMAP_TABLE, TonemapOperator, register

for _module in pkgutil.iter_modules(__path__):
    if not _module.name.startswith("_"):
        importlib.import_module(f"{__name__}.{_module.name}")

from pointillist.imaging.tone.operators.aces import ACES_CONSTANTS  # noqa: E402
from pointillist.imaging.tone.operators.hable import HABLE_CONSTANTS  # noqa: E402

__all__ = ["TONEMAP_OPERATORS", "TONEMAP_TABLE", "TonemapOperator", "HABLE_CONSTANTS", "ACES_CONSTANTS", "tonemap",
           "register"]

# documented here, where they are used (their module is this package's private registry)
TonemapOperator.__module__ = register.__module__ = __name__

#: Tone-mapping operators and the extra keyword parameters each accepts (from :data:`TONEMAP_TABLE`).
TONEMAP_OPERATORS: dict[str, tuple[str, ...]] = {name: op.parameters for name, op in TONEMAP_TABLE.items()}


@eager_if_shared
def tonemap(image: Any, operator: str = "clip", exposure: float = 0.0, **params: Any) -> TensorXf:
    """Tone-map a linear HDR render to display values 0..255 (curve, then the sRGB encoding).

    The image is scaled by 2^exposure, mapped to 0..1 by ``operator``, clipped,
    sRGB-encoded (:func:`imaging.colour.srgb_encode`) and scaled to 0..255.

    Operators (x a linear value, L the Rec. 709 luminance, w the white point), one module each:

    {operators}

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W), (H, W, 1) or (H, W, 3)
        Linear light (an EXR render).
    operator : str
        One of :data:`TONEMAP_OPERATORS`.
    exposure : float
        Stops: the image is multiplied by 2^exposure first; -100..100.
    **params
        ``white`` (> 0) for the operators that take it.

    Returns
    -------
    drjit.llvm.ad.TensorXf
        Same shape, display values in [0, 255] (not rounded).

    Raises
    ------
    ValueError
        Unknown ``operator``, a parameter the operator does not take, a
        non-positive ``white``, or ``exposure`` outside -100..100.

    Notes
    -----
    Negative values become 0; values are clamped at 1e15 after exposure (all
    curves are saturated long before; 1e30 maps to white without overflow).
    NaN -> 0, +inf -> 255, -inf -> 0, with a :class:`NonFiniteWarning` giving
    the count; the default white point ignores them. An all-black image stays
    black. Luminance operators scale colour by L_d / L (hue kept); channels
    above 1 after that are clipped.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.tone import tonemap
    >>> np.asarray(tonemap(np.array([[0.0, 1.0, 3.0]]), "reinhard", white=np.inf), dtype=float).round(2).tolist()
    [[0.0, 187.52, 224.61]]
    """
    if not isinstance(operator, str) or operator not in TONEMAP_TABLE:
        raise ValueError(f"operator: expected one of {', '.join(TONEMAP_OPERATORS)}, got {operator!r}")
    exposure = checks.real(exposure, "exposure", low=-100.0, high=100.0)
    unknown = set(params) - set(TONEMAP_TABLE[operator].parameters)
    if unknown:
        allowed = ", ".join(TONEMAP_TABLE[operator].parameters) or "none"
        raise ValueError(f"{sorted(unknown)[0]}: not a parameter of tonemap operator {operator!r} "
                         f"(it takes: {allowed})")
    white = params.get("white")
    if white is not None:
        white = checks.real(white, "white", low=0.0, low_open=True, allow_inf=True)

    tensor = as_tensor(image, channels=(1, 3))
    count = dr.zeros(UInt32, 1)
    scale = opaque_scalar(Float, 2.0 ** exposure)

    def prepare(values: Float) -> tuple[Float, Float]:
        """Sanitised, exposed, clamped channel and its +inf mask (counted); per pixel, so that
        the whole operator is one pass over the (H, W, 3) data, not one per step."""
        bad = ~dr.isfinite(values)
        dr.scatter_add(count, 1, UInt32(0), active=bad)
        return dr.clip(dr.select(bad, 0.0, values) * scale, 0.0, HDR_MAX), bad & (values > 0)

    if tensor.ndim == 3 and tensor.shape[2] == 3:
        rgb = dr.unravel(Array3f, tensor.array)
        prepared = [prepare(c) for c in (rgb.x, rgb.y, rgb.z)]
    else:
        prepared = [prepare(tensor.array)]
    channels = [c for c, _ in prepared]
    posinf = [p for _, p in prepared]

    mapped = TONEMAP_TABLE[operator].curve(channels, white)

    display = [dr.select(inf, 255.0, srgb_encode_values(dr.clip(m, 0.0, 1.0)) * 255.0)
               for m, inf in zip(mapped, posinf)]
    values = dr.ravel(Array3f(*display)) if len(display) == 3 else display[0]
    return _finish(TensorXf(values, tensor.shape), count, "tonemap")



def _operator_list() -> str:
    """The operators of :data:`TONEMAP_TABLE` as the bullet list of :func:`tonemap`'s documentation."""
    import textwrap

    items = []
    for name, op in TONEMAP_TABLE.items():
        text = f"- ``{name}``: {op.summary}."
        items.append(textwrap.fill(text, 92, subsequent_indent="  ")
                     .replace("\n", "\n    "))
    return "\n    ".join(items)


tonemap.__doc__ = tonemap.__doc__.replace("{operators}", _operator_list())
