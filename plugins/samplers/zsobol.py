"""The ``zsobol`` sampler: pbrt-v4's ZSobolSampler, Owen-scrambled Sobol' points in Morton order over the film."""

from __future__ import annotations

import math
import warnings

import drjit as dr
import mitsuba as mi

from pointillist.plugins.samplers._base import GOLDEN_GAMMA, fmix32
from pointillist.plugins.samplers._sobol import TAG_X, TAG_Y, SobolBase, bits_for, laine_karras, morton2, \
    packed_permutations, pascal_transform, zsobol_index

__all__ = ["ZSobolSampler", "MORTON_BITS", "film_layout", "morton_levels"]

#: Bits of the Morton index ``morton2(x, y) << log2(spp) | sample`` (a ``UInt32``).
MORTON_BITS = 32


def film_layout(film, pixels: int) -> tuple[int, int, int, int]:
    """How the wavefront's pixels lie on the film: ``(width, x0, y0, extent)``.

    Pixel ``p`` of the wavefront is ``(x0 + p mod width, y0 + p div width)``; ``extent`` is the
    full film's larger side (the Morton grid covers ``2^ceil(log2 extent)`` squared). From the
    film (its crop window, and its border when it samples one) when its pixel count is
    ``pixels``; else ``film`` is None or describes another wavefront (e.g. an integrator's own
    batches): a square of ``pixels`` when that is a perfect square, otherwise rows of the power
    of two at or above its square root.

    >>> film_layout(None, 256), film_layout(None, 8)
    ((16, 0, 0, 16), (4, 0, 0, 4))
    """
    if film is not None:
        border = _border(film)
        width, height = (int(v) + 2 * border for v in film.crop_size())
        if width * height == pixels:
            x0, y0 = (int(v) for v in film.crop_offset())
            return width, x0, y0, _extent(film)
    side = math.isqrt(max(pixels, 1))
    if side * side != pixels:
        side = 1 << side.bit_length()  # the power of two above the square root
    return side, 0, 0, max(side, -(-pixels // side))


def _border(film) -> int:
    """Pixels sampled beyond each edge of ``film`` (its filter's border when it samples one)."""
    return int(film.rfilter().border_size()) if film.sample_border() else 0


def _extent(film) -> int:
    """The larger side of the whole sampled film (border included)."""
    return max(int(v) for v in film.size()) + 2 * _border(film)


def morton_levels(extent: int, log2_spp: int) -> int:
    """Quadtree levels over a film of larger side ``extent``; ValueError when the Morton index of
    ``2^log2_spp`` samples per pixel needs more than :data:`MORTON_BITS` bits.

    >>> morton_levels(256, 4), morton_levels(1, 0)
    (8, 0)
    """
    levels = max(extent - 1, 0).bit_length()
    if 2 * levels + log2_spp > MORTON_BITS:
        raise ValueError(f"zsobol sampler: a film of side {extent} (rounded up to {1 << levels}) at "
                         f"{1 << log2_spp} spp needs {2 * levels + log2_spp}-bit Morton indices; at most "
                         f"{MORTON_BITS} (e.g. 4096 x 4096 at 256 spp)")
    return levels


class ZSobolSampler(SobolBase):
    r"""
    Z-ordered Sobol' sampler (:monosp:`zsobol`)
    -------------------------------------------

    .. pluginparameters::

     * - sample_count
       - |int|
       - Number of samples per pixel (Default: 4), rounded up to a power of two (with a
         ``RuntimeWarning``).
     * - seed
       - |int|
       - Seed offset (Default: 0).
     * - randomization
       - |string|
       - ``owen`` (Default): hash-based Owen scrambling per seed and dimension; ``none``:
         the plain Sobol' points (still in the permuted Morton order).

    pbrt-v4's ``ZSobolSampler`` (Ahmed and Wonka, "Screen-space blue-noise diffusion of Monte
    Carlo sampling error via hierarchical ordering of pixels", SIGGRAPH Asia 2020). All the
    film shares one Owen-scrambled Sobol' sequence per dimension; sample ``s`` of pixel
    ``(x, y)`` takes its point at index ``morton(x, y) * spp + s`` after every base-4 digit of
    that index went through a random permutation chosen by the digits above it (and by the
    seed and dimension). Pixels under one node of the quadtree share its permutations, so any
    aligned 2^k x 2^k block of pixels takes an aligned block of ``4^k spp`` points of the
    sequence: together their samples form a (0, 2k + log2 spp, 2)-net. Neighbouring pixels
    sample complementary parts of the pixel square, their errors cancel at low spatial
    frequencies and the error looks like blue noise, at the cost per pixel of ``sobol``.
    The first two dimensions (the film position) of one pixel are still a (0, m, 2)-net of its
    2^m samples; every 1D or 2D request uses Sobol' dimensions 0 and 1 under its own digit
    permutations and scrambling (padding, as pbrt does).

    The sampler needs the film's width: scenes loaded with ``pointillist`` (``load_scene``,
    ``compare``, ``render``) give it the film (crop windows and sampled borders included).
    Otherwise (``mi.load_file``) a square film is assumed when the pixel count is a square,
    else rows of the next power of two with a warning: unbiased still, the blue noise lost.
    The Morton index is 32 bits: the film's larger side rounded up to a power of two, squared,
    times spp must be at most 2^32 (4096 x 4096 at 256 spp). Per lane the state is the Morton
    index and the dimension counter (Dr.Jit ``UInt32``\ s).

    .. tabs::
        .. code-tab:: xml

            <sampler type="zsobol">
                <integer name="sample_count" value="16"/>
            </sampler>

        .. code-tab:: python

            'type': 'zsobol',
            'sample_count': 16
    """

    _STATE = ("m_index",)

    def _round_count(self, spp: int) -> int:
        rounded = 1 << (spp - 1).bit_length()
        if rounded != spp:
            self._warn_rounded(spp, rounded, "the Morton index holds the sample in whole bits")
        return rounded

    def _configure(self, spp: int) -> None:
        self.log2_spp = spp.bit_length() - 1  # (seed() lays the lanes out again for a new count)
        if not hasattr(self, "_film"):  # first call, from the constructor
            self._film: tuple = ()
            self._warned = False
            self._digits, self._odd = 0, False
            # (the digit permutations, the seed): in a tuple, which Dr.Jit does not traverse as loop state
            self._constants = (mi.UInt32(packed_permutations()), dr.opaque(mi.UInt32, 0))

    def attach_film(self, film) -> None:
        """Lay the pixels out as on ``film`` (:func:`film_layout`); ``pointillist.scene`` calls this."""
        self._film = (film,) if film is not None else ()

    def check_render(self, spp: int) -> None:
        """ValueError, before any work, when a render of ``spp`` samples per pixel on the attached film
        would need Morton indices longer than :data:`MORTON_BITS` (``pointillist.scene.timed_render``
        asks; inside ``mi.render`` the same error would come wrapped in Mitsuba's)."""
        if self._film:
            morton_levels(_extent(self._film[0]), bits_for(spp))

    def _copy_config(self, other: "ZSobolSampler") -> None:
        other._film = self._film

    def _copy_seeded(self, other: "ZSobolSampler") -> None:
        other._digits, other._odd, other._constants = self._digits, self._odd, self._constants

    def _seed_lanes(self, seed_value, pixel, sample, pixels: int) -> None:
        width, x0, y0, extent = film_layout(self._film[0] if self._film else None, pixels)
        if not self._film and width * width != pixels and not self._warned:
            self._warned = True
            warnings.warn(f"zsobol sampler: the film's width is unknown (load the scene with pointillist); "
                          f"laying its {pixels} pixels out in rows of {width}: the error is no longer blue noise",
                          RuntimeWarning, stacklevel=2)
        levels = morton_levels(extent, self.log2_spp)
        width_opaque = dr.opaque(mi.UInt32, width)
        row = pixel // width_opaque
        x = pixel - row * width_opaque + dr.opaque(mi.UInt32, x0)
        y = row + dr.opaque(mi.UInt32, y0)
        self.m_index = (morton2(x, y) << self.log2_spp) | sample
        self._digits = levels + (self.log2_spp + 1) // 2
        self._odd = bool(self.log2_spp & 1)
        self._constants = (self._constants[0], seed_value)

    def _advance_lanes(self) -> None:
        key = fmix32(self._constants[1] ^ mi.UInt32(GOLDEN_GAMMA))
        dr.make_opaque(key)
        self._constants = (self._constants[0], key)

    def _values(self, dim, count: int):
        permutations, seed_key = self._constants
        key = self._request_key(seed_key, dim)
        index = zsobol_index(self.m_index, key, self._digits, self._odd, permutations)
        # Sobol' dimension 0 is brev(index), dimension 1 brev(pascal_transform(index)); the Owen scramble
        # (brev, Laine-Karras, brev) then starts from the bits before their reversal.
        reversed_bits = [index, pascal_transform(index)][:count]
        if self.scrambled:
            reversed_bits = [laine_karras(bits, fmix32(key ^ mi.UInt32(tag)))
                             for bits, tag in zip(reversed_bits, (TAG_X, TAG_Y))]
        return [dr.brev(bits) for bits in reversed_bits]

    def to_string(self) -> str:
        return (f"ZSobolSampler[sample_count={self.sample_count()}, randomization={self.randomization}, "
                f"seed={self._base_seed}, film={'attached' if self._film else 'unknown'}]")


#: The plugin's class, which pointillist.plugins registers with Mitsuba under this file's name.
PLUGIN_CLASS = ZSobolSampler
