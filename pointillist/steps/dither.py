"""``pointillist post`` step ``dither`` (imaging.dither): error diffusion, ordered, pattern, halftone.

Examples: ``--dither floyd_steinberg``, ``--dither floyd_steinberg:levels=4,serpentine=true``,
``--dither jarvis_judice_ninke``, ``--dither ordered:levels=4``, ``--dither bayer:n=8``,
``--dither blue_noise``, ``--dither pattern``, ``--dither halftone:n=3``,
``--dither error_diffusion``, ``--dither threshold:level=100``; ``--report`` prints the SPEC
dither error (total and average intensity of the result minus the original's).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pointillist.imaging import dither
from pointillist.steps import step

#: Methods and the keyword options each accepts (besides ``method``).
METHODS: dict[str, tuple[str, ...]] = {
    "threshold": ("level",),
    "error_diffusion": ("level", "levels", "linear"),
    **{name: ("level", "levels", "serpentine", "linear") for name in dither.KERNELS},
    "ordered": ("n", "levels", "linear"),
    "bayer": ("n", "levels", "linear"),
    "blue_noise": ("levels", "linear"),
    "pattern": ("n", "levels", "linear"),
    "halftone": ("n",),
}


def _report(before: Any, after: Any) -> dict[str, float]:
    """The SPEC dither error; for halftone (n times larger) the average is per unit area."""
    before_shape, after_shape = tuple(before.shape), tuple(after.shape)
    if before_shape == after_shape:
        error = dither.dither_error(before, after)
        return {"dither error total": error.total, "dither error average": error.average}
    a = np.asarray(before, dtype=np.float64)
    b = np.asarray(after, dtype=np.float64)
    average = float(b.mean() - a.mean())
    return {"dither error total": average * a.size, "dither error average": average}


@step("dither", params=("method",), report=_report,
      help="dither to 1 bit (or levels=N): " + ", ".join(METHODS)
           + "; options level, levels, serpentine, n, linear")
def _dither(image, method: str = "floyd_steinberg", **options):
    if not isinstance(method, str) or method not in METHODS:
        raise ValueError(f"dither: method: expected one of {', '.join(METHODS)}, got {method!r}")
    unknown = sorted(set(options) - set(METHODS[method]))
    if unknown:
        raise ValueError(f"dither: {method} takes the options {', '.join(METHODS[method]) or 'none'}, "
                         f"got {', '.join(unknown)}")
    if method == "threshold":
        return dither.threshold(image, options.get("level", 128))
    if method == "error_diffusion":
        return dither.error_diffusion(image, **options)
    if method in dither.KERNELS:
        return dither.diffuse(image, method, **options)
    if method == "halftone":
        return dither.halftone(image, options.get("n", 3))
    if method == "blue_noise":
        return dither.blue_noise(image, **options)
    n = options.pop("n", 4)
    if method == "pattern":
        template = dither.TEMPLATE_4 if n == 4 else dither.bayer(n)
        return dither.pattern(image, template, **options)
    return dither.ordered(image, dither.TEMPLATE_4 if n == 4 else dither.bayer(n), **options)
