"""The accumulator of a progressive render's passes and its error estimate without a reference.

A progressive render is a sequence of *passes*, each an independent estimate of the image (its
own seed). The passes are accumulated per pixel and channel in float64, in two ways:

- Welford's update in the weighted form of West (1979), weights = the passes' sample counts::

      W += n;  delta = x - mean;  mean += (n / W) * delta;  M2 += n * delta * (x - mean)

  If a sample has variance ``sigma^2``, a pass of ``n`` spp has ``sigma^2 / n`` and ``E[M2] = (K -
  1) sigma^2`` for ``K`` passes of any sizes, so ``var_of_mean = M2 / ((K - 1) W)`` (unbiased;
  the ``variance`` layer);
- four *quarters*: each pass goes to the half with fewer samples so far (ties: the first), and
  within it to the quarter with fewer samples; each quarter keeps the mean of its passes, and the
  quarters combined (Chan, Golub and LeVeque 1979, exact) give the mean of all samples.

With a box reconstruction filter a pass image is the plain mean of its samples in each pixel, so
the mean is that of all ``W`` samples: statistically one render of ``W`` spp (bit for bit the same
mean when every pass gives the same image, e.g. a deterministic estimator with a seed-free sampler).

The error estimate takes the variance of the mean from the spread between the quarters, ``v = sum_q
W_q (m_q - m)^2 / (3 W)`` (unbiased for any split): a firefly found in a pass of ``n`` spp adds
``F^2 / n`` to Welford's ``M2`` but about ``F^2 / (W / 4)`` to the quarters', so the quarters' ``v``
follows the error the firefly really adds, ``(F / W)^2``, while ``var_of_mean`` over-states it
``W / ((K - 1) n)`` times when it fell in a small pass (the passes of 1 spp an error budget starts
with put the estimate of the sun scene of benchmarks/estimator.py 30-170x high from 16 spp on).

**Estimated relMSE** (the relMSE of :func:`pointillist.imaging.metrics.image_errors`, epsilon
``eps`` = :data:`pointillist.imaging.metrics.RELMSE_EPSILON`, without the reference ``r``): the
expected squared error of a pixel is ``v``; the reference in the denominator is unknown. A pixel's
own mean ``m`` stands for it when the pixel is *reliable*, its relative standard error at most 1/2
(``v <= m^2 / 4``, :data:`RELIABLE_VARIANCE`; a rare path has then been found in three quarters, or
in two unevenly), with the bias of ``m^2`` removed (``E[m^2] = r^2 + v``). In an unreliable pixel
the mean may rest on a few rare, bright samples (a firefly) and say little about ``r`` (``m^2 -
v`` is about 0 after one firefly, ``m^2`` far above ``r^2``); the pixel takes the smaller of that
and ``n^2``, ``n`` the mean of its 8 neighbours (border pixels repeated outward), which its own
firefly does not reach and which the fireflies found around it make an estimate of the local
``r``, but not less than ``(m / 64)^2``::

    d = m^2 - v                                       where v <= m^2 / 4
    d = max(min(max(m^2 - v, 0), n^2), (m / 64)^2)    elsewhere
    estimated_relmse = mean over finite pixels and colour channels of v / (d + eps)

A firefly then raises the estimate by about ``v / (n^2 + eps)``, as much as it raises the true
error, up to 64 times the pixel's reference, and a second firefly in the same pixel raises it
again. (The previous estimate, ``var_of_mean / (max(m^2 - var_of_mean, m^2 / 4) + eps)``, topped
out near 4 per pixel whatever the firefly: 40-200x below the truth on a path-traced glass caustic
at 8-32 spp.) The floor ``(m / 64)^2`` (:data:`FIREFLY_RANGE`) bounds what one hit of a feature
smaller than a pixel may claim where its neighbours are dark (a glint of a small light in a
mirror, hit once, is not known from a firefly); such pixels keep the estimate high, on the safe
side, until they have been hit in three quarters. A path that no pass has found yet leaves no
trace in its pixel; over an image, the pixels where it was found stand in for those where it was
not.

**Trust.** The estimate is reported from :data:`MIN_PASSES` passes on (before: NaN). It is
*trusted* when the two halves agree on the error per spp and the estimate does not rest on single
extreme samples:

- with ``e_h`` the mean of ``(m_q1 - m_q2)^2 W_q1 W_q2 / W_h / (d + eps)`` over the pixels (half
  ``h``'s variance from its two quarters, per spp, same denominators), ``max(e_A, e_B) / min(e_A,
  e_B) <= HALVES_AGREEMENT`` (3: each half then lies within 1.5x of their mean); a firefly, or a
  rare path that only one half has found, makes them disagree;
- at most :data:`FLOORED_SHARE` (1/2) of the estimate comes from pixels held at the floor (their
  true weight is unknown either way).

An error budget stops only on a trusted estimate. Pixels holding NaN or inf (a NaN sample makes
its pixel NaN for good) are counted (:attr:`ErrorEstimate.nonfinite`) and left out of the estimate. It
assumes independent passes and an unbiased estimator: a seed-free ``grid`` sampler gives identical
passes (estimate 0), and a bias (clamping, a ``max_depth`` cut-off) is not in the spread.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from pointillist.imaging.metrics import RELMSE_EPSILON

__all__ = ["MIN_PASSES", "RELIABLE_VARIANCE", "FIREFLY_RANGE", "FLOORED_SHARE", "HALVES_AGREEMENT", "ErrorEstimate",
           "Accumulator", "estimate_error", "nonfinite_pixels"]

#: Passes before the first error estimate (the spread of fewer passes is too noisy to use: at 4
#: passes the estimate was off by up to 2x on small path-traced images, at 8 within 1.8x).
MIN_PASSES = 8

#: A pixel's own mean stands for its reference where its variance (from the quarters) is at most
#: ``RELIABLE_VARIANCE * mean^2``: relative standard error at most 1/2. Rare hits spread evenly over
#: 1, 2, 3, 4 quarters give 1, 1/3, 1/9, 0 x mean^2: reliable once a path has been found in three
#: quarters, or in two unevenly. (benchmarks/estimator.py: 1/2 let the glass caustic drift to 1.1-1.4x
#: low at 512-1024 spp; 1/9 kept a tiny light's glint, hit 4 times in 20000 spp, unreliable and
#: the estimate 500x high.)
RELIABLE_VARIANCE = 0.25

#: An unreliable pixel's reference is taken to be at least its mean / FIREFLY_RANGE (one hit then
#: claims at most FIREFLY_RANGE^2 times its relative variance). benchmarks/estimator.py: the firefly
#: pixels of the glass caustic at 8 spp have mean / reference about 40, the glint of the tiny light
#: in the mirror sphere, hit once at 256-1024 spp, 8-16: 64 kept the first within 1.36x (16: 12x low)
#: and the second 5-300x high, on the safe side (without a floor: 1e5-1e7x).
FIREFLY_RANGE = 64

#: An estimate more than this share of which comes from pixels held at that floor rests on single
#: extreme samples whose weight is unknown (either way): not trusted.
FLOORED_SHARE = 0.5

#: An error budget stops only when the two halves' errors per spp agree within this factor (each half
#: is then within 1.5x of their mean). benchmarks/estimator.py: 1.0-1.7 on edges.xml and default.xml,
#: up to 3 on the hard scenes where the estimate was within 0.5-2, 5-140 where a firefly or a newly
#: found caustic sat in one half (glass caustic and Phong spheres at 8 spp, sun scene at 32-128 spp),
#: 300-2600 at the first hits of a tiny light's glint.
HALVES_AGREEMENT = 3.0


@dataclass(frozen=True)
class ErrorEstimate:
    """The error estimate of an :class:`Accumulator` (module docstring).

    ``relmse``: the estimated relMSE (NaN before :data:`MIN_PASSES` passes or without a finite
    pixel); ``halves``: the two halves' errors per spp ``(e_A, e_B)``; ``halves_ratio``: ``max /
    min`` of those (1 when both are 0, inf when one is); ``trusted``: the halves agree within
    :data:`HALVES_AGREEMENT` and at most :data:`FLOORED_SHARE` of the estimate is ``floored``
    (from pixels held at the floor ``(m / 64)^2``, :data:`FIREFLY_RANGE`); ``nonfinite``: pixels
    with a NaN or inf colour value (left out).
    """

    relmse: float
    halves: tuple[float, float]
    halves_ratio: float
    trusted: bool
    nonfinite: int
    floored: float = math.nan


#: The 3x3 neighbourhood without its centre (:meth:`Accumulator.estimate`).
_AROUND = np.array([[1, 1, 1], [1, 0, 1], [1, 1, 1]], np.float32)


class Accumulator:
    """Per-pixel, per-channel sums of pass images in four quarters, float64 (immutable).

    ``quarters`` holds four ``(mean, weight, passes)``: a Dr.Jit float64 tensor of the image's shape
    (None while empty), the quarter's spp and passes; quarters 0-1 are the first half, 2-3 the
    second. Each pass goes to the half with fewer samples (ties: the first), and there to the
    quarter with fewer samples. ``m2`` is Welford's ``M2`` over all passes. ``mean`` (all samples),
    ``weight`` (spp) and ``passes`` are the whole render's. :meth:`add` returns a new accumulator,
    so a render interrupted at any point keeps a consistent one.

    Examples
    --------
    >>> import numpy as np, pointillist
    >>> from pointillist.progressive import Accumulator
    >>> mi = pointillist.setup()
    >>> acc = Accumulator.empty()
    >>> for x, n in [(1.0, 1), (3.0, 1), (2.0, 2)]:
    ...     acc = acc.add(mi.TensorXf(np.full((1, 1, 1), x, np.float32)), n)
    >>> float(acc.mean.numpy()[0, 0, 0]), round(float(acc.variance_of_mean().numpy()[0, 0, 0]), 12)
    (2.0, 0.25)
    >>> [(q[1], q[2]) for q in acc.quarters]     # (spp, passes): passes 1 and 3 in the first half, 2 in the second
    [(1, 1), (2, 1), (1, 1), (0, 0)]
    """

    __slots__ = ("quarters", "m2", "weight", "passes", "_means")

    _EMPTY = (None, 0, 0)

    def __init__(self, quarters=None, m2=None):
        self.quarters = tuple(quarters) if quarters is not None else (self._EMPTY,) * 4
        self.m2 = m2
        self.weight = sum(int(q[1]) for q in self.quarters)
        self.passes = sum(int(q[2]) for q in self.quarters)
        self._means = None

    @classmethod
    def empty(cls) -> Accumulator:
        return cls()

    @staticmethod
    def _quarter(quarters) -> int:
        w = [q[1] for q in quarters]
        half = 0 if w[0] + w[1] <= w[2] + w[3] else 2
        return half if w[half] <= w[half + 1] else half + 1

    def add(self, image, spp: int) -> Accumulator:
        """The accumulator with ``image`` (a pass of ``spp`` samples per pixel) added; evaluated."""
        import drjit as dr

        x = dr.float64_array_t(type(image))(image)
        shape = self.shape
        if shape is not None and tuple(x.shape) != shape:
            raise ValueError(f"image: expected shape {shape}, got {tuple(x.shape)}")
        f64 = dr.float64_array_t(dr.array_t(x))
        k = self._quarter(self.quarters)
        mean, weight, passes = self.quarters[k]
        quarters = list(self.quarters)
        quarters[k] = (x if mean is None else mean + (x - mean) * dr.opaque(f64, spp / (weight + spp)),
                       weight + spp, passes + 1)
        new = Accumulator(quarters)
        if self.passes == 0:
            new.m2 = dr.zeros(type(x), x.shape)
        else:   # Welford: M2 += n (x - mean_before) (x - mean_after)
            new.m2 = self.m2 + dr.opaque(f64, float(spp)) * (x - self.mean) * (x - new.mean)
        dr.eval(quarters[k][0], new.m2, *new._combined())
        dr.sync_thread()   # done reading the image: a caller's numpy array may change from now on
        return new

    @property
    def shape(self) -> tuple[int, ...] | None:
        """The image's shape (None before the first pass)."""
        for mean, *_ in self.quarters:
            if mean is not None:
                return tuple(mean.shape)
        return None

    @staticmethod
    def _merge(a, b):
        """Two ``(mean, weight)`` as one (Chan et al.: exact where both means are equal)."""
        import drjit as dr

        (mean_a, w_a), (mean_b, w_b) = a, b
        if mean_a is None or mean_b is None:
            return (mean_b, w_b) if mean_a is None else (mean_a, w_a)
        f64 = dr.float64_array_t(dr.array_t(mean_a))
        return mean_a + (mean_b - mean_a) * dr.opaque(f64, w_b / (w_a + w_b)), w_a + w_b

    def _combined(self):
        """``(mean of the first half, of the second, of all)`` (cached; None while empty)."""
        if self._means is None:
            q = [(mean, weight) for mean, weight, _ in self.quarters]
            first, second = self._merge(q[0], q[1]), self._merge(q[2], q[3])
            self._means = (first[0], second[0], self._merge(first, second)[0])
        return self._means

    @property
    def mean(self):
        """The mean of all samples, a float64 Dr.Jit tensor (None before the first pass)."""
        return self._combined()[2]

    def variance_of_mean(self):
        """``M2 / ((K - 1) W)``: the variance of each pixel's mean from its ``K`` passes (zeros before two)."""
        import drjit as dr

        if self.passes < 2:
            return dr.zeros(type(self.m2), self.m2.shape)
        return self.m2 * dr.opaque(dr.float64_array_t(dr.array_t(self.m2)), 1.0 / ((self.passes - 1) * self.weight))

    def quarters_variance(self):
        """``sum_q W_q (m_q - m)^2 / (3 W)``: the variance of each pixel's mean from its four quarters
        (None until every quarter has a pass)."""
        import drjit as dr

        if any(q[2] == 0 for q in self.quarters):
            return None
        mean, f64 = self.mean, dr.float64_array_t(dr.array_t(self.mean))
        total = 0.0
        for m_q, w_q, _ in self.quarters:
            total = total + dr.square(m_q - mean) * dr.opaque(f64, w_q / (3.0 * self.weight))
        return total

    def spread(self):
        """``(mean, variance, spread_a, spread_b)``: the per-pixel float64 tensors the estimate is made
        of (all channels): the mean, the quarters' variance of the mean (:meth:`quarters_variance`) and
        each half's spread ``(m_q1 - m_q2)^2 W_q1 W_q2 / W_h`` (its variance per spp, from its two
        quarters); None until every quarter has a pass. A tiled render assembles these from its tiles'
        accumulators (:func:`estimate_error`)."""
        import drjit as dr

        variance = self.quarters_variance()
        if variance is None:
            return None
        f64 = dr.float64_array_t(dr.array_t(self.mean))
        halves = []
        for a, b in ((0, 1), (2, 3)):
            (m_a, w_a, _), (m_b, w_b, _) = self.quarters[a], self.quarters[b]
            halves.append(dr.square(m_a - m_b) * dr.opaque(f64, w_a * w_b / (w_a + w_b)))
        return self.mean, variance, halves[0], halves[1]

    def estimate(self, channels: int = 3) -> ErrorEstimate:
        """The relMSE estimated from the spread between the quarters, and whether it is trusted (module
        docstring). Over all pixels and the first ``channels`` channels (the colour; not AOVs).
        """
        if self.passes == 0:
            return _NONE
        spread = self.spread() if self.passes >= MIN_PASSES else None
        if spread is None:
            return dataclasses.replace(_NONE, nonfinite=nonfinite_pixels(self.mean, channels))
        return estimate_error(*spread, channels=channels)

    def estimated_relmse(self, channels: int = 3) -> float:
        """The estimated relMSE alone (:meth:`estimate`; NaN before :data:`MIN_PASSES` passes)."""
        return self.estimate(channels).relmse

    def image(self):
        """The mean so far as a float32 Dr.Jit tensor (lazy: costs nothing unless used)."""
        import mitsuba as mi

        return mi.TensorXf(self.mean)

    # -- checkpoint I/O
    #: The arrays :meth:`from_numpy` reads: ``m2`` and, per quarter ``k``, ``q{k}_mean/weight/passes``.
    KEYS = ("m2",) + tuple(f"q{k}_{name}" for k in range(4) for name in ("mean", "weight", "passes"))

    def to_numpy(self) -> dict[str, Any]:
        """:data:`KEYS`, and the whole render's ``mean``, ``weight`` and ``passes`` (for checks)."""
        empty = np.zeros(self.shape or (0,), np.float64)
        data = {"m2": empty if self.m2 is None else self.m2.numpy().astype(np.float64),
                "mean": empty if self.mean is None else self.mean.numpy().astype(np.float64),
                "weight": np.int64(self.weight), "passes": np.int64(self.passes)}
        for k, (mean, weight, passes) in enumerate(self.quarters):
            data.update({f"q{k}_mean": empty if mean is None else mean.numpy().astype(np.float64),
                         f"q{k}_weight": np.int64(weight), f"q{k}_passes": np.int64(passes)})
        return data

    @classmethod
    def from_numpy(cls, data: dict[str, Any]) -> Accumulator:
        import mitsuba as mi
        import drjit as dr

        t64 = dr.float64_array_t(mi.TensorXf)
        quarters = []
        for k in range(4):
            passes = int(data[f"q{k}_passes"])
            quarters.append((t64(np.asarray(data[f"q{k}_mean"], np.float64)) if passes else None,
                             int(data[f"q{k}_weight"]), passes))
        acc = cls(quarters)
        acc.m2 = t64(np.asarray(data["m2"], np.float64)) if acc.passes else None
        return acc


_NONE = ErrorEstimate(math.nan, (math.nan, math.nan), math.nan, False, 0, math.nan)


def _colour(t, channels: int):
    """The first ``channels`` channels of an (H, W, C) tensor, flat (at least 1, at most C)."""
    depth = (tuple(t.shape) + (1,))[2]
    c = max(min(int(channels), depth), 1)
    return (t[..., :c] if c < depth else t).array, c


def nonfinite_pixels(mean, channels: int = 3) -> int:
    """Pixels of the (H, W, C) tensor ``mean`` with a NaN or inf in any of its first ``channels`` channels."""
    import drjit as dr
    import mitsuba as mi

    m, c = _colour(mean, channels)
    pixels = int(mean.shape[0]) * int(mean.shape[1])
    bad = dr.select(dr.isfinite(m), 0.0, 1.0)
    first = dr.arange(mi.UInt32, pixels) * c
    any_bad = dr.gather(type(bad), bad, first)
    for k in range(1, c):
        any_bad = dr.maximum(any_bad, dr.gather(type(bad), bad, first + k))
    return int(dr.sum(any_bad)[0])


def estimate_error(mean, variance, spread_a, spread_b, *, channels: int = 3, per_pixel: bool = False):
    """The error estimate (module docstring) of per-pixel float64 tensors (H, W, C): the ``mean`` of
    all samples, the ``variance`` of that mean and the two halves' spreads (:meth:`Accumulator.spread`),
    over the first ``channels`` channels.

    Returns the :class:`ErrorEstimate`; with ``per_pixel``, also each pixel's share of the relMSE
    (float64 numpy (H, W): its terms ``v / (d + eps)`` summed over the channels, divided by the
    number of finite values, so that the shares add up to the estimate).
    """
    import drjit as dr
    import mitsuba as mi

    from pointillist.imaging.filters import correlate

    height, width = int(mean.shape[0]), int(mean.shape[1])
    m, c = _colour(mean, channels)
    f64 = type(m)
    finite = dr.isfinite(m)
    v = dr.select(finite, _colour(variance, channels)[0], 0.0)
    m = dr.select(finite, m, 0.0)
    # the mean of the 8 neighbours (the border pixels repeated outward)
    around = correlate(mi.TensorXf(dr.float32_array_t(f64)(m), (height, width, c)), _AROUND, border="clamp")
    n = f64(around.array) * (1.0 / 8.0)
    square = m * m
    own = dr.maximum(square - v, 0.0)
    local = dr.select(v <= RELIABLE_VARIANCE * square, own, dr.minimum(own, n * n))
    floor = square * (1.0 / FIREFLY_RANGE ** 2)
    inverse = dr.select(finite, 1.0 / (dr.maximum(local, floor) + RELMSE_EPSILON), 0.0)
    terms = [v * inverse, dr.select(floor > local, v * inverse, 0.0), dr.select(finite, 0.0, 1.0)]
    for spread in (spread_a, spread_b):   # each half's variance per spp, same denominators
        terms.append(dr.select(finite, _colour(spread, channels)[0], 0.0) * inverse)
    dr.eval(*terms)       # one kernel; the sums below read its results
    sums = [dr.sum(t) for t in terms]
    dr.eval(*sums)
    total, floored, bad, e_a, e_b = (float(s[0]) for s in sums)
    nonfinite = nonfinite_pixels(mean, channels) if bad else 0
    values = height * width * c - bad
    if values == 0:
        none = dataclasses.replace(_NONE, nonfinite=nonfinite)
        return (none, np.zeros((height, width))) if per_pixel else none
    total, floored, e_a, e_b = total / values, floored / values, e_a / values, e_b / values
    if max(e_a, e_b) == 0:
        ratio = 1.0
    else:
        ratio = max(e_a, e_b) / min(e_a, e_b) if min(e_a, e_b) > 0 else math.inf
    share = floored / total if total > 0 else 0.0
    estimate = ErrorEstimate(total, (e_a, e_b), ratio, ratio <= HALVES_AGREEMENT and share <= FLOORED_SHARE,
                             nonfinite, share)
    if not per_pixel:
        return estimate
    shares = terms[0].numpy().reshape(height, width, c).sum(axis=2) / values
    return estimate, shares
