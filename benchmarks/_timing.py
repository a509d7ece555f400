"""The one timer of the benchmarks: one call timed with its Dr.Jit work finished, interleaved
repeats, medians and minima, and the machine's load beside every figure.

Dr.Jit is lazy: a call returns before its kernels ran. :func:`seconds` evaluates what the call
returned (``dr.eval``) and waits for the kernels (``dr.sync_thread``) before it stops the clock,
so a figure is the whole work; the first call of a kernel also compiles it, so benchmarks report
it apart (``Timings.first``) from the steady state (the median of the repeats after it).

The machine is shared: the cases compared are timed in interleaved rounds (A B, then B A, ...),
so that a change of load hits them alike, and a ratio is the median of the per-round ratios
(beside the ratio of the minima, the least disturbed runs). :func:`load_note` records the load
average before and after the run.

Examples
--------
>>> from _timing import interleaved, ratio
>>> times = interleaved({"sum": lambda: sum(range(1000)), "list": lambda: list(range(1000))}, rounds=3)
>>> len(times["sum"].wall), times["sum"].first > 0
(3, True)
>>> median_ratio, minima_ratio = ratio(times["sum"], times["list"])
"""

from __future__ import annotations

import os
import statistics
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

__all__ = ["finish", "timed", "seconds", "clocks", "Timings", "repeat", "interleaved", "ratio", "load", "load_note"]


def finish(result: Any = None) -> Any:
    """``result`` with its Dr.Jit arrays evaluated and this thread's kernels finished (nothing to do
    when Dr.Jit is not imported); returns ``result``."""
    if "drjit" in sys.modules:
        import drjit as dr

        try:
            dr.eval(result)
        except (TypeError, RuntimeError):  # not a Dr.Jit type or PyTree of them: nothing to evaluate
            pass
        dr.sync_thread()
    return result


def timed(function: Callable[..., Any], *args: Any, **kwargs: Any) -> tuple[Any, float, float]:
    """``(result, wall seconds, CPU seconds of this process)`` of ``function(*args, **kwargs)``, its
    Dr.Jit work finished (:func:`finish`). The CPU time counts every thread of the process (Dr.Jit's
    pool too); on a loaded machine it is the steadier of the two."""
    wall, cpu = time.perf_counter(), time.process_time()
    result = finish(function(*args, **kwargs))
    return result, time.perf_counter() - wall, time.process_time() - cpu


def clocks(function: Callable[..., Any], *args: Any, **kwargs: Any) -> tuple[float, float]:
    """``(wall seconds, CPU seconds)`` of ``function(*args, **kwargs)`` (:func:`timed`)."""
    return timed(function, *args, **kwargs)[1:]


def seconds(function: Callable[..., Any], *args: Any, **kwargs: Any) -> float:
    """Wall seconds of ``function(*args, **kwargs)``, its Dr.Jit work finished (:func:`finish`)."""
    return clocks(function, *args, **kwargs)[0]


@dataclass
class Timings:
    """The times of one case: ``first`` (the warm-up call: JIT compilation or a kernel-cache load,
    None without one), then ``wall`` and ``cpu`` seconds of each repeat."""

    first: float | None = None
    wall: list[float] = field(default_factory=list)
    cpu: list[float] = field(default_factory=list)

    @property
    def median(self) -> float:
        """Median wall seconds of the repeats."""
        return statistics.median(self.wall)

    @property
    def minimum(self) -> float:
        """Least wall seconds of the repeats."""
        return min(self.wall)

    @property
    def cpu_median(self) -> float:
        """Median CPU seconds of the repeats."""
        return statistics.median(self.cpu)

    def add(self, sample: tuple[float, float]) -> None:
        """Record one repeat's ``(wall, cpu)``."""
        self.wall.append(sample[0])
        self.cpu.append(sample[1])


def repeat(function: Callable[[], Any], repeats: int, *, warmup: bool = True, bar=None) -> Timings:
    """Time ``function()`` ``repeats`` times (after a warm-up call when ``warmup``); ``bar``: a tqdm
    bar advanced once per repeat."""
    return interleaved({"": function}, repeats, warmup=warmup, bar=bar)[""]


def interleaved(cases: Mapping[str, Callable[[], Any]], rounds: int, *, warmup: bool = True,
                bar=None) -> dict[str, Timings]:
    """Time every case once per round, in alternating order (A B, B A, ...), after a warm-up call of
    each when ``warmup``; ``bar``: a tqdm bar advanced once per round."""
    if rounds < 1:
        raise ValueError(f"rounds: expected an integer >= 1, got {rounds}")
    times = {name: Timings() for name in cases}
    if warmup:
        for name, function in cases.items():
            times[name].first = seconds(function)
    names = list(cases)
    for r in range(rounds):
        for name in (names if r % 2 == 0 else names[::-1]):
            times[name].add(clocks(cases[name]))
        if bar is not None:
            bar.update(1)
    return times


def ratio(a: Timings, b: Timings, clock: str = "wall") -> tuple[float, float]:
    """``a / b``: the median of the per-round ratios and the ratio of the minima (``clock``: ``"wall"``
    or ``"cpu"``)."""
    x, y = getattr(a, clock), getattr(b, clock)
    return statistics.median(p / q for p, q in zip(x, y)), min(x) / min(y)


def load() -> tuple[float, float, float]:
    """The 1, 5 and 15 minute load averages (``os.getloadavg``)."""
    return os.getloadavg()


def load_note(before: tuple[float, ...] | float, after: tuple[float, ...] | float | None = None) -> str:
    """A sentence giving the load average (1 minute) before and after a run, and what it means here."""
    first = before[0] if isinstance(before, tuple) else before
    text = f"load average {first:.1f} before"
    if after is not None:
        text += f", {after[0] if isinstance(after, tuple) else after:.1f} after"
    cores = os.cpu_count() or 1
    loaded = max(first, after[0] if isinstance(after, tuple) else (after or 0.0)) > cores / 2
    return text + (f" ({cores} cores: loaded-machine figures, to rerun on a quiet machine)" if loaded else
                   f" ({cores} cores: a quiet machine)")
