"""The ``sobol`` sampler: an Owen-scrambled Sobol' sequence in every pixel, in all dimensions."""

from __future__ import annotations

import functools

import drjit as dr
import mitsuba as mi

from pointillist.plugins.samplers._base import GOLDEN_GAMMA, TEA_ROUNDS, fmix32
from pointillist.plugins.samplers._sobol import TAG_SHUFFLE, TAG_X, SobolBase, bits_for, owen_scramble, \
    sobol_coordinate
from pointillist.plugins.samplers._sobol_matrices import SOBOL_BITS, SOBOL_DIMENSIONS, sobol_matrices

__all__ = ["SobolSampler"]

#: log2 of :data:`SOBOL_DIMENSIONS`: dimension ``d`` uses matrix ``d & (D - 1)`` in block ``d >> LOG2``.
_LOG2_DIMENSIONS = SOBOL_DIMENSIONS.bit_length() - 1


@functools.lru_cache(maxsize=1)
def _matrix_buffer():
    """The shipped generator matrices as one ``UInt32`` buffer: column ``k`` of dimension ``j`` at ``32 j + k``."""
    buffer = mi.UInt32(sobol_matrices().ravel())
    dr.eval(buffer)
    return buffer


class SobolSampler(SobolBase):
    r"""
    Owen-scrambled Sobol' sampler (:monosp:`sobol`)
    -----------------------------------------------

    .. pluginparameters::

     * - sample_count
       - |int|
       - Number of samples per pixel (Default: 4); any count, powers of two stratify best.
     * - seed
       - |int|
       - Seed offset (Default: 0).
     * - randomization
       - |string|
       - ``owen`` (Default): hash-based Owen scrambling, a fresh one per pixel and dimension;
         ``none``: the plain Sobol' sequence, the same in every pixel.

    Sample ``i`` of a pixel is point ``i`` of a Sobol' sequence (Joe and Kuo's generator
    matrices, natural order) in every dimension the integrator asks for, the film position
    being dimensions 0 and 1: so the first 2^m samples of a pixel form a (0, m, 2)-net there
    (every elementary interval of area 2^-m of the pixel holds one sample) and the sequence is
    low-discrepancy in all its dimensions together. Each coordinate is Owen-scrambled with a
    seed hashed from ``(seed, pixel, dimension)``, so any ``(seed, pixel, index, dimension)``
    is reproducible on its own, every sample is uniformly distributed, pixels are independent
    and the nets stay nets. Dimensions from 256 on (a path of about 40 bounces) reuse the
    matrices of dimension ``d mod 256`` with the sample index shuffled (a nested uniform
    shuffle per pixel and block of 256 dimensions, Burley 2020): stratified in each
    dimension, not jointly with the first 256.

    Per lane the state is the pixel's hash key, the sample index and the dimension counter
    (Dr.Jit ``UInt32``\ s). A request costs one hash, ``ceil(log2 spp)`` gathers of matrix
    columns per coordinate and the scramble.

    .. tabs::
        .. code-tab:: xml

            <sampler type="sobol">
                <integer name="sample_count" value="16"/>
            </sampler>

        .. code-tab:: python

            'type': 'sobol',
            'sample_count': 16
    """

    _STATE = ("m_pixel_key", "m_sample")

    def _configure(self, spp: int) -> None:
        self.index_bits = bits_for(spp)
        # Constant buffers live in a tuple: Dr.Jit does not traverse it as per-lane (loop) state.
        self._constants = (_matrix_buffer(),)

    def _seed_lanes(self, seed_value, pixel, sample, pixels: int) -> None:
        self.m_pixel_key = mi.sample_tea_32(seed_value, pixel, TEA_ROUNDS)[0]
        self.m_sample = sample

    def _advance_lanes(self) -> None:
        self.m_pixel_key = mi.sample_tea_32(self.m_pixel_key, mi.UInt32(GOLDEN_GAMMA), TEA_ROUNDS)[0]

    def _values(self, dim, count: int):
        matrices = self._constants[0]
        bits = self.index_bits
        index = self.m_sample
        if self.scrambled:
            # Padding beyond the shipped dimensions: one shuffle per request, by the block of its
            # last dimension (block 0 keeps the index: the sequence's own joint structure).
            block = (dim + (count - 1)) >> _LOG2_DIMENSIONS
            key = fmix32(self._request_key(self.m_pixel_key, block) ^ mi.UInt32(TAG_SHUFFLE))
            shuffled = owen_scramble(index, key) & ((1 << bits) - 1)
            index = dr.select(block == 0, index, shuffled)
        values = []
        for c in range(count):
            d = dim + c
            base = (d & (SOBOL_DIMENSIONS - 1)) * SOBOL_BITS
            bits_of_d = sobol_coordinate(index, lambda k: dr.gather(mi.UInt32, matrices, base + k), bits)
            values.append(self._scramble(bits_of_d, self._request_key(self.m_pixel_key, d), TAG_X))
        return values

    def to_string(self) -> str:
        return (f"SobolSampler[sample_count={self.sample_count()}, randomization={self.randomization}, "
                f"seed={self._base_seed}]")


#: The plugin's class, which pointillist.plugins registers with Mitsuba under this file's name.
PLUGIN_CLASS = SobolSampler
