"""Owen-scrambled Sobol' points: the machinery shared by the ``sobol`` and ``zsobol`` samplers.

- **Generator matrices**: Joe and Kuo's, shipped (:mod:`._sobol_matrices`). Point ``i`` of a
  dimension is the XOR of the matrix columns of the bits set in ``i`` (:func:`sobol_coordinate`;
  the first dimension's matrix is the bit reversal, ``dr.brev``).
- **Owen scrambling** (:func:`owen_scramble`): the hash-based nested scramble of pbrt-v4's
  ``FastOwenScrambler`` (Laine and Karras 2011 with Vegdahl's constants; Burley, "Practical
  hash-based Owen scrambling", JCGT 9(4), 2020). In the bit-reversed value each step changes a
  bit only as a function of the bits below it, i.e. of the bits above it in the original: a
  nested (Owen) scrambling, which maps every elementary interval onto one of the same size (a
  net stays a net) and makes each point uniformly distributed.
- **Morton order with random base-4 digit permutations** (:func:`zsobol_index`): pbrt-v4's
  ``ZSobolSampler`` (Ahmed and Wonka, "Screen-space blue-noise diffusion of Monte Carlo sampling
  error via hierarchical ordering of pixels", ACM TOG 39(6), 2020).

The Dr.Jit functions take and return ``mi.UInt32`` arrays; their Python loops run over the bits
or digits of an index while the kernel is traced, never over samples.
"""

from __future__ import annotations

import warnings

import drjit as dr
import mitsuba as mi

from pointillist.plugins.properties import string_property
from pointillist.plugins.samplers._base import (GOLDEN_GAMMA, checked_sample_count, fmix32, read_count_and_seed,
                                               unit_float, wavefront_lanes)

__all__ = ["RANDOMIZATIONS", "DIGIT_PERMUTATIONS", "owen_scramble", "laine_karras", "sobol_coordinate",
           "pascal_transform", "morton2", "node_hash", "zsobol_index", "packed_permutations", "bits_for",
           "SobolBase"]

#: ``randomization`` property values: ``owen`` (hash-based Owen scrambling, the default) or
#: ``none`` (the plain Sobol' sequence, the same in every pixel: for tests and pictures).
RANDOMIZATIONS = ("owen", "none")

#: The 24 permutations of a base-4 digit, in pbrt-v4's order (``ZSobolSampler::GetSampleIndex``).
DIGIT_PERMUTATIONS = (
    (0, 1, 2, 3), (0, 1, 3, 2), (0, 2, 1, 3), (0, 2, 3, 1), (0, 3, 2, 1), (0, 3, 1, 2),
    (1, 0, 2, 3), (1, 0, 3, 2), (1, 2, 0, 3), (1, 2, 3, 0), (1, 3, 2, 0), (1, 3, 0, 2),
    (2, 1, 0, 3), (2, 1, 3, 0), (2, 0, 1, 3), (2, 0, 3, 1), (2, 3, 0, 1), (2, 3, 1, 0),
    (3, 1, 2, 0), (3, 1, 0, 2), (3, 2, 1, 0), (3, 2, 0, 1), (3, 0, 2, 1), (3, 0, 1, 2))

#: Multipliers of the hash-based Owen scramble (pbrt-v4 ``FastOwenScrambler``, after Vegdahl).
OWEN_MULTIPLIERS = (0x3D20ADEA, 0x05526C56, 0x53A22864)

#: Tags deriving, from a request's key, the scrambling seeds of its two coordinates and of an
#: index shuffle (arbitrary odd constants; only their being distinct matters).
TAG_X, TAG_Y, TAG_SHUFFLE = 0x68E31DA4, 0xB5297A4D, 0x1B56C4E9


def laine_karras(v, seed):
    """The Laine-Karras style hash of pbrt-v4's ``FastOwenScrambler`` on bit-reversed values: every
    step changes bit ``k`` of ``v`` only as a function of its bits below ``k``."""
    m0, m1, m2 = OWEN_MULTIPLIERS  # (no in-place operators: they would change the caller's array)
    v = v ^ (v * mi.UInt32(m0))
    v = (v + seed) * ((seed >> 16) | 1)
    v = v ^ (v * mi.UInt32(m1))
    return v ^ (v * mi.UInt32(m2))


def owen_scramble(v, seed):
    """Hash-based Owen scrambling of the 32 bits ``v`` (a Sobol' coordinate) with ``seed``.

    pbrt-v4's ``FastOwenScrambler``: reverse the bits, :func:`laine_karras`, reverse back. Applied
    to an index instead of a coordinate it is a nested uniform shuffle: the low ``m`` bits of the
    result are a permutation of the low ``m`` bits of the index.
    """
    return dr.brev(laine_karras(dr.brev(v), seed))


def sobol_coordinate(index, column, bits: int):
    """The Sobol' bits of ``index`` (below 2^bits) in one dimension: the XOR of the generator
    matrix columns ``column(k)`` of the bits ``k`` set in ``index``.

    ``column(k)`` returns a Python int (a fixed dimension: a kernel constant) or a ``UInt32``
    (gathered, when the dimension varies).
    """
    v = mi.UInt32(0)
    for k in range(bits):
        v ^= (mi.UInt32(0) - ((index >> k) & 1)) & column(k)  # all ones where bit k is set
    return v


#: Masks of the superset-sum transform over the 5-bit positions of a 32-bit word (:func:`pascal_transform`).
_PASCAL_STEPS = ((1, 0x55555555), (2, 0x33333333), (4, 0x0F0F0F0F), (8, 0x00FF00FF), (16, 0x0000FFFF))


def pascal_transform(index):
    """Bit ``r`` of the result is the XOR of the bits ``k`` of ``index`` whose position contains ``r``
    bitwise (``k & r == r``): five shift-and-XOR steps.

    The second Sobol' dimension's generator matrix (primitive polynomial x + 1) is Pascal's triangle
    mod 2, whose entry ``C(k, r)`` is odd exactly when ``r`` is a bitwise subset of ``k`` (Lucas), so
    that dimension's point ``index`` is ``dr.brev(pascal_transform(index))``: 20 operations instead of
    a loop over the index's bits.

    >>> [int(dr.brev(pascal_transform(mi.UInt32(i)))[0]) >> 29 for i in range(4)]  # x 8: 0, 1/2, 3/4, 1/4
    [0, 4, 6, 2]
    """
    for shift, mask in _PASCAL_STEPS:
        index = index ^ ((index >> shift) & mask)  # (not ^=: that would change the caller's array)
    return index


def morton2(x, y):
    """Interleave the bits of ``x`` and ``y`` (each below 2^16): ``... y1 x1 y0 x0``.

    Examples
    --------
    >>> int(morton2(mi.UInt32(0b11), mi.UInt32(0b01))[0]) == 0b0111
    True
    """
    def spread(v):
        v = v & 0xFFFF
        v = (v | (v << 8)) & 0x00FF00FF
        v = (v | (v << 4)) & 0x0F0F0F0F
        v = (v | (v << 2)) & 0x33333333
        return (v | (v << 1)) & 0x55555555

    return spread(x) | (spread(y) << 1)


def packed_permutations() -> list[int]:
    """:data:`DIGIT_PERMUTATIONS` packed 2 bits a digit: digit ``d`` goes to bits ``2d, 2d + 1``.

    >>> packed_permutations()[:2] == [0b11100100, 0b10110100]
    True
    """
    return [sum(p[d] << (2 * d) for d in range(4)) for p in DIGIT_PERMUTATIONS]


def node_hash(x):
    """A 32-bit hash whose *top* bits (read with ``dr.mul_hi``) choose a quadtree node's permutation.

    MurmurHash3's finaliser (:func:`fmix32`) less its first and last xor-shifts: the last changes only
    the low 16 bits, which ``mul_hi`` does not read, and the node numbers hashed here are XORed with a
    random 32-bit key first. Sibling nodes still get independent permutations (tests/test_sobol.py:
    chi-square over the 24 x 24 pairs); a single multiplication would not (siblings' choices a fixed
    stride apart). Four operations fewer per digit than fmix32.
    """
    x = x * mi.UInt32(0x85EBCA6B)
    x = x ^ (x >> 13)
    return x * mi.UInt32(0xC2B2AE35)


def zsobol_index(morton_index, key, digits: int, odd: bool, permutations):
    """pbrt-v4's ``ZSobolSampler::GetSampleIndex``: the Sobol' index of a (pixel, sample).

    ``morton_index = morton2(x, y) << log2(spp) | sample`` has ``digits`` base-4 digits, the
    lowest a single bit when ``odd`` (spp an odd power of two). From the top, each digit goes
    through one of the 24 permutations, chosen by a hash of the digits above it and of ``key``
    (one per seed and dimension): pixels under one quadtree node share its permutations, so an
    aligned 2^k x 2^k block of pixels takes an aligned block of 4^k indices of the sequence, in a
    random order. ``permutations``: :func:`packed_permutations` as a ``UInt32`` buffer.
    """
    index = mi.UInt32(0)
    low = 1 if odd else 0
    for i in range(digits - 1, low - 1, -1):
        shift = 2 * i - low
        digit = (morton_index >> shift) & 3
        higher = morton_index >> (shift + 2) if shift + 2 < 32 else mi.UInt32(0)
        choice = dr.mul_hi(node_hash(higher ^ key), mi.UInt32(len(DIGIT_PERMUTATIONS)))
        packed = dr.gather(mi.UInt32, permutations, choice)
        index |= ((packed >> (digit << 1)) & 3) << shift
    if odd:
        index |= (morton_index & 1) ^ (node_hash((morton_index >> 1) ^ key) >> 31)
    return index


def bits_for(count: int) -> int:
    """Bits of the largest index below ``count``, ``ceil(log2(count))`` (0 for one sample).

    >>> bits_for(1), bits_for(2), bits_for(16), bits_for(17)
    (0, 1, 4, 5)
    """
    return max(int(count) - 1, 0).bit_length()


class SobolBase(mi.Sampler):
    """Properties, per-lane state, clones and forks of the Sobol' samplers.

    A sub-class names its per-lane ``UInt32`` state in ``_STATE`` (set by :meth:`_seed_lanes`,
    copied by :meth:`clone`) and gives ``_values(dim, count)``: the 32-bit coordinates of
    dimensions ``dim .. dim + count - 1``. The dimension counter ``m_dim`` is a Dr.Jit ``UInt32``
    (loop state inside the integrators' symbolic loops); the seed is opaque, so a new seed does
    not recompile the kernels.
    """

    PLUGIN_NAME: str  # the sub-class's plugin name, given by pointillist.plugins.register()
    _STATE: tuple[str, ...] = ()

    def __init__(self, props: mi.Properties):
        self._base_seed = read_count_and_seed(props)
        self.randomization = string_property(props, "randomization", "owen", RANDOMIZATIONS)
        super().__init__(props)
        spp = int(self.sample_count())
        rounded = self._round_count(spp)
        if rounded != spp:
            mi.Sampler.set_sample_count(self, rounded)
        self._configure(rounded)
        for name in self._STATE:
            setattr(self, name, mi.UInt32(0))
        self.m_dim = dr.opaque(mi.UInt32, 0)

    # -- configuration ---------------------------------------------------------------------
    @property
    def scrambled(self) -> bool:
        """Whether the points are Owen-scrambled (``randomization = "owen"``)."""
        return self.randomization == "owen"

    def _round_count(self, spp: int) -> int:
        return spp

    def set_sample_count(self, spp: int) -> None:
        spp = self._round_count(checked_sample_count(spp))
        super().set_sample_count(spp)
        self._configure(spp)

    def _warn_rounded(self, spp: int, rounded: int, why: str) -> None:
        warnings.warn(f"{self.PLUGIN_NAME} sampler: sample_count {spp} is not a power of two; using {rounded} "
                      f"({why})", RuntimeWarning, stacklevel=3)

    # -- seeding -------------------------------------------------------------------------------
    def seed(self, seed=0, wavefront_size: int = 2**32 - 1) -> None:
        """Lanes ``pixel * spp + sample`` (Mitsuba's single-pass wavefront)."""
        super().seed(seed, wavefront_size)
        seed_value, pixel, sample = wavefront_lanes(self, seed, self._base_seed)
        self._seed_lanes(seed_value, pixel, sample, -(-int(self.wavefront_size()) // int(self.sample_count())))
        self.m_dim = dr.opaque(mi.UInt32, 0)

    def advance(self) -> None:
        """The next pass: dimension 0 again, with a fresh scrambling (:meth:`_advance_lanes`)."""
        super().advance()
        self._advance_lanes()
        self.m_dim = dr.opaque(mi.UInt32, 0)

    def schedule_state(self) -> None:
        dr.schedule(*(getattr(self, name) for name in self._STATE), self.m_dim)

    # -- numbers ---------------------------------------------------------------------------------
    def next_1d(self, active=True):
        (x,) = self._values(self.m_dim, 1)
        self.m_dim += 1
        return unit_float(x)

    def next_2d(self, active=True):
        x, y = self._values(self.m_dim, 2)
        self.m_dim += 2
        return mi.Point2f(unit_float(x), unit_float(y))

    @staticmethod
    def _request_key(key, dim):
        """The 32-bit key of dimension ``dim`` under ``key`` (a seed, or a seed and a pixel)."""
        return fmix32(key ^ (dim * mi.UInt32(GOLDEN_GAMMA)))

    def _scramble(self, bits, key, tag: int):
        """``bits`` Owen-scrambled with a seed hashed from ``key`` and ``tag`` (unless randomization is none)."""
        return owen_scramble(bits, fmix32(key ^ mi.UInt32(tag))) if self.scrambled else bits

    # -- copies --------------------------------------------------------------------------------
    def _new(self) -> "SobolBase":
        props = mi.Properties()
        props["sample_count"] = int(self.sample_count())
        props["seed"] = int(self._base_seed)
        props["randomization"] = self.randomization
        return type(self)(props)

    def fork(self):
        other = self._new()
        self._copy_config(other)
        return other

    def clone(self):
        other = self.fork()
        if self.wavefront_size():
            mi.Sampler.seed(other, 0, int(self.wavefront_size()))
        for name in self._STATE:
            setattr(other, name, mi.UInt32(getattr(self, name)))
        other.m_dim = mi.UInt32(self.m_dim)
        self._copy_seeded(other)
        return other

    def _copy_config(self, other: "SobolBase") -> None:
        """Copy what the constructor does not set (e.g. an attached film) into ``other``."""

    def _copy_seeded(self, other: "SobolBase") -> None:
        """Copy what :meth:`seed` set besides ``_STATE`` into ``other``."""

    def to_string(self) -> str:
        return (f"{type(self).__name__}[sample_count={self.sample_count()}, randomization={self.randomization}, "
                f"seed={self._base_seed}]")

    # -- to be provided ------------------------------------------------------------------------
    def _configure(self, spp: int) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _seed_lanes(self, seed_value, pixel, sample, pixels: int) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _advance_lanes(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _values(self, dim, count: int):  # pragma: no cover - abstract
        raise NotImplementedError
