"""The ``grid`` sampler: samples at the centres of a regular sub-pixel grid."""

from __future__ import annotations

from pointillist.plugins.samplers._base import MAX_GRID_ASPECT, GridLayout

__all__ = ["GridSampler", "MAX_GRID_ASPECT"]


class GridSampler(GridLayout):
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

    def _pattern(self, sample, pixel_key):
        col, row = self._cell(sample)
        width, height = self._cell_size()
        return (col + 0.5) * width, (row + 0.5) * height

    def to_string(self) -> str:
        return (f"GridSampler[sample_count={self.sample_count()}, grid={self.rows}x{self.cols}, "
                f"seed={self._base_seed}]")


#: The plugin's class, which pointillist.plugins registers with Mitsuba under this file's name.
PLUGIN_CLASS = GridSampler
