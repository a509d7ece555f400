"""Every dithering method by name (:func:`dither`) and the dither error of a result."""

from __future__ import annotations

import inspect
from functools import lru_cache
from typing import Any, Callable, NamedTuple

import drjit as dr
from drjit.llvm.ad import Float64

from pointillist.imaging.arrays import TensorXf, TensorXu8, as_tensor
from pointillist.imaging.dither.diffusion import KERNELS, diffuse, error_diffusion
from pointillist.imaging.dither.templates import bayer, blue_noise, halftone, ordered, pattern
from pointillist.imaging.filters import threshold

__all__ = ["DitherError", "DITHER_METHODS", "dither", "dither_options", "dither_error"]


class DitherError(NamedTuple):
    """The error of a dithered image: its total and average intensity minus the original's.

    As :ref:`conventions-dithering` defines it."""

    total: float
    average: float



def _threshold_method(image: Any, *, level: float = 128) -> TensorXf | TensorXu8:
    return threshold(image, level)


def _ordered_method(image: Any, *, n: int = 4, levels: int = 2, linear: bool = False) -> TensorXf | TensorXu8:
    return ordered(image, bayer(n), levels=levels, linear=linear)


def _pattern_method(image: Any, *, n: int = 4, levels: int = 2, linear: bool = False) -> TensorXf | TensorXu8:
    return pattern(image, bayer(n), levels=levels, linear=linear)


def _blue_noise_method(image: Any, *, levels: int = 2, linear: bool = False) -> TensorXf | TensorXu8:
    return blue_noise(image, levels=levels, linear=linear)


def _halftone_method(image: Any, *, n: int = 3) -> TensorXf | TensorXu8:
    return halftone(image, n)


def _kernel_method(kernel: str) -> Any:
    def method(image: Any, *, level: float = 128, levels: int = 2, serpentine: bool = False,
               linear: bool = False) -> TensorXf | TensorXu8:
        return diffuse(image, kernel, level=level, levels=levels, serpentine=serpentine, linear=linear)

    return method


#: The methods of :func:`dither`, by name: each a function ``(image, **options)`` whose keyword
#: parameters are the method's options and defaults. ``ordered``/``bayer`` and ``pattern`` use the
#: ``n`` x ``n`` Bayer matrix (``n=4``: the conventions' :data:`TEMPLATE_4`).
DITHER_METHODS: dict[str, Callable[..., TensorXf | TensorXu8]] = {
    "threshold": _threshold_method,
    "error_diffusion": error_diffusion,
    **{name: _kernel_method(name) for name in KERNELS},
    "ordered": _ordered_method,
    "bayer": _ordered_method,
    "blue_noise": _blue_noise_method,
    "pattern": _pattern_method,
    "halftone": _halftone_method,
}


@lru_cache(maxsize=None)
def dither_options(method: str) -> tuple[str, ...]:
    """The option names :func:`dither` takes for ``method`` (the keyword parameters of its function).

    Examples
    --------
    >>> from pointillist.imaging.dither import dither_options
    >>> dither_options("halftone"), dither_options("ordered")
    (('n',), ('n', 'levels', 'linear'))
    """
    if not isinstance(method, str) or method not in DITHER_METHODS:
        raise ValueError(f"method: expected one of {', '.join(DITHER_METHODS)}, got {method!r}")
    parameters = list(inspect.signature(DITHER_METHODS[method]).parameters.values())[1:]
    return tuple(p.name for p in parameters)


def dither(image: Any, method: str = "floyd_steinberg", **options: Any) -> TensorXf | TensorXu8:
    """Dither ``image`` with the named ``method`` of :data:`DITHER_METHODS` and its ``options``.

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
        Intensities on 0..255.
    method : str
        ``threshold`` (option ``level``), ``error_diffusion`` (``level``, ``levels``, ``linear``),
        an error-diffusion kernel of :data:`KERNELS` such as ``floyd_steinberg`` (``level``,
        ``levels``, ``serpentine``, ``linear``; see :func:`diffuse`), ``ordered`` or ``bayer``
        (``n``, ``levels``, ``linear``), ``blue_noise`` (``levels``, ``linear``; the shipped mask),
        ``pattern`` (``n``, ``levels``, ``linear``) or ``halftone`` (``n``).
    **options
        The method's options (:func:`dither_options`); values are checked by the method.

    Returns
    -------
    drjit.llvm.ad.TensorXf or drjit.llvm.ad.TensorXu8
        The dithered image (``halftone``: n times larger in each direction); uint8 for uint8 input
        (numpy ``uint8`` or ``TensorXu8``), float32 otherwise.

    Raises
    ------
    ValueError
        For an unknown method or an option the method does not take.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.dither import dither
    >>> np.asarray(dither(np.full((2, 4), 64.0), "floyd_steinberg")).tolist()
    [[0.0, 0.0, 0.0, 0.0], [0.0, 255.0, 0.0, 255.0]]
    >>> np.asarray(dither(np.array([[128.0]]), "halftone", n=2)).astype(int).tolist()
    [[0, 0], [255, 255]]
    >>> out = dither(np.full((2, 4), 64, np.uint8), "floyd_steinberg")
    >>> np.asarray(out).dtype, np.asarray(out).tolist()
    (dtype('uint8'), [[0, 0, 0, 0], [0, 255, 0, 255]])
    """
    allowed = dither_options(method)
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise ValueError(f"{unknown[0]}: not an option of dither method {method!r} "
                         f"(its options: {', '.join(allowed) or 'none'})")
    return DITHER_METHODS[method](image, **options)


# --------------------------------------------------------------------------------------------
# error


def dither_error(original: Any, result: Any) -> DitherError:
    """The conventions' dither error: total (and average) intensity of ``result`` minus ``original``'s.

    Sums in float64 over every value (all channels). NaN anywhere gives NaN.

    Parameters
    ----------
    original, result : array_like or Dr.Jit tensor
        Images of the same shape.

    Returns
    -------
    DitherError
        ``total`` = sum(result) - sum(original), ``average`` = total / number of values.

    Examples
    --------
    >>> from pointillist.imaging.dither import dither_error
    >>> dither_error([[100.0, 100.0]], [[0.0, 255.0]])
    DitherError(total=55.0, average=27.5)
    """
    a = as_tensor(original, "original")
    b = as_tensor(result, "result")
    if tuple(a.shape) != tuple(b.shape):
        raise ValueError(f"result: expected the shape of original {tuple(a.shape)}, got {tuple(b.shape)}")
    total = dr.sum(Float64(b.array) - Float64(a.array), mode="evaluated")
    total = float(total[0] if dr.width(total) else total)
    count = dr.width(a.array)
    return DitherError(total, total / count)
