"""The ``grid`` sampler: samples at the centres of a regular sub-pixel grid."""

from __future__ import annotations

import warnings

import drjit as dr
import mitsuba as mi

from pointillist.plugins.samplers._base import PatternSampler, grid_shape

__all__ = ["GridSampler", "MAX_GRID_ASPECT"]

#: Largest cols / rows ratio accepted without a warning (2: e.g. 8 = 2 x 4, 32 = 4 x 8).
MAX_GRID_ASPECT = 2.0


class _GridLayout(PatternSampler):
    """Shared grid layout of ``grid`` and ``jitter``: ``rows x cols == sample_count``."""

    def _configure(self, spp: int) -> None:
        rows, cols = grid_shape(spp)
        if cols / rows > MAX_GRID_ASPECT:
            warnings.warn(
                f"{self.PLUGIN_NAME} sampler: sample_count {spp} has no factorisation close to a "
                f"square; using a {rows} x {cols} grid (choose a square or 2:1 count such as "
                f"{_nearest_nice(spp)} for even strata)", RuntimeWarning, stacklevel=2)
        self.rows, self.cols = rows, cols

    def _cell(self, sample):
        """Column and row of ``sample`` (row-major: sample = row * cols + col) as floats."""
        cols = dr.opaque(mi.UInt32, self.cols)
        row = sample // cols
        col = sample - row * cols
        return mi.Float(col), mi.Float(row)

    def _cell_size(self):
        return dr.opaque(mi.Float, 1.0 / self.cols), dr.opaque(mi.Float, 1.0 / self.rows)


def _nearest_nice(spp: int) -> int:
    """The nearest count whose grid is square or 1:2."""
    best = None
    for n in range(1, 2 * spp + 2):
        rows, cols = grid_shape(n)
        if cols / rows <= MAX_GRID_ASPECT and (best is None or abs(n - spp) < abs(best - spp)):
            best = n
    return best


class GridSampler(_GridLayout):
    r"""
    Regular grid sampler (:monosp:`grid`)
    -------------------------------------

    .. pluginparameters::

     * - sample_count
       - |int|
       - Number of samples per pixel (Default: 4). Laid out as ``rows x cols ==
         sample_count`` with ``rows`` the largest divisor of the count not above its
         square root (16: 4 x 4; 8: 2 x 4; 12: 3 x 4). Counts whose grid is longer than
         2:1 (primes such as 7: 1 x 7) are used as they are, with a ``RuntimeWarning``.
     * - seed
       - |int|
       - Seed offset of the random numbers of the non-image dimensions (Default: 0).

    Sample ``s`` of every pixel sits at the centre of grid cell
    ``(col, row) = (s mod cols, s div cols)``, i.e. at sub-pixel position
    ``((col + 0.5) / cols, (row + 0.5) / rows)``: the same deterministic pattern in
    every pixel, for every seed (the classic supersampling grid, which aliases on
    patterns at the grid frequency). With one sample that is the pixel centre.

    Only the image plane (the first 2D request after ``seed``, which Mitsuba's
    sampling integrators use for the film position) follows the grid; every other
    dimension (lens, time, lights, BSDFs) gets uniform random numbers hashed from
    ``(seed, pixel, sample, dimension)`` with TEA, so any (pixel, sample) can be
    reproduced on its own and the grid does not correlate with the light or BSDF
    samples.

    .. tabs::
        .. code-tab:: xml

            <sampler type="grid">
                <integer name="sample_count" value="16"/>
            </sampler>

        .. code-tab:: python

            'type': 'grid',
            'sample_count': 16
    """

    PLUGIN_NAME = "grid"

    def _pattern(self, sample, pixel_key):
        col, row = self._cell(sample)
        width, height = self._cell_size()
        return (col + 0.5) * width, (row + 0.5) * height

    def to_string(self) -> str:
        return (f"GridSampler[sample_count={self.sample_count()}, grid={self.rows}x{self.cols}, "
                f"seed={self._base_seed}]")


PLUGIN_NAME = "grid"
PLUGIN_CLASS = GridSampler
