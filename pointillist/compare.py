"""Compare sampling methods on one scene: error against a reference, against time and spp.

The sweep is a list of :class:`Task` (method, sweep value, seed). Each task is one
call of :func:`render_one`, a pure, picklable function (it sets Mitsuba up itself,
loads the scene with the method swapped in (:mod:`pointillist.compare_methods`),
renders with :func:`pointillist.scene.timed_render`, writes ``renders/<task>.exr``
and ``renders/<task>.json`` and returns a :class:`RenderRecord`). A task whose EXR
and record exist for the same scene is not rendered again, so an interrupted sweep
resumes where it stopped. Errors against the reference are computed afterwards
(:func:`pointillist.imaging.metrics.image_errors`, and the power spectrum of each error image)
and kept with the render (the scores in its record, the spectrum and the per-pixel maps of a
seed-0 render in ``renders/<task>.maps.npz``, keyed by the render and the reference:
:func:`scores_key`), so a rerun scores only what changed; and
:func:`pointillist.compare_report.write_report` writes ``results.csv``, ``results.md``, the two
log-log plots and the error spectra, and
:func:`pointillist.compare_html.write_html_report` ``report.html`` (renders, error
maps, interactive plots), from every record of the sweep on disk. On a Dask cluster
(:func:`prerender_sweep`) every missing render is a task; the scoring pass that
follows finds them finished. :func:`compare_scene` is ``pointillist compare``.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from pointillist.compare_methods import METHODS, load_configured_scene, resolve_methods, scene_key, sweep_parameter
from pointillist import signals
from pointillist.distributed import DEFAULT_RETRIES, json_key, open_client, run_tasks, setup_process
from pointillist.errors import UsageError

__all__ = [
    "Task", "RenderRecord", "render_one", "task_paths", "render_reference",
    "run_sweep", "scores_key", "maps_path", "SCORES_VERSION",
    "compare_task", "prerender_sweep", "CompareResult", "sweep_tasks", "compare_scene",
    "DEFAULT_SPP", "DEFAULT_METHODS", "REFERENCE_SAMPLER", "REFERENCE_SEED",
]



#: Default sweep of ``pointillist compare``.
DEFAULT_SPP = (1, 4, 16, 64, 256)

DEFAULT_METHODS = ("grid", "jitter", "random", "poisson")

#: The reference is rendered with Mitsuba's own stratified sampler (all dimensions
#: stratified, an implementation independent of the samplers compared) ...
REFERENCE_SAMPLER = "stratified"

#: ... with a seed no sweep uses.
REFERENCE_SEED = 1_000_003


# ------------------------------------------------------------------------------ tasks
@dataclass(frozen=True)
class Task:
    """One render of the sweep."""

    method: str
    value: float
    seed: int

    @property
    def stem(self) -> str:
        value = f"{int(self.value):05d}" if float(self.value).is_integer() else f"{self.value:g}"
        parameter = sweep_parameter(self.method)
        return f"{self.method}_{parameter}{value}_seed{self.seed}"

@dataclass
class RenderRecord:
    """What :func:`render_one` returns (and stores as JSON beside the EXR).

    Times in seconds, each reported apart: ``trace``, ``compile``, ``execute`` and
    ``total`` are those of the timed render (``total`` its wall time, which includes
    the other three); ``time = total - compile`` is the figure the comparison plots
    (trace + kernel execution). ``warm_up`` is the wall time of the untimed warm-up
    render before a method's first render in a process (0 without one) and
    ``warm_up_compile`` its JIT compilation (:func:`render_one`).
    ``spp`` is the samples per pixel actually taken (the sampler may round the
    requested count; adaptive methods report their mean). ``rmse``, ``relmse`` and
    ``flip`` are the errors against the reference once scored (:func:`run_sweep`), and
    ``scores_key`` says against what (:func:`scores_key`; empty while unscored). ``notice``: why
    a cached render was rendered again. ``cached`` and ``notice`` describe this run and are not
    stored (:func:`record_json`).
    """

    method: str
    value: float
    seed: int
    spp: float
    exr: str
    width: int
    height: int
    trace: float
    compile: float
    execute: float
    total: float
    time: float
    kernels: int
    cache_hits: int
    scene_key: str
    warm_up: float = 0.0
    warm_up_compile: float = 0.0
    cached: bool = False
    rmse: float = math.nan
    relmse: float = math.nan
    flip: float = math.nan
    lowfreq: float = math.nan
    scores_key: str = ""
    notice: str = ""

    @property
    def mse(self) -> float:
        return self.rmse ** 2

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

def task_paths(out_dir: str | os.PathLike, task: Task, key: str) -> tuple[Path, Path]:
    """``(exr, json)`` paths of a task's render: ``out_dir/renders/<scene key>/<task>.*``.

    One folder per scene key: renders of an edited scene never overwrite (or get
    mistaken for) those of the old one.
    """
    folder = Path(out_dir) / "renders" / key
    return folder / f"{task.stem}.exr", folder / f"{task.stem}.json"

def _load_record(path: Path, key: str, exr: Path) -> tuple[RenderRecord | None, str]:
    """The stored record of a finished render, or ``(None, why)`` when it must be rendered (again).

    A record counts only with its EXR, for the same scene key, and when that EXR reads back as an
    image of the record's size with the record's channels: a damaged file (truncated, replaced,
    edited) is rendered again, with ``why`` saying so, instead of failing every later run.
    """
    if not (path.is_file() and exr.is_file()):
        return None, ""
    try:
        data = json.loads(path.read_text())
        names = {f.name for f in fields(RenderRecord)}
        record = RenderRecord(**{k: v for k, v in data.items() if k in names and k not in ("cached", "notice")})
    except (ValueError, TypeError, OSError):
        for stale in (exr, path):
            stale.unlink(missing_ok=True)
        return None, f"cached render {exr.name}: its record {path.name} is damaged; rendered again"
    if record.scene_key != key:
        return None, ""
    problem = _damage(exr, record.width, record.height)
    if problem:
        for stale in (exr, path):  # removed first: the new render is a new file, not one this process read
            stale.unlink(missing_ok=True)
        return None, f"cached render {exr.name} {problem}; rendered again"
    record.cached = True
    return record, ""


def _damage(exr: Path, width: int, height: int) -> str:
    """What is wrong with a cached render's EXR ('' when it reads back as a width x height image)."""
    from pointillist.imaging.io import read_exr

    try:
        image = read_exr(exr).image
    except (ValueError, OSError) as error:
        return f"cannot be read ({str(error).splitlines()[0] if str(error) else type(error).__name__})"
    if image.shape[:2] != (height, width):
        return f"is {image.shape[1]}x{image.shape[0]}, its record says {width}x{height}"
    return ""


def record_json(record: RenderRecord) -> dict[str, Any]:
    """What a record stores: its fields but ``cached`` and ``notice``, which describe one run."""
    return {k: v for k, v in record.as_dict().items() if k not in ("cached", "notice")}


def _write_json(path: Path, data: dict) -> None:
    from pointillist.files import atomic_write

    atomic_write(path, lambda tmp: Path(tmp).write_text(json.dumps(data, indent=1)))

#: The definition of the stored scores: bump it when a score is defined or computed differently
#: (relMSE's epsilon, FLIP's implementation), so that scores stored by an older version are computed again
#: (2: the low-frequency error and the error spectrum were added).
SCORES_VERSION = 2


def scores_key(render: str | os.PathLike, reference_digest: str) -> str:
    """What a render's stored scores are valid for: the render file (its size and modification time,
    so a render written again is scored again), the reference's pixels (``reference_digest``, see
    :func:`image_digest`) and :data:`SCORES_VERSION` with the FLIP implementation; a SHA-256 (hex)."""
    from pointillist.imaging.metrics import FLIP_BACKENDS, RELMSE_EPSILON

    stat = Path(render).stat()
    return json_key({"render": [stat.st_size, stat.st_mtime_ns], "reference": reference_digest,
                     "version": SCORES_VERSION, "relmse_epsilon": RELMSE_EPSILON, "flip": FLIP_BACKENDS[0]})


def image_digest(image: np.ndarray) -> str:
    """BLAKE2b (hex) of an image's shape, dtype and pixels: the reference's identity in :func:`scores_key`."""
    import hashlib

    array = np.ascontiguousarray(image)
    digest = hashlib.blake2b(f"{array.shape}{array.dtype}".encode(), digest_size=20)
    digest.update(memoryview(array).cast("B"))
    return digest.hexdigest()


def maps_path(exr: str | os.PathLike) -> Path:
    """Where the error spectrum (and a seed-0 render's per-pixel error maps) of the render ``exr`` are kept:
    ``<task>.maps.npz`` beside it."""
    exr = Path(exr)
    return exr.with_name(exr.stem + ".maps.npz")


#: The per-pixel maps kept for a seed-0 render (the report page's error maps).
_MAPS = ("relmse", "flip")


def _load_scores(path: Path, key: str, *, maps: bool) -> dict[str, Any] | None:
    """What :func:`_save_scores` stored at ``path`` for ``key``: the error spectrum and, with ``maps``,
    the relmse and flip maps; None when missing, stale or unreadable."""
    from pointillist.imaging.spectrum import RadialSpectrum

    try:
        with np.load(path) as stored:
            if str(stored["scores_key"]) != key:
                return None
            found: dict[str, Any] = {"spectrum": RadialSpectrum(stored["spectrum_frequency"], stored["spectrum_power"],
                                                                stored["spectrum_count"])}
            if maps:
                found.update({name: stored[name] for name in _MAPS})
            return found
    except (OSError, KeyError, ValueError):
        return None


def _save_scores(path: Path, key: str, scores: dict[str, Any], *, maps: bool) -> None:
    from pointillist.files import atomic_write

    spectrum = scores["spectrum"]
    arrays = dict(scores_key=np.array(key), spectrum_frequency=spectrum.frequency, spectrum_power=spectrum.power,
                  spectrum_count=spectrum.count)
    if maps:
        arrays.update({name: scores[name] for name in _MAPS})
    atomic_write(path, lambda tmp: np.savez(tmp, **arrays))


#: Methods rendered at least once in this process (:func:`render_one`'s warm-up).
_WARMED: set[str] = set()

def render_one(scene_path: str, method: str, value: float, seed: int, params: dict[str, str] | None,
               out_dir: str, key: str | None = None, warm_up: bool = True) -> RenderRecord:
    """Render one task of the sweep and write its EXR and JSON record; picklable.

    Skips the render when ``out_dir/renders/<key>/<task>.exr`` and ``.json`` exist
    (``key``: :func:`scene_key` of the scene's inputs and parameters) and the EXR reads
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
        A name in :data:`METHODS`.
    value : float
        The sweep value: samples per pixel for samplers.
    seed : int
        Render seed.
    params : dict
        ``$name`` overrides for the scene.
    out_dir : str
        The comparison folder.
    key : str, optional
        :func:`scene_key` of the scene's inputs and params (computed when omitted).
    warm_up : bool
        Render untimed first if ``method`` has not rendered in this process yet.
    """
    import pointillist

    pointillist.setup()
    from pointillist.channels import channel_layout
    from pointillist.render_output import write_render
    from pointillist.scene import scene_info, timed_render

    task = Task(method, value, int(seed))
    key = key or scene_key(scene_path, params)
    exr, record_path = task_paths(out_dir, task, key)
    record, notice = _load_record(record_path, key, exr)
    if record is not None:
        return record

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
    exr.parent.mkdir(parents=True, exist_ok=True)  # only now: an interrupted render leaves no empty folder
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
    _write_json(record_path, record_json(record))
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


# ------------------------------------------------------------------------------ sweep
def run_sweep(scene_path: str, tasks: Sequence[Task], *, params: dict[str, str] | None, out_dir: str,
              reference: Path, progress: bool = True, log: Callable[[str], None] | None = None,
              maps: dict[str, dict[str, np.ndarray]] | None = None,
              spectra: dict[str, Any] | None = None,
              render: Callable[..., RenderRecord] = render_one, key: str | None = None) -> list[RenderRecord]:
    """Run ``tasks`` (skipping finished ones), then score each render against ``reference``.

    With ``progress``, a progress bar draws on a terminal (standard error a TTY);
    otherwise (a log file, a pipe) ``log`` gets one line per finished render instead
    of the bar's redraws. A ``maps`` dict receives the per-pixel error maps of every
    seed-0 render (by ``record.exr``, :func:`pointillist.imaging.metrics.error_maps`) for the report page;
    a ``spectra`` dict the radially averaged power spectrum of every render's luminance error
    (by ``record.exr``, :func:`pointillist.imaging.metrics.error_spectrum`) for the spectrum plot.

    Scores are kept: a render's errors go into its JSON record with their :func:`scores_key`,
    its error spectrum (and a seed-0 render's maps) into :func:`maps_path`; a render whose stored
    scores have the key of this render file and this reference (and whose spectrum and maps are
    there) is not scored again; with ``progress``, ``log`` is told how many were reused.
    """
    from tqdm import tqdm

    from pointillist.compare_report import format_time
    from pointillist.terminal import draws_progress
    from pointillist.imaging.io import read_exr
    from pointillist.imaging.metrics import error_spectrum, image_errors

    key = key or scene_key(scene_path, params)
    ref_image = read_exr(reference).image
    records = []
    terminal = draws_progress(progress)
    bar = tqdm(tasks, desc="compare", unit="render", disable=not terminal)
    for number, task in enumerate(bar, 1):
        signals.check()
        bar.set_postfix_str(task.stem)
        record = render(scene_path, task.method, task.value, task.seed, params, out_dir, key)
        records.append(record)
        if record.notice and log is not None:
            log(f"compare: notice: {record.notice}")
        if progress and not terminal and log is not None:
            log(f"compare {number}/{len(tasks)}: {task.stem} "
                + ("(reused)" if record.cached else format_time(record.time)))
    digest = image_digest(ref_image)
    reused = 0
    for record in records:
        signals.check()
        exr = Path(out_dir) / "renders" / record.exr
        score_key = scores_key(exr, digest)
        keep_maps = record.seed == 0                      # the report page shows each point's seed-0 render
        stored = _load_scores(maps_path(exr), score_key, maps=keep_maps)
        if record.scores_key == score_key and stored is not None:
            reused += 1
        else:
            image, stored = read_exr(exr).image, {}
            record.__dict__.update(image_errors(image, ref_image, maps=stored))
            stored["spectrum"] = error_spectrum(image, ref_image)
            record.scores_key = score_key
            _write_json(exr.with_suffix(".json"), record_json(record))
            _save_scores(maps_path(exr), score_key, stored, maps=keep_maps)
        if maps is not None and keep_maps:
            maps[record.exr] = {name: stored[name] for name in _MAPS}
        if spectra is not None:
            spectra[record.exr] = stored["spectrum"]
    if progress and log is not None and reused:
        log(f"compare: scores of {reused} of {len(records)} renders reused (same render and reference)")
    return records


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
                    retries: int = DEFAULT_RETRIES, progress: bool = True, key: str | None = None) -> int:
    """Render a comparison's missing renders (and its reference) as tasks on ``client``.

    Every :class:`Task` (and the reference, when
    ``reference_spp`` is given) whose EXR and JSON record are not yet in
    ``out_dir`` becomes one :func:`compare_task`; the workers write them where a
    serial ``compare`` would, so the serial scoring pass that follows finds
    them all finished. ``out_dir`` and the scene must be reachable by the
    workers under the same (absolute) paths. Returns how many were rendered.
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
        if _load_record(record, key, exr)[0] is None:  # missing or damaged
            todo.append(call)
    keys = [json_key(c) for c in todo]
    run_tasks(compare_task, todo, client=client, keys=keys, retries=retries, progress=progress,
              desc="compare on cluster")
    return len(todo)


# ------------------------------------------------------------------------ `pointillist compare`
@dataclass
class CompareResult:
    """What :func:`compare_scene` did: the records, the report's files, the reference used."""

    records: list[RenderRecord]
    paths: dict[str, Path]
    reference: Path
    out_dir: Path
    cluster_renders: int = 0
    notes: list[str] = field(default_factory=list)

    @property
    def new(self) -> int:
        """How many renders were made by this run (the rest came from the folder)."""
        return sum(1 for r in self.records if not r.cached)


def sweep_tasks(methods: Sequence[str] | str, spp: Sequence[int], seeds: int) -> list[Task]:
    """The tasks of a sweep: every method at every sweep value (``spp`` for samplers, the
    method's own values otherwise) and seed ``0..seeds-1``."""
    tasks = []
    for method in resolve_methods(methods):
        values = list(spp) if method.parameter == "spp" else list(method.values)
        if not values:
            raise UsageError(f"--samplers: {method.name} sweeps {method.parameter}, which has no values")
        tasks += [Task(method.name, v, seed) for v in values for seed in range(int(seeds))]
    return tasks


def compare_scene(scene: str | os.PathLike, *, methods: Sequence[str] | str = DEFAULT_METHODS,
                  spp: Sequence[int] = DEFAULT_SPP, seeds: int = 1, reference_spp: int = 4096,
                  reference: str | os.PathLike | None = None, out_dir: str | os.PathLike | None = None,
                  params: dict[str, str] | None = None, workers: int | None = None, scheduler: str | None = None,
                  progress: bool = True, report: bool = True,
                  log: Callable[[str], None] = lambda line: None) -> CompareResult:
    """``pointillist compare``: sweep ``methods`` over ``spp`` and ``seeds`` on one scene, score
    every render against a reference and write the report into ``out_dir``.

    The reference is ``reference`` (an EXR of the render's size) or a render of
    :data:`REFERENCE_SAMPLER` at ``reference_spp``, kept in ``out_dir/reference``.
    Everything that can be checked (scene, sample counts, reference size) is checked
    before the first render. ``log`` receives progress lines (e.g. ``print``; one per
    finished render when ``progress`` is on and standard error is not a terminal).
    With ``report``, ``out_dir/report.html`` (:mod:`pointillist.compare_html`) is
    written too, from every render of the sweep on disk (also those of earlier,
    interrupted runs); ``paths["html"]`` is its path and ``notes`` say its size.
    ``notes`` (also given to ``log`` and listed in results.md) also say which
    reconstruction filter the film uses (only a box filter makes a pixel the plain
    average of its samples) and when the reference took another spp than asked.

    Raises
    ------
    UsageError
        For a missing scene, unknown method, an output folder that is a file, a sample
        count Mitsuba cannot take, or a reference of the wrong size.
    """
    import pointillist
    from pointillist.channels import channel_layout
    from pointillist.compare_html import REPORT_NAME
    from pointillist.compare_report import report_paths, write_report
    from pointillist.plan import Output, Plan, inputs_digest, scene_inputs
    from pointillist.scene import (check_sample_count, check_scene_file, film_filter, filter_note, instantiate_scene,
                                   parse_scene, scene_info)

    params = dict(params or {})
    tasks = sweep_tasks(methods, spp, seeds)
    scene = check_scene_file(scene)
    out = Path(out_dir) if out_dir else Path("out") / "compare" / scene.stem
    if reference is not None and not Path(reference).is_file():
        raise UsageError(f"--reference: no such file: {reference}")
    # The plan, before any work: the folder and every file of the report writable, none an input.
    files = list(report_paths(out).values()) + ([out / REPORT_NAME] if report else [])
    plan = Plan(inputs=[scene] + ([Path(reference)] if reference is not None else []),
                outputs=[Output(out, "--out", folder=True)]
                + [Output(path, f"--out ({path.name})", make_parent=True) for path in files]
                + [Output(out / "renders", "--out (renders)", folder=True),
                   Output(out / "reference", "--out (reference)", folder=True)])
    plan.check()
    pointillist.setup()
    parsed = parse_scene(scene, params)
    inputs = scene_inputs(parsed)
    plan.add(inputs=inputs)
    key = inputs_digest(inputs, params)[:12]
    loaded = instantiate_scene(parsed)  # bad scenes fail before any render
    info, rfilter, layout = scene_info(loaded), film_filter(loaded), channel_layout(loaded)
    del loaded
    if not layout.colour:
        raise UsageError(f"scene {scene}: the render has no colour channels (Mitsuba's aov integrator without a "
                         f"nested integrator renders only AOVs: {', '.join(layout.names)}): nothing to compare")
    size = (info["width"], info["height"])
    for count in [t.value for t in tasks if sweep_parameter(t.method) == "spp"] + (
            [] if reference else [reference_spp]):
        check_sample_count(*size, int(count))  # before any render starts (and its progress bar)
    if reference is not None:
        _check_reference(Path(reference), size, what="--reference")
    with plan.writing():
        notes: list[str] = [filter_note(rfilter)]
        log(notes[0])
        cluster_renders = 0
        if workers or scheduler:
            with open_client(workers, scheduler) as client:
                cluster_renders = prerender_sweep(client, scene, tasks, params=params, out_dir=out,
                                                  reference_spp=None if reference else reference_spp,
                                                  progress=progress, key=key)
            log(f"{cluster_renders} renders done on the cluster")
        if reference is not None:
            reference = Path(reference)
        else:
            log(f"reference: {reference_spp} spp with Mitsuba's stratified sampler (cached in {out / 'reference'})")
            reference = render_reference(str(scene), params, str(out), reference_spp, key, log=log)
            taken = _reference_spp(_check_reference(reference, size, what="reference").metadata)
            if taken is not None and taken != reference_spp:
                note = (f"reference: the stratified sampler took {taken} spp for the {reference_spp} asked "
                        "(it rounds up to a square)")
                notes.append(note)
                log(note)
        maps: dict[str, dict[str, np.ndarray]] | None = {} if report else None  # FLIP once per render, not twice
        spectra: dict[str, Any] = {}
        records = run_sweep(str(scene), tasks, params=params, out_dir=str(out), reference=reference,
                            progress=progress, log=log, maps=maps, spectra=spectra, key=key)
        signals.check()
        title = f"Sampler comparison: {scene.name}"
        paths = write_report(records, out, scene=str(scene), reference=str(reference), title=title, notes=notes,
                             spectra=spectra)
        if report:
            from pointillist.compare_html import write_html_report

            page = write_html_report(records, out, scene=str(scene), reference=reference, title=title, maps=maps)
            paths["html"] = page.path
            notes.append(page.summary)
    return CompareResult(records=records, paths=paths, reference=reference, out_dir=out,
                         cluster_renders=cluster_renders, notes=notes)


def _reference_spp(metadata: dict) -> int | None:
    """The samples per pixel a rendered reference took (from its EXR header), or None."""
    value = metadata.get("spp")
    return int(value) if isinstance(value, (int, float)) and math.isfinite(value) else None


def _check_reference(reference: Path, size: tuple[int, int], *, what: str = "--reference"):
    """The reference must read as a finite image of the render size ``(width, height)``; returns it
    as read (an ``EXRImage``). A NaN or infinite value would make every error against it NaN or
    infinite (and their log-log plots impossible): refused, with the count of each kind."""
    from pointillist.imaging.io import read_exr

    try:
        exr = read_exr(reference)
    except ValueError as error:
        raise UsageError(f"{what}: {error}") from None
    image = exr.image
    if image.shape[:2] != (size[1], size[0]):
        raise UsageError(f"{what}: {reference} is {image.shape[1]}x{image.shape[0]}, the scene "
                         f"renders {size[0]}x{size[1]}")
    bad = ~np.isfinite(image)
    if bad.any():
        counts = [(int(np.count_nonzero(image == np.inf)), "+inf"), (int(np.count_nonzero(image == -np.inf)), "-inf"),
                  (int(np.count_nonzero(np.isnan(image))), "NaN")]
        y, x = (int(v) for v in np.argwhere(bad.reshape(image.shape[0], image.shape[1], -1).any(axis=2))[0])
        kinds = ", ".join(f"{n} {name}" for n, name in counts if n)
        cause = "" if what == "--reference" else " (the scene renders them)"
        raise UsageError(f"{what}: {reference} holds non-finite values{cause}: {kinds} (first at pixel x={x}, "
                         f"y={y}); errors against it would be NaN or infinite: expected a finite reference")
    return exr
