"""The ``centre`` sampler: every sample at the pixel centre."""

from __future__ import annotations

from pathlib import Path

import numpy as np

EDGES = Path(__file__).resolve().parent.parent / "scenes" / "edges.xml"


def test_centre_is_the_pixel_centre_whatever_the_count(mi):
    """edges.xml (a point light, `direct`) is a function of the film position alone: 16 samples at the
    centre give grid's one sample, which sits at the centre of its one cell."""
    from pointillist.compare.methods import METHODS, load_configured_scene

    centre = np.asarray(mi.render(load_configured_scene(EDGES, METHODS["centre"], 16, {"res": "16"})))
    grid = np.asarray(mi.render(load_configured_scene(EDGES, METHODS["grid"], 1, {"res": "16"})))
    assert centre.std() > 0.05
    np.testing.assert_allclose(centre, grid, rtol=1e-6, atol=1e-7)
