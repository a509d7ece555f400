"""Progressive rendering in tiles, in this process or on a Dask cluster, the work going to the noise.

The film is split into tiles (:func:`pointillist.tiles.tile_grid`) and rendered in *rounds*. A round
gives some tiles one or more passes each (a pass: a crop-window render of its tile, one Dask task);
when every pass of the round is back, the passes are added to their tiles' accumulators
(:class:`~pointillist.progressive.estimate.Accumulator`) in (tile, pass) order, the frame's error is
estimated, and the budget decides the next round. A round is the tiled render's *pass* in the progress
log and the budgets (``passes`` counts rounds; ``spp`` is the frame's mean spp, ``pass_spp`` the
round's work in frame spp).

Seeds
-----
Pass ``k`` of tile ``t`` of a render with seed ``s`` renders with Mitsuba's seed ``(TEA(s, t) + k)
mod 2^32`` (:func:`tile_pass_seed`): it depends on nothing but (seed, tile, pass). Tile 0's passes
have the seeds of an untiled progressive render's (:func:`~pointillist.progressive.seeds.pass_seed`).

The same image everywhere
-------------------------
Each pass renders on one Dr.Jit thread (the film's atomic additions then come in one order) from the
scene loaded without Mitsuba's mesh merging (which orders the emitters differently in every process):
the same pass is the same to the last bit in every process; what a round renders depends only on the
rounds before it (never on which worker finished first, nor on how many there are); the passes are
added in tile order. So the EXR is the same bit for bit in this process and on 1, 2 or N workers,
and a checkpoint resumed on another cluster continues the render exactly. Decisions that read the
clock (a time budget, automatic pass sizes from the measured speed) depend on the machines, as they
do on one machine; with ``pass_spp`` and an spp or error budget none does.

The estimate
------------
The frame has **one** error estimate: the one-machine formula
(:func:`~pointillist.progressive.estimate.estimate_error`) on the per-pixel mean, variance and
halves' spreads assembled from the tiles, with the same trust rule (the halves agree, at most half
of it from floored pixels) and the same rare-path rule (:func:`~pointillist.progressive.stats.settled`).
There is none until every tile has :data:`~pointillist.progressive.estimate.MIN_PASSES` passes: the
first rounds give every tile the same passes. The rare-path rule reads the tiles' spp weighted by
their shares of the estimate (``sum_t c_t W_t / sum_t c_t``; the mean spp under uniform passes):
doubling the samples means doubling them where the error is.

Work to the noise
-----------------
With a target error, each tile ``t`` (``P_t`` pixels, ``W_t`` spp, ``c_t`` its share of the estimated
relMSE ``sum_t c_t``) is given the spp that reach the target ``E`` at the least cost: ``c_t`` falls
as ``1 / W_t``, and minimising ``sum_t P_t W'_t`` subject to ``sum_t c_t W_t / W'_t = E`` gives
(Lagrange)::

    W'_t = sqrt(c_t W_t / P_t) * sum_u sqrt(c_u W_u P_u) / E

The tiles below their ``W'_t`` get passes (each at most a quarter of the tile's spp so far, as on one
machine, so its four quarters stay within 2x of each other; powers of two), the round at
most the budget's pass size in frame spp (the same spp more where they are needed). On a cluster the
round's passes go out in two bundles a worker, balanced by their samples (which process renders a
pass changes nothing in its image). Each tile stays unbiased.
No tile is left below :data:`MIN_TILE_SHARE` of the most sampled tile's spp, so a region whose
estimate is too low (a path it has not found yet) still gets an eighth of the samples, and its
estimate rests on a proportionate number of passes.

Failures
--------
A worker that dies in a pass: Dask runs the task again on another worker (up to
``distributed.scheduler.allowed-failures`` times); the pass has its seed, so its result is the same,
and the round keeps one result per (tile, pass): never counted twice. Workers that join are used
from the next task on (:class:`pointillist.distributed.PointillistWorker` sets them up). A scheduler
that goes away ends the render with a :class:`~pointillist.core.errors.ClusterError`, after the
rounds done are written to the checkpoint (when there is a checkpoint file): ``--resume`` continues
there, on this cluster or another.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from pointillist.core import checks, signals
from pointillist.core.errors import ClusterError
from pointillist.core.terminal import draws_progress
from pointillist.progressive.budget import Budget, _pow2_floor
from pointillist.progressive.checkpoint import load_tiled_checkpoint, save_checkpoint, scene_fingerprint
from pointillist.progressive.estimate import Accumulator, estimate_error
from pointillist.progressive.seeds import tea32
from pointillist.progressive.stats import PassStats, history_row, settled
from pointillist.tiles import RenderResult, RenderTask, Tile, render_task, tile_grid

__all__ = ["DEFAULT_TILES", "MIN_TILE_SHARE", "tile_pass_seed", "render_tile_pass", "render_tile_passes",
           "tile_targets", "render_progressive_tiled"]

#: Tiles of a progressive render on a cluster when ``--tiles`` is not given (at most one per pixel
#: row and column): enough tasks per round for a few workers, and regions small enough for the
#: work to go to the noise.
DEFAULT_TILES = (4, 4)

#: No tile's spp falls below 1 / MIN_TILE_SHARE of the most sampled tile's.
MIN_TILE_SHARE = 8


def tile_pass_seed(seed: int, tile: int, index: int) -> int:
    """Mitsuba seed of pass ``index`` of tile ``tile``: ``(TEA(seed, tile) + index) mod 2^32``.

    Examples
    --------
    >>> from pointillist.progressive.seeds import pass_seed
    >>> from pointillist.progressive.tiled import tile_pass_seed
    >>> tile_pass_seed(0, 0, 5) == pass_seed(0, 5), tile_pass_seed(0, 1, 0)
    (True, 1569133783)
    """
    return (tea32(checks.seed(seed), int(tile))[0] + int(index)) & checks.UINT32_MAX


def render_tile_pass(task: RenderTask) -> RenderResult:
    """Render one pass of one tile (a Dask task): :func:`pointillist.tiles.render_task` ``exact``
    (one Dr.Jit thread, the scene's shapes and emitters in their declared order), so that the pass
    is the same to the last bit in every process."""
    return render_task(task, exact=True)


def render_tile_passes(tasks: Sequence[RenderTask]) -> list[RenderResult]:
    """Render several tile passes, one after the other (one Dask task): :func:`render_tile_pass` each.
    A round's passes go to a cluster in a few such bundles, balanced by their samples: fewer tasks,
    less of Dask's cost per task; which process renders a pass changes nothing in its image."""
    return [render_tile_pass(task) for task in tasks]


def _bundles(tasks: Sequence[RenderTask], count: int) -> list[list[int]]:
    """The indices of ``tasks`` in at most ``count`` bundles of about equal samples (the largest task
    first to the lightest bundle), each bundle in task order."""
    loads, bundles = [0] * count, [[] for _ in range(count)]
    for i in sorted(range(len(tasks)), key=lambda i: -tasks[i].spp * tasks[i].crop[2] * tasks[i].crop[3]):
        lightest = loads.index(min(loads))
        bundles[lightest].append(i)
        loads[lightest] += tasks[i].spp * tasks[i].crop[2] * tasks[i].crop[3]
    return [sorted(b) for b in bundles if b]


def tile_targets(shares: Sequence[float], spp: Sequence[int], pixels: Sequence[int], target: float) -> np.ndarray:
    """The spp each tile needs for the frame to reach ``target`` at the least cost (module docstring):
    ``W'_t = sqrt(c_t W_t / P_t) * sum_u sqrt(c_u W_u P_u) / E``, raised to the tile's ``W_t`` and to
    ``max W' / MIN_TILE_SHARE``.

    Examples
    --------
    >>> from pointillist.progressive.tiled import tile_targets
    >>> tile_targets([0.04, 0.01], [16, 16], [100, 100], 0.01).tolist()   # 4x the error: 2x the spp
    [96.0, 48.0]
    >>> tile_targets([0.08, 0.0], [16, 16], [100, 100], 0.01).tolist()    # none needed: an eighth
    [128.0, 16.0]
    """
    c, w, p = (np.asarray(x, np.float64) for x in (shares, spp, pixels))
    target = checks.real(target, "target", low=0, low_open=True, float32=False)
    wanted = np.sqrt(c * w / p) * np.sqrt(c * w * p).sum() / target
    return np.maximum(np.maximum(wanted, wanted.max() / MIN_TILE_SHARE), w)


@dataclasses.dataclass(frozen=True)
class _Frame:
    """The render's state after a round: one accumulator per tile (immutable), the frame's stats."""

    accs: tuple[Accumulator, ...]
    stats: PassStats


class _Engine:
    """The rounds of one render: planning, running, adding (module docstring)."""

    def __init__(self, scene_path: Path, params: dict, budget: Budget, tiles: list[Tile], *, window, seed: int,
                 sensor: int, client, inputs_sha256: str, channels: int, clock: Callable[[], float],
                 adaptive: bool = True):
        self.x0, self.y0, self.width, self.height = window
        self.adaptive = adaptive
        self.probe = RenderTask(str(scene_path), params, None, 0, sensor, inputs_sha256=inputs_sha256)
        self.budget, self.tiles, self.seed, self.client = budget, tiles, seed, client
        self.channels, self.clock = channels, clock
        self.pixels = np.array([t.width * t.height for t in tiles], np.float64)
        self.shares: np.ndarray | None = None   # each tile's share of the estimate (after a round)

    # -- planning
    def plan(self, frame: _Frame, history: Sequence[tuple[float, ...]]) -> list[tuple[int, int]]:
        """The round after ``frame`` (``history``: the rows of the rounds done): ``(tile, spp)`` per
        pass, in (tile, pass) order; empty: done."""
        n = int(self.budget(frame.stats))   # the round's size in frame spp (0: the budget is spent)
        if n < 1:
            return []
        weights = np.array([acc.weight for acc in frame.accs], np.float64)
        warm = min(acc.passes for acc in frame.accs) < self.budget.min_passes
        if self.budget.target_error is None or warm or self.shares is None or not self.adaptive:
            # every tile the same pass (the first rounds, and renders without a target)
            return [(t.index, self._cap(n, int(weights[t.index]))) for t in self.tiles
                    if self._cap(n, int(weights[t.index])) > 0]
        target = self.budget.target_error
        if frame.stats.estimated_relmse <= target:
            # below it but not trusted or not settled: half the error it had when it first came below
            # (a doubling of the samples where the error is, which the rare-path rule asks for); that
            # reached, half the error it has now
            first = _first_below(history, target) / 2
            target = max(first if frame.stats.estimated_relmse > first else frame.stats.estimated_relmse / 2, 1e-12)
        wanted = tile_targets(self.shares, weights, self.pixels, target)
        more = np.maximum(wanted - weights, 0.0)
        # the round's work at most n frame spp: each tile's way to its target cut in proportion
        work = float((more * self.pixels).sum())
        scale = min(1.0, n * self.pixels.sum() / work) if work > 0 else 0.0
        plan = self._passes(weights + more * scale, weights)
        return plan or [(t.index, self._cap(1, int(weights[t.index]))) for t in self.tiles
                        if self._cap(1, int(weights[t.index])) > 0]

    def _passes(self, goals: np.ndarray, weights: np.ndarray) -> list[tuple[int, int]]:
        """``(tile, spp)`` passes that take the tiles from their spp towards their ``goals``: each at
        most a quarter of the tile's spp so far (or ``pass_spp``), powers of two."""
        plan = []
        for t in self.tiles:
            goal, have = goals[t.index], weights[t.index]
            while have < goal - 0.5:
                quarter = self.budget.pass_spp or _pow2_floor(max(int(have) // 4, 1))
                size = self._cap(min(quarter, _pow2_floor(max(int(goal - have + 0.5), 1))), int(have))
                if size < 1:
                    break
                plan.append((t.index, size))
                have += size
        return plan

    def _cap(self, n: int, have: int) -> int:
        """``n`` spp more for a tile at ``have``, within the spp budget and 2^32 - 1 samples."""
        cap = self.budget.spp if self.budget.spp is not None else checks.UINT32_MAX
        return max(min(n, cap - have), 0)

    # -- running
    def run(self, frame: _Frame, plan: list[tuple[int, int]]) -> tuple[_Frame, dict]:
        """Render the round ``plan``, add its passes in (tile, pass) order; the new frame and the
        round's summed timing."""
        from pointillist.core.digests import json_key
        from pointillist.distributed import run_tasks, task_key

        begin = self.clock()
        tasks, passes = [], [acc.passes for acc in frame.accs]
        for tile, spp in plan:
            crop = self.tiles[tile].crop
            tasks.append(dataclasses.replace(self.probe, spp=spp, crop=crop,
                                             seed=tile_pass_seed(self.seed, tile, passes[tile])))
            passes[tile] += 1
        try:
            if self.client is None:
                results = run_tasks(render_tile_pass, tasks, progress=False)
            else:   # two bundles a worker: fewer tasks, the workers still evenly loaded
                workers = max(len(self.client.scheduler_info(n_workers=-1)["workers"]), 1)
                bundles = _bundles(tasks, 2 * workers)
                keys = [json_key([task_key(render_tile_pass, tasks[i]) for i in bundle]) for bundle in bundles]
                done = run_tasks(render_tile_passes, [[tasks[i] for i in b] for b in bundles], client=self.client,
                                 keys=keys, progress=False)
                results = [None] * len(tasks)
                for bundle, rendered in zip(bundles, done):
                    for i, result in zip(bundle, rendered):
                        results[i] = result
        except Exception as error:  # noqa: BLE001 - only the loss of the cluster is turned into ClusterError
            if self.client is not None and _cluster_lost(error):
                raise ClusterError(f"lost the Dask cluster at {_address(self.client)} during a round "
                                   f"({_reason(error)})") from None
            raise
        accs = list(frame.accs)
        for (tile, spp), result in zip(plan, results):
            accs[tile] = accs[tile].add(_tensor(result.image), spp)
        seconds = self.clock() - begin
        timing = {name: sum(r.timing.get(name, 0.0) for r in results)
                  for name in ("trace", "compile", "execute", "kernels", "cache_hits")}
        stats = self._stats(frame, accs, plan, seconds, timing)
        return _Frame(tuple(accs), stats), timing

    def _stats(self, frame: _Frame, accs: list, plan, seconds: float, timing: dict) -> PassStats:
        """The frame's stats after a round: the assembled estimate and each tile's share of it."""
        previous = frame.stats
        total = float(self.pixels.sum())
        mean_spp = int(sum(acc.weight * p for acc, p in zip(accs, self.pixels)) // total)
        work = sum(spp * self.pixels[tile] for tile, spp in plan) / total
        estimate = self.measure(accs)
        sizes = tuple(sorted(set(previous.sizes) | {spp for _, spp in plan}))
        # the round's compilation (summed over its tasks; workers compile alongside each other)
        compile_s = min(timing["compile"], seconds)
        new = dataclasses.replace(
            previous, passes=previous.passes + 1, spp=mean_spp, pass_spp=work, seconds=previous.seconds + seconds,
            pass_seconds=seconds, pass_compile_seconds=compile_s,
            compile_seconds=previous.compile_seconds + timing["compile"], sizes=sizes,
            size_compile_seconds=compile_s if len(sizes) > len(previous.sizes)
            else previous.size_compile_seconds, seed=tile_pass_seed(self.seed, 0, accs[0].passes - 1))
        if estimate is None:
            return dataclasses.replace(new, estimated_relmse=math.nan, trusted=False, settled=False)
        return dataclasses.replace(new, estimated_relmse=estimate.relmse, halves_ratio=estimate.halves_ratio,
                                   floored=estimate.floored, trusted=estimate.trusted, nonfinite=estimate.nonfinite)

    def measure(self, accs: Sequence[Accumulator]):
        """The frame's :class:`~pointillist.progressive.estimate.ErrorEstimate` from its tiles (None
        until every tile has ``min_passes`` passes); keeps each tile's share of it for the plan."""
        spreads = [acc.spread() if acc.passes >= self.budget.min_passes else None for acc in accs]
        if any(s is None for s in spreads):
            return None
        arrays = [self._assemble([s[k] for s in spreads]) for k in range(4)]
        estimate, per_pixel = estimate_error(*arrays, channels=self.channels, per_pixel=True)
        self.shares = np.array([per_pixel[self._window(t)].sum() for t in self.tiles])
        return estimate

    def weighted_spp(self, accs: Sequence[Accumulator]) -> float:
        """The tiles' spp weighted by their shares of the estimate (the mean spp before there is one,
        or where the shares are all 0): the spp the rare-path rule reads."""
        weights = np.array([acc.weight for acc in accs], np.float64)
        shares = self.shares if self.shares is not None else np.zeros(len(accs))
        if shares.sum() > 0:
            return float((shares * weights).sum() / shares.sum())
        return float((weights * self.pixels).sum() / self.pixels.sum())

    def _window(self, tile: Tile) -> tuple[slice, slice]:
        """The tile's rows and columns in the frame's arrays."""
        return (slice(tile.y - self.y0, tile.y - self.y0 + tile.height),
                slice(tile.x - self.x0, tile.x - self.x0 + tile.width))

    def _assemble(self, parts: list):
        """One (H, W, C) float64 Dr.Jit tensor of the frame from one tensor per tile."""
        import drjit as dr
        import mitsuba as mi

        return dr.float64_array_t(mi.TensorXf)(self.place([part.numpy() for part in parts]))

    def place(self, parts: Sequence[np.ndarray]) -> np.ndarray:
        """One frame array from one numpy array per tile (``(h, w, ...)`` each, the tiles' order)."""
        out = np.zeros((self.height, self.width) + parts[0].shape[2:], parts[0].dtype)
        for tile, part in zip(self.tiles, parts):
            out[self._window(tile)] = part
        return out

    def image(self, accs: Sequence[Accumulator]) -> tuple[np.ndarray, np.ndarray]:
        """The frame's mean (float32 (H, W, C)) and the variance of the mean averaged over the colour
        channels (float32 (H, W)), assembled from the tiles (each as one machine's render makes them)."""
        from pointillist.progressive import _image

        images, variances = zip(*(_image(acc, self.channels) for acc in accs))
        return self.place(images), self.place(variances)


def _first_below(history: Sequence[tuple[float, ...]], target: float) -> float:
    """The estimate of the first round of the latest run of rounds (``history`` rows) whose estimate is
    at or below ``target`` (``target`` when there is none)."""
    first = math.nan
    for row in reversed(history):
        if not (math.isfinite(row[3]) and row[3] <= target):
            break
        first = row[3]
    return first if math.isfinite(first) else target


def _tensor(image: np.ndarray):
    import mitsuba as mi

    return mi.TensorXf(np.ascontiguousarray(image, np.float32))


def _address(client) -> str:
    try:
        return str(client.scheduler.address)
    except Exception:  # noqa: BLE001 - only for a message
        return "its scheduler"


def _reason(error: BaseException) -> str:
    """The last words of a Dask connection error (``Stream is closed``), without its object reprs."""
    text = str(error).rsplit(">: ", 1)[-1].strip() or type(error).__name__
    return text if len(text) <= 120 else text[:117] + "..."


def _cluster_lost(error: BaseException) -> bool:
    """Whether ``error`` says the Dask scheduler went away (a closed connection, a timeout, futures
    cancelled by the lost connection)."""
    import asyncio
    import concurrent.futures

    try:
        from distributed.comm.core import CommClosedError
    except ImportError:  # pragma: no cover - Dask is there when a client is
        CommClosedError = OSError  # noqa: N806
    lost = (CommClosedError, OSError, TimeoutError, asyncio.CancelledError, concurrent.futures.CancelledError)
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, lost) or "connection" in str(error).lower() and "scheduler" in str(error).lower():
            return True
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return False


def render_progressive_tiled(scene, scene_path: str | Path, budget: Budget, *, tiles: tuple[int, int] = DEFAULT_TILES,
                             params: dict[str, str] | None = None, seed: int = 0, sensor: int = 0, client=None,
                             checkpoint_seconds: float | None = None, checkpoint_file: str | Path | None = None,
                             resume: bool = False, progress: bool = True,
                             clock: Callable[[], float] = time.perf_counter,
                             inputs: Sequence[str | Path] | None = None, layout=None, adaptive: bool = True,
                             abandon: Callable | None = None):
    """Render ``scene`` progressively in ``tiles`` (rows, cols) until ``budget`` is spent: in this
    process (``client`` None: one pass at a time, each on one thread) or on a Dask ``client``.

    Parameters and result as :func:`pointillist.progressive.render_progressive` (a
    :class:`~pointillist.progressive.ProgressiveResult`; its ``passes`` are rounds, its ``spp`` the
    frame's mean; ``metadata`` adds the tile grid and each tile's spp range). The workers read the
    scene by its absolute path. With a target error the passes go to the tiles whose error is largest
    (module docstring; ``adaptive=False``: every tile the same passes, as one machine's render). A
    checkpoint holds every tile's accumulator; it resumes in this process or on any cluster, with the
    same tiles. A second signal (or a round still running a second after the first) ends the process
    at once: the rounds done go to the checkpoint file (where there is one) and to ``abandon(result)``.

    Raises
    ------
    ClusterError
        When the Dask scheduler goes away (the rounds done are in the checkpoint first, where there is
        a checkpoint file).

    Examples
    --------
    >>> import pointillist
    >>> mi = pointillist.setup()
    >>> from pointillist.progressive import Budget
    >>> from pointillist.progressive.tiled import render_progressive_tiled
    >>> from pointillist.scene import load_scene
    >>> scene = load_scene("scenes/edges.xml", {"res": "16"})
    >>> result = render_progressive_tiled(scene, "scenes/edges.xml", Budget(spp=16, pass_spp=2), tiles=(2, 2),
    ...                                   params={"res": "16"}, progress=False)
    >>> result.image.shape, result.stats.passes, result.stats.spp, result.metadata["tile_grid"]
    ((16, 16, 3), 8, 16, '2x2')
    """
    from pointillist.channels import channel_layout
    from pointillist.plan import inputs_digest, scene_inputs
    from pointillist.progressive import (STATUS_SECONDS, _bar, _bar_position, _is_interrupt, _postfix, _result,
                                         status_line)
    from pointillist.scene import parse_scene

    seed = checks.seed(seed)
    if not isinstance(budget, Budget):
        raise TypeError(f"budget: expected a Budget, got {type(budget).__name__}")
    if checkpoint_seconds is not None:
        checkpoint_seconds = checks.real(checkpoint_seconds, "checkpoint_seconds", low=0, low_open=True, float32=False)
    if resume and checkpoint_file is None:
        raise ValueError("checkpoint_file: needed with resume")
    rows, cols = (checks.integer(v, name, low=1) for name, v in zip(("rows", "cols"), tiles))
    scene_path = Path(scene_path).resolve()
    layout = layout or channel_layout(scene, sensor)
    channels = len(layout.colour) or layout.channels
    film = scene.sensors()[sensor].film()
    (x0, y0), (width, height) = (tuple(map(int, film.crop_offset())), tuple(map(int, film.crop_size())))
    grid = tile_grid(width, height, rows, cols, x=x0, y=y0)
    if inputs is None:
        inputs = scene_inputs(parse_scene(scene_path, params))
    engine = _Engine(scene_path, dict(params or {}), budget, grid, window=(x0, y0, width, height), seed=seed,
                     sensor=sensor, client=client, inputs_sha256=inputs_digest(inputs, params), channels=channels,
                     clock=clock, adaptive=adaptive)
    checkpoint_file = None if checkpoint_file is None else Path(checkpoint_file)
    identity = (dict(scene_fingerprint(scene, scene_path, params, seed, sensor, inputs=inputs), tiles=f"{rows}x{cols}")
                if checkpoint_file else {})
    start = PassStats(passes=0, spp=0, pass_spp=0, seconds=0.0, pass_seconds=0.0, pass_compile_seconds=0.0,
                      compile_seconds=0.0, estimated_relmse=math.nan, width=width, height=height)
    frame, history, settle_rows = _Frame((Accumulator.empty(),) * len(grid), start), [], []
    if resume:
        accs, stats, history, settle_rows = load_tiled_checkpoint(checkpoint_file, identity, grid, layout.channels)
        frame = _Frame(tuple(accs), stats)
        engine.measure(accs)   # each tile's share of the estimate, for the next plan
    resumed_from, stop, signum, checkpoints, first_nonfinite = frame.stats.passes, None, None, 0, None
    sums = [0.0, 0.0, 0.0, 0, 0]

    def save(current: _Frame, rows_done: list) -> None:
        save_checkpoint(checkpoint_file, list(current.accs), current.stats, rows_done, identity,
                        settle=settle_rows[:len(rows_done)])

    def finish(stop: str, signum: int | None, done: dict):
        current = done["frame"]
        image, variance = engine.image(current.accs)
        result = _result(image, variance, current.stats, done["history"], done["sums"], stop, signum, budget, seed,
                         resumed_from, checkpoints, done["first_nonfinite"])
        spp = [acc.weight for acc in current.accs]
        result.spp_map = engine.place([np.full((t.height, t.width), n, np.float32) for t, n in zip(grid, spp)])
        result.metadata.update(tile_grid=f"{rows}x{cols}", tile_spp=f"{min(spp)}..{max(spp)}",
                               rounds=current.stats.passes,
                               pass_seeds="(TEA(seed, tile) + pass) mod 2^32, each pass on one thread")
        result.metadata.pop("passes", None)
        return result

    # what a second signal writes (read by the signal watcher's thread: replaced, never changed)
    done = dict(frame=frame, history=list(history), settle=list(settle_rows), sums=list(sums), first_nonfinite=None)

    def abandoned() -> None:
        current = dict(done)
        if current["frame"].stats.passes == resumed_from:
            return
        if checkpoint_file is not None:
            save_checkpoint(checkpoint_file, list(current["frame"].accs), current["frame"].stats,
                            current["history"], identity, settle=current["settle"])
        if abandon is not None:
            abandon(finish("interrupted", signals.received(), current))

    last_write = last_status = clock()
    bar = _bar(budget, frame.stats, progress)
    status = progress and not draws_progress(progress)
    try:
        with signals.deferred() as requested, signals.on_abandon(abandoned):
            while True:
                plan = engine.plan(frame, history)
                if not plan:
                    break
                try:
                    new, timing = engine.run(frame, plan)
                except ClusterError as error:
                    kept = ""
                    if checkpoint_file is not None and frame.stats.passes > 0:
                        save(frame, history)
                        kept = (f"; the {frame.stats.passes} rounds done ({frame.stats.spp} spp) are in "
                                f"{checkpoint_file}: --resume continues them, on this cluster or another")
                    raise ClusterError(f"{error}{kept}") from None
                weighted = engine.weighted_spp(new.accs)
                new = _Frame(new.accs, dataclasses.replace(
                    new.stats, settled=new.stats.trusted and settled(settle_rows, weighted,
                                                                     new.stats.estimated_relmse)))
                history = history + [history_row(new.stats)]
                settle_rows = settle_rows + [history_row(dataclasses.replace(new.stats, spp=weighted))]
                if new.stats.nonfinite and first_nonfinite is None:
                    first_nonfinite = new.stats.passes
                sums = [sums[0] + timing["trace"], sums[1] + timing["compile"], sums[2] + timing["execute"],
                        sums[3] + timing["kernels"], sums[4] + timing["cache_hits"]]
                bar.update(_bar_position(budget, new.stats) - _bar_position(budget, frame.stats))
                frame = new
                done = dict(frame=frame, history=list(history), settle=list(settle_rows), sums=list(sums),
                            first_nonfinite=first_nonfinite)
                bar.set_postfix_str(_postfix(budget, frame.stats), refresh=False)
                if status and clock() - last_status >= STATUS_SECONDS:
                    print(status_line(budget, frame.stats), file=sys.stderr, flush=True)
                    last_status = clock()
                if requested() is not None:
                    stop, signum = "interrupted", requested()
                    break
                if checkpoint_seconds is not None and clock() - last_write >= checkpoint_seconds:
                    save(frame, history)
                    last_write, checkpoints = clock(), checkpoints + 1
        stop = stop or budget.stop_reason(frame.stats)
        if stop is None:
            raise RuntimeError("the budget stopped the render without a reason")
    except BaseException as error:  # noqa: BLE001 - only interruptions are handled here
        if not _is_interrupt(error) or frame.stats.passes == 0:
            raise
        stop = "interrupted"
    finally:
        bar.close()
    if checkpoint_seconds is not None and frame.stats.passes > resumed_from:
        save(frame, history)
        checkpoints += 1
    return finish(stop, (signum or signals.received()) if stop == "interrupted" else None,
                  dict(frame=frame, history=history, sums=sums, first_nonfinite=first_nonfinite))

