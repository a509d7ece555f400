"""Shared machinery of pointillist's image-plane pattern samplers (grid, jitter, poisson).

Every pattern sampler draws its numbers from a counter-based hash, as pbrt-v4's
samplers do, so that any (pixel, sample) is reproducible on its own:

- ``seed(seed, wavefront_size)`` gets ``W * H * spp`` lanes laid out as
  ``lane = pixel * spp + sample`` (Mitsuba's single-pass wavefront). Each lane keeps
  two keys: ``pixel_key = TEA(base_seed + seed, pixel)`` and
  ``sample_key = TEA(pixel_key, sample)``.
- The first 2D request after ``seed``/``advance`` (``dimension == 0``: the film
  position asked for by ``SamplingIntegrator.render_sample``) returns the
  sampler's image-plane pattern for ``(pixel, sample)``.
- Every other request (lens, time, light, BSDF ...) returns
  ``x = fmix32(sample_key ^ dimension * 0x9E3779B9)``, ``y = fmix32(x ^ c)``
  (MurmurHash3's finaliser): uniform numbers decorrelated from the pattern, from
  other dimensions, pixels and seeds.

A sampler only places the samples; the film's reconstruction filter turns them into pixels.
The course's super-sampling (a pixel = the plain average of its own samples) is what these
samplers give with ``<rfilter type="box"/>`` in the film; Mitsuba's default Gaussian filter
(radius 2 pixels) weights samples by distance and spreads them into neighbouring pixels, so a
pixel next to an edge gets another value.

The dimension counter is a Dr.Jit ``UInt32`` (never a Python int) so that it is
loop state inside the integrators' symbolic loops (a Python int would be frozen into the
traced loop as a constant); the seed
is opaque so a new seed does not recompile the kernels.

Sub-classes implement ``_pattern(sample, pixel_key) -> (x, y)`` in [0, 1)^2 and
``_configure(spp)`` (called on construction and by ``set_sample_count``).
"""

from __future__ import annotations

import numbers
import warnings

import drjit as dr
import mitsuba as mi

from pointillist.plugins.properties import integer_property

__all__ = ["PatternSampler", "GridLayout", "unit_float", "grid_shape", "TEA_ROUNDS", "PIXEL_OFFSET_TAG",
           "MAX_GRID_ASPECT", "MAX_SAMPLE_COUNT", "read_count_and_seed", "checked_sample_count", "wavefront_lanes"]

#: Rounds of the Tiny Encryption Algorithm per hash: 4, Mitsuba's own default for
#: ``sample_tea_32`` (Zafar, Olano, Curtis, "GPU random numbers via the tiny
#: encryption algorithm", HPG 2010, found 4 rounds enough for image synthesis).
TEA_ROUNDS = 4

#: Second TEA input for the per-pixel random offset (the Poisson sampler's
#: Cranley-Patterson shift); sample indices never reach it.
PIXEL_OFFSET_TAG = 0xFFFFFFFF


#: Largest sample count per pixel a pattern sampler accepts (lane = pixel * spp + sample is 32-bit).
MAX_SAMPLE_COUNT = 1 << 24

#: Seeds are any 64-bit integer (only the low 32 bits are used).
_SEED_RANGE = (-(1 << 63), (1 << 64) - 1)

#: Weyl-sequence step (2^32 / golden ratio) that spreads dimension indices over 32 bits.
GOLDEN_GAMMA = 0x9E3779B9


def fmix32(h):
    """MurmurHash3's 32-bit finaliser (Appleby, public domain): a bijective avalanche mix."""
    h = h ^ (h >> 16)
    h = h * mi.UInt32(0x85EBCA6B)
    h = h ^ (h >> 13)
    h = h * mi.UInt32(0xC2B2AE35)
    return h ^ (h >> 16)


def unit_float(bits):
    """Map uniformly distributed ``UInt32`` bits to a float32 in [0, 1).

    Uses the 24 high bits (float32 has a 24-bit significand), so 1.0 is never returned.
    """
    return mi.Float(bits >> 8) * (1.0 / 16777216.0)


def read_count_and_seed(props: mi.Properties) -> int:
    """Check ``sample_count`` and ``seed`` before Mitsuba's own reader sees them (it would wrap or coerce a
    bad value); returns the seed offset."""
    integer_property(props, "sample_count", 4, 1, MAX_SAMPLE_COUNT)
    return integer_property(props, "seed", 0, *_SEED_RANGE)


def checked_sample_count(spp) -> int:
    """``spp`` as an int for ``set_sample_count``; ValueError unless an integer in 1..MAX_SAMPLE_COUNT."""
    if isinstance(spp, bool) or not isinstance(spp, numbers.Integral) or not 1 <= spp <= MAX_SAMPLE_COUNT:
        raise ValueError(f"sample_count: expected an integer in 1..{MAX_SAMPLE_COUNT}, got {spp!r}")
    return int(spp)


def wavefront_lanes(sampler: mi.Sampler, seed, base_seed: int):
    """``(seed_value, pixel, sample)`` of a seeded sampler's lanes, ``lane = pixel * spp + sample``
    (Mitsuba's single-pass wavefront): the seed plus ``base_seed`` as an opaque ``UInt32`` (a new
    seed recompiles nothing), and each lane's pixel and sample index."""
    size = int(sampler.wavefront_size())
    spp = int(sampler.sample_count())
    seed_value = mi.UInt32(seed) + mi.UInt32(base_seed & 0xFFFFFFFF)
    dr.make_opaque(seed_value)
    lane = dr.arange(mi.UInt32, size)
    spp_opaque = dr.opaque(mi.UInt32, spp)
    pixel = lane // spp_opaque
    return seed_value, pixel, lane - pixel * spp_opaque


def grid_shape(spp: int) -> tuple[int, int]:
    """The rectangular grid ``(rows, cols)`` with ``rows * cols == spp`` closest to square.

    ``rows`` is the largest divisor of ``spp`` that is at most ``sqrt(spp)``, so
    ``cols >= rows``. Perfect squares give ``sqrt(spp) x sqrt(spp)``; 8 gives 2 x 4;
    a prime gives 1 x spp.

    >>> grid_shape(16), grid_shape(8), grid_shape(12), grid_shape(7), grid_shape(1)
    ((4, 4), (2, 4), (3, 4), (1, 7), (1, 1))
    """
    if not isinstance(spp, int) or spp < 1:
        raise ValueError(f"sample_count: expected a positive integer, got {spp!r}")
    rows = int(spp ** 0.5)
    while rows * rows > spp:
        rows -= 1
    while spp % rows:
        rows -= 1
    return rows, spp // rows


class PatternSampler(mi.Sampler):
    """Base class: an image-plane pattern at dimension 0, hashed random numbers elsewhere."""

    def __init__(self, props: mi.Properties):
        self._base_seed = read_count_and_seed(props)
        super().__init__(props)
        spp = int(self.sample_count())
        self._configure(spp)
        self._reset_state()

    # -- per-lane state ---------------------------------------------------------------
    def _reset_state(self) -> None:
        self.m_pixel_key = mi.UInt32(0)
        self.m_sample_key = mi.UInt32(0)
        self.m_sample = mi.UInt32(0)
        self.m_dim = dr.opaque(mi.UInt32, 0)
        self._pattern_pending = True

    def seed(self, seed=0, wavefront_size: int = 2**32 - 1) -> None:
        super().seed(seed, wavefront_size)
        seed_value, pixel, sample = wavefront_lanes(self, seed, self._base_seed)
        self.m_pixel_key = mi.sample_tea_32(seed_value, pixel, TEA_ROUNDS)[0]
        self.m_sample_key = mi.sample_tea_32(self.m_pixel_key, sample, TEA_ROUNDS)[0]
        self.m_sample = sample
        self.m_dim = dr.opaque(mi.UInt32, 0)
        self._pattern_pending = True

    def advance(self) -> None:
        """Start the next pass: dimension 0 again, fresh random numbers (new sample keys)."""
        super().advance()
        self.m_sample_key = mi.sample_tea_32(self.m_sample_key, mi.UInt32(0x9E3779B9), TEA_ROUNDS)[0]
        self.m_dim = dr.opaque(mi.UInt32, 0)
        self._pattern_pending = True

    def schedule_state(self) -> None:
        dr.schedule(self.m_pixel_key, self.m_sample_key, self.m_sample, self.m_dim)

    def set_sample_count(self, spp: int) -> None:
        spp = checked_sample_count(spp)
        super().set_sample_count(spp)
        self._configure(spp)

    # -- numbers ------------------------------------------------------------------------
    def _random_2d(self):
        # TEA with 4 rounds left consecutive dimensions correlated (|r| up to 0.09 over
        # 32000 lanes); MurmurHash3's finaliser of key ^ dim * golden gamma does not.
        v0 = fmix32(self.m_sample_key ^ (self.m_dim * mi.UInt32(GOLDEN_GAMMA)))
        v1 = fmix32(v0 ^ mi.UInt32(0x68E31DA4))
        return unit_float(v0), unit_float(v1)

    def next_1d(self, active=True):
        x, _ = self._random_2d()
        self.m_dim += 1
        return x

    def next_2d(self, active=True):
        rx, ry = self._random_2d()
        if self._pattern_pending:
            # The film position is the first 2D request after seed()/advance(); the
            # select keeps this right when that request happens inside a symbolic loop.
            self._pattern_pending = False
            px, py = self._pattern(self.m_sample, self.m_pixel_key)
            first = self.m_dim == 0
            rx = dr.select(first, px, rx)
            ry = dr.select(first, py, ry)
        self.m_dim += 1
        return mi.Point2f(rx, ry)

    # -- copies ---------------------------------------------------------------------------
    def _new(self) -> "PatternSampler":
        props = mi.Properties()
        props["sample_count"] = int(self.sample_count())
        props["seed"] = int(self._base_seed)
        return type(self)(props)

    def fork(self):
        return self._new()

    def clone(self):
        other = self._new()
        if self.wavefront_size():
            mi.Sampler.seed(other, 0, int(self.wavefront_size()))
        other.m_pixel_key = mi.UInt32(self.m_pixel_key)
        other.m_sample_key = mi.UInt32(self.m_sample_key)
        other.m_sample = mi.UInt32(self.m_sample)
        other.m_dim = mi.UInt32(self.m_dim)
        other._pattern_pending = self._pattern_pending
        return other

    # -- to be provided ---------------------------------------------------------------------
    def _configure(self, spp: int) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _pattern(self, sample, pixel_key):  # pragma: no cover - abstract
        raise NotImplementedError

    def to_string(self) -> str:
        return f"{type(self).__name__}[sample_count={self.sample_count()}, seed={self._base_seed}]"


#: Largest cols / rows ratio accepted without a warning (2: e.g. 8 = 2 x 4, 32 = 4 x 8).
MAX_GRID_ASPECT = 2.0


class GridLayout(PatternSampler):
    """Base of the grid samplers (``grid``, ``jitter``): ``rows x cols == sample_count`` cells,
    laid out by :func:`grid_shape`; sub-classes place a sample inside its cell (``_pattern``)."""

    PLUGIN_NAME: str  # the sub-class's plugin name, given by pointillist.plugins.register()

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
