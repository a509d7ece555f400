"""``pointillist post`` step ``dither`` (imaging.dither): error diffusion, ordered, pattern, halftone.

Examples: ``--dither floyd_steinberg``, ``--dither floyd_steinberg:levels=4,serpentine=true``,
``--dither jarvis_judice_ninke``, ``--dither ordered:levels=4``, ``--dither bayer:n=8``,
``--dither blue_noise``, ``--dither pattern``, ``--dither halftone:n=3``,
``--dither error_diffusion``, ``--dither threshold:level=100``; ``--report`` prints the conventions'
dither error (total and average intensity of the result minus the original's).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pointillist.imaging import dither
from pointillist.steps import step


def _report(before: Any, after: Any) -> dict[str, float]:
    """The dither error of the conventions; for halftone (n times larger) the average is per unit area."""
    before_shape, after_shape = tuple(before.shape), tuple(after.shape)
    if before_shape == after_shape:
        error = dither.dither_error(before, after)
        return {"dither error total": error.total, "dither error average": error.average}
    a = np.asarray(before, dtype=np.float64)
    b = np.asarray(after, dtype=np.float64)
    average = float(b.mean() - a.mean())
    return {"dither error total": average * a.size, "dither error average": average}


@step("dither", params=("method",), report=_report,
      help="dither to 1 bit (or levels=N): " + ", ".join(dither.DITHER_METHODS) + "; options "
           + ", ".join(dict.fromkeys(o for m in dither.DITHER_METHODS for o in dither.dither_options(m))))
def _dither(image, method: str = "floyd_steinberg", **options):
    return dither.dither(image, method, **options)
