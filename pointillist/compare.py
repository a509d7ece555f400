"""Compare sampling methods on one scene: error against a reference, against time and spp.

The sweep is a list of :class:`Task` (method, sweep value, seed). Each task is one
call of :func:`render_one`, a pure, picklable function (it sets Mitsuba up itself,
loads the scene with the method swapped in, renders with
:func:`pointillist.scene.timed_render`, writes ``renders/<task>.exr`` and
``renders/<task>.json`` and returns a :class:`RenderRecord`). A task whose EXR and
record exist for the same scene is not rendered again, so an interrupted sweep
resumes where it stopped. Errors against the reference are computed afterwards
(:func:`image_errors`), and :func:`write_report` writes ``results.csv``,
``results.md`` and the two log-log plots.

Methods live in :data:`METHODS` (:func:`register_method`): a sampler method swaps
the ``<sampler>`` of every ``<sensor>`` of the scene XML (so any user scene works,
whatever its sampler); an integrator method (e.g. adaptive super-sampling, whose
sweep parameter is a threshold) swaps the ``<integrator>``. Every Mitsuba sampler
plugin (``stratified``, ``multijitter``, ``orthogonal``, ``ldsampler``,
``independent``) is a valid method too.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import os
import xml.etree.ElementTree as ET
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from pointillist.errors import UsageError

__all__ = [
    "Method", "METHODS", "MITSUBA_SAMPLERS", "register_method", "resolve_methods", "configure_scene",
    "scene_key", "load_configured_scene", "Task", "RenderRecord", "render_one", "task_paths",
    "render_reference", "image_errors", "fit_slope", "run_sweep", "summarise", "equal_time_ranking",
    "equal_error_ranking", "setting_label",
    "write_report", "RELMSE_EPSILON", "DEFAULT_SPP", "DEFAULT_METHODS", "REFERENCE_SAMPLER",
    "REFERENCE_SEED",
]

#: Epsilon of the relative MSE, mean((x - ref)^2 / (ref^2 + eps)) (issue 4).
RELMSE_EPSILON = 0.01
#: Default sweep of ``pointillist compare``.
DEFAULT_SPP = (1, 4, 16, 64, 256)
DEFAULT_METHODS = ("grid", "jitter", "random", "poisson")
#: The reference is rendered with Mitsuba's own stratified sampler (all dimensions
#: stratified, an implementation independent of the samplers compared) ...
REFERENCE_SAMPLER = "stratified"
#: ... with a seed no sweep uses.
REFERENCE_SEED = 1_000_003
#: Mitsuba's built-in samplers, all valid peers.
MITSUBA_SAMPLERS = ("independent", "stratified", "multijitter", "orthogonal", "ldsampler")


# ----------------------------------------------------------------------------- methods
@dataclass(frozen=True)
class Method:
    """How the scene is configured for one compared method.

    Attributes
    ----------
    name : str
        The name on the command line (``random``).
    plugin : str
        The Mitsuba plugin type put into the scene (``independent``).
    kind : {"sampler", "integrator"}
        ``sampler``: every sensor's ``<sampler>`` becomes ``<sampler type=plugin>``
        with ``sample_count`` = the sweep value; ``integrator``: the scene's
        ``<integrator>`` becomes ``<integrator type=plugin>`` with the property
        ``parameter`` = the sweep value.
    parameter : str
        The sweep parameter: ``spp`` for samplers (the ``--spp`` list), or the
        integrator property swept (e.g. ``threshold``).
    values : tuple of float
        The default sweep of a non-``spp`` parameter.
    configure : callable, optional
        ``configure(root, value)`` edits the parsed scene XML in place instead of
        the default for ``kind`` (must be a module-level function: tasks are pickled).
    """

    name: str
    plugin: str
    kind: str = "sampler"
    parameter: str = "spp"
    values: tuple[float, ...] = ()
    configure: Callable[[ET.Element, float], None] | None = None


#: Registered methods by name. ``random`` is Mitsuba's ``independent``.
METHODS: dict[str, Method] = {}


def register_method(method: Method) -> None:
    """Add ``method`` to :data:`METHODS` (replacing one of the same name)."""
    if method.kind not in ("sampler", "integrator"):
        raise ValueError(f"method.kind: expected 'sampler' or 'integrator', got {method.kind!r}")
    METHODS[method.name] = method


for _name, _plugin in (("grid", "grid"), ("jitter", "jitter"), ("poisson", "poisson"),
                       ("random", "independent")):
    register_method(Method(_name, _plugin))
for _name in MITSUBA_SAMPLERS:
    register_method(Method(_name, _name))


def _configure_adaptive(root: ET.Element, value: float) -> None:
    """Wrap the scene's ``<integrator>`` in ``<integrator type="adaptive">`` with
    ``threshold`` = ``value`` (an adaptive integrator already there gets the threshold)."""
    old = root.findall("integrator")
    if old and old[0].get("type") == "adaptive":
        adaptive = old[0]
        for element in adaptive.findall("*[@name='threshold']"):
            adaptive.remove(element)
        adaptive.insert(0, _property("float", "threshold", float(value)))
        return
    position = list(root).index(old[0]) if old else 0
    for element in old:
        root.remove(element)
    adaptive = ET.Element("integrator", {"type": "adaptive"})
    adaptive.append(_property("float", "threshold", float(value)))
    for name, depth in ADAPTIVE_DEPTHS.items():
        adaptive.append(_property("integer", name, depth))
    adaptive.append(old[0] if old else ET.Element("integrator", {"type": "path"}))
    root.insert(position, adaptive)


#: Adaptive super-sampling (plugins/integrators/adaptive.py) sweeps its threshold on
#: the 0..255 display scale, around the scene's own integrator, starting from the 3 x 3
#: lattice per pixel (min_depth 1) down to depth 3: the best error-vs-time curve on
#: scenes/edges.xml (benchmarks/RESULTS.md, "adaptive"); below 16 the error stops falling.
ADAPTIVE_THRESHOLDS = (128.0, 64.0, 32.0, 16.0)
ADAPTIVE_DEPTHS = {"min_depth": 1, "max_depth": 3}
register_method(Method("adaptive", "adaptive", kind="integrator", parameter="threshold",
                       values=ADAPTIVE_THRESHOLDS, configure=_configure_adaptive))


def resolve_methods(names: str | Iterable[str]) -> list[Method]:
    """Parse ``grid,jitter,...`` into methods; UsageError names an unknown one."""
    if isinstance(names, str):
        names = [n.strip() for n in names.split(",")]
    names = [n for n in names if n]
    if not names:
        raise UsageError("--samplers: expected a comma-separated list of sampler names")
    methods, seen = [], set()
    for name in names:
        if name not in METHODS:
            raise UsageError(f"--samplers: unknown sampler {name!r}; expected some of "
                             f"{', '.join(sorted(METHODS))}")
        if name not in seen:
            seen.add(name)
            methods.append(METHODS[name])
    return methods


# ------------------------------------------------------------------------ scene set-up
def _property(tag: str, name: str, value: Any) -> ET.Element:
    return ET.Element(tag, {"name": name, "value": str(value)})


def configure_scene(xml_text: str, method: Method, value: float) -> str:
    """The scene XML text with ``method`` swapped in at sweep value ``value``.

    Sampler methods replace the ``<sampler>`` of every top-level ``<sensor>`` (adding
    one where a sensor has none) by ``<sampler type=plugin>`` holding only
    ``sample_count``: properties of the old sampler (which may not exist for the new
    type) are dropped. Integrator methods replace the ``<integrator>``.

    Raises UsageError for XML that does not parse or a scene without a sensor.
    """
    try:
        root = ET.fromstring(xml_text)
    except ET.ParseError as error:
        raise UsageError(f"scene: not valid XML ({error})") from None
    if method.configure is not None:
        method.configure(root, value)
    elif method.kind == "sampler":
        sensors = root.findall("sensor")
        if not sensors:
            raise UsageError("scene: no <sensor> element at the top level of the scene file "
                             "(compare swaps the sensor's <sampler>)")
        for sensor in sensors:
            old = sensor.findall("sampler")
            position = list(sensor).index(old[0]) if old else len(sensor)
            for element in old:
                sensor.remove(element)
            sampler = ET.Element("sampler", {"type": method.plugin})
            sampler.append(_property("integer", "sample_count", int(value)))
            sensor.insert(position, sampler)
    else:
        old = root.findall("integrator")
        position = list(root).index(old[0]) if old else 0
        for element in old:
            root.remove(element)
        integrator = ET.Element("integrator", {"type": method.plugin})
        integrator.append(_property("float", method.parameter, float(value)))
        root.insert(position, integrator)
    return ET.tostring(root, encoding="unicode")


def scene_key(scene_path: str | os.PathLike, params: dict[str, str] | None = None) -> str:
    """A short hash of the scene file's bytes and parameters (cache validity)."""
    digest = hashlib.sha1(Path(scene_path).read_bytes())
    digest.update(json.dumps(sorted((params or {}).items())).encode())
    return digest.hexdigest()[:12]


def load_configured_scene(scene_path: str | os.PathLike, method: Method, value: float,
                          params: dict[str, str] | None = None):
    """Load ``scene_path`` with ``method`` swapped in; relative paths resolve as in the file.

    Pointillist must be set up (:func:`pointillist.setup`).
    """
    import mitsuba as mi

    from pointillist.scene import mitsuba_message

    path = Path(scene_path)
    if not path.is_file():
        raise UsageError(f"scene: no such file: {path}")
    text = configure_scene(path.read_text(), method, value)
    resolver = mi.file_resolver()
    saved = mi.FileResolver(resolver)
    resolver.prepend(str(path.resolve().parent))
    try:
        # parallel=False as in pointillist.scene.load_scene: the parallel loader failed about one
        # run in ten here (hdrfilm: std::bad_alloc) and orders plugins (hence kernels) randomly.
        return mi.load_string(text, parallel=False, **(params or {}))
    except RuntimeError as error:
        raise UsageError(f"scene {path} with {method.name}: {mitsuba_message(error)}") from None
    finally:
        resolver.clear()
        for i in range(len(saved)):
            resolver.append(saved[i])


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
        parameter = METHODS[self.method].parameter if self.method in METHODS else "spp"
        return f"{self.method}_{parameter}{value}_seed{self.seed}"


@dataclass
class RenderRecord:
    """What :func:`render_one` returns (and stores as JSON beside the EXR).

    Times in seconds: ``time`` is the timed render's wall time without its JIT
    compilation (trace + kernel execution), the figure the comparison plots;
    ``compile`` is its JIT compilation plus, for a method's first render in a process,
    that of the untimed warm-up render (:func:`render_one`).
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
    cached: bool = False
    rmse: float = math.nan
    relmse: float = math.nan
    flip: float = math.nan

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
    warm-up's compile time is added to the record's ``compile``.

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
    from pointillist.commands.render import write_render
    from pointillist.scene import scene_info, timed_render

    spec = METHODS[method]
    scene = load_configured_scene(scene_path, spec, value, params)
    spp = int(value) if spec.parameter == "spp" else None
    warm_compile = 0.0
    if warm_up and method not in _WARMED:
        warm_compile = timed_render(scene, spp=spp, seed=int(seed))[1].compile
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
        compile=timing.compile + warm_compile, execute=timing.execute, total=timing.total,
        time=max(timing.total - timing.compile, 0.0), kernels=timing.kernels,
        cache_hits=timing.cache_hits, scene_key=key)
    _write_json(record_path, record.as_dict())
    return record


def render_reference(scene_path: str, params: dict[str, str] | None, out_dir: str, spp: int,
                     key: str | None = None) -> Path:
    """Render (or reuse) the reference: :data:`REFERENCE_SAMPLER` at ``spp``; returns its EXR."""
    record = render_one(scene_path, REFERENCE_SAMPLER, spp, REFERENCE_SEED, params,
                        str(Path(out_dir) / "reference"), key, warm_up=False)
    return Path(out_dir) / "reference" / "renders" / record.exr


# ----------------------------------------------------------------------------- errors
def _rgb(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image, dtype=np.float64)
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, axis=2)
    return image[..., :3]


def image_errors(image: np.ndarray, reference: np.ndarray, *, flip: bool = True) -> dict[str, float]:
    """RMSE, relative MSE and HDR-FLIP of ``image`` against ``reference``.

    - ``rmse = sqrt(mean((x - r)^2))`` over all pixels and RGB channels;
    - ``relmse = mean((x - r)^2 / (r^2 + 0.01))`` (:data:`RELMSE_EPSILON`);
    - ``flip``: mean HDR-FLIP (flip-evaluator, linear sRGB input, default viewing
      conditions), NaN values and negatives set to 0 first.

    Non-finite pixels of ``image`` make RMSE and relative MSE non-finite (they are
    reported, not hidden). Grey (H, W) images are compared as RGB.

    Examples
    --------
    >>> import numpy as np
    >>> ref = np.full((4, 4, 3), 0.5, np.float32)
    >>> e = image_errors(ref + 0.1, ref, flip=False)
    >>> round(e["rmse"], 6), round(e["relmse"], 6)
    (0.1, 0.038462)
    """
    x, r = _rgb(image), _rgb(reference)
    if x.shape != r.shape:
        raise ValueError(f"image: expected the reference's shape {r.shape[:2]}, got {x.shape[:2]}")
    diff2 = (x - r) ** 2
    result = {"rmse": float(np.sqrt(diff2.mean())),
              "relmse": float((diff2 / (r * r + RELMSE_EPSILON)).mean()),
              "flip": math.nan}
    if flip:
        import flip_evaluator

        def clean(a):
            return np.ascontiguousarray(np.clip(np.nan_to_num(a, nan=0.0, posinf=1e4), 0.0, 1e4),
                                        dtype=np.float32)

        reference = clean(r)
        _, mean, _ = flip_evaluator.evaluate(reference, clean(x), "HDR", applyMagma=False,
                                             **_flip_exposures(reference))
        result["flip"] = float(mean)
    return result


def _flip_exposures(reference: np.ndarray) -> dict[str, Any]:
    """HDR-FLIP's own exposure range, except where flip-evaluator would exit the process.

    flip-evaluator takes start = log2(x_max / Y_max) and stop = log2(x_max / Y_median) from the
    reference's luminance and calls ``exit`` ("Start exposure must be smaller than stop exposure!")
    when rounding puts start above stop (a constant reference of 1e-7) or the reference is black.
    In those cases (median luminance = maximum) both are passed explicitly as the one exposure
    log2(x_max / Y_max) (0 for a black reference), which is what flip-evaluator uses when they tie.
    """
    luminance = reference @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    y_max, y_median = float(luminance.max()), float(np.median(luminance))
    if y_median < y_max * (1 - 1e-5):
        return {}
    exposure = math.log2(_FLIP_ACES_X_MAX / y_max) if y_max > 0 else 0.0
    return {"parameters": {"startExposure": exposure, "stopExposure": exposure}}


def _aces_x_max(t: float = 0.85) -> float:
    """HDR-FLIP's x_max: where the ACES fit (with FLIP's 0.6 pre-exposure) reaches t (Andersson et al. 2021)."""
    k0, k1, k2, k3, k4, k5 = 0.36 * 2.51, 0.6 * 0.03, 0.0, 0.36 * 2.43, 0.6 * 0.59, 0.14
    c0, c1 = (k1 - k4 * t) / (k0 - k3 * t), (k2 - k5 * t) / (k0 - k3 * t)
    return -0.5 * c0 + math.sqrt(0.25 * c0 * c0 - c1)


_FLIP_ACES_X_MAX = _aces_x_max()


def fit_slope(x: Sequence[float], y: Sequence[float]) -> float:
    """Least-squares slope of log(y) against log(x); NaN with fewer than two usable points."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y) & (x > 0) & (y > 0)
    if np.unique(x[ok]).size < 2:
        return math.nan
    return float(np.polyfit(np.log(x[ok]), np.log(y[ok]), 1)[0])


# ------------------------------------------------------------------------------ sweep
def run_sweep(scene_path: str, tasks: Sequence[Task], *, params: dict[str, str] | None, out_dir: str,
              reference: Path, progress: bool = True,
              render: Callable[..., RenderRecord] = render_one) -> list[RenderRecord]:
    """Run ``tasks`` (skipping finished ones), then score each render against ``reference``."""
    from tqdm import tqdm

    from pointillist.imaging.io import read_exr

    key = scene_key(scene_path, params)
    ref_image = read_exr(reference).image
    records = []
    bar = tqdm(tasks, desc="compare", unit="render", disable=not progress)
    for task in bar:
        bar.set_postfix_str(task.stem)
        records.append(render(scene_path, task.method, task.value, task.seed, params, out_dir, key))
    for record in records:
        image = read_exr(Path(out_dir) / "renders" / record.exr).image
        record.__dict__.update(image_errors(image, ref_image))
    return records


def summarise(records: Sequence[RenderRecord]) -> list[dict[str, Any]]:
    """Mean and standard deviation over seeds per (method, value)."""
    groups: dict[tuple[str, float], list[RenderRecord]] = {}
    for record in records:
        groups.setdefault((record.method, record.value), []).append(record)
    rows = []
    for (method, value), group in groups.items():
        row: dict[str, Any] = {"method": method, "value": value, "seeds": len(group)}
        for name in ("spp", "time", "compile", "rmse", "relmse", "flip"):
            data = np.array([getattr(r, name) for r in group], float)
            row[name] = float(data.mean())
            row[f"{name}_std"] = float(data.std(ddof=1)) if len(data) > 1 else 0.0
        row["mse"] = float(np.mean([r.rmse ** 2 for r in group]))
        rows.append(row)
    return rows


def slopes(rows: Sequence[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Fitted log-log slopes per method: MSE against spp and against time."""
    result = {}
    for method in dict.fromkeys(r["method"] for r in rows):
        mine = [r for r in rows if r["method"] == method]
        result[method] = {"mse_vs_spp": fit_slope([r["spp"] for r in mine], [r["mse"] for r in mine]),
                          "mse_vs_time": fit_slope([r["time"] for r in mine], [r["mse"] for r in mine])}
    return result


def equal_time_ranking(rows: Sequence[dict[str, Any]], budgets: Sequence[float] | None = None,
                       metric: str = "mse") -> list[tuple[float, list[tuple[str, float]]]]:
    """For each time budget, the methods ranked by the lowest ``metric`` reached within it.

    A method reaches, within budget ``T``, the lowest mean error among its sweep
    points whose mean render time is at most ``T``; methods with no point that fast
    are left out of that budget. Default budgets: 6 log-spaced times from the
    fastest to the slowest mean render.
    """
    times = np.array([r["time"] for r in rows], float)
    if budgets is None:
        lo, hi = float(times.min()), float(times.max())
        budgets = np.geomspace(lo, hi, 6) if hi > lo else [hi]
    ranking = []
    for budget in budgets:
        best: dict[str, float] = {}
        for r in rows:
            if r["time"] <= budget * (1 + 1e-9) and np.isfinite(r[metric]):
                best[r["method"]] = min(best.get(r["method"], math.inf), r[metric])
        ranking.append((float(budget), sorted(best.items(), key=lambda kv: kv[1])))
    return ranking


def equal_error_ranking(rows: Sequence[dict[str, Any]], budgets: Sequence[float] | None = None,
                        metric: str = "rmse") -> list[tuple[float, list[tuple[str, float, float]]]]:
    """For each error budget, the methods ranked by the shortest time reaching it.

    The dual of :func:`equal_time_ranking`: a method reaches budget ``E`` with its
    fastest sweep point whose mean ``metric`` is at most ``E``; methods with no point
    that accurate are left out of that budget. Each entry is ``(method, value,
    time)``. Default budgets: the errors of the first method's points in ``rows``
    (e.g. ``jitter`` at each spp, so a line answers "how long does each method take
    to get as close as jitter at 16 spp").

    Examples
    --------
    >>> rows = [{"method": "a", "value": 4, "time": 1.0, "rmse": 0.2},
    ...         {"method": "b", "value": 64, "time": 0.5, "rmse": 0.1}]
    >>> equal_error_ranking(rows)
    [(0.2, [('b', 64.0, 0.5), ('a', 4.0, 1.0)])]
    """
    if budgets is None:
        first = rows[0]["method"] if rows else None
        budgets = [r[metric] for r in rows if r["method"] == first]
    ranking = []
    for budget in budgets:
        best: dict[str, tuple[float, float]] = {}
        for r in rows:
            if r[metric] <= budget * (1 + 1e-9) and np.isfinite(r["time"]):
                if r["time"] < best.get(r["method"], (math.inf, math.inf))[1]:
                    best[r["method"]] = (float(r["value"]), float(r["time"]))
        ranked = sorted(((m, v, t) for m, (v, t) in best.items()), key=lambda entry: entry[2])
        ranking.append((float(budget), ranked))
    return ranking


def setting_label(method: str, value: float) -> str:
    """The sweep point as people read it: ``16 spp`` for a sampler, ``threshold 64``
    for an integrator method (its :attr:`Method.parameter`)."""
    spec = METHODS.get(method)
    parameter = spec.parameter if spec is not None else "spp"
    return f"{value:g} spp" if parameter == "spp" else f"{parameter} {value:g}"


def _sweeps_spp(method: str) -> bool:
    spec = METHODS.get(method)
    return spec is None or spec.parameter == "spp"


_CSV_FIELDS = ("method", "value", "seed", "spp", "time", "compile", "trace", "execute", "total",
               "kernels", "cache_hits", "rmse", "relmse", "flip", "width", "height", "exr")


def write_report(records: Sequence[RenderRecord], out_dir: str | os.PathLike, *, scene: str,
                 reference: str, title: str | None = None) -> dict[str, Path]:
    """Write results.csv, results.md, error_vs_time.png and error_vs_spp.png into ``out_dir``."""
    from pointillist.imaging.io import atomic_write

    out = Path(out_dir)
    paths = {"csv": out / "results.csv", "md": out / "results.md",
             "time_plot": out / "error_vs_time.png", "spp_plot": out / "error_vs_spp.png"}
    def write_csv(tmp: str) -> None:
        with open(tmp, "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=_CSV_FIELDS, extrasaction="ignore")
            writer.writeheader()
            for record in records:
                row = record.as_dict()
                row["exr"] = f"renders/{record.exr}"
                writer.writerow(row)

    atomic_write(paths["csv"], write_csv)

    rows = summarise(records)
    fitted = slopes(rows)
    lines = [f"# {title or 'Sampler comparison'}", "",
             f"Scene `{scene}`, reference `{reference}`. Errors against the reference; time = render "
             "wall time without JIT compilation (compile listed apart); mean ± standard deviation "
             "over seeds. relMSE uses epsilon 0.01; FLIP is HDR-FLIP.", "",
             "| method | setting | spp | seeds | time (s) | compile (s) | RMSE | relMSE | FLIP |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['method']} | {setting_label(r['method'], r['value'])} | {r['spp']:.4g} | {r['seeds']} "
                     f"| {r['time']:.3f} ± {r['time_std']:.3f} "
                     f"| {r['compile']:.3f} | {r['rmse']:.5f} ± {r['rmse_std']:.5f} "
                     f"| {r['relmse']:.3e} | {r['flip']:.4f} |")
    lines += ["", "spp: samples per pixel taken (an adaptive method's mean over the pixels).", "",
              "## Fitted log-log slopes (least squares over the sweep)", "",
              "| method | MSE vs spp | MSE vs time |", "|---|---:|---:|"]
    for method, s in fitted.items():
        if _sweeps_spp(method):
            lines.append(f"| {method} | {s['mse_vs_spp']:.2f} | {s['mse_vs_time']:.2f} |")
        else:
            lines.append(f"| {method} | – | – |")
    if not all(_sweeps_spp(method) for method in fitted):
        lines += ["", "–: the method sweeps another parameter than spp; a fit over that sweep is not "
                  "a convergence rate."]
    lines += ["", "## Equal-time ranking (lowest MSE reached within each time budget)", "",
              "| budget (s) | ranking (MSE) |", "|---:|---|"]
    for budget, ranked in equal_time_ranking(rows):
        text = ", ".join(f"{i + 1}. {m} ({e:.2e})" for i, (m, e) in enumerate(ranked)) or "none"
        lines.append(f"| {budget:.3f} | {text} |")
    anchors = [r for r in rows if r["method"] == rows[0]["method"]] if rows else []
    lines += ["", "## Equal-error ranking (fastest render reaching each RMSE)", "",
              f"Budgets: the RMSE of each {anchors[0]['method'] if anchors else ''} point; times relative to "
              "that point's.", "",
              "| RMSE budget (from) | ranking (time) |", "|---|---|"]
    for anchor, (budget, ranked) in zip(anchors, equal_error_ranking(rows, [a["rmse"] for a in anchors])):
        text = ", ".join(f"{i + 1}. {m} {setting_label(m, v)} ({t:.3f} s, {t / anchor['time']:.2f}x)"
                         if anchor["time"] > 0 else f"{i + 1}. {m} {setting_label(m, v)} ({t:.3f} s)"
                         for i, (m, v, t) in enumerate(ranked))
        lines.append(f"| {budget:.5f} ({anchor['method']} {setting_label(anchor['method'], anchor['value'])}, "
                     f"{anchor['time']:.3f} s) | {text} |")
    atomic_write(paths["md"], lambda tmp: Path(tmp).write_text("\n".join(lines) + "\n"))

    _plot(rows, fitted, "time", "render time without JIT compile (s)", "mse_vs_time", paths["time_plot"])
    _plot(rows, fitted, "spp", "samples per pixel", "mse_vs_spp", paths["spp_plot"])
    return paths


def _plot(rows, fitted, x_name: str, x_label: str, slope_name: str, path: Path) -> None:
    from pointillist.imaging.io import atomic_write

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.8), dpi=110)
    xs_all, ys_all = [], []
    for method in dict.fromkeys(r["method"] for r in rows):
        spp_sweep = _sweeps_spp(method)
        mine = [r for r in rows if r["method"] == method]  # another parameter: in sweep order
        if spp_sweep:
            mine.sort(key=lambda r: r[x_name])
        x = np.array([r[x_name] for r in mine])
        y = np.array([r["mse"] for r in mine])
        err = np.array([2 * r["rmse"] * r["rmse_std"] for r in mine])  # std of MSE, first order
        ok = (x > 0) & (y > 0)
        xs_all += list(x[ok])
        ys_all += list(y[ok])
        label = f"{method} (slope {fitted[method][slope_name]:.2f})" if spp_sweep else \
            f"{method} ({METHODS[method].parameter} labelled)"
        ax.errorbar(x[ok], y[ok], yerr=err[ok], marker="o", capsize=2, label=label)
        if not spp_sweep:  # a threshold sweep: say which point is which
            for xi, yi, r in zip(x[ok], y[ok], [r for r, good in zip(mine, ok) if good]):
                ax.annotate(f"{r['value']:g}", (xi, yi), textcoords="offset points", xytext=(4, 4), fontsize=7)
    if xs_all:
        x0, y0 = min(xs_all), max(ys_all)
        x1 = max(xs_all)
        for slope, style in ((-1, ":"), (-1.5, "--"), (-2, "-.")):
            ax.plot([x0, x1], [y0, y0 * (x1 / x0) ** slope], style, color="grey", linewidth=1,
                    label=f"slope {slope:g}")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(x_label)
    ax.set_ylabel("MSE against the reference")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    try:
        atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))
    finally:
        plt.close(fig)
