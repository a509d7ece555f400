"""The sweep of ``pointillist compare``: each render, the reference, and the scores against it.

Each :class:`~pointillist.compare.records.Task` is one call of :func:`render_one`, a pure,
picklable function (it sets Mitsuba up itself, loads the scene with the method swapped in
(:mod:`pointillist.compare.methods`), renders with :func:`pointillist.scene.timed_render`, writes
``renders/<task>.exr`` and ``renders/<task>.json`` and returns a
:class:`~pointillist.compare.records.RenderRecord`). A task whose EXR and record exist for the
same scene is not rendered again, so an interrupted sweep resumes where it stopped.
:func:`run_sweep` renders the tasks, then scores each render against the reference
(:func:`pointillist.imaging.metrics.image_errors`, and the power spectrum of its error image),
keeping the scores with the render (:mod:`pointillist.compare.records`), so a rerun scores only
what changed. On a Dask cluster (:func:`prerender_sweep`) every missing render is a task; the
scoring pass that follows finds them finished.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Collection, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pointillist.core import signals
from pointillist.compare.methods import METHODS, load_configured_scene, scene_key
from pointillist.compare.records import (MAP_NAMES, RenderRecord, Task, image_digest, load_record, load_scores,
                                         maps_path, record_json, save_scores, scores_key, task_paths, write_json)
from pointillist.core.digests import json_key
from pointillist.distributed import DEFAULT_RETRIES, run_tasks, setup_process
from pointillist.core.errors import UsageError

__all__ = ["REFERENCE_SAMPLER", "REFERENCE_SEED", "render_one", "render_reference", "run_sweep", "compare_task",
           "prerender_sweep"]

#: The reference is rendered with Mitsuba's own stratified sampler (all dimensions
#: stratified, an implementation independent of the samplers compared) ...
REFERENCE_SAMPLER = "stratified"

#: The seed of the reference render: one no sweep uses.
REFERENCE_SEED = 1_000_003


# ------------------------------------------------------------------------------ renders
#: Methods rendered at least once in this process (:func:`render_one`'s warm-up).
_WARMED: set[str] = set()

def render_one(scene_path: str, method: str, value: float, seed: int, params: dict[str, str] | None,
               out_dir: str, key: str | None = None, warm_up: bool = True) -> RenderRecord:
    """Render one task of the sweep and write its EXR and JSON record; picklable.

    Skips the render when ``out_dir/renders/<key>/<task>.exr`` and ``.json`` exist
    (``key``: :func:`~pointillist.compare.methods.scene_key` of the scene's inputs and parameters) and the EXR reads
    back, returning the stored record with ``cached=True``; a damaged one is rendered
    again (``notice`` says so).

    The first render of a method in a process (with ``warm_up``) is preceded by the
    same render untimed: besides JIT compilation (reported apart anyway), a first
    render pays one-off costs (plugin imports, first traces, the allocator's growth;
    measured on scenes/edges.xml: the first ``adaptive`` render 47 ms, the next ones
    29 ms), which would otherwise land on whichever sweep point comes first. The
    warm-up's times are recorded apart (``warm_up``, ``warm_up_compile``).

    Parameters
    ----------
    scene_path : str
        Scene XML.
    method : str
        A name in :data:`pointillist.compare.methods.METHODS`.
    value : float
        The sweep value: samples per pixel for samplers.
    seed : int
        Render seed.
    params : dict
        ``$name`` overrides for the scene.
    out_dir : str
        The comparison folder.
    key : str, optional
        :func:`~pointillist.compare.methods.scene_key` of the scene's inputs and params (computed when omitted).
    warm_up : bool
        Render untimed first if ``method`` has not rendered in this process yet.
    """
    import pointillist

    task = Task(method, value, int(seed))
    if not key:
        pointillist.setup(plugins=False)  # parsing the scene needs no plugins
        key = scene_key(scene_path, params)
    exr, record_path = task_paths(out_dir, task, key)
    record, notice = load_record(record_path, key, exr)
    if record is not None:
        return record

    pointillist.setup()  # a render: the plugins too
    from pointillist.channels import channel_layout
    from pointillist.render_output import write_render
    from pointillist.scene import scene_info, timed_render

    spec = METHODS[method]
    scene = load_configured_scene(scene_path, spec, value, params)
    if scene_key(scene_path, params) != key:  # read again with the scene: it must still be the scene of `key`
        raise UsageError(f"scene {scene_path}: it or a file it reads changed during the sweep (the renders so far "
                         "belong to the scene as it was); run the command again")
    layout = channel_layout(scene)
    if not layout.colour:
        raise UsageError(f"scene {scene_path}: the render has no colour channels (Mitsuba's aov integrator without "
                         "a nested integrator renders only AOVs): nothing to compare")
    spp = int(value) if spec.parameter == "spp" else None
    warm = None
    if warm_up and method not in _WARMED:
        warm = timed_render(scene, spp=spp, seed=int(seed))[1]
        _WARMED.add(method)
    image, timing = timed_render(scene, spp=spp, seed=int(seed))
    info = scene_info(scene)  # after the render: the sampler's own rounding of spp applies
    info.update(method=method, value=float(value), seed=int(seed))
    with signals.new_folders(exr):  # only now, and removed if the write is cut: no empty folder left
        write_render(exr, image, scene, scene_path, info, timing, png=False, layout=layout)
    samples = float(info["spp"])
    layers = layout.split(image).layers
    for name in ("spp", "sample_count", "samples"):
        if name in layers:  # adaptive methods: the mean of their per-pixel count
            samples = float(layers[name].mean())
            break
    record = RenderRecord(
        method=method, value=float(value), seed=int(seed), spp=samples, exr=f"{key}/{exr.name}",
        width=int(info["width"]), height=int(info["height"]), trace=timing.trace,
        compile=timing.compile, execute=timing.execute, total=timing.total,
        time=max(timing.total - timing.compile, 0.0), kernels=timing.kernels,
        cache_hits=timing.cache_hits, scene_key=key, warm_up=warm.total if warm else 0.0,
        warm_up_compile=warm.compile if warm else 0.0)
    write_json(record_path, record_json(record))
    record.notice = notice
    return record

def render_reference(scene_path: str, params: dict[str, str] | None, out_dir: str, spp: int,
                     key: str | None = None, log: Callable[[str], None] | None = None) -> Path:
    """Render (or reuse) the reference: :data:`REFERENCE_SAMPLER` at ``spp``; returns its EXR.

    A damaged cached reference is rendered again; ``log`` gets the notice."""
    record = render_one(scene_path, REFERENCE_SAMPLER, spp, REFERENCE_SEED, params,
                        str(Path(out_dir) / "reference"), key, warm_up=False)
    if record.notice and log is not None:
        log(f"compare: notice: reference: {record.notice}")
    return Path(out_dir) / "reference" / "renders" / record.exr


# ------------------------------------------------------------------------------ the sweep
def run_sweep(scene_path: str, tasks: Sequence[Task], *, params: dict[str, str] | None, out_dir: str,
              reference: Path, progress: bool = True, log: Callable[[str], None] | None = None,
              maps: dict[str, dict[str, np.ndarray]] | None = None,
              spectra: dict[str, Any] | None = None,
              render: Callable[..., RenderRecord] = render_one, key: str | None = None,
              rendered: Collection[Task] = ()) -> list[RenderRecord]:
    """Run ``tasks`` (skipping finished ones), then score each render against ``reference``.

    ``rendered``: tasks this run already rendered elsewhere (:func:`prerender_sweep` on a cluster):
    their records are found finished but count as new (``cached`` false), not as reused.

    With ``progress``, a progress bar draws on a terminal (standard error a TTY);
    otherwise (a log file, a pipe) ``log`` gets one line per finished render instead
    of the bar's redraws. A ``maps`` dict receives the per-pixel error maps of every
    seed-0 render (by ``record.exr``, :func:`pointillist.imaging.metrics.error_maps`) for the report page;
    a ``spectra`` dict the radially averaged power spectrum of every render's luminance error
    (by ``record.exr``, :func:`pointillist.imaging.metrics.error_spectrum`) for the spectrum plot.

    Scores are kept: a render's errors go into its JSON record with their
    :func:`~pointillist.compare.records.scores_key`, its error spectrum (and a seed-0 render's maps)
    into :func:`~pointillist.compare.records.maps_path`; a render whose stored scores have the key
    of this render file and this reference (and whose spectrum and maps are there) is not scored
    again; with ``progress``, ``log`` is told how many were reused.
    """
    key = key or scene_key(scene_path, params)
    records = _render_tasks(scene_path, tasks, params=params, out_dir=out_dir, key=key, render=render,
                            progress=progress, log=log, rendered=frozenset(rendered))
    reused = _score_records(records, out_dir=out_dir, reference=reference, maps=maps, spectra=spectra)
    if progress and log is not None and reused:
        log(f"compare: scores of {reused} of {len(records)} renders reused (same render and reference)")
    return records


def _render_tasks(scene_path: str, tasks: Sequence[Task], *, params: dict[str, str] | None, out_dir: str, key: str,
                  render: Callable[..., RenderRecord], progress: bool,
                  log: Callable[[str], None] | None, rendered: frozenset = frozenset()) -> list[RenderRecord]:
    """The sweep's first step: every task's record, rendered or found finished, with its progress."""
    from pointillist.compare.tables import format_time
    from pointillist.core.terminal import draws_progress

    records = []
    terminal = draws_progress(progress)
    bar = None
    if terminal:  # (tqdm's import alone is a tenth of a cached rerun: only for a bar)
        from tqdm import tqdm

        bar = tqdm(tasks, desc="compare", unit="render")
    for number, task in enumerate(bar if bar is not None else tasks, 1):
        signals.check()
        if bar is not None:
            bar.set_postfix_str(task.stem)
        record = render(scene_path, task.method, task.value, task.seed, params, out_dir, key)
        if record.cached and task in rendered:
            record.cached = False  # rendered by this run, on the cluster
        records.append(record)
        if record.notice and log is not None:
            log(f"compare: notice: {record.notice}")
        if progress and not terminal and log is not None:
            log(f"compare {number}/{len(tasks)}: {task.stem} "
                + ("(reused)" if record.cached else format_time(record.time)))
    return records


def _score_records(records: Sequence[RenderRecord], *, out_dir: str, reference: Path,
                   maps: dict[str, dict[str, np.ndarray]] | None, spectra: dict[str, Any] | None) -> int:
    """The sweep's second step: each record's scores against ``reference``, computed (and stored with
    the render) or reused; fills ``maps`` and ``spectra``. Returns how many were reused."""
    from pointillist.imaging.io import read_exr
    from pointillist.imaging.metrics import error_spectrum, image_errors

    ref_image = read_exr(reference).image
    digest = image_digest(ref_image)
    reused = 0
    for record in records:
        signals.check()
        exr = Path(out_dir) / "renders" / record.exr
        score_key = scores_key(exr, digest)
        keep_maps = record.seed == 0                      # the report page shows each point's seed-0 render
        stored = load_scores(maps_path(exr), score_key, maps=keep_maps)
        if record.scores_key == score_key and stored is not None:
            reused += 1
        else:
            image, stored = read_exr(exr).image, {}
            record.__dict__.update(image_errors(image, ref_image, maps=stored))
            stored["spectrum"] = error_spectrum(image, ref_image)
            record.scores_key = score_key
            write_json(exr.with_suffix(".json"), record_json(record))
            save_scores(maps_path(exr), score_key, stored, maps=keep_maps)
        if maps is not None and keep_maps:
            maps[record.exr] = {name: stored[name] for name in MAP_NAMES}
        if spectra is not None:
            spectra[record.exr] = stored["spectrum"]
    return reused

# --------------------------------------------------------------------------- sweeps on a Dask cluster
def compare_task(call: tuple) -> Any:
    """Run :func:`render_one` ``(*call)`` in this process (a worker).

    ``render_one`` renders one (sampler, value, seed), times it here and writes
    its EXR and JSON record into the comparison folder (its on-disk cache).
    """
    setup_process()
    return render_one(*call)

def prerender_sweep(client, scene: str | os.PathLike, tasks: Sequence, *, params: dict[str, str] | None,
                    out_dir: str | os.PathLike, reference_spp: int | None = None,
                    retries: int = DEFAULT_RETRIES, progress: bool = True, key: str | None = None) -> list[Task]:
    """Render a comparison's missing renders (and its reference) as tasks on ``client``.

    Every :class:`Task` (and the reference, when
    ``reference_spp`` is given) whose EXR and JSON record are not yet in
    ``out_dir`` becomes one :func:`compare_task`; the workers write them where a
    serial ``compare`` would, so the serial scoring pass that follows finds
    them all finished. ``out_dir`` and the scene must be reachable by the
    workers under the same (absolute) paths. Returns the tasks rendered (the reference as the task
    ``(REFERENCE_SAMPLER, reference_spp, REFERENCE_SEED)``).
    """
    scene = str(Path(scene).resolve())
    out_dir = str(Path(out_dir).resolve())
    params = dict(params or {})
    key = key or scene_key(scene, params)
    calls = []
    if reference_spp:
        calls.append((scene, REFERENCE_SAMPLER, int(reference_spp), REFERENCE_SEED, params,
                      str(Path(out_dir) / "reference"), key, False))  # False: no warm-up render
    calls += [(scene, t.method, t.value, int(t.seed), params, out_dir, key) for t in tasks]
    todo = []
    for call in calls:
        exr, record = task_paths(call[5], Task(call[1], call[2], call[3]), key)
        if load_record(record, key, exr)[0] is None:  # missing or damaged
            todo.append(call)
    keys = [json_key(c) for c in todo]
    run_tasks(compare_task, todo, client=client, keys=keys, retries=retries, progress=progress,
              desc="compare on cluster")
    return [Task(call[1], call[2], call[3]) for call in todo]
