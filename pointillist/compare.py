"""Compare sampling methods on one scene: error against a reference, against time and spp.

The sweep is a list of :class:`Task` (method, sweep value, seed). Each task is one
call of :func:`render_one`, a pure, picklable function (it sets Mitsuba up itself,
loads the scene with the method swapped in (:mod:`pointillist.compare_methods`),
renders with :func:`pointillist.scene.timed_render`, writes ``renders/<task>.exr``
and ``renders/<task>.json`` and returns a :class:`RenderRecord`). A task whose EXR
and record exist for the same scene is not rendered again, so an interrupted sweep
resumes where it stopped. Errors against the reference are computed afterwards
(:func:`pointillist.imaging.metrics.image_errors`, and the power spectrum of each error image), and
:func:`pointillist.compare_report.write_report` writes ``results.csv``, ``results.md``, the two log-log
plots and the error spectra, and
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
from pointillist.distributed import DEFAULT_RETRIES, json_key, open_client, run_tasks, setup_process
from pointillist.errors import UsageError

__all__ = [
    "Task", "RenderRecord", "render_one", "task_paths", "render_reference",
    "run_sweep",
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
    requested count; adaptive methods report their mean).
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

def _load_record(path: Path, key: str, exr: Path) -> RenderRecord | None:
    if not (path.is_file() and exr.is_file()):
        return None
    try:
        data = json.loads(path.read_text())
        names = {f.name for f in fields(RenderRecord)}
        record = RenderRecord(**{k: v for k, v in data.items() if k in names})
    except (ValueError, TypeError):
        return None
    if record.scene_key != key:
        return None
    record.cached = True
    return record

def _write_json(path: Path, data: dict) -> None:
    from pointillist.imaging.io import atomic_write

    atomic_write(path, lambda tmp: Path(tmp).write_text(json.dumps(data, indent=1)))

#: Methods rendered at least once in this process (:func:`render_one`'s warm-up).
_WARMED: set[str] = set()

def render_one(scene_path: str, method: str, value: float, seed: int, params: dict[str, str] | None,
               out_dir: str, key: str | None = None, warm_up: bool = True) -> RenderRecord:
    """Render one task of the sweep and write its EXR and JSON record; picklable.

    Skips the render when ``out_dir/renders/<key>/<task>.exr`` and ``.json`` exist
    (``key``: :func:`scene_key` of the scene file and parameters), returning the
    stored record with ``cached=True``.

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
        :func:`scene_key` of the scene and params (computed when omitted).
    warm_up : bool
        Render untimed first if ``method`` has not rendered in this process yet.
    """
    import pointillist

    task = Task(method, value, int(seed))
    key = key or scene_key(scene_path, params)
    exr, record_path = task_paths(out_dir, task, key)
    record = _load_record(record_path, key, exr)
    if record is not None:
        return record
    exr.parent.mkdir(parents=True, exist_ok=True)

    pointillist.setup()
    from pointillist.render_output import write_render
    from pointillist.scene import scene_info, timed_render

    spec = METHODS[method]
    scene = load_configured_scene(scene_path, spec, value, params)
    spp = int(value) if spec.parameter == "spp" else None
    warm = None
    if warm_up and method not in _WARMED:
        warm = timed_render(scene, spp=spp, seed=int(seed))[1]
        _WARMED.add(method)
    image, timing = timed_render(scene, spp=spp, seed=int(seed))
    info = scene_info(scene)  # after the render: the sampler's own rounding of spp applies
    info.update(method=method, value=float(value), seed=int(seed))
    write_render(exr, image, scene, scene_path, info, timing, png=False)
    samples = float(info["spp"])
    names = list(scene.integrator().aov_names())
    for name in ("spp", "sample_count", "samples"):
        if name in names:  # adaptive methods: the mean of their per-pixel count
            pixels = np.asarray(image)
            samples = float(pixels[..., pixels.shape[2] - len(names) + names.index(name)].mean())
            break
    record = RenderRecord(
        method=method, value=float(value), seed=int(seed), spp=samples, exr=f"{key}/{exr.name}",
        width=int(info["width"]), height=int(info["height"]), trace=timing.trace,
        compile=timing.compile, execute=timing.execute, total=timing.total,
        time=max(timing.total - timing.compile, 0.0), kernels=timing.kernels,
        cache_hits=timing.cache_hits, scene_key=key, warm_up=warm.total if warm else 0.0,
        warm_up_compile=warm.compile if warm else 0.0)
    _write_json(record_path, record.as_dict())
    return record

def render_reference(scene_path: str, params: dict[str, str] | None, out_dir: str, spp: int,
                     key: str | None = None) -> Path:
    """Render (or reuse) the reference: :data:`REFERENCE_SAMPLER` at ``spp``; returns its EXR."""
    record = render_one(scene_path, REFERENCE_SAMPLER, spp, REFERENCE_SEED, params,
                        str(Path(out_dir) / "reference"), key, warm_up=False)
    return Path(out_dir) / "reference" / "renders" / record.exr


# ------------------------------------------------------------------------------ sweep
def run_sweep(scene_path: str, tasks: Sequence[Task], *, params: dict[str, str] | None, out_dir: str,
              reference: Path, progress: bool = True, log: Callable[[str], None] | None = None,
              maps: dict[str, dict[str, np.ndarray]] | None = None,
              spectra: dict[str, Any] | None = None,
              render: Callable[..., RenderRecord] = render_one) -> list[RenderRecord]:
    """Run ``tasks`` (skipping finished ones), then score each render against ``reference``.

    With ``progress``, a progress bar draws on a terminal (standard error a TTY);
    otherwise (a log file, a pipe) ``log`` gets one line per finished render instead
    of the bar's redraws. A ``maps`` dict receives the per-pixel error maps of every
    seed-0 render (by ``record.exr``, :func:`pointillist.imaging.metrics.error_maps`) for the report page;
    a ``spectra`` dict the radially averaged power spectrum of every render's luminance error
    (by ``record.exr``, :func:`pointillist.imaging.metrics.error_spectrum`) for the spectrum plot.
    """
    import sys

    from tqdm import tqdm

    from pointillist.compare_report import format_time
    from pointillist.imaging.io import read_exr
    from pointillist.imaging.metrics import error_spectrum, image_errors

    key = scene_key(scene_path, params)
    ref_image = read_exr(reference).image
    records = []
    terminal = progress and sys.stderr.isatty()
    bar = tqdm(tasks, desc="compare", unit="render", disable=not terminal)
    for number, task in enumerate(bar, 1):
        bar.set_postfix_str(task.stem)
        record = render(scene_path, task.method, task.value, task.seed, params, out_dir, key)
        records.append(record)
        if progress and not terminal and log is not None:
            log(f"compare {number}/{len(tasks)}: {task.stem} "
                + ("(reused)" if record.cached else format_time(record.time)))
    for record in records:
        image = read_exr(Path(out_dir) / "renders" / record.exr).image
        kept = {} if maps is not None and record.seed == 0 else None
        record.__dict__.update(image_errors(image, ref_image, maps=kept))
        if kept is not None:
            maps[record.exr] = kept
        if spectra is not None:
            spectra[record.exr] = error_spectrum(image, ref_image)
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
                    retries: int = DEFAULT_RETRIES, progress: bool = True) -> int:
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
    key = scene_key(scene, params)
    calls = []
    if reference_spp:
        calls.append((scene, REFERENCE_SAMPLER, int(reference_spp), REFERENCE_SEED, params,
                      str(Path(out_dir) / "reference"), key, False))  # False: no warm-up render
    calls += [(scene, t.method, t.value, int(t.seed), params, out_dir, key) for t in tasks]
    todo = [c for c in calls
            if not all(p.is_file() for p in task_paths(c[5], Task(c[1], c[2], c[3]), key))]
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
    from pointillist.compare_report import write_report
    from pointillist.scene import check_sample_count, check_scene_file, filter_note

    params = dict(params or {})
    tasks = sweep_tasks(methods, spp, seeds)
    scene = check_scene_file(scene)
    out = Path(out_dir) if out_dir else Path("out") / "compare" / scene.stem
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out: {out} exists and is not a folder")
    if reference is not None and not Path(reference).is_file():
        raise UsageError(f"--reference: no such file: {reference}")
    size, rfilter = _scene_size(scene, params)
    for count in [t.value for t in tasks if sweep_parameter(t.method) == "spp"] + (
            [] if reference else [reference_spp]):
        check_sample_count(*size, int(count))  # before any render starts (and its progress bar)
    if reference is not None:
        _check_reference(Path(reference), size)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise UsageError(f"--out: cannot create the folder {out} ({error.strerror or error})") from None
    notes: list[str] = [filter_note(rfilter)]
    log(notes[0])
    cluster_renders = 0
    if workers or scheduler:
        with open_client(workers, scheduler) as client:
            cluster_renders = prerender_sweep(client, scene, tasks, params=params, out_dir=out,
                                              reference_spp=None if reference else reference_spp,
                                              progress=progress)
        log(f"{cluster_renders} renders done on the cluster")
    if reference is not None:
        reference = Path(reference)
    else:
        log(f"reference: {reference_spp} spp with Mitsuba's stratified sampler (cached in {out / 'reference'})")
        reference = render_reference(str(scene), params, str(out), reference_spp)
        taken = _reference_spp(_check_reference(reference, size).metadata)
        if taken is not None and taken != reference_spp:
            note = (f"reference: the stratified sampler took {taken} spp for the {reference_spp} asked "
                    "(it rounds up to a square)")
            notes.append(note)
            log(note)
    maps: dict[str, dict[str, np.ndarray]] | None = {} if report else None  # FLIP once per render, not twice
    spectra: dict[str, Any] = {}
    records = run_sweep(str(scene), tasks, params=params, out_dir=str(out), reference=reference, progress=progress,
                        log=log, maps=maps, spectra=spectra)
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


def _scene_size(scene: Path, params: dict) -> tuple[tuple[int, int], str]:
    """``((width, height), film filter)`` of the scene (loads it once: bad scenes fail before any render)."""
    import pointillist

    pointillist.setup()
    from pointillist.scene import film_filter, load_scene, scene_info

    loaded = load_scene(scene, params)
    info = scene_info(loaded)
    return (info["width"], info["height"]), film_filter(loaded)


def _check_reference(reference: Path, size: tuple[int, int]):
    """The reference must have the render size ``(width, height)``; returns it as read (an ``EXRImage``)."""
    from pointillist.imaging.io import read_exr

    try:
        exr = read_exr(reference)
    except ValueError as error:
        raise UsageError(f"--reference: {error}") from None
    image = exr.image
    if image.shape[:2] != (size[1], size[0]):
        raise UsageError(f"--reference: {reference} is {image.shape[1]}x{image.shape[0]}, the scene "
                         f"renders {size[0]}x{size[1]}")
    return exr
