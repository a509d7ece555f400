"""Write ``scenes/sun_sky.exr``, the environment map of ``scenes/sun_sky.xml``.

A 128 x 64 latitude-longitude map (Mitsuba's ``envmap``: row 0 is straight up): a sky that goes
from deep blue at the zenith to pale blue at the horizon, a dim grey ground, and a sun of one
texel (about 2.8 x 2.8 degrees) of radiance 2000 at 35 degrees above the horizon, which gives
about 1.7 times the sky's irradiance on the ground (2.2 and 1.3 in green). Deterministic: rerun
to recreate the file.

    .venv/bin/python scenes/sun_sky.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

WIDTH, HEIGHT = 128, 64
SUN_ROW, SUN_COLUMN, SUN_RADIANCE = 19, 40, 2000.0   # row 19 of 64: 90 - (19.5 / 64) * 180 = 35 degrees up


def sun_sky() -> np.ndarray:
    """The map as (64, 128, 3) float32 RGB radiance."""
    elevation = 90.0 - (np.arange(HEIGHT) + 0.5) / HEIGHT * 180.0            # degrees, per row
    t = np.clip(elevation / 90.0, 0.0, 1.0)[:, None]
    zenith, horizon = np.array([0.1, 0.2, 0.5]), np.array([0.5, 0.6, 0.75])
    sky = (1 - t) * horizon + t * zenith
    ground = np.array([0.12, 0.11, 0.1])
    rows = np.where((elevation > 0)[:, None], sky, ground)
    image = np.repeat(rows[:, None, :], WIDTH, axis=1)
    image[SUN_ROW, SUN_COLUMN] = SUN_RADIANCE * np.array([1.0, 0.95, 0.85])
    return image.astype(np.float32)


if __name__ == "__main__":
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    from pointillist.imaging.io import write_exr

    write_exr(Path(__file__).with_suffix(".exr"), sun_sky())
