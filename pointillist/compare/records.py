"""What a comparison keeps on disk: each render's record, its stored scores, the scene's facts.

Every render of a sweep is a :class:`Task` (method, sweep value, seed) whose EXR and JSON
:class:`RenderRecord` lie in ``DIR/renders/<scene key>/`` (:func:`task_paths`); a record counts
only with its EXR, for the same scene key, and when that EXR still reads back
(:func:`load_record`). A render's scores (its errors in the record; its error spectrum and, for
a seed-0 render, the per-pixel maps in ``<task>.maps.npz``) are valid for the render file and
the reference's pixels they were computed from (:func:`scores_key`). What the scene itself
renders (size, film filter) is kept once per scene key (:class:`SceneFacts`), so that a rerun
whose renders are all cached does not build the scene to learn it.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from pointillist.core import signals
from pointillist.compare.methods import sweep_parameter
from pointillist.core.digests import json_key

__all__ = ["Task", "RenderRecord", "task_paths", "load_record", "record_json", "write_json", "SCORES_VERSION",
           "scores_key", "image_digest", "maps_path", "MAP_NAMES", "load_scores", "save_scores", "SceneFacts",
           "load_scene_facts", "save_scene_facts"]


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
    """What :func:`pointillist.compare.sweep.render_one` returns (and stores as JSON beside the EXR).

    Times in seconds, each reported apart: ``trace``, ``compile``, ``execute`` and
    ``total`` are those of the timed render (``total`` its wall time, which includes
    the other three); ``time = total - compile`` is the figure the comparison plots
    (trace + kernel execution). ``warm_up`` is the wall time of the untimed warm-up
    render before a method's first render in a process (0 without one) and
    ``warm_up_compile`` its JIT compilation (:func:`pointillist.compare.sweep.render_one`).
    ``spp`` is the samples per pixel actually taken (the sampler may round the
    requested count; adaptive methods report their mean). ``rmse``, ``relmse`` and
    ``flip`` are the errors against the reference once scored (:func:`pointillist.compare.sweep.run_sweep`), and
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

def load_record(path: Path, key: str, exr: Path) -> tuple[RenderRecord | None, str]:
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


def write_json(path: Path, data: dict) -> None:
    """Write ``data`` as indented JSON into ``path``, atomically."""
    from pointillist.core.files import atomic_write

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
MAP_NAMES = ("relmse", "flip")


def load_scores(path: Path, key: str, *, maps: bool) -> dict[str, Any] | None:
    """What :func:`save_scores` stored at ``path`` for ``key``: the error spectrum and, with ``maps``,
    the relmse and flip maps; None when missing, stale or unreadable."""
    from pointillist.imaging.spectrum import RadialSpectrum

    try:
        with np.load(path) as stored:
            if str(stored["scores_key"]) != key:
                return None
            found: dict[str, Any] = {"spectrum": RadialSpectrum(stored["spectrum_frequency"], stored["spectrum_power"],
                                                                stored["spectrum_count"])}
            if maps:
                found.update({name: stored[name] for name in MAP_NAMES})
            return found
    except (OSError, KeyError, ValueError):
        return None


def save_scores(path: Path, key: str, scores: dict[str, Any], *, maps: bool) -> None:
    """Store a render's error spectrum (and with ``maps`` its :data:`MAP_NAMES` maps) for ``key`` at ``path``."""
    from pointillist.core.files import atomic_write

    spectrum = scores["spectrum"]
    arrays = dict(scores_key=np.array(key), spectrum_frequency=spectrum.frequency, spectrum_power=spectrum.power,
                  spectrum_count=spectrum.count)
    if maps:
        arrays.update({name: scores[name] for name in MAP_NAMES})
    atomic_write(path, lambda tmp: np.savez(tmp, **arrays))


# ------------------------------------------------------------------------------ the scene's facts
@dataclass(frozen=True)
class SceneFacts:
    """What the scene of one scene key renders, learnt by building it once: its film's size and
    reconstruction filter (as Mitsuba prints it, :func:`pointillist.scene.film_filter`)."""

    width: int
    height: int
    film_filter: str


def _facts_path(out_dir: str | os.PathLike, key: str) -> Path:
    return Path(out_dir) / "renders" / key / "scene.json"


def load_scene_facts(out_dir: str | os.PathLike, key: str) -> SceneFacts | None:
    """The :class:`SceneFacts` stored for scene key ``key`` in the comparison folder; None when
    missing or unreadable (the scene is then built to learn them)."""
    try:
        data = json.loads(_facts_path(out_dir, key).read_text())
        facts = SceneFacts(width=data["width"], height=data["height"], film_filter=data["film_filter"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    ok = all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in (facts.width, facts.height))
    return facts if ok and isinstance(facts.film_filter, str) else None


def save_scene_facts(out_dir: str | os.PathLike, key: str, facts: SceneFacts) -> Path:
    """Store ``facts`` for scene key ``key`` (``DIR/renders/<key>/scene.json``); returns the path."""
    path = _facts_path(out_dir, key)
    with signals.new_folders(path):
        write_json(path, asdict(facts))
    return path
