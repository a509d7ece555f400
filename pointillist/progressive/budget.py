"""When a progressive render stops, and how many samples each pass takes: :class:`Budget`."""

from __future__ import annotations

import math
from dataclasses import dataclass

from pointillist.core import checks
from pointillist.core.errors import UsageError
from pointillist.progressive.estimate import MIN_PASSES
from pointillist.progressive.stats import PassStats

__all__ = ["STOP_REASONS", "TARGET_PASS_SECONDS", "FIRST_PASS_SAMPLES", "Budget"]

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


def _pow2_floor(n: int) -> int:
    """The largest power of two ``<= n`` (``n >= 1``)."""
    return 1 << (int(n).bit_length() - 1)


@dataclass(frozen=True)
class Budget:
    """When a progressive render stops, and how many spp each pass takes.

    Parameters
    ----------
    seconds : float, optional
        Stop when the render seconds (``PassStats.seconds``) reach this, or when less than
        one spp fits in the time left; the last passes shrink (halving their spp) to end close
        to it, to a size already rendered where one fits (Mitsuba compiles a kernel for each new
        spp: a new size must fit with that compilation, ``PassStats.size_compile_seconds``), and
        auto passes leave room for ``min_passes`` passes (an estimate) where the time allows. At
        least one pass always runs.
    target_error : float, optional
        Stop when the estimated relMSE is at most this, trusted (checked from ``min_passes``
        on; :class:`~pointillist.progressive.estimate.ErrorEstimate`) and settled (the rare-path
        rule, :func:`~pointillist.progressive.stats.settled`: trusted at half the spp too, the
        error per spp not grown since; so never before 16 spp). Auto passes take 1 spp
        until the first estimate, then at most a quarter of the spp so far (so that the four
        quarters of the passes stay within 2x of each other: a firefly in a quarter holding more
        than its share is under-counted) and, while the estimate is trusted, no more than the
        1/spp law says is still needed (rounded down to a power of two), so the render stops
        close to the target. Without ``seconds`` and ``spp``, a target that a trusted estimate
        puts beyond 2^32 - 1 spp raises a :class:`~pointillist.core.errors.UsageError` (it would run
        for ever), and so does an image whose every pixel is NaN or inf (no estimate).
    spp : int, optional
        Stop at this many samples per pixel (the last pass is cut to land on it exactly).
    pass_spp : int, optional
        Samples per pass; default (None): the first pass takes about
        :data:`FIRST_PASS_SAMPLES` samples (it compiles the kernels), the others the power of
        two nearest to :data:`TARGET_PASS_SECONDS` (at most an eighth of ``seconds``). With
        ``seconds`` it is the most a pass takes: no pass may outlast the budget, so the first
        one (its cost unknown) takes no more than an auto first pass, and the others no more
        than fits in the time left.
    min_passes : int
        Passes before ``target_error`` is checked (at least
        :data:`~pointillist.progressive.estimate.MIN_PASSES`).

    Without ``seconds``, ``target_error`` or ``spp`` the passes go on until interrupted (Ctrl-C),
    or until 2^32 - 1 spp. The budget is a callable: ``budget(stats)`` is the spp of the next pass;
    it is 0 exactly when :meth:`stop_reason` names why the render is done. Auto and shrunk passes
    are powers of two, which share one compiled kernel (a pass cut to land on ``spp`` exactly
    may take one more compilation).

    Examples
    --------
    >>> import math
    >>> from dataclasses import replace
    >>> from pointillist.progressive import Budget, PassStats
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
        for name in ("seconds", "target_error"):   # compared in float64, never in a kernel
            if getattr(self, name) is not None:
                checks.real(getattr(self, name), name, low=0, low_open=True, float32=False)
        for name in ("spp", "pass_spp"):
            if getattr(self, name) is not None:
                checks.integer(getattr(self, name), name, low=1, high=checks.UINT32_MAX)
        checks.integer(self.min_passes, "min_passes", low=MIN_PASSES)

    def _fitting_spp(self, stats: PassStats) -> float:
        """Spp that fit in the time left at the last pass's rate (inf without a time budget or a rate)."""
        rate = stats.seconds_per_spp()
        if self.seconds is None or stats.passes == 0 or not math.isfinite(rate):
            return math.inf
        return (self.seconds - stats.seconds) / rate

    def _last_fitting_pass(self, stats: PassStats, cap: float = math.inf) -> int:
        """The largest pass of at most ``cap`` spp that ends within the time left (0: none): a size
        already rendered (its kernel compiled) that fits at the last pass's rate, or a new power of
        two that still fits once its kernel is compiled (``size_compile_seconds`` more)."""
        fit = min(self._fitting_spp(stats) + 0.5, cap)
        known = [size for size in stats.sizes if size <= fit]
        rate = stats.seconds_per_spp()
        fresh = min((self.seconds - stats.seconds - stats.size_compile_seconds) / rate + 0.5, cap)
        return max(max(known, default=0), _pow2_floor(int(fresh)) if fresh >= 1 else 0)

    def stop_reason(self, stats: PassStats) -> str | None:
        """Why the render is done after ``stats`` (one of :data:`STOP_REASONS` but ``"interrupted"``), or None.

        ``"time"`` also when less than one spp fits in the time left.
        """
        if stats.passes == 0:
            return None
        if self.spp is not None and stats.spp >= self.spp:
            return "spp"
        if self.target_error is not None and stats.passes >= self.min_passes and stats.trusted \
                and stats.settled and stats.estimated_relmse <= self.target_error:
            return "error"
        if self.seconds is not None and (stats.seconds >= self.seconds or (
                math.isfinite(self._fitting_spp(stats)) and self._last_fitting_pass(stats) == 0)):
            return "time"   # also when less than one spp fits: no pass fits then
        if stats.spp >= checks.UINT32_MAX:
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
            if needed > checks.UINT32_MAX:
                raise UsageError(f"target error {self.target_error:g} is out of reach: the estimated relMSE is "
                                 f"{stats.estimated_relmse:.3g} at {stats.spp} spp and falls as 1/spp, so it needs "
                                 f"about {needed:.2g} spp, more than the 2^32 - 1 a render may take; "
                                 "set a larger target, or bound the render with a time or spp budget")

    def __call__(self, stats: PassStats) -> int:
        self._check_reachable(stats)
        if self.stop_reason(stats):
            return 0
        pixels = max(stats.width * stats.height, 1)
        largest = _pow2_floor(max(checks.UINT32_MAX // pixels, 1))
        rate = stats.seconds_per_spp()
        first = _pow2_floor(max(FIRST_PASS_SAMPLES // pixels, 1))
        if self.pass_spp is not None:
            # under a time budget, a pass of unknown cost may not outlast it: the first pass (no
            # rate yet) takes no more than an auto first pass, the others what fits (below)
            n = self.pass_spp if self.seconds is None or math.isfinite(rate) else min(self.pass_spp, first)
        elif self.target_error is not None and stats.passes < self.min_passes:
            n = 1  # until the first estimate, as few samples as possible: the target may need only a few
        elif stats.passes == 0 or not math.isfinite(rate):
            n = first
        else:
            target = TARGET_PASS_SECONDS if self.seconds is None else min(TARGET_PASS_SECONDS, self.seconds / 8)
            n = 1 << max(round(math.log2(max(target / rate, 1.0))), 0)  # nearest power of two
        n = min(n, largest)
        if self.target_error is not None and stats.passes >= self.min_passes and math.isfinite(stats.estimated_relmse):
            if self.pass_spp is None:   # a quarter of the spp so far at most: the quarters stay within 2x
                n = min(n, _pow2_floor(max(stats.spp // 4, 1)))
            if stats.trusted and stats.estimated_relmse > self.target_error:  # approach it from below (1/spp)
                needed = stats.spp * stats.estimated_relmse / self.target_error - stats.spp
                n = min(n, _pow2_floor(max(int(math.ceil(needed)), 1)))
        n = min(n, checks.UINT32_MAX - stats.spp)
        if self.spp is not None and self.spp - stats.spp < n:
            left = self.spp - stats.spp
            n = left if left <= largest else _pow2_floor(left)
        fit = self._fitting_spp(stats)
        if math.isfinite(fit) and self.pass_spp is None and stats.passes < self.min_passes:
            # leave room for the passes an estimate needs (the first one, compiling, may take most of it)
            n = min(n, _pow2_floor(max(int(fit / (self.min_passes - stats.passes)), 1)))
        if math.isfinite(fit):
            fitting = self._last_fitting_pass(stats, n)
            if int(fit + 0.5) < n or (n not in stats.sizes and fitting < n):
                # a size whose kernel is compiled, or one worth compiling; a compiled one larger than
                # asked rather than none (0 is for stop_reason alone to say)
                n = fitting or self._last_fitting_pass(stats)
        return int(n)
