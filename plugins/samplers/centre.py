"""The ``centre`` sampler: every sample at the pixel centre (a one-point rule: no anti-aliasing)."""

from __future__ import annotations

import mitsuba as mi

from pointillist.plugins.samplers._base import PatternSampler

__all__ = ["CentreSampler"]


class CentreSampler(PatternSampler):
    r"""
    Pixel-centre sampler (:monosp:`centre`)
    ---------------------------------------

    .. pluginparameters::

     * - sample_count
       - |int|
       - Number of samples per pixel (Default: 4).
     * - seed
       - |int|
       - Seed offset of the random numbers of the non-image dimensions (Default: 0).

    Every sample of a pixel sits at its centre (0.5, 0.5): the pixel's area is not
    integrated at all (edges alias as with one sample); the other dimensions get
    hashed random numbers as in :monosp:`grid`.
    """

    def _configure(self, spp: int) -> None:
        pass

    def _pattern(self, sample, pixel_key):
        return mi.Float(0.5), mi.Float(0.5)

    def to_string(self) -> str:
        return f"CentreSampler[sample_count={self.sample_count()}, seed={self._base_seed}]"


PLUGIN_CLASS = CentreSampler
