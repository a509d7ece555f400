"""Where a progressive render stands after each pass (:class:`PassStats`), and the history row
kept of it (:data:`HISTORY_COLUMNS`: the progress log's and the checkpoint's rows)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from pointillist.progressive.estimate import HALVES_AGREEMENT

__all__ = ["PassStats", "HISTORY_COLUMNS", "history_row", "SETTLE_GROWTH", "settled"]

#: Columns of a history row (the ``history`` of :class:`~pointillist.progressive.ProgressiveResult`, the progress
#: CSV, checkpoints).
HISTORY_COLUMNS = ("pass", "seconds", "spp", "estimated_relmse", "halves_ratio", "floored", "trusted")


@dataclass(frozen=True)
class PassStats:
    """Where a progressive render stands after a pass (``passes == 0``: before the first).

    ``seconds``: render seconds of all passes so far (rendering, JIT compilation, accumulation;
    resumed renders include the earlier ones); ``compile_seconds``: the JIT compilation part;
    ``estimated_relmse``: NaN before :data:`~pointillist.progressive.estimate.MIN_PASSES` passes;
    ``halves_ratio``, ``floored`` and ``trusted``: as in
    :class:`~pointillist.progressive.estimate.ErrorEstimate`; ``nonfinite``: pixels holding NaN or
    inf; ``seed``: the Mitsuba seed of the last pass; ``settled``: the error per spp has held over the
    last doubling of the samples (:func:`settled`: an error budget stops only then). ``sizes``: the
    pass spp this process has rendered (Mitsuba compiles a kernel for each new spp; these are compiled), and
    ``size_compile_seconds`` what a pass of another size is expected to add: the compilation the
    latest pass of a new size took (the first pass's until another size ran; a new size may also
    find its kernels compiled already, as powers of two often do). A checkpoint keeps neither (a
    resumed process compiles anew).
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
    settled: bool = False
    sizes: tuple[int, ...] = ()
    size_compile_seconds: float = 0.0

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


def history_row(stats: PassStats) -> tuple[float, ...]:
    """One row of :data:`HISTORY_COLUMNS`."""
    trusted = math.nan if stats.estimate_state == "none" else float(stats.trusted)
    return (stats.passes, stats.seconds, stats.spp, stats.estimated_relmse, stats.halves_ratio, stats.floored, trusted)


#: The rare-path rule: an error budget stops only when the estimate, trusted now, was trusted at half
#: the samples or fewer too, and the error per spp (relMSE x spp, constant while the 1/spp law holds)
#: has not grown more than this factor since (the halves' agreement factor). A path found for the
#: first time (a caustic, a light seen only in a mirror) raises the error per spp many times; a
#: render that has not doubled its samples since its first trusted estimate has not had the chance
#: to find it. An estimate is first made at 8 passes, so no error budget stops before 16 spp.
SETTLE_GROWTH = HALVES_AGREEMENT


def settled(history: Sequence[Sequence[float]], spp: float, relmse: float) -> bool:
    """Whether a trusted estimate ``relmse`` at ``spp`` is settled (:data:`SETTLE_GROWTH`): the last
    history row (:data:`HISTORY_COLUMNS`) with at most ``spp / 2`` samples and an estimate was
    trusted, and ``relmse * spp`` is at most ``SETTLE_GROWTH`` times its error per spp.

    Examples
    --------
    >>> from pointillist.progressive.stats import settled
    >>> rows = [(8, 1.0, 8, 0.02, 1.1, 0.0, 1.0), (12, 1.5, 12, 0.014, 1.2, 0.0, 1.0)]
    >>> settled(rows, 16, 0.011), settled(rows, 12, 0.014)   # 16 spp: 0.176 against 0.16 at 8 spp
    (True, False)
    >>> settled(rows, 16, 0.05)     # the error per spp grew 5x: a path found since 8 spp
    False
    """
    earlier = [row for row in history if row[2] <= spp / 2 and math.isfinite(row[3])]
    if not earlier or not math.isfinite(relmse):
        return False
    _, _, spp_then, relmse_then, _, _, trusted_then = earlier[-1][:7]
    return trusted_then == 1 and relmse * spp <= SETTLE_GROWTH * relmse_then * spp_then
