"""Where a progressive render stands after each pass (:class:`PassStats`), and the history row
kept of it (:data:`HISTORY_COLUMNS`: the progress log's and the checkpoint's rows)."""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["PassStats", "HISTORY_COLUMNS", "history_row"]

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
    inf; ``seed``: the Mitsuba seed of the last pass. ``sizes``: the pass spp this process has
    rendered (Mitsuba compiles a kernel for each new spp; these are compiled), and
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
