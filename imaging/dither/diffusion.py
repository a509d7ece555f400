"""Error diffusion: the kernels (Floyd-Steinberg and others) and the simple diffusion,
scheduled as wavefronts (:mod:`pointillist.imaging.wavefront`)."""

from __future__ import annotations

from typing import Any, NamedTuple

import drjit as dr
from drjit.llvm.ad import Float, UInt8

from pointillist.imaging.arrays import TensorXf, TensorXu8, eager_if_shared
from pointillist.imaging.dither._shared import (_check_bool, _check_level, _check_levels, _pixels, _quantiser,
                                                _srgb_decode_255)
from pointillist.imaging.wavefront import clip_intensity, diffuse_wavefront

__all__ = ["KERNELS", "DiffusionKernel", "diffuse", "floyd_steinberg", "error_diffusion"]


class DiffusionKernel(NamedTuple):
    """An error-diffusion kernel: ``weights`` are ``(dy, dx, numerator)`` for a left-to-right scan.

    The error of a pixel is sent to (y + dy, x + dx) with weight ``numerator / divisor`` (mirrored
    in x on right-to-left rows of a serpentine scan).
    """

    name: str
    weights: tuple[tuple[int, int, int], ...]
    divisor: int
    source: str


#: Error-diffusion kernels, by name (weights from the cited papers; the usual tables, e.g. in
#: Lee Crocker et al., "DHALF.TXT", 1991, and Ulichney, "Digital Halftoning", 1987).
KERNELS: dict[str, DiffusionKernel] = {k.name: k for k in (
    DiffusionKernel("floyd_steinberg", ((0, 1, 7), (1, -1, 3), (1, 0, 5), (1, 1, 1)), 16,
                    "Floyd & Steinberg, Proc. SID 17(2), 1976"),
    DiffusionKernel("jarvis_judice_ninke",
                    ((0, 1, 7), (0, 2, 5), (1, -2, 3), (1, -1, 5), (1, 0, 7), (1, 1, 5), (1, 2, 3),
                     (2, -2, 1), (2, -1, 3), (2, 0, 5), (2, 1, 3), (2, 2, 1)), 48,
                    "Jarvis, Judice & Ninke, Comput. Graph. Image Process. 5(1), 1976"),
    DiffusionKernel("stucki",
                    ((0, 1, 8), (0, 2, 4), (1, -2, 2), (1, -1, 4), (1, 0, 8), (1, 1, 4), (1, 2, 2),
                     (2, -2, 1), (2, -1, 2), (2, 0, 4), (2, 1, 2), (2, 2, 1)), 42,
                    "Stucki, IBM Research Report RZ1060, 1981"),
    DiffusionKernel("atkinson", ((0, 1, 1), (0, 2, 1), (1, -1, 1), (1, 0, 1), (1, 1, 1), (2, 0, 1)), 8,
                    "Bill Atkinson, Apple MacPaint, 1984 (diffuses 6/8 of the error)"),
    DiffusionKernel("burkes", ((0, 1, 8), (0, 2, 4), (1, -2, 2), (1, -1, 4), (1, 0, 8), (1, 1, 4), (1, 2, 2)),
                    32, "Daniel Burkes, CIS Graphics Support Forum, 1988"),
    DiffusionKernel("sierra",
                    ((0, 1, 5), (0, 2, 3), (1, -2, 2), (1, -1, 4), (1, 0, 5), (1, 1, 4), (1, 2, 2),
                     (2, -1, 2), (2, 0, 3), (2, 1, 2)), 32,
                    "Frankie Sierra, three-row filter, 1989"),
    DiffusionKernel("sierra_lite", ((0, 1, 2), (1, -1, 1), (1, 0, 1)), 4, "Frankie Sierra, filter lite, 1990"),
)}

#: The simple error diffusion of the conventions: 100 % of the error to the next pixel of the scan.
SIMPLE_KERNEL = DiffusionKernel("simple", ((0, 1, 1),), 1,
                                "100% of the error to the next pixel (the course's simple diffusion)")



def _diffuse(image: Any, kernel: DiffusionKernel, *, level: float, levels: int, serpentine: bool,
             linear: bool, carry: bool = False) -> TensorXf | TensorXu8:
    level = _check_level(level)
    levels = _check_levels(levels)
    serpentine = _check_bool(serpentine, "serpentine")
    linear = _check_bool(linear, "linear")
    values, shape = _pixels(image)
    eight_bit = isinstance(values, UInt8)
    clip = False
    if linear:
        values = _srgb_decode_255(clip_intensity(Float(values)))
    elif not eight_bit:  # clipped in the diffusion loop itself: no separate pass (bytes are read as they are)
        clip = True
    dr.eval(values)
    height, width = shape[0], shape[1]
    channels = shape[2] if len(shape) == 3 else 1
    weights = tuple((dy, dx, n / kernel.divisor) for dy, dx, n in kernel.weights)
    out = diffuse_wavefront(values, height, width, channels, weights, serpentine,
                        _quantiser(levels, level, linear), carry=carry, clip=clip, eight_bit=eight_bit)
    return TensorXu8(out, shape) if eight_bit else TensorXf(out, shape)


@eager_if_shared
def diffuse(image: Any, kernel: str = "floyd_steinberg", *, level: float = 128, levels: int = 2,
            serpentine: bool = False, linear: bool = False) -> TensorXf | TensorXu8:
    """Error diffusion with a named kernel, exact and parallel (one Dr.Jit kernel launch).

    Each pixel (in scan order) becomes the nearest output level by the threshold rule, and its
    error (value - output, in float64) is added to the pixels not yet scanned with the kernel's
    weights ``numerator / divisor`` (a float64 constant); error that would leave the image is
    dropped. The result is bit-identical to that sequential float64 scan (see the module notes for
    the wavefront schedule).

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
        Intensities on 0..255. NaN becomes 0 and values are clipped to 0..255 first (so one
        huge value cannot flood the image with error). Channels are diffused independently.
    kernel : str
        One of :data:`KERNELS`: ``floyd_steinberg``, ``jarvis_judice_ninke``, ``stucki``,
        ``atkinson``, ``burkes``, ``sierra``, ``sierra_lite``.
    level : float
        Threshold on 0..255 (the conventions: 128; ``>=`` becomes the upper level). For ``levels > 2`` the
        thresholds lie at the same fraction ``level / 255`` of each gap between levels.
    levels : int
        Number of output levels, 2..256, at ``k * 255 / (levels - 1)``. ``levels=256`` leaves
        integer input unchanged.
    serpentine : bool
        Scan odd rows right to left with the kernel mirrored (runs sequentially: a serpentine
        row cannot start before the previous one ends).
    linear : bool
        Decode sRGB first and diffuse in linear light: thresholds and errors are measured in
        linear light (the output levels keep their display values), so the mean linear light is
        preserved, as careful dithering tools do.

    Returns
    -------
    drjit.llvm.ad.TensorXf or drjit.llvm.ad.TensorXu8
        Same shape as ``image``; values in the ``levels`` output levels (uint8 input: uint8, rounded).

    Notes
    -----
    Edges: a constant 0 or 255 image stays constant (zero error); a 1 x 1 image is thresholded;
    1 x N and N x 1 images diffuse along their one row or column (lower rows do not exist, so that
    part of the error is dropped).

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.dither import diffuse
    >>> np.asarray(diffuse(np.full((1, 4), 100.0), "sierra_lite")).tolist()
    [[0.0, 255.0, 0.0, 0.0]]
    """
    if not isinstance(kernel, str) or kernel not in KERNELS:
        raise ValueError(f"kernel: expected one of {', '.join(KERNELS)}, got {kernel!r}")
    return _diffuse(image, KERNELS[kernel], level=level, levels=levels, serpentine=serpentine, linear=linear)


@eager_if_shared
def floyd_steinberg(image: Any, level: float = 128, serpentine: bool = False, *, levels: int = 2,
                    linear: bool = False) -> TensorXf | TensorXu8:
    """Floyd-Steinberg error diffusion: 7/16 right, 3/16 below-left, 5/16 below, 1/16 below-right.

    As :ref:`conventions-dithering` defines it.

    Same as ``diffuse(image, "floyd_steinberg", ...)``; see :func:`diffuse` for the parameters,
    the edges of the domain and exactness.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.dither import floyd_steinberg
    >>> np.asarray(floyd_steinberg(np.array([[100.0, 100.0]]))).tolist()
    [[0.0, 255.0]]
    """
    return _diffuse(image, KERNELS["floyd_steinberg"], level=level, levels=levels, serpentine=serpentine,
                    linear=linear)


@eager_if_shared
def error_diffusion(image: Any, level: float = 128, *, levels: int = 2, linear: bool = False) -> TensorXf | TensorXu8:
    """Simple error diffusion: 100 % of each pixel's error goes to the next pixel, serpentine.

    As :ref:`conventions-dithering` defines it.

    The scan runs left to right on even rows and right to left on odd rows; the next pixel after
    the end of a row is the pixel below it (the first of the next row in the scan), so the error
    follows the serpentine path and only the last pixel's error leaves the image. The scan is
    inherently sequential; it runs as one lane per channel inside one kernel.

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
        Intensities on 0..255 (NaN -> 0, clipped to 0..255).
    level : float
        Threshold (the conventions: 128, ``>=`` goes up).
    levels : int
        Output levels 2..256 (see :func:`diffuse`).
    linear : bool
        Diffuse in linear light (see :func:`diffuse`).

    Returns
    -------
    drjit.llvm.ad.TensorXf or drjit.llvm.ad.TensorXu8
        Same shape; values in the output levels (uint8 input: uint8, rounded).

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.dither import error_diffusion
    >>> np.asarray(error_diffusion(np.array([[100.0, 100.0], [100.0, 100.0]]))).tolist()
    [[0.0, 255.0], [255.0, 0.0]]
    """
    return _diffuse(image, SIMPLE_KERNEL, level=level, levels=levels, serpentine=True, linear=linear, carry=True)

