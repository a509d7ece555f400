"""Progressive rendering: passes, a running error estimate without a reference, and budgets.

A progressive render is a sequence of *passes*: ``mi.render(scene, spp=n_k, seed=s_k)``, each an
independent estimate of the image (its own seed, :func:`pass_seed`). The passes are accumulated per
pixel and channel in float64, in two ways:

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
its pixel NaN for good) are counted (:attr:`PassStats.nonfinite`) and left out of the estimate. It
assumes independent passes and an unbiased estimator: a seed-free ``grid`` sampler gives identical
passes (estimate 0), and a bias (clamping, a ``max_depth`` cut-off) is not in the spread.

:func:`render_passes` is the engine (a generator of ``(image so far, PassStats)``),
:class:`Budget` decides the size of each pass (time, error and spp budgets, auto pass size),
:func:`render_progressive` is the workflow of ``pointillist render --time/--target-error``
(progress bar, checkpoints, resume, Ctrl-C/SIGTERM) and :func:`write_progress` writes the
``.progress.csv`` log and the log-log ``.progress.png`` plot.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pointillist import signals
from pointillist.errors import UsageError
from pointillist.imaging.metrics import RELMSE_EPSILON
from pointillist.scene import MAX_SAMPLES, RenderTiming, scene_info, timed_render

__all__ = ["MIN_PASSES", "TARGET_PASS_SECONDS", "FIRST_PASS_SAMPLES", "CHECKPOINT_VERSION", "HISTORY_COLUMNS",
           "RELIABLE_VARIANCE", "FIREFLY_RANGE", "FLOORED_SHARE", "HALVES_AGREEMENT", "STOP_REASONS", "pass_seed",
           "tea32", "PassStats", "ErrorEstimate", "Accumulator", "Budget", "render_passes", "ProgressiveResult",
           "render_progressive", "write_progress", "checkpoint_path", "progress_paths", "scene_fingerprint"]

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

#: Why a progressive render stopped (``stopped_by`` in the EXR header): the spp budget, the time
#: budget, the error target (reached with a trusted estimate), Ctrl-C/SIGTERM, or ``limit``: the
#: most samples per pixel a render may reach (2^32 - 1, for a budget that gave none).
STOP_REASONS = ("spp", "time", "error", "interrupted", "limit")

#: Auto pass size: aim at passes of about this many seconds (at most an eighth of a time budget).
#: A pass costs tens of ms besides its samples (tracing the integrator again, film set-up, the
#: tail of each kernel): passes of ~1 s measured 6-9 % of overhead at 256x256-512x512 here
#: (benchmarks/RESULTS.md), so passes are twice that.
TARGET_PASS_SECONDS = 2.0

#: Auto pass size: samples (pixels x spp) of the first pass, which also compiles the kernels.
FIRST_PASS_SAMPLES = 2**18

#: Format version of the checkpoint file (2: the inputs' digest and a checksum of the contents;
#: 3: the four quarters' means and the longer history rows of the error estimate).
CHECKPOINT_VERSION = 3

#: Columns of a history row (:attr:`ProgressiveResult.history`, the progress CSV, checkpoints).
HISTORY_COLUMNS = ("pass", "seconds", "spp", "estimated_relmse", "halves_ratio", "floored", "trusted")

_U32 = 0xFFFFFFFF


def tea32(v0: int, v1: int, rounds: int = 4) -> tuple[int, int]:
    """The TEA hash Mitsuba seeds with (``mi.sample_tea_32``), on Python ints.

    Examples
    --------
    >>> tea32(0, 0)
    (1576399551, 1422788794)
    """
    v0, v1, total = v0 & _U32, v1 & _U32, 0
    for _ in range(rounds):
        total = (total + 0x9E3779B9) & _U32
        v0 = (v0 + ((((v1 << 4) + 0xA341316C) & _U32) ^ ((v1 + total) & _U32) ^ ((v1 >> 5) + 0xC8013EA4))) & _U32
        v1 = (v1 + ((((v0 << 4) + 0xAD90777D) & _U32) ^ ((v0 + total) & _U32) ^ ((v0 >> 5) + 0x7E95761E))) & _U32
    return v0, v1


def pass_seed(seed: int, index: int) -> int:
    """Mitsuba seed of pass ``index`` (0, 1, ...) of a render with ``seed``: ``(TEA(seed, 0) + index) mod 2^32``.

    Passes of one render never share a seed (for fewer than 2^32 passes); renders with other
    seeds start at hashed, unrelated offsets.

    Examples
    --------
    >>> [pass_seed(0, k) for k in range(3)]
    [1576399551, 1576399552, 1576399553]
    """
    return (tea32(int(seed), 0)[0] + int(index)) & _U32




@dataclass(frozen=True)
class PassStats:
    """Where a progressive render stands after a pass (``passes == 0``: before the first).

    ``seconds``: render seconds of all passes so far (rendering, JIT compilation, accumulation;
    resumed renders include the earlier ones); ``compile_seconds``: the JIT compilation part;
    ``estimated_relmse``: NaN before :data:`MIN_PASSES` passes; ``halves_ratio``, ``floored`` and
    ``trusted``: as in :class:`ErrorEstimate`; ``nonfinite``: pixels holding NaN or inf; ``seed``:
    the Mitsuba seed of the last pass.
    """

    passes: int
    spp: int
    pass_spp: int
    seconds: float
    pass_seconds: float
    pass_compile_seconds: float
    compile_seconds: float
    estimated_relmse: float
    width: int
    height: int
    seed: int = 0
    halves_ratio: float = math.nan
    floored: float = math.nan
    trusted: bool = False
    nonfinite: int = 0

    def seconds_per_spp(self) -> float:
        """Seconds one spp of the last pass took, JIT compilation left out (NaN before a pass)."""
        if self.pass_spp < 1:
            return math.nan
        return max(self.pass_seconds - self.pass_compile_seconds, 1e-9) / self.pass_spp

    @property
    def estimate_state(self) -> str:
        """``"none"`` (no estimate yet), ``"trusted"`` or ``"untrusted"`` (the halves disagree)."""
        if not math.isfinite(self.estimated_relmse):
            return "none"
        return "trusted" if self.trusted else "untrusted"


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

    def estimate(self, channels: int = 3) -> ErrorEstimate:
        """The relMSE estimated from the spread between the quarters, and whether it is trusted (module
        docstring). Over all pixels and the first ``channels`` channels (the colour; not AOVs).
        """
        import drjit as dr
        import mitsuba as mi

        from pointillist.imaging.filters import correlate

        none = ErrorEstimate(math.nan, (math.nan, math.nan), math.nan, False, 0, math.nan)
        if self.passes == 0:
            return none
        height, width, depth = (self.shape + (1,))[:3]
        c = max(min(int(channels), depth), 1)

        def colour(t):
            return (t[..., :c] if c < depth else t).array

        m = colour(self.mean)
        f64 = type(m)
        finite = dr.isfinite(m)
        variance = self.quarters_variance()
        if self.passes < MIN_PASSES or variance is None:
            return dataclasses.replace(none, nonfinite=self._nonfinite_pixels(finite, height * width, c))
        v = dr.select(finite, colour(variance), 0.0)
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
        for a, b in ((0, 1), (2, 3)):   # each half's variance per spp from its two quarters
            (m_a, w_a, _), (m_b, w_b, _) = self.quarters[a], self.quarters[b]
            terms.append(dr.select(finite, dr.square(colour(m_a) - colour(m_b)), 0.0) * inverse
                         * dr.opaque(f64, w_a * w_b / (w_a + w_b)))
        dr.eval(*terms)       # one kernel; the sums below read its results
        sums = [dr.sum(t) for t in terms]
        dr.eval(*sums)
        total, floored, bad, e_a, e_b = (float(s[0]) for s in sums)
        nonfinite = self._nonfinite_pixels(finite, height * width, c) if bad else 0
        values = height * width * c - bad
        if values == 0:
            return dataclasses.replace(none, nonfinite=nonfinite)
        total, floored, e_a, e_b = total / values, floored / values, e_a / values, e_b / values
        if max(e_a, e_b) == 0:
            ratio = 1.0
        else:
            ratio = max(e_a, e_b) / min(e_a, e_b) if min(e_a, e_b) > 0 else math.inf
        share = floored / total if total > 0 else 0.0
        return ErrorEstimate(total, (e_a, e_b), ratio, ratio <= HALVES_AGREEMENT and share <= FLOORED_SHARE,
                             nonfinite, share)

    @staticmethod
    def _nonfinite_pixels(finite, pixels: int, channels: int) -> int:
        """Pixels with a non-finite value in any of their ``channels`` (``finite``: per value)."""
        import drjit as dr
        import mitsuba as mi

        bad = dr.select(finite, 0.0, 1.0)
        first = dr.arange(mi.UInt32, pixels) * channels
        any_bad = dr.gather(type(bad), bad, first)
        for k in range(1, channels):
            any_bad = dr.maximum(any_bad, dr.gather(type(bad), bad, first + k))
        return int(dr.sum(any_bad)[0])

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


def _pow2_floor(n: int) -> int:
    return 1 << (int(n).bit_length() - 1)


@dataclass(frozen=True)
class Budget:
    """When a progressive render stops, and how many spp each pass takes.

    Parameters
    ----------
    seconds : float, optional
        Stop when the render seconds (:attr:`PassStats.seconds`) reach this, or when less than
        one spp fits in the time left; the last passes shrink (halving their spp) to end close
        to it, and auto passes leave room for ``min_passes`` passes (an estimate) where the time
        allows. At least one pass always runs.
    target_error : float, optional
        Stop when the estimated relMSE is at most this and trusted (checked from ``min_passes``
        on; :class:`ErrorEstimate`). Auto passes take 1 spp until the first estimate, then at
        most a quarter of the spp so far (so that the four quarters of the passes stay within
        2x of each other: a firefly in a quarter holding more than its share is under-counted)
        and, while the estimate is trusted, no more than the 1/spp law says is still needed
        (rounded down to a power of two), so the render stops close to the target. Without
        ``seconds`` and ``spp``, a target that a trusted estimate
        puts beyond 2^32 - 1 spp raises a :class:`~pointillist.errors.UsageError` (it would run
        for ever), and so does an image whose every pixel is NaN or inf (no estimate).
    spp : int, optional
        Stop at this many samples per pixel (the last pass is cut to land on it exactly).
    pass_spp : int, optional
        Samples per pass; default (None): the first pass takes about
        :data:`FIRST_PASS_SAMPLES` samples (it compiles the kernels), the others the power of
        two nearest to :data:`TARGET_PASS_SECONDS` (at most an eighth of ``seconds``).
    min_passes : int
        Passes before ``target_error`` is checked (at least :data:`MIN_PASSES`).

    Without ``seconds``, ``target_error`` or ``spp`` the passes go on until interrupted (Ctrl-C),
    or until 2^32 - 1 spp. The budget is a callable: ``budget(stats)`` is the spp of the next pass;
    it is 0 exactly when :meth:`stop_reason` names why the render is done. Auto and shrunk passes
    are powers of two, which share one compiled kernel (a pass cut to land on ``spp`` exactly
    may take one more compilation).

    Examples
    --------
    >>> from dataclasses import replace
    >>> b = Budget(spp=10, pass_spp=4)
    >>> start = PassStats(0, 0, 0, 0.0, 0.0, 0.0, 0.0, math.nan, 8, 8)
    >>> b(start), b(replace(start, passes=2, spp=8, pass_spp=4)), b(replace(start, passes=3, spp=10))
    (4, 2, 0)
    >>> b.stop_reason(replace(start, passes=3, spp=10))
    'spp'
    """

    seconds: float | None = None
    target_error: float | None = None
    spp: int | None = None
    pass_spp: int | None = None
    min_passes: int = MIN_PASSES

    def __post_init__(self):
        for name in ("seconds", "target_error"):
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))
                                      or not math.isfinite(value) or value <= 0):
                raise ValueError(f"{name}: expected a positive finite number, got {value!r}")
        for name in ("spp", "pass_spp"):
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, (int, np.integer))
                                      or not 1 <= value <= MAX_SAMPLES):
                raise ValueError(f"{name}: expected an integer in 1..2^32-1, got {value!r}")
        if isinstance(self.min_passes, bool) or not isinstance(self.min_passes, int) or self.min_passes < MIN_PASSES:
            raise ValueError(f"min_passes: expected an integer >= {MIN_PASSES}, got {self.min_passes!r}")

    def _fitting_spp(self, stats: PassStats) -> float:
        """Spp that fit in the time left at the last pass's rate (inf without a time budget or a rate)."""
        rate = stats.seconds_per_spp()
        if self.seconds is None or stats.passes == 0 or not math.isfinite(rate):
            return math.inf
        return (self.seconds - stats.seconds) / rate

    def stop_reason(self, stats: PassStats) -> str | None:
        """Why the render is done after ``stats`` (one of :data:`STOP_REASONS` but ``"interrupted"``), or None.

        ``"time"`` also when less than one spp fits in the time left.
        """
        if stats.passes == 0:
            return None
        if self.spp is not None and stats.spp >= self.spp:
            return "spp"
        if self.target_error is not None and stats.passes >= self.min_passes and stats.trusted \
                and stats.estimated_relmse <= self.target_error:
            return "error"
        if self.seconds is not None and (stats.seconds >= self.seconds or self._fitting_spp(stats) + 0.5 < 1):
            return "time"
        if stats.spp >= MAX_SAMPLES:
            return "limit"
        return None

    def _check_reachable(self, stats: PassStats) -> None:
        """UsageError where an error budget alone would never end: no finite pixel, or out of reach."""
        if self.target_error is None or stats.passes < self.min_passes:
            return
        if stats.nonfinite >= stats.width * stats.height:
            raise UsageError(f"target error: every pixel is NaN or inf after {stats.passes} passes, so the error "
                             "cannot be estimated (the scene or its integrator gives non-finite values)")
        if self.seconds is None and self.spp is None and stats.trusted and stats.estimated_relmse > 0:
            needed = stats.spp * stats.estimated_relmse / self.target_error
            if needed > MAX_SAMPLES:
                raise UsageError(f"target error {self.target_error:g} is out of reach: the estimated relMSE is "
                                 f"{stats.estimated_relmse:.3g} at {stats.spp} spp and falls as 1/spp, so it needs "
                                 f"about {needed:.2g} spp, more than the 2^32 - 1 a render may take; "
                                 "set a larger target, or bound the render with a time or spp budget")

    def __call__(self, stats: PassStats) -> int:
        self._check_reachable(stats)
        if self.stop_reason(stats):
            return 0
        pixels = max(stats.width * stats.height, 1)
        largest = _pow2_floor(max(MAX_SAMPLES // pixels, 1))
        rate = stats.seconds_per_spp()
        if self.pass_spp is not None:
            n = self.pass_spp
        elif self.target_error is not None and stats.passes < self.min_passes:
            n = 1  # until the first estimate, as few samples as possible: the target may need only a few
        elif stats.passes == 0 or not math.isfinite(rate):
            n = _pow2_floor(max(FIRST_PASS_SAMPLES // pixels, 1))
        else:
            target = TARGET_PASS_SECONDS if self.seconds is None else min(TARGET_PASS_SECONDS, self.seconds / 8)
            n = 1 << max(round(math.log2(max(target / rate, 1.0))), 0)  # nearest power of two
        n = min(n, largest)
        if self.target_error is not None and stats.passes >= self.min_passes and math.isfinite(stats.estimated_relmse):
            if self.pass_spp is None:   # a quarter of the spp so far at most: the quarters stay within 2x
                n = min(n, _pow2_floor(max(stats.spp // 4, 1)))
            if stats.trusted:           # approach the target from below (the 1/spp law)
                needed = stats.spp * stats.estimated_relmse / self.target_error - stats.spp
                n = min(n, _pow2_floor(max(int(math.ceil(needed)), 1)))
        n = min(n, MAX_SAMPLES - stats.spp)
        if self.spp is not None and self.spp - stats.spp < n:
            left = self.spp - stats.spp
            n = left if left <= largest else _pow2_floor(left)
        fit = self._fitting_spp(stats)
        if math.isfinite(fit) and self.pass_spp is None and stats.passes < self.min_passes:
            # leave room for the passes an estimate needs (the first one, compiling, may take most of it)
            n = min(n, _pow2_floor(max(int(fit / (self.min_passes - stats.passes)), 1)))
        if math.isfinite(fit) and int(fit + 0.5) < n:
            n = _pow2_floor(int(fit + 0.5))
        return int(n)


def _passes(scene, plan: Callable[[PassStats], int], *, seed: int, sensor: int, accumulator: Accumulator,
            start: PassStats, clock: Callable[[], float],
            channels: int | None = None) -> Iterator[tuple[Accumulator, PassStats, RenderTiming]]:
    """The pass loop: render, accumulate, estimate; yields ``(accumulator, stats, timing)``.

    ``channels``: the leading channels the estimate takes (the colour; default from the scene's
    :func:`pointillist.channels.channel_layout`)."""
    import drjit as dr
    import mitsuba as mi

    if channels is None:
        from pointillist.channels import channel_layout

        layout = channel_layout(scene, sensor)
        channels = len(layout.colour) or layout.channels
    acc, stats = accumulator, start
    while True:
        spp = int(plan(stats))
        if spp < 1:
            return
        seed_k = pass_seed(seed, acc.passes)
        begin = clock()
        image, timing = timed_render(scene, spp=spp, seed=dr.opaque(mi.UInt32, seed_k), sensor=sensor)
        new = acc.add(image, spp)
        estimate = new.estimate(channels)
        seconds = clock() - begin
        acc = new
        stats = PassStats(passes=acc.passes, spp=acc.weight, pass_spp=spp, seconds=stats.seconds + seconds,
                          pass_seconds=seconds, pass_compile_seconds=timing.compile,
                          compile_seconds=stats.compile_seconds + timing.compile, estimated_relmse=estimate.relmse,
                          width=stats.width, height=stats.height, seed=seed_k, halves_ratio=estimate.halves_ratio,
                          floored=estimate.floored, trusted=estimate.trusted, nonfinite=estimate.nonfinite)
        yield acc, stats, timing


def _start_stats(scene, sensor: int, accumulator: Accumulator) -> PassStats:
    info = scene_info(scene, sensor)
    return PassStats(passes=accumulator.passes, spp=accumulator.weight, pass_spp=0, seconds=0.0, pass_seconds=0.0,
                     pass_compile_seconds=0.0, compile_seconds=0.0, estimated_relmse=math.nan,
                     width=info["width"], height=info["height"])


def _check_seed(seed) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed <= _U32:
        raise ValueError(f"seed: expected an integer in 0..2^32-1, got {seed!r}")
    return int(seed)


def render_passes(scene, *, pass_spp: int | Callable[[PassStats], int], seed: int = 0, sensor: int = 0,
                  clock: Callable[[], float] = time.perf_counter) -> Iterator[tuple[Any, PassStats]]:
    """Render ``scene`` in passes; yield ``(image so far, PassStats)`` after each.

    Parameters
    ----------
    scene : mitsuba.Scene
        A loaded scene (:func:`pointillist.scene.load_scene`).
    pass_spp : int or callable
        Samples per pixel of every pass (the generator is endless: stop iterating when done), or a
        callable ``(PassStats) -> int`` giving each pass's spp, 0 to stop, e.g. a :class:`Budget`.
    seed : int
        Pass ``k`` uses the Mitsuba seed :func:`pass_seed(seed, k) <pass_seed>`.
    sensor : int
        Sensor index.
    clock : callable
        Wall clock in seconds (injectable for tests).

    Yields
    ------
    image : mitsuba.TensorXf
        The mean of all samples so far, (H, W, C) float32 (lazy: evaluated when used).
    stats : PassStats
        Passes, spp, seconds and the estimated relMSE so far.

    Examples
    --------
    >>> import pointillist
    >>> mi = pointillist.setup()
    >>> from pointillist.scene import load_scene
    >>> scene = load_scene("scenes/edges.xml", {"res": "16"})
    >>> for image, stats in render_passes(scene, pass_spp=Budget(spp=16, pass_spp=2)):
    ...     pass
    >>> stats.passes, stats.spp, image.shape, stats.estimated_relmse > 0
    (8, 16, (16, 16, 3), True)
    """
    seed = _check_seed(seed)
    if callable(pass_spp):
        plan = pass_spp
    else:
        if isinstance(pass_spp, bool) or not isinstance(pass_spp, (int, np.integer)) \
                or not 1 <= pass_spp <= MAX_SAMPLES:
            raise ValueError(f"pass_spp: expected an integer in 1..2^32-1 or a callable, got {pass_spp!r}")
        plan = lambda _stats, n=int(pass_spp): n  # noqa: E731
    acc = Accumulator.empty()
    for acc, stats, _timing in _passes(scene, plan, seed=seed, sensor=sensor, accumulator=acc,
                                        start=_start_stats(scene, sensor, acc), clock=clock):
        yield acc.image(), stats


# ------------------------------------------------------------------------------ checkpoints
def checkpoint_path(out: str | Path) -> Path:
    """``OUT.checkpoint.npz`` beside the EXR ``OUT.exr``."""
    return Path(out).with_suffix(".checkpoint.npz")


def progress_paths(out: str | Path) -> tuple[Path, Path]:
    """``(OUT.progress.csv, OUT.progress.png)`` beside the EXR ``OUT.exr``."""
    return Path(out).with_suffix(".progress.csv"), Path(out).with_suffix(".progress.png")


def scene_fingerprint(scene, scene_path: str | Path, params: dict[str, str] | None, seed: int,
                      sensor: int = 0, *, inputs: Sequence[str | Path] | None = None) -> dict[str, Any]:
    """What a checkpoint must match to be resumed: the SHA-256 of the scene's inputs (the scene file
    and every file it reads: includes, textures, meshes, volumes; :func:`pointillist.plan.inputs_digest`)
    with the ``-D`` values, the seed, the film, integrator and sampler.

    ``inputs``: the scene's inputs when known (:func:`pointillist.plan.scene_inputs`); else the
    scene file is parsed again to list them.
    """
    import mitsuba as mi

    from pointillist.plan import inputs_digest, scene_inputs
    from pointillist.scene import parse_scene

    if inputs is None:
        inputs = scene_inputs(parse_scene(scene_path, params))
    info = scene_info(scene, sensor)
    return {"inputs_sha256": inputs_digest(inputs, params),
            "params": json.dumps(dict(sorted((params or {}).items()))), "seed": int(seed), "sensor": int(sensor),
            "film": f"{info['width']}x{info['height']}", "integrator": info["integrator"],
            "sampler": info["sampler"], "variant": mi.variant()}


def _checksum(arrays: dict[str, Any]) -> str:
    """SHA-256 of a checkpoint's contents (every entry but the checksum, by name, dtype, shape, bytes)."""
    digest = hashlib.sha256()
    for name in sorted(arrays):
        if name == "checksum":
            continue
        value = np.ascontiguousarray(np.asarray(arrays[name]))
        digest.update(f"{name}|{value.dtype.str}|{value.shape}|".encode())
        digest.update(value.tobytes())
    return digest.hexdigest()


def _save_checkpoint(path: Path, acc: Accumulator, stats: PassStats, history: list, identity: dict) -> None:
    from pointillist.imaging.io import atomic_write

    arrays = dict(acc.to_numpy(), history=np.asarray(history, np.float64).reshape(-1, len(HISTORY_COLUMNS)),
                  stats=np.array(json.dumps(asdict(stats))), identity=np.array(json.dumps(identity)),
                  version=np.int64(CHECKPOINT_VERSION))
    arrays["checksum"] = np.array(_checksum(arrays))
    atomic_write(path, lambda tmp: np.savez(tmp, **arrays))


def _load_checkpoint(path: Path, identity: dict, channels: int | None = None) -> tuple[Accumulator, PassStats, list]:
    """Read a checkpoint; UsageError unless it is one this version wrote, unchanged (its checksum),
    for the same scene and settings (``identity``), and consistent (``channels``: the render's)."""
    if not path.is_file():
        raise UsageError(f"--resume: no checkpoint {path} (write one with --checkpoint SECONDS)")
    try:
        with np.load(path, allow_pickle=False) as data:
            if "version" not in data.files or int(data["version"]) != CHECKPOINT_VERSION:
                version = int(data["version"]) if "version" in data.files else "none"
                raise UsageError(f"--resume: checkpoint {path} has format version {version}, "
                                 f"expected {CHECKPOINT_VERSION}")
            arrays = {name: data[name] for name in data.files}
    except UsageError:
        raise
    except Exception as error:  # noqa: BLE001 - any unreadable file is a usage error here
        raise UsageError(f"--resume: {path} is not a readable checkpoint ({type(error).__name__}: {error})") from None
    if "checksum" not in arrays or str(arrays["checksum"]) != _checksum(arrays):
        raise UsageError(f"--resume: checkpoint {path} was changed or damaged after it was written "
                         "(its checksum does not match its contents)")
    try:
        saved = json.loads(str(arrays["identity"]))
        stats = PassStats(**json.loads(str(arrays["stats"])))
        mean, m2 = np.asarray(arrays["mean"]), np.asarray(arrays["m2"])
        weight, passes = int(arrays["weight"]), int(arrays["passes"])
        history = [tuple(float(v) for v in row)
                   for row in np.asarray(arrays["history"], np.float64).reshape(-1, len(HISTORY_COLUMNS))]
        acc = Accumulator.from_numpy(arrays)
    except (KeyError, TypeError, ValueError) as error:
        raise UsageError(f"--resume: {path} is not a readable checkpoint ({type(error).__name__}: {error})") from None
    for key, value in identity.items():
        if saved.get(key) != value:
            what = ("another scene (the scene file or a file it reads changed)" if key == "inputs_sha256"
                    else f"other settings ({key} {saved.get(key)!r}, now {value!r})")
            raise UsageError(f"--resume: checkpoint {path} was made from {what}")
    problem = _inconsistency(mean, m2, weight, passes, stats, history, channels)
    if not problem and (acc.weight, acc.passes) != (weight, passes):
        problem = (f"its quarters hold {acc.passes} passes of {acc.weight} spp, the whole render {passes} of "
                   f"{weight}")
    if problem:
        raise UsageError(f"--resume: checkpoint {path} is inconsistent ({problem})")
    return acc, stats, history


def _inconsistency(mean, m2, weight: int, passes: int, stats: PassStats, history: list,
                   channels: int | None) -> str:
    """What is wrong with a checkpoint's numbers ('' when nothing is): counts in range and agreeing
    with each other, arrays of the film's shape, times finite."""
    if mean.ndim != 3 or m2.shape != mean.shape or mean.dtype != np.float64 or m2.dtype != np.float64:
        return f"sums of shape {mean.shape} and {m2.shape}, expected two equal (H, W, C) float64 arrays"
    if tuple(mean.shape[:2]) != (stats.height, stats.width) or (channels is not None and mean.shape[2] != channels):
        return f"sums of shape {mean.shape}, the render is {stats.height}x{stats.width}x{channels or mean.shape[2]}"
    largest = max(MAX_SAMPLES // max(stats.width * stats.height, 1), 1)
    if not 1 <= passes <= weight <= passes * largest:
        return f"{passes} passes of {weight} spp in all (each pass takes 1..{largest} spp)"
    if stats.passes != passes or stats.spp != weight or len(history) != passes:
        return (f"{passes} passes and {weight} spp in the sums, {stats.passes} and {stats.spp} in the stats, "
                f"{len(history)} rows of history")
    if not (math.isfinite(stats.seconds) and stats.seconds >= 0 and math.isfinite(stats.compile_seconds)):
        return f"render seconds {stats.seconds}"
    return ""


# ------------------------------------------------------------------------------ the workflow
@dataclass
class ProgressiveResult:
    """What :func:`render_progressive` rendered.

    ``image``: (H, W, C) float32 mean of all samples; ``variance``: (H, W) float32 variance of
    the pixel mean averaged over the colour channels; ``history``: one row per pass,
    :data:`HISTORY_COLUMNS` (``trusted`` 1, 0, or NaN without an estimate); ``timing``: phases
    summed over the passes (``total`` = the render seconds); ``stop``: one of
    :data:`STOP_REASONS`; ``signum``: the signal that interrupted it (``signal.SIGINT``/``SIGTERM``;
    None otherwise); ``warnings``: one line each (NaN or inf pixels, an estimate the halves do not
    confirm), for the command line to print.
    """

    image: np.ndarray
    variance: np.ndarray
    stats: PassStats
    history: list[tuple[float, ...]]
    timing: RenderTiming
    interrupted: bool
    stop: str
    resumed_from: int = 0
    checkpoints: int = 0
    metadata: dict[str, Any] = field(default_factory=dict)
    signum: int | None = None
    warnings: list[str] = field(default_factory=list)


def _is_interrupt(error: BaseException | None) -> bool:
    """KeyboardInterrupt, or an error caused by one (Dr.Jit wraps exceptions raised inside a render)."""
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, KeyboardInterrupt):
            return True
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return False


def _bar(budget: Budget, start: PassStats, progress: bool):
    from tqdm import tqdm

    total, unit = ((budget.seconds, "s") if budget.seconds is not None else (budget.spp, "spp")
                   if budget.spp is not None else (None, "pass"))
    return tqdm(total=total, initial=_bar_position(budget, start), unit=unit, desc="render", leave=False,
                disable=None if progress else True,
                bar_format="{l_bar}{bar}| {n:.4g}/{total:.4g} {unit} [{elapsed}<{remaining}{postfix}]"
                if total is not None else None)


def _bar_position(budget: Budget, stats: PassStats) -> float:
    """Where the bar stands: seconds (time budget), spp (spp budget) or passes, never past the total."""
    if budget.seconds is not None:
        return min(stats.seconds, budget.seconds)
    if budget.spp is not None:
        return min(stats.spp, budget.spp)
    return stats.passes


def _postfix(budget: Budget, stats: PassStats) -> str:
    text = f"{stats.passes} passes, {stats.spp} spp"
    if math.isfinite(stats.estimated_relmse):
        text += f", est. relMSE {stats.estimated_relmse:.3g}" + ("" if stats.trusted else " (untrusted)")
        if budget.target_error is not None and stats.estimated_relmse > budget.target_error:
            more = stats.spp * (stats.estimated_relmse / budget.target_error - 1)
            text += f", error ETA ~{more * stats.seconds_per_spp():.0f} s"
    return text


def render_progressive(scene, scene_path: str | Path, budget: Budget, *, params: dict[str, str] | None = None,
                       seed: int = 0, sensor: int = 0, checkpoint_seconds: float | None = None,
                       checkpoint_file: str | Path | None = None, resume: bool = False, progress: bool = True,
                       clock: Callable[[], float] = time.perf_counter, inputs: Sequence[str | Path] | None = None,
                       layout=None, abandon: Callable[[ProgressiveResult], None] | None = None) -> ProgressiveResult:
    """Render ``scene`` in passes until ``budget`` is spent; Ctrl-C or SIGTERM keep what is done.

    Parameters
    ----------
    scene : mitsuba.Scene
        The loaded scene; ``scene_path`` its XML (hashed into checkpoints).
    budget : Budget
        When to stop, and the pass sizes.
    params, seed, sensor
        The ``-D`` values the scene was loaded with (checked on resume), the seed, the sensor.
    checkpoint_seconds : float, optional
        Write ``checkpoint_file`` (atomically) when this many wall seconds passed since the last
        write, after a pass, and once at the end.
    checkpoint_file : path, optional
        The checkpoint (``OUT.checkpoint.npz``); needed with ``checkpoint_seconds`` or ``resume``.
    resume : bool
        Continue from ``checkpoint_file`` (same scene file, ``-D`` values, seed, film, integrator
        and sampler, else :class:`~pointillist.errors.UsageError`); the budget counts the
        resumed passes too.
    progress : bool
        Draw a tqdm bar on stderr (only when stderr is a terminal; it is cleared at the end).
    clock : callable
        Wall clock in seconds (injectable for tests).
    inputs : sequence of paths, optional
        The scene's inputs (:func:`pointillist.plan.scene_inputs`), whose contents the checkpoint's
        fingerprint holds; listed from ``scene_path`` when not given.
    layout : pointillist.channels.ChannelLayout, optional
        The render's channels (read from ``scene`` when not given): the estimate and the variance
        take the colour channels.
    abandon : callable, optional
        Under ``pointillist``'s signal boundary, a second signal during the passes ends the process
        at once; ``abandon(result)`` is then called (from another thread, numpy data only) with
        the passes done, to write them; the checkpoint is written too.

    Returns
    -------
    ProgressiveResult
        With ``interrupted=True`` after SIGINT (Ctrl-C) or SIGTERM (``signum`` says which): the
        pass in flight finishes and the result holds the passes done; also after a
        KeyboardInterrupt raised elsewhere (re-raised when no pass was done).
    """
    from pointillist.channels import channel_layout

    seed = _check_seed(seed)
    if not isinstance(budget, Budget):
        raise TypeError(f"budget: expected a Budget, got {type(budget).__name__}")
    if checkpoint_seconds is not None and not (math.isfinite(checkpoint_seconds) and checkpoint_seconds > 0):
        raise ValueError(f"checkpoint_seconds: expected a positive finite number, got {checkpoint_seconds!r}")
    if (checkpoint_seconds is not None or resume) and checkpoint_file is None:
        raise ValueError("checkpoint_file: needed with checkpoint_seconds or resume")
    layout = layout or channel_layout(scene, sensor)
    channels = len(layout.colour) or layout.channels  # the colour channels lead; none: every channel
    checkpoint_file = None if checkpoint_file is None else Path(checkpoint_file)
    identity = scene_fingerprint(scene, scene_path, params, seed, sensor, inputs=inputs) if checkpoint_file else {}
    acc, history = Accumulator.empty(), []
    start = _start_stats(scene, sensor, acc)
    if resume:
        acc, start, history = _load_checkpoint(checkpoint_file, identity, layout.channels)
    resumed_from, stats, stop, checkpoints, signum, first_nonfinite = acc.passes, start, None, 0, None, None
    sums = [0.0, 0.0, 0.0, 0, 0]  # trace, compile, execute, kernels, cache hits
    # What a second signal writes (read by the signal watcher's thread: replaced, never changed).
    done = {"acc": acc, "stats": stats, "history": list(history), "sums": list(sums), "first_nonfinite": None}

    def finish(stop: str, signum: int | None, *, done: dict) -> ProgressiveResult:
        return _result(done["acc"], done["stats"], done["history"], done["sums"], stop, signum, budget, seed,
                       resumed_from, checkpoints, channels, done["first_nonfinite"])

    def abandoned() -> None:
        current = dict(done)
        if current["acc"].passes == resumed_from:
            return
        if checkpoint_seconds is not None:
            _save_checkpoint(checkpoint_file, current["acc"], current["stats"], current["history"], identity)
        if abandon is not None:
            abandon(finish("interrupted", signals.received(), done=current))

    last_write = clock()
    bar = _bar(budget, start, progress)
    try:
        with signals.deferred() as requested, signals.on_abandon(abandoned):
            for acc, new, timing in _passes(scene, budget, seed=seed, sensor=sensor, accumulator=acc, start=start,
                                            clock=clock, channels=channels):
                history.append(_history_row(new))
                if new.nonfinite and first_nonfinite is None:
                    first_nonfinite = new.passes
                sums = [sums[0] + timing.trace, sums[1] + timing.compile, sums[2] + timing.execute,
                        sums[3] + timing.kernels, sums[4] + timing.cache_hits]
                bar.update(_bar_position(budget, new) - _bar_position(budget, stats))
                stats = new
                done = {"acc": acc, "stats": stats, "history": list(history), "sums": list(sums),
                        "first_nonfinite": first_nonfinite}
                bar.set_postfix_str(_postfix(budget, stats), refresh=False)
                if requested() is not None:  # first signal: stop after the pass in flight
                    stop, signum = "interrupted", requested()
                    break
                if checkpoint_seconds is not None and clock() - last_write >= checkpoint_seconds:
                    _save_checkpoint(checkpoint_file, acc, stats, history, identity)
                    last_write, checkpoints = clock(), checkpoints + 1
        stop = stop or budget.stop_reason(stats)
        if stop is None:   # Budget returns 0 exactly when stop_reason names a reason
            raise RuntimeError("the budget stopped the render without a reason")
    except BaseException as error:  # noqa: BLE001 - only interruptions are handled here
        if not _is_interrupt(error) or acc.passes == 0:
            raise
        stop = "interrupted"
    finally:
        bar.close()
    if checkpoint_seconds is not None and acc.passes > resumed_from:
        _save_checkpoint(checkpoint_file, acc, stats, history, identity)
        checkpoints += 1
    return finish(stop, (signum or signals.received()) if stop == "interrupted" else None,
                  done={"acc": acc, "stats": stats, "history": history, "sums": sums,
                        "first_nonfinite": first_nonfinite})


def _result(acc: Accumulator, stats: PassStats, history: list, sums: list, stop: str, signum: int | None,
            budget: Budget, seed: int, resumed_from: int, checkpoints: int, channels: int,
            first_nonfinite: int | None = None) -> ProgressiveResult:
    """The :class:`ProgressiveResult` of the passes in ``acc`` (numpy only: also called from the
    signal watcher's thread while the main thread renders)."""
    image = acc.mean.numpy().astype(np.float32)
    if acc.passes >= 2:
        variance = acc.m2.numpy()[..., :channels] * (1.0 / ((acc.passes - 1) * acc.weight))
    else:
        variance = np.zeros(tuple(acc.mean.shape)[:2] + (channels,))
    variance = variance.mean(axis=2).astype(np.float32)
    timing = RenderTiming(trace=sums[0], compile=sums[1], execute=sums[2], total=stats.seconds, kernels=int(sums[3]),
                          cache_hits=int(sums[4]))
    metadata = {"spp": stats.spp, "passes": stats.passes, "estimated_relmse": stats.estimated_relmse,
                "estimate_state": stats.estimate_state, "halves_ratio": stats.halves_ratio,
                "nonfinite_pixels": stats.nonfinite, "interrupted": stop == "interrupted", "stopped_by": stop,
                "pass_seeds": "(TEA(seed, 0) + pass) mod 2^32", "seed": seed}
    for name, value in (("time_budget", budget.seconds), ("target_error", budget.target_error),
                        ("spp_budget", budget.spp), ("pass_spp", budget.pass_spp)):
        if value is not None:
            metadata[name] = value
    if resumed_from:
        metadata["resumed_from_passes"] = resumed_from
    return ProgressiveResult(image=image, variance=variance, stats=stats, history=list(history), timing=timing,
                             interrupted=stop == "interrupted", stop=stop, resumed_from=resumed_from,
                             checkpoints=checkpoints, metadata=metadata, signum=signum,
                             warnings=_warnings(stats, first_nonfinite, stop))


def _history_row(stats: PassStats) -> tuple[float, ...]:
    """One row of :data:`HISTORY_COLUMNS`."""
    trusted = math.nan if stats.estimate_state == "none" else float(stats.trusted)
    return (stats.passes, stats.seconds, stats.spp, stats.estimated_relmse, stats.halves_ratio, stats.floored, trusted)


def _warnings(stats: PassStats, first_nonfinite: int | None, stop: str = "") -> list[str]:
    """The lines a finished render warns with: NaN/inf pixels, an estimate that is not trusted (not after an
    interruption: the render is known to be unfinished, and says so in one line)."""
    warnings = []
    if stats.nonfinite:
        since = "in the resumed passes" if first_nonfinite is None else f"from pass {first_nonfinite} on"
        warnings.append(f"{stats.nonfinite} of {stats.width * stats.height} pixels are NaN or inf ({since}); "
                        "they stay so in the image and are left out of the error estimate")
    if stats.estimate_state == "untrusted" and stop != "interrupted":
        why = (f"its two halves differ {stats.halves_ratio:.3g}x (more than {HALVES_AGREEMENT:g}x)"
               if not stats.halves_ratio <= HALVES_AGREEMENT else
               f"{stats.floored:.0%} of it comes from single samples more than {FIREFLY_RANGE}x their pixel's "
               "neighbourhood")
        warnings.append(f"the error estimate is not trusted: {why}, so rare bright paths dominate it and the true "
                        "error may be far from it; render longer")
    return warnings


def write_progress(out: str | Path, history: list, *, png: bool = False, inputs=()) -> list[Path]:
    """Write ``OUT.progress.csv`` and, with ``png``, ``OUT.progress.png``.

    The CSV has one row per pass: ``pass, seconds, spp, estimated_relmse, halves_ratio, floored,
    estimate_state`` (``none``, ``trusted`` or ``untrusted``; empty numbers where there is no
    estimate; :class:`ErrorEstimate`). The plot shows the estimated relMSE against render seconds
    on log-log axes, trusted estimates filled and untrusted ones hollow, with a line of slope -1
    (error proportional to 1/t, the Monte Carlo rate) through the last estimate. Returns the paths
    written.
    """
    from pointillist.imaging.io import atomic_write, check_output_path, save_figure

    csv_path, png_path = progress_paths(out)
    check_output_path(csv_path, inputs)
    data = np.asarray(history, np.float64).reshape(-1, len(HISTORY_COLUMNS))
    states = np.where(np.isnan(data[:, 6]), "none", np.where(data[:, 6] > 0, "trusted", "untrusted"))

    def number(x: float, fmt: str) -> str:
        return "" if not math.isfinite(x) else format(x, fmt)

    rows = [",".join(HISTORY_COLUMNS[:6] + ("estimate_state",))] + [
        f"{int(k)},{t:.6f},{int(n)},{number(e, '.6g')},{number(q, '.4g')},{number(f, '.3g')},{state}"
        for (k, t, n, e, q, f, _), state in zip(data, states)]
    atomic_write(csv_path, lambda tmp: Path(tmp).write_text("\n".join(rows) + "\n"))
    written = [csv_path]
    if png:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        check_output_path(png_path, inputs)
        ok = np.isfinite(data[:, 3]) & (data[:, 3] > 0) & (data[:, 1] > 0)
        fig, ax = plt.subplots(figsize=(5.5, 4), dpi=110)
        if ok.any():
            t, e, trusted = data[ok, 1], data[ok, 3], states[ok] == "trusted"
            ax.loglog(t, e, "-", color="C0", lw=1, label="estimated relMSE")
            ax.loglog(t[trusted], e[trusted], "o", ms=3, color="C0", label="trusted (halves agree)")
            if (~trusted).any():
                ax.loglog(t[~trusted], e[~trusted], "o", ms=4, mfc="none", color="C3",
                          label="untrusted (halves disagree)")
            span = np.array([t.min(), t.max()])
            ax.loglog(span, e[-1] * t[-1] / span, "--", color="grey", label="1/t (slope -1)")
            ax.legend(fontsize=8)
        else:
            ax.text(0.5, 0.5, f"no estimate yet (from {MIN_PASSES} passes on)", ha="center", transform=ax.transAxes)
        ax.set_xlabel("render seconds")
        ax.set_ylabel("estimated relMSE")
        ax.set_title(f"{int(data[-1, 0]) if len(data) else 0} passes, {int(data[-1, 2]) if len(data) else 0} spp",
                     fontsize=9)
        ax.grid(True, which="both", lw=0.3)
        fig.tight_layout()
        save_figure(fig, png_path)
        written.append(png_path)
    return written
