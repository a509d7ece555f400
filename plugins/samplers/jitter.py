"""The ``jitter`` sampler: the regular grid, each sample moved randomly inside its own cell."""

from __future__ import annotations

import mitsuba as mi

from pointillist.plugins.samplers._base import PIXEL_OFFSET_TAG, TEA_ROUNDS, GridLayout, unit_float

__all__ = ["JitterSampler"]

#: Second TEA input of the jitter offsets. The jitter is hashed from the sample key
#: with this tag, apart from the per-dimension numbers (whose tags are the dimension
#: index, small integers) and from the per-pixel offset tag.
JITTER_TAG = PIXEL_OFFSET_TAG - 1


class JitterSampler(GridLayout):
    r"""
    Jittered (stratified) sampler (:monosp:`jitter`)
    ------------------------------------------------

    .. pluginparameters::

     * - sample_count
       - |int|
       - Number of samples per pixel (Default: 4); the strata form a ``rows x cols``
         grid exactly as in :monosp:`grid` (16: 4 x 4, 8: 2 x 4, 12: 3 x 4; counts
         whose grid is longer than 2:1, such as primes, with a ``RuntimeWarning``).
     * - seed
       - |int|
       - Seed offset (Default: 0).

    Sample ``s`` of a pixel is drawn uniformly inside its own grid cell
    ``(col, row) = (s mod cols, s div cols)``:
    ``((col + u) / cols, (row + v) / rows)`` with ``(u, v)`` uniform in [0, 1)^2,
    hashed from ``(seed, pixel, sample)``. Every cell holds exactly one sample, so
    the image-plane estimate of an edge converges as spp^-1.5 in MSE instead of
    random sampling's spp^-1. With one sample it is uniform random sampling.

    Only the image plane (the first 2D request after ``seed``) is stratified; other
    dimensions get decorrelated uniform random numbers hashed from
    ``(seed, pixel, sample, dimension)`` (Mitsuba's :monosp:`stratified` instead
    stratifies every dimension, with a shuffled sample order per dimension).

    .. tabs::
        .. code-tab:: xml

            <sampler type="jitter">
                <integer name="sample_count" value="16"/>
            </sampler>

        .. code-tab:: python

            'type': 'jitter',
            'sample_count': 16
    """

    def _pattern(self, sample, pixel_key):
        col, row = self._cell(sample)
        width, height = self._cell_size()
        u, v = mi.sample_tea_32(self.m_sample_key, mi.UInt32(JITTER_TAG), TEA_ROUNDS)
        return (col + unit_float(u)) * width, (row + unit_float(v)) * height

    def to_string(self) -> str:
        return (f"JitterSampler[sample_count={self.sample_count()}, grid={self.rows}x{self.cols}, "
                f"seed={self._base_seed}]")


#: The plugin's class, which pointillist.plugins registers with Mitsuba under this file's name.
PLUGIN_CLASS = JitterSampler
