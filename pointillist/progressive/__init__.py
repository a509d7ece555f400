"""Progressive rendering: passes, a running error estimate without a reference, and budgets.

A progressive render is a sequence of *passes*: ``mi.render(scene, spp=n_k, seed=s_k)``, each an
independent estimate of the image (its own seed, :func:`~pointillist.progressive.seeds.pass_seed`).
This module holds the pass loop and the workflow; the rest has a module each:

=================================================  ==================================================
:mod:`~pointillist.progressive.seeds`              each pass's seed
:mod:`~pointillist.progressive.estimate`           the accumulator of the passes (Welford, four
                                                   quarters) and the error estimate, with its formula
:mod:`~pointillist.progressive.stats`              where the render stands after a pass, history rows
:mod:`~pointillist.progressive.budget`             when to stop, and the size of each pass
:mod:`~pointillist.progressive.checkpoint`         checkpoints: written atomically, resumed only into
                                                   the render they came from
:mod:`~pointillist.progressive.report`             the progress log and plot, the final warnings
=================================================  ==================================================

:func:`render_passes` is the engine (a generator of ``(image so far, PassStats)``),
:class:`~pointillist.progressive.budget.Budget` decides the size of each pass (time, error and spp
budgets, auto pass size), :func:`render_progressive` is the workflow of ``pointillist render
--time/--target-error`` (progress bar, checkpoints, resume, Ctrl-C/SIGTERM). Every public name of
the modules above is importable from here too.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pointillist.core import checks, signals
from pointillist.progressive.budget import FIRST_PASS_SAMPLES, STOP_REASONS, TARGET_PASS_SECONDS, Budget
from pointillist.progressive.checkpoint import (CHECKPOINT_VERSION, checkpoint_path, load_checkpoint,
                                                save_checkpoint, scene_fingerprint)
from pointillist.progressive.estimate import (FIREFLY_RANGE, FLOORED_SHARE, HALVES_AGREEMENT, MIN_PASSES,
                                              RELIABLE_VARIANCE, Accumulator, ErrorEstimate)
from pointillist.progressive.report import progress_paths, render_warnings, write_progress
from pointillist.progressive.seeds import pass_seed, tea32
from pointillist.progressive.stats import HISTORY_COLUMNS, SETTLE_GROWTH, PassStats, history_row, settled
from pointillist.scene import RenderTiming, scene_info, timed_render
from pointillist.core.terminal import draws_progress, progress_bar

__all__ = ["MIN_PASSES", "TARGET_PASS_SECONDS", "FIRST_PASS_SAMPLES", "CHECKPOINT_VERSION", "HISTORY_COLUMNS",
           "RELIABLE_VARIANCE", "FIREFLY_RANGE", "FLOORED_SHARE", "HALVES_AGREEMENT", "STOP_REASONS", "pass_seed",
           "tea32", "PassStats", "ErrorEstimate", "Accumulator", "Budget", "render_passes", "ProgressiveResult",
           "render_progressive", "write_progress", "checkpoint_path", "progress_paths", "scene_fingerprint",
           "STATUS_SECONDS", "status_line", "SETTLE_GROWTH", "settled"]


def _passes(scene, plan: Callable[[PassStats], int], *, seed: int, sensor: int, accumulator: Accumulator,
            start: PassStats, clock: Callable[[], float], channels: int | None = None,
            history: Sequence[tuple[float, ...]] = ()) -> Iterator[tuple[Accumulator, PassStats, RenderTiming]]:
    """The pass loop: render, accumulate, estimate; yields ``(accumulator, stats, timing)``.

    ``channels``: the leading channels the estimate takes (the colour; default from the scene's
    :func:`pointillist.channels.channel_layout`); ``history``: the rows of the passes before
    ``start`` (a resumed render's), for :func:`~pointillist.progressive.stats.settled`."""
    import drjit as dr
    import mitsuba as mi

    if channels is None:
        from pointillist.channels import channel_layout

        layout = channel_layout(scene, sensor)
        channels = len(layout.colour) or layout.channels
    acc, stats, rows = accumulator, start, list(history)
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
                          floored=estimate.floored, trusted=estimate.trusted, nonfinite=estimate.nonfinite,
                          settled=estimate.trusted and settled(rows, acc.weight, estimate.relmse),
                          sizes=stats.sizes if spp in stats.sizes else (*stats.sizes, spp),
                          size_compile_seconds=stats.size_compile_seconds if spp in stats.sizes else timing.compile)
        rows.append(history_row(stats))
        yield acc, stats, timing


def _start_stats(scene, sensor: int, accumulator: Accumulator) -> PassStats:
    info = scene_info(scene, sensor)
    return PassStats(passes=accumulator.passes, spp=accumulator.weight, pass_spp=0, seconds=0.0, pass_seconds=0.0,
                     pass_compile_seconds=0.0, compile_seconds=0.0, estimated_relmse=math.nan,
                     width=info["width"], height=info["height"])


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
    >>> from pointillist.progressive import Budget, render_passes
    >>> from pointillist.scene import load_scene
    >>> scene = load_scene("scenes/edges.xml", {"res": "16"})
    >>> for image, stats in render_passes(scene, pass_spp=Budget(spp=16, pass_spp=2)):
    ...     pass
    >>> stats.passes, stats.spp, image.shape, stats.estimated_relmse > 0
    (8, 16, (16, 16, 3), True)
    """
    seed = checks.seed(seed)
    if callable(pass_spp):
        plan = pass_spp
    else:
        plan = lambda _stats, n=checks.integer(pass_spp, "pass_spp", low=1, high=checks.UINT32_MAX): n  # noqa: E731
    acc = Accumulator.empty()
    for acc, stats, _timing in _passes(scene, plan, seed=seed, sensor=sensor, accumulator=acc,
                                        start=_start_stats(scene, sensor, acc), clock=clock):
        yield acc.image(), stats


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
    confirm), for the command line to print; ``spp_map``: a tiled render's samples per pixel, float32
    (H, W) (the EXR layer ``tile_spp``; None in one piece).
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
    spp_map: np.ndarray | None = None


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
    total, unit = ((budget.seconds, "s") if budget.seconds is not None else (budget.spp, "spp")
                   if budget.spp is not None else (None, "pass"))
    return progress_bar(total=total, initial=_bar_position(budget, start), unit=unit, desc="render",
                        progress=progress,
                        bar_format="{l_bar}{bar}| {n:.4g}/{total:.4g} {unit} [{elapsed}<{remaining}{postfix}]"
                        if total is not None else None)


def _bar_position(budget: Budget, stats: PassStats) -> float:
    """Where the bar stands: seconds (time budget), spp (spp budget) or passes, never past the total."""
    if budget.seconds is not None:
        return min(stats.seconds, budget.seconds)
    if budget.spp is not None:
        return min(stats.spp, budget.spp)
    return stats.passes


#: Without a terminal (a log file, a pipe, a batch job) a progressive render writes one status line
#: to standard error this often (wall seconds), so that a long render says where it stands.
STATUS_SECONDS = 60.0


def _postfix(budget: Budget, stats: PassStats) -> str:
    """Where the render stands: passes, spp, the estimate and, under a target error, what reaching it
    takes (relMSE falls as 1/spp: ``spp * estimate / target`` spp in all), once the estimate is trusted."""
    text = f"{stats.passes} passes, {stats.spp} spp"
    if math.isfinite(stats.estimated_relmse):
        text += f", est. relMSE {stats.estimated_relmse:.3g}" + ("" if stats.trusted else " (untrusted)")
        if budget.target_error is not None and stats.estimated_relmse > budget.target_error:
            if stats.trusted:
                needed = math.ceil(stats.spp * stats.estimated_relmse / budget.target_error)
                more = (needed - stats.spp) * stats.seconds_per_spp()
                text += f", target {budget.target_error:g} projected at {needed} spp, {_duration(more)} more"
            else:
                text += f", target {budget.target_error:g}: no projection until the estimate is trusted"
        elif budget.target_error is not None and stats.trusted and not stats.settled:
            text += f", below target {budget.target_error:g}: confirming it over a doubling of the spp"
    return text


def _duration(seconds: float) -> str:
    """``~N s`` below two minutes, ``~N min`` below two hours, else ``~N.N h``."""
    if not math.isfinite(seconds):
        return "~? s"
    if seconds < 120:
        return f"~{seconds:.0f} s"
    return f"~{seconds / 60:.0f} min" if seconds < 7200 else f"~{seconds / 3600:.1f} h"


def status_line(budget: Budget, stats: PassStats) -> str:
    """The line a render without a terminal writes every :data:`STATUS_SECONDS`.

    Examples
    --------
    >>> from pointillist.progressive import Budget, status_line
    >>> from pointillist.progressive.stats import PassStats
    >>> stats = PassStats(passes=12, spp=96, pass_spp=8, seconds=45.0, pass_seconds=3.0, pass_compile_seconds=0.0,
    ...                   compile_seconds=0.5, estimated_relmse=0.004, width=64, height=64, trusted=True)
    >>> status_line(Budget(target_error=0.002), stats)
    'render: 45 s, 12 passes, 96 spp, est. relMSE 0.004, target 0.002 projected at 192 spp, ~36 s more'
    """
    return f"render: {stats.seconds:.0f} s, " + _postfix(budget, stats)


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
        and sampler, else :class:`~pointillist.core.errors.UsageError`); the budget counts the
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

    seed = checks.seed(seed)
    if not isinstance(budget, Budget):
        raise TypeError(f"budget: expected a Budget, got {type(budget).__name__}")
    if checkpoint_seconds is not None:   # compared in float64, never in a kernel
        checkpoint_seconds = checks.real(checkpoint_seconds, "checkpoint_seconds", low=0, low_open=True, float32=False)
    if (checkpoint_seconds is not None or resume) and checkpoint_file is None:
        raise ValueError("checkpoint_file: needed with checkpoint_seconds or resume")
    layout = layout or channel_layout(scene, sensor)
    channels = len(layout.colour) or layout.channels  # the colour channels lead; none: every channel
    checkpoint_file = None if checkpoint_file is None else Path(checkpoint_file)
    identity = scene_fingerprint(scene, scene_path, params, seed, sensor, inputs=inputs) if checkpoint_file else {}
    acc, history = Accumulator.empty(), []
    start = _start_stats(scene, sensor, acc)
    if resume:
        acc, start, history = load_checkpoint(checkpoint_file, identity, layout.channels)
    resumed_from, stats, stop, checkpoints, signum, first_nonfinite = acc.passes, start, None, 0, None, None
    sums = [0.0, 0.0, 0.0, 0, 0]  # trace, compile, execute, kernels, cache hits
    # What a second signal writes (read by the signal watcher's thread: replaced, never changed).
    done = {"acc": acc, "stats": stats, "history": list(history), "sums": list(sums), "first_nonfinite": None}

    def finish(stop: str, signum: int | None, *, done: dict) -> ProgressiveResult:
        return _result(*_image(done["acc"], channels), done["stats"], done["history"], done["sums"], stop, signum,
                       budget, seed, resumed_from, checkpoints, done["first_nonfinite"])

    def abandoned() -> None:
        current = dict(done)
        if current["acc"].passes == resumed_from:
            return
        if checkpoint_seconds is not None:
            save_checkpoint(checkpoint_file, current["acc"], current["stats"], current["history"], identity)
        if abandon is not None:
            abandon(finish("interrupted", signals.received(), done=current))

    last_write = last_status = clock()
    bar = _bar(budget, start, progress)
    status = progress and not draws_progress(progress)   # no bar drawn: a line every STATUS_SECONDS
    try:
        with signals.deferred() as requested, signals.on_abandon(abandoned):
            for acc, new, timing in _passes(scene, budget, seed=seed, sensor=sensor, accumulator=acc, start=start,
                                            clock=clock, channels=channels, history=history):
                history.append(history_row(new))
                if new.nonfinite and first_nonfinite is None:
                    first_nonfinite = new.passes
                sums = [sums[0] + timing.trace, sums[1] + timing.compile, sums[2] + timing.execute,
                        sums[3] + timing.kernels, sums[4] + timing.cache_hits]
                bar.update(_bar_position(budget, new) - _bar_position(budget, stats))
                stats = new
                done = {"acc": acc, "stats": stats, "history": list(history), "sums": list(sums),
                        "first_nonfinite": first_nonfinite}
                bar.set_postfix_str(_postfix(budget, stats), refresh=False)
                if status and clock() - last_status >= STATUS_SECONDS:
                    print(status_line(budget, stats), file=sys.stderr, flush=True)
                    last_status = clock()
                if requested() is not None:  # first signal: stop after the pass in flight
                    stop, signum = "interrupted", requested()
                    break
                if checkpoint_seconds is not None and clock() - last_write >= checkpoint_seconds:
                    save_checkpoint(checkpoint_file, acc, stats, history, identity)
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
        save_checkpoint(checkpoint_file, acc, stats, history, identity)
        checkpoints += 1
    return finish(stop, (signum or signals.received()) if stop == "interrupted" else None,
                  done={"acc": acc, "stats": stats, "history": history, "sums": sums,
                        "first_nonfinite": first_nonfinite})


def _image(acc: Accumulator, channels: int) -> tuple[np.ndarray, np.ndarray]:
    """The mean of the passes in ``acc`` (float32 (H, W, C)) and the variance of the mean averaged
    over the first ``channels`` channels (float32 (H, W)); numpy only: also called from the signal
    watcher's thread while the main thread renders."""
    image = acc.mean.numpy().astype(np.float32)
    if acc.passes >= 2:
        variance = acc.m2.numpy()[..., :channels] * (1.0 / ((acc.passes - 1) * acc.weight))
    else:
        variance = np.zeros(tuple(acc.mean.shape)[:2] + (channels,))
    return image, variance.mean(axis=2).astype(np.float32)


def _result(image: np.ndarray, variance: np.ndarray, stats: PassStats, history: list, sums: list, stop: str,
            signum: int | None, budget: Budget, seed: int, resumed_from: int, checkpoints: int,
            first_nonfinite: int | None = None) -> ProgressiveResult:
    """The :class:`ProgressiveResult` of a render's ``image`` and ``variance`` (:func:`_image`) and
    its ``stats``, ``history``, timing ``sums``, why it stopped, its budget and seed."""
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
                             warnings=render_warnings(stats, first_nonfinite, stop))
