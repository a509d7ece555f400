"""``pointillist post`` steps for spatial filtering and resampling (imaging.filters, imaging.resample).

Examples: ``--steps "sobel;normalize;threshold:level=128"``,
``--steps "correlate:gaussian,border=reflect,normalize=true"``,
``--steps "laplacian;zero_crossings"``, ``--steps "median:5"``,
``--steps "resize:512,256,bicubic"``.
"""

from __future__ import annotations

from pointillist.imaging import filters, resample
from pointillist.steps import step


def _ring(radius: int, default: str = "zero"):
    """``Step.ring`` of a window step of this radius: the ring is uncomputed for the zero and keep
    borders (crop drops it, the padded borders compute it)."""
    return lambda kwargs: radius if kwargs.get("border", default) in ("zero", "keep") else 0


@step("correlate", params=("kernel", "border", "normalize"), ring=_ring(1),
      help="cross-correlate with a named kernel (" + ", ".join(filters.KERNELS) + "); "
           "border zero|crop|keep|clamp|reflect|mirror|wrap|constant; normalize=true stretches |I| to 0..255")
def _correlate(image, kernel, border="zero", normalize=False):
    if not isinstance(kernel, str):
        raise ValueError(f"correlate: kernel: expected a kernel name ({', '.join(filters.KERNELS)}), got {kernel!r}")
    return filters.correlate(image, kernel, border=border, normalize=normalize)


@step("sobel", params=("border",), ring=_ring(1), help="Sobel gradient magnitude")
def _sobel(image, border="zero"):
    return filters.sobel(image, border=border)


@step("prewitt", params=("border",), ring=_ring(1), help="Prewitt gradient magnitude")
def _prewitt(image, border="zero"):
    return filters.prewitt(image, border=border)


@step("laplacian", params=("border",), ring=_ring(1), help="Laplacian (second derivative, 4-neighbour kernel)")
def _laplacian(image, border="zero"):
    return filters.laplacian(image, border=border)


@step("zero_crossings", params=("connectivity",),
      help="255 where a pixel above zero has a neighbour below zero (after laplacian)")
def _zero_crossings(image, connectivity=8):
    return filters.zero_crossings(image, connectivity=connectivity)


@step("normalize", params=("absolute", "ring"),
      help="min-max stretch of |I| to 0..255 (constant image -> 0); after a zero-border window step "
           "its uncomputed ring is left out (ring=N sets it)")
def _normalize(image, absolute=True, ring=0):
    return filters.normalize(image, absolute=absolute, ring=ring)


@step("threshold", params=("level",), help="values below level -> 0, at or above -> 255 (default 128)")
def _threshold(image, level=128, max_value=255.0):
    return filters.threshold(image, level, max_value=max_value)


@step("median", params=("size", "border"), help="median filter, odd size (default 3), border clamp",
      ring=lambda kwargs: _ring(int(kwargs.get("size", 3)) // 2, "clamp")(kwargs))
def _median(image, size=3, border="clamp"):
    return filters.median(image, size, border=border)


@step("resize", params=("width", "height", "method"), ring=lambda kwargs: 0,
      help="resize to width,height with nearest|bilinear|bicubic (a=-0.5, clamp=false)")
def _resize(image, width, height, method="bilinear", a=resample.KEYS_A, clamp=False):
    return resample.resize(image, (width, height), method, a=a, clamp=clamp)
