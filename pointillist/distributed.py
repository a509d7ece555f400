"""Renders as tasks on Dask distributed: sweeps, tiled big renders, an on-disk result cache.

pointillist does not schedule work itself; it hands independent renders to
`Dask distributed <https://distributed.dask.org>`_ as tasks:

* :func:`open_client` gives a Dask client for ``--workers N`` (a
  :class:`distributed.LocalCluster` of N worker processes on loopback, one task
  thread each) or ``--scheduler ADDRESS`` (an existing cluster), or ``None``
  for the default serial, in-process run.
* :class:`PointillistWorker` (a Dask ``WorkerPlugin``) makes every worker set
  the Mitsuba variant and register pointillist's plugins itself; every task
  function also does so (idempotently), so a worker that joins later or is
  restarted after a crash is ready too.
* :func:`run_tasks` runs a list of tasks (serially, or on the client), keeps
  each result in an on-disk :class:`ResultCache` as soon as it arrives, and
  reuses cached results: a restarted command redoes only what is missing. A
  task whose worker dies is re-run on another worker by the scheduler (up to
  ``distributed.scheduler.allowed-failures`` times, 3 by default); a task that
  raises is retried ``retries`` times.
* :func:`render_task` renders one :class:`RenderTask` (scene, parameters, spp,
  seed, optional crop window) and measures its timing on the worker, so
  error-against-time tables stay honest.
* :func:`render_tiled` splits the film into ``rows x cols`` tiles with
  Mitsuba's crop window (``film.crop_offset`` / ``film.crop_size``), renders
  each tile as a task with its own seed and assembles the image.

Seeds of tiles
--------------
Tile ``i`` of ``K = rows * cols`` tiles renders with seed
``(seed * K + i) mod 2**32`` (:func:`tile_seed`): distinct for every tile of
one render and for every base seed of one tiling (until the 32-bit wrap), so
tiles never share a random stream. A ``1x1`` tiling uses ``seed`` itself and
equals the untiled render. Mitsuba's samplers key their stream on the
*wavefront lane* (pixel index inside the crop window times spp plus the sample
index), so a tiled render is a different, equally valid, sample of the same
estimator as the untiled one: they agree exactly (to float rounding) for
estimators that use no random numbers (e.g. the ``aov`` integrator with an
unjittered ``stratified`` sampler at 1 spp), and statistically otherwise. With
a reconstruction filter wider than the ``box`` filter, pixels at tile edges
miss the splats of samples in the neighbouring tile unless the film has
``sample_border=true``.

What workers need
-----------------
Each worker imports ``pointillist`` (same version, with its plugins, Mitsuba
and Dr.Jit, a usable libLLVM) and reads the scene by the path the client
gives (an absolute path: use a shared file system or the same checkout path on
every machine). Results come back to the client; the cache lives on the
client's disk.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import os
import pickle
import re
import socket
import time
from collections import OrderedDict
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pointillist.errors import UsageError

try:
    from distributed import WorkerPlugin as _WorkerPluginBase
except ImportError:  # pragma: no cover - the optional 'distributed' extra is not installed
    _WorkerPluginBase = object

__all__ = [
    "DEFAULT_RETRIES",
    "Tile",
    "parse_tiles",
    "tile_grid",
    "tile_seed",
    "PointillistWorker",
    "start_cluster",
    "connect",
    "open_client",
    "RenderTask",
    "RenderResult",
    "render_task",
    "task_key",
    "ResultCache",
    "run_tasks",
    "TiledRender",
    "assemble_tiles",
    "render_tiled",
    "render_command",
    "compare_task",
    "prerender_sweep",
    "mip_frame_task",
    "project_frames",
]

#: How often a task that raises is re-run (``retries=`` of ``Client.submit``).
DEFAULT_RETRIES = 2

#: Version of the cache file layout and key scheme; bump to invalidate caches.
CACHE_FORMAT = 1

_TILES = re.compile(r"^\s*(\d+)\s*[xX]\s*(\d+)\s*$")


# --------------------------------------------------------------------------- tiles
@dataclasses.dataclass(frozen=True)
class Tile:
    """One tile of a film: its index (row-major) and its window in film pixels."""

    index: int
    x: int
    y: int
    width: int
    height: int

    @property
    def crop(self) -> tuple[int, int, int, int]:
        """``(offset_x, offset_y, width, height)`` for the film's crop window."""
        return (self.x, self.y, self.width, self.height)


def parse_tiles(text: str) -> tuple[int, int]:
    """Parse ``"RxC"`` (rows x columns, e.g. ``"4x4"``) into ``(rows, cols)``.

    Raises
    ------
    ValueError
        Unless both are integers >= 1.

    Examples
    --------
    >>> parse_tiles("2x3")
    (2, 3)
    """
    match = _TILES.match(str(text))
    if not match:
        raise ValueError(f"tiles: expected ROWSxCOLS such as 4x4, got {text!r}")
    rows, cols = int(match.group(1)), int(match.group(2))
    if rows < 1 or cols < 1:
        raise ValueError(f"tiles: rows and columns must be >= 1, got {text!r}")
    return rows, cols


def tile_grid(width: int, height: int, rows: int, cols: int, *, x: int = 0, y: int = 0) -> list[Tile]:
    """Split a ``width x height`` window at ``(x, y)`` into ``rows x cols`` tiles.

    Tile edges are at ``x + (j * width) // cols`` and ``y + (i * height) // rows``:
    tiles cover the window exactly once, and their sizes differ by at most one
    pixel. Tiles are numbered row-major.

    Raises
    ------
    ValueError
        If ``rows > height`` or ``cols > width`` (a tile would be empty), or a
        size is not positive.

    Examples
    --------
    >>> [t.crop for t in tile_grid(5, 2, 1, 2)]
    [(0, 0, 2, 2), (2, 0, 3, 2)]
    """
    for name, value in (("width", width), ("height", height), ("rows", rows), ("cols", cols)):
        if int(value) != value or value < 1:
            raise ValueError(f"{name}: expected an integer >= 1, got {value!r}")
    if rows > height or cols > width:
        raise ValueError(f"tiles: {rows}x{cols} tiles do not fit a {width}x{height} film "
                         "(at most one tile per pixel row/column)")
    xs = [x + (j * width) // cols for j in range(cols + 1)]
    ys = [y + (i * height) // rows for i in range(rows + 1)]
    return [Tile(i * cols + j, xs[j], ys[i], xs[j + 1] - xs[j], ys[i + 1] - ys[i])
            for i in range(rows) for j in range(cols)]


def tile_seed(seed: int, index: int, count: int) -> int:
    """The sample seed of tile ``index`` of ``count``: ``(seed * count + index) mod 2**32``.

    Distinct for the ``count`` tiles of one render; ``count == 1`` gives ``seed``.

    Examples
    --------
    >>> [tile_seed(3, i, 4) for i in range(4)]
    [12, 13, 14, 15]
    """
    if not 0 <= index < count:
        raise ValueError(f"index: expected 0 <= index < {count}, got {index}")
    if not 0 <= seed < 2**32:
        raise ValueError(f"seed: expected an integer in 0..2^32-1, got {seed}")
    return (seed * count + index) % 2**32


# --------------------------------------------------------------------------- workers and clients
def _setup_process(drjit_threads: int | None = None):
    """Set the variant and register the plugins in this process (idempotent); returns ``mitsuba``."""
    import pointillist

    mi = pointillist.setup()
    if drjit_threads:
        import drjit as dr

        if dr.thread_count() != drjit_threads:
            dr.set_thread_count(drjit_threads)
    return mi


class PointillistWorker(_WorkerPluginBase):
    """Dask ``WorkerPlugin``: each worker sets ``llvm_ad_rgb`` and registers the plugins.

    ``drjit_threads`` caps Dr.Jit's thread pool of the worker (``None`` keeps
    Dr.Jit's default, one thread per core): N workers on one C-core machine
    should use about C / N threads each. Register with
    ``client.register_plugin(PointillistWorker())``; workers that join later
    (or are restarted after a crash) run it too.
    """

    name = "pointillist-setup"

    def __init__(self, drjit_threads: int | None = None):
        if drjit_threads is not None and (int(drjit_threads) != drjit_threads or drjit_threads < 1):
            raise ValueError(f"drjit_threads: expected an integer >= 1 or None, got {drjit_threads!r}")
        self.drjit_threads = drjit_threads

    def setup(self, worker):  # noqa: D401 - Dask API
        _setup_process(self.drjit_threads)


def _need_dask():
    if _WorkerPluginBase is object:
        raise UsageError("--workers/--scheduler need Dask distributed: pip install 'pointillist[distributed]'")


def start_cluster(n_workers: int, *, drjit_threads: int | None = None, quiet: bool = True):
    """Start a :class:`distributed.LocalCluster` of ``n_workers`` processes; return its Client.

    Loopback only (``127.0.0.1``), one task thread per worker, no dashboard.
    Each worker gets ``drjit_threads`` Dr.Jit threads (default: cores // workers,
    at least 1). Close with ``client.close(); client.cluster.close()`` or use
    :func:`open_client`.
    """
    if int(n_workers) != n_workers or n_workers < 1:
        raise ValueError(f"n_workers: expected an integer >= 1, got {n_workers!r}")
    _need_dask()
    import logging

    from distributed import Client, LocalCluster

    if drjit_threads is None:
        drjit_threads = max(1, (os.cpu_count() or 1) // int(n_workers))
    cluster = LocalCluster(n_workers=int(n_workers), threads_per_worker=1, processes=True,
                           host="127.0.0.1", dashboard_address=None,
                           silence_logs=logging.ERROR if quiet else logging.WARNING)
    client = Client(cluster)
    client.register_plugin(PointillistWorker(drjit_threads))
    return client


def connect(address: str, *, timeout: float = 10.0, drjit_threads: int | None = None):
    """Connect to a running Dask scheduler at ``address``; return the Client.

    Raises
    ------
    UsageError
        If no scheduler answers within ``timeout`` seconds.
    """
    _need_dask()
    from distributed import Client

    if not isinstance(address, str) or not address.strip():
        raise UsageError(f"--scheduler: expected an address such as tcp://host:8786, got {address!r}")
    try:
        client = Client(address.strip(), timeout=timeout)
    except (OSError, TimeoutError, ValueError) as error:
        raise UsageError(f"--scheduler: cannot connect to {address}: {error}") from None
    client.register_plugin(PointillistWorker(drjit_threads))
    return client


@contextlib.contextmanager
def open_client(workers: int | None = None, scheduler: str | None = None) -> Iterator[Any]:
    """Context manager: a Dask client for ``workers`` or ``scheduler``, or ``None`` (serial).

    Raises UsageError if both are given. The local cluster (``workers``) is
    shut down on exit; a remote cluster (``scheduler``) is only disconnected.
    """
    if workers is not None and scheduler is not None:
        raise UsageError("--workers and --scheduler: give one or the other, not both")
    if workers is None and scheduler is None:
        yield None
        return
    client = start_cluster(workers) if workers is not None else connect(scheduler)
    try:
        yield client
    finally:
        cluster = client.cluster if workers is not None else None
        client.close()
        if cluster is not None:
            cluster.close()


# --------------------------------------------------------------------------- render tasks
@dataclasses.dataclass(frozen=True)
class RenderTask:
    """One render: what :func:`render_task` needs, picklable and hashable.

    Attributes
    ----------
    scene : str
        Scene XML path (absolute paths work on every worker that sees it).
    params : tuple of (str, str)
        Scene parameters (``$key`` overrides), sorted; a dict is accepted.
    spp : int or None
        Samples per pixel (None: the scene's).
    seed : int
        Sample seed, 0..2^32-1.
    sensor : int
        Sensor index.
    crop : tuple of 4 ints or None
        ``(offset_x, offset_y, width, height)`` film crop window in film
        pixels; None renders the scene's own window.
    """

    scene: str
    params: tuple[tuple[str, str], ...] = ()
    spp: int | None = None
    seed: int = 0
    sensor: int = 0
    crop: tuple[int, int, int, int] | None = None

    def __post_init__(self):
        params = self.params
        if isinstance(params, dict):
            params = tuple(sorted((str(k), str(v)) for k, v in params.items()))
        else:
            params = tuple(sorted((str(k), str(v)) for k, v in params))
        object.__setattr__(self, "params", params)
        object.__setattr__(self, "scene", str(self.scene))
        if self.spp is not None and (int(self.spp) != self.spp or self.spp < 1):
            raise ValueError(f"spp: expected an integer >= 1 or None, got {self.spp!r}")
        if int(self.seed) != self.seed or not 0 <= self.seed < 2**32:
            raise ValueError(f"seed: expected an integer in 0..2^32-1, got {self.seed!r}")
        if self.crop is not None:
            crop = tuple(int(v) for v in self.crop)
            if len(crop) != 4 or min(crop[:2]) < 0 or min(crop[2:]) < 1:
                raise ValueError(f"crop: expected (offset_x >= 0, offset_y >= 0, width >= 1, height >= 1), "
                                 f"got {self.crop!r}")
            object.__setattr__(self, "crop", crop)

    def cache_token(self) -> dict[str, Any]:
        """What identifies the result: the fields plus the scene file's SHA-256."""
        token = dataclasses.asdict(self)
        token["scene_sha256"] = _file_digest(self.scene)
        return token


@dataclasses.dataclass
class RenderResult:
    """What :func:`render_task` returns.

    ``image`` is float32 (H, W, C) numpy; ``timing`` holds the seconds of
    :class:`pointillist.scene.RenderTiming` measured on the worker plus
    ``load`` (scene loading, 0 when the worker had the scene loaded);
    ``worker`` is ``host:pid`` of the process that rendered it.
    """

    image: np.ndarray
    timing: dict[str, float]
    worker: str
    task: RenderTask


_SCENES: OrderedDict = OrderedDict()
_SCENE_CACHE_SIZE = 2


def _scene_for(task: RenderTask):
    """Load (or reuse) the task's scene in this process; returns (scene, sensor params, window, load s)."""
    import mitsuba as mi

    from pointillist.scene import load_scene

    path = Path(task.scene)
    try:
        stamp = path.stat().st_mtime_ns
    except OSError:
        raise UsageError(f"scene: no such file: {path}") from None
    key = (str(path.resolve()), stamp, task.params)
    entry = _SCENES.get(key)
    load_s = 0.0
    if entry is None:
        start = time.perf_counter()
        scene = load_scene(path, dict(task.params))
        load_s = time.perf_counter() - start
        entry = {"scene": scene, "sensors": {}}
        _SCENES[key] = entry
        while len(_SCENES) > _SCENE_CACHE_SIZE:
            _SCENES.popitem(last=False)
    _SCENES.move_to_end(key)
    scene = entry["scene"]
    sensors = scene.sensors()
    if not 0 <= task.sensor < len(sensors):
        raise ValueError(f"sensor: scene {path} has {len(sensors)} sensor(s), got index {task.sensor}")
    if task.sensor not in entry["sensors"]:
        params = mi.traverse(sensors[task.sensor])
        film = sensors[task.sensor].film()
        window = (*map(int, film.crop_offset()), *map(int, film.crop_size()))
        entry["sensors"][task.sensor] = (params, window, tuple(map(int, film.size())))
    params, window, size = entry["sensors"][task.sensor]
    return scene, params, window, size, load_s


def _set_crop(mi, params, crop, size) -> None:
    if crop[0] + crop[2] > size[0] or crop[1] + crop[3] > size[1]:
        raise ValueError(f"crop: window {crop} does not fit the {size[0]}x{size[1]} film")
    if tuple(map(int, params["film.crop_offset"])) + tuple(map(int, params["film.crop_size"])) == tuple(crop):
        return
    params["film.crop_offset"] = mi.ScalarPoint2u(crop[0], crop[1])
    params["film.crop_size"] = mi.ScalarVector2u(crop[2], crop[3])
    params.update()


def render_task(task: RenderTask) -> RenderResult:
    """Render one :class:`RenderTask` in this process (a Dask worker or the client).

    Sets up Mitsuba if needed, loads the scene (the last two scenes stay
    loaded per process), sets the film's crop window, renders with
    :func:`pointillist.scene.timed_render` and returns the image as numpy with
    the timing measured here.

    Raises
    ------
    UsageError
        For a missing or invalid scene file.
    ValueError
        For a sensor index or crop window outside the scene's film.
    """
    mi = _setup_process()
    from pointillist.scene import timed_render

    scene, params, window, size, load_s = _scene_for(task)
    _set_crop(mi, params, task.crop or window, size)
    image, timing = timed_render(scene, spp=task.spp, seed=task.seed, sensor=task.sensor)
    pixels = np.array(image, dtype=np.float32, copy=True)
    del image
    return RenderResult(image=pixels, timing=dict(timing.as_dict(), load=load_s),
                        worker=f"{socket.gethostname()}:{os.getpid()}", task=task)


# --------------------------------------------------------------------------- cache and task runner
_DIGESTS: dict[tuple[str, int, int], str] = {}


def _file_digest(path: str | os.PathLike) -> str:
    """SHA-256 of a file's bytes (memoised on path, size and mtime); '' if it does not exist."""
    try:
        stat = os.stat(path)
    except OSError:
        return ""
    key = (str(Path(path).resolve()), stat.st_size, stat.st_mtime_ns)
    if key not in _DIGESTS:
        _DIGESTS[key] = hashlib.sha256(Path(path).read_bytes()).hexdigest()
    return _DIGESTS[key]


def task_key(function: Callable, task: Any) -> str:
    """A stable key for ``function(task)``: SHA-256 of the function's name and the task's token.

    The token is ``task.cache_token()`` when the task has one (as
    :class:`RenderTask` does: its fields and the scene file's hash), else the
    task itself, which must then be JSON-serialisable (numbers, strings,
    lists, dicts). Scene assets other than the XML file (meshes, textures,
    included files) are not hashed: clear the cache when you change them.
    """
    token = task.cache_token() if hasattr(task, "cache_token") else task
    name = f"{getattr(function, '__module__', '?')}.{getattr(function, '__qualname__', repr(function))}"
    try:
        text = json.dumps({"format": CACHE_FORMAT, "function": name, "task": token},
                          sort_keys=True, default=_json_default)
    except TypeError as error:
        raise TypeError(f"task: cannot make a cache key from {type(task).__name__} ({error}); "
                        "give it a cache_token() method or pass keys=") from None
    return hashlib.sha256(text.encode()).hexdigest()


def _json_default(value):
    if isinstance(value, (tuple, set, frozenset)):
        return list(value)
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"{type(value).__name__} is not JSON-serialisable")


class ResultCache:
    """Task results on disk, one pickle file per key in ``directory``.

    Writes are atomic (temporary file, then rename), so a command killed
    mid-write leaves no half file; a file that cannot be read counts as
    missing. The files are pickles: only point this at your own folder.
    """

    def __init__(self, directory: str | os.PathLike):
        self.directory = Path(directory)
        if self.directory.exists() and not self.directory.is_dir():
            raise ValueError(f"cache: {self.directory} exists and is not a folder")
        self.directory.mkdir(parents=True, exist_ok=True)

    def path(self, key: str) -> Path:
        if not re.fullmatch(r"[0-9A-Za-z_.-]+", key):
            raise ValueError(f"key: expected letters, digits, '_', '-', '.', got {key!r}")
        return self.directory / f"{key}.pkl"

    def get(self, key: str, default=None):
        """The cached result for ``key``, or ``default`` if missing or unreadable."""
        try:
            with open(self.path(key), "rb") as handle:
                return pickle.load(handle)
        except (OSError, EOFError, pickle.UnpicklingError, AttributeError, ImportError, ValueError):
            return default

    def __contains__(self, key: str) -> bool:
        return self.path(key).is_file()

    def put(self, key: str, result) -> None:
        """Store ``result`` under ``key`` (atomically)."""
        from pointillist.imaging.io import atomic_write

        def write(tmp: str) -> None:
            with open(tmp, "wb") as handle:
                pickle.dump(result, handle, protocol=pickle.HIGHEST_PROTOCOL)

        atomic_write(self.path(key), write)

    def __len__(self) -> int:
        return sum(1 for _ in self.directory.glob("*.pkl"))


_MISSING = object()


def run_tasks(function: Callable, tasks: Sequence, *, client=None, cache: ResultCache | str | os.PathLike | None = None,
              keys: Sequence[str] | None = None, retries: int = DEFAULT_RETRIES, progress: bool = True,
              desc: str = "tasks", stats: dict | None = None) -> list:
    """Run ``function(task)`` for every task; return the results in task order.

    Parameters
    ----------
    function : callable
        A module-level function (workers import it by name), e.g. :func:`render_task`.
    tasks : sequence
        Its arguments, one task each.
    client : distributed.Client or None
        Where to run: None runs serially in this process.
    cache : ResultCache, path or None
        Results found there are not recomputed; new results are stored there
        as soon as each arrives (so an interrupted run keeps what finished).
    keys : sequence of str, optional
        Cache / Dask keys, one per task (default :func:`task_key`).
    retries : int
        Re-runs of a task that raises (a task whose worker dies is re-run by
        the scheduler regardless, up to ``allowed-failures``).
    progress : bool
        Show a tqdm progress bar.
    stats : dict, optional
        Filled with ``cached`` and ``computed`` counts.

    Raises
    ------
    The task's exception once its retries are spent (results that finished
    before stay in the cache); ``distributed.KilledWorker`` if a task kept
    killing its workers.
    """
    from tqdm.auto import tqdm

    tasks = list(tasks)
    if int(retries) != retries or retries < 0:
        raise ValueError(f"retries: expected an integer >= 0, got {retries!r}")
    if cache is not None and not isinstance(cache, ResultCache):
        cache = ResultCache(cache)
    if keys is None and (cache is not None or client is not None):
        keys = [task_key(function, task) for task in tasks]
    if keys is not None and len(keys) != len(tasks):
        raise ValueError(f"keys: expected {len(tasks)} keys, one per task, got {len(keys)}")
    results = [_MISSING] * len(tasks)
    if cache is not None:
        for i, key in enumerate(keys):
            results[i] = cache.get(key, _MISSING)
    todo = [i for i, r in enumerate(results) if r is _MISSING]
    if stats is not None:
        stats.update(cached=len(tasks) - len(todo), computed=len(todo))
    bar = tqdm(total=len(tasks), initial=len(tasks) - len(todo), desc=desc, disable=not progress,
               unit="task", leave=False)
    try:
        if client is None:
            for i in todo:
                results[i] = _finish(cache, keys, i, function(tasks[i]))
                bar.update()
        else:
            from distributed import as_completed

            name = getattr(function, "__name__", "task")
            futures = {}
            for i in todo:
                future = client.submit(function, tasks[i], key=f"pointillist-{name}-{keys[i]}",
                                       retries=int(retries), pure=False)
                futures[future] = i
            try:
                for future in as_completed(futures):
                    i = futures[future]
                    results[i] = _finish(cache, keys, i, future.result())
                    bar.update()
            finally:
                for future in futures:
                    future.release()
    finally:
        bar.close()
    return results


def _finish(cache, keys, i, result):
    if cache is not None:
        cache.put(keys[i], result)
    return result


# --------------------------------------------------------------------------- tiled rendering
@dataclasses.dataclass
class TiledRender:
    """What :func:`render_tiled` returns.

    ``image`` float32 (H, W, C) numpy; ``tiles`` the :class:`Tile` list;
    ``results`` the :class:`RenderResult` of each tile; ``wall`` seconds from
    submission to assembly; ``cached`` how many tiles came from the cache.
    """

    image: np.ndarray
    tiles: list[Tile]
    results: list[RenderResult]
    wall: float
    cached: int

    def timing(self):
        """A :class:`pointillist.scene.RenderTiming`: sums over tiles, ``total`` = wall time."""
        from pointillist.scene import RenderTiming

        def total(name):
            return sum(r.timing.get(name, 0) for r in self.results)

        return RenderTiming(trace=total("trace"), compile=total("compile"), execute=total("execute"),
                            total=self.wall, kernels=int(total("kernels")), cache_hits=int(total("cache_hits")))


def assemble_tiles(tiles: Sequence[Tile], images: Sequence[np.ndarray], *, x: int = 0, y: int = 0,
                   width: int | None = None, height: int | None = None) -> np.ndarray:
    """Place tile images into one float32 (H, W, C) image.

    ``x, y`` is the window's offset (tile coordinates are film pixels);
    ``width, height`` default to the tiles' extent. Raises ValueError if a
    tile's image does not match its size or channel count, or tiles leave a
    pixel uncovered or cover it twice.
    """
    if len(tiles) != len(images) or not tiles:
        raise ValueError(f"images: expected one image per tile ({len(tiles)}), got {len(images)}")
    width = max(t.x + t.width for t in tiles) - x if width is None else width
    height = max(t.y + t.height for t in tiles) - y if height is None else height
    first = np.asarray(images[0])
    channels = first.shape[2] if first.ndim == 3 else 1
    out = np.zeros((height, width, channels), np.float32)
    covered = np.zeros((height, width), np.int32)
    for tile, image in zip(tiles, images):
        image = np.asarray(image, dtype=np.float32)
        if image.ndim == 2:
            image = image[..., None]
        if image.shape != (tile.height, tile.width, channels):
            raise ValueError(f"images: tile {tile.index} expected shape {(tile.height, tile.width, channels)}, "
                             f"got {image.shape}")
        ys, xs = slice(tile.y - y, tile.y - y + tile.height), slice(tile.x - x, tile.x - x + tile.width)
        if tile.y < y or tile.x < x or ys.stop > height or xs.stop > width:
            raise ValueError(f"tiles: tile {tile.index} lies outside the {width}x{height} window")
        out[ys, xs] = image
        covered[ys, xs] += 1
    if covered.min() != 1 or covered.max() != 1:
        raise ValueError("tiles: the tiles must cover every pixel of the window exactly once")
    return out


def render_tiled(scene: str | os.PathLike, params: dict[str, str] | None = None, *, tiles: tuple[int, int] = (1, 1),
                 spp: int | None = None, seed: int = 0, sensor: int = 0, client=None,
                 cache: ResultCache | str | os.PathLike | None = None, retries: int = DEFAULT_RETRIES,
                 progress: bool = True) -> TiledRender:
    """Render a scene as ``rows x cols`` crop-window tiles (tasks) and assemble the image.

    Tile ``i`` renders with seed :func:`tile_seed` ``(seed, i, rows * cols)``.
    The tiles cover the scene's own crop window (the whole film unless the
    scene sets one); the image has that window's size.

    Examples
    --------
    >>> from pointillist.distributed import render_tiled
    >>> result = render_tiled("scenes/default.xml", {"res": "8"}, tiles=(2, 2), spp=1,
    ...                       progress=False)
    >>> result.image.shape, len(result.tiles)
    ((8, 8, 3), 4)
    """
    rows, cols = tiles
    path = Path(scene).resolve()
    probe = RenderTask(str(path), params or {}, spp, seed, sensor)
    _setup_process()
    _, _, window, _, _ = _scene_for(probe)
    ox, oy, width, height = window
    grid = tile_grid(width, height, rows, cols, x=ox, y=oy)
    tasks = [dataclasses.replace(probe, seed=tile_seed(seed, t.index, len(grid)), crop=t.crop) for t in grid]
    stats: dict[str, int] = {}
    start = time.perf_counter()
    results = run_tasks(render_task, tasks, client=client, cache=cache, retries=retries, progress=progress,
                        desc="tiles", stats=stats)
    image = assemble_tiles(grid, [r.image for r in results], x=ox, y=oy, width=width, height=height)
    return TiledRender(image=image, tiles=grid, results=results, wall=time.perf_counter() - start,
                       cached=stats["cached"])


# --------------------------------------------------------------------------- `pointillist compare` sweeps
def compare_task(call: tuple) -> Any:
    """Run :func:`pointillist.compare.render_one` ``(*call)`` in this process (a worker).

    ``render_one`` renders one (sampler, value, seed), times it here and writes
    its EXR and JSON record into the comparison folder (its on-disk cache).
    """
    _setup_process()
    from pointillist.compare import render_one

    return render_one(*call)


def prerender_sweep(client, scene: str | os.PathLike, tasks: Sequence, *, params: dict[str, str] | None,
                    out_dir: str | os.PathLike, reference_spp: int | None = None,
                    retries: int = DEFAULT_RETRIES, progress: bool = True) -> int:
    """Render a comparison's missing renders (and its reference) as tasks on ``client``.

    Every :class:`pointillist.compare.Task` (and the reference, when
    ``reference_spp`` is given) whose EXR and JSON record are not yet in
    ``out_dir`` becomes one :func:`compare_task`; the workers write them where a
    serial ``compare`` would, so the serial scoring pass that follows finds
    them all finished. ``out_dir`` and the scene must be reachable by the
    workers under the same (absolute) paths. Returns how many were rendered.
    """
    from pointillist.compare import REFERENCE_SAMPLER, REFERENCE_SEED, Task, scene_key, task_paths

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
    keys = [hashlib.sha256(json.dumps(c, sort_keys=True, default=_json_default).encode()).hexdigest()
            for c in todo]
    run_tasks(compare_task, todo, client=client, keys=keys, retries=retries, progress=progress,
              desc="compare on cluster")
    return len(todo)


# --------------------------------------------------------------------------- `pointillist mip --turntable`
_VOLUMES: OrderedDict = OrderedDict()


def mip_frame_task(spec: dict) -> dict:
    """Project one frame of a volume in this process (a worker); picklable.

    ``spec``: ``volume`` (path), ``spacing`` (or None), ``view`` (keyword
    arguments of the view: ``view``/``azimuth``/``elevation``) and ``options``
    (the other keyword arguments of
    :func:`pointillist.commands.mip.project_volume`). The volume and its
    texture stay loaded per process for the next frame. Returns
    ``{"image": (H, W) float32, "seconds": projection time here,
    "texture": the integrator's texture_info(), "worker": host:pid}``.
    """
    _setup_process()
    from pointillist.commands.mip import project_volume
    from pointillist.imaging.volumes import load_volume

    path = str(Path(spec["volume"]).resolve())
    try:
        stamp = os.stat(path).st_mtime_ns
    except OSError:
        raise UsageError(f"volume: no such file or folder: {path}") from None
    spacing = tuple(spec["spacing"]) if spec.get("spacing") else None
    key = (path, stamp, spacing, tuple(sorted(spec["options"].items())))
    entry = _VOLUMES.get(key)
    if entry is None:
        _VOLUMES.clear()  # one volume per process: they can be large
        entry = _VOLUMES[key] = {"volume": load_volume(path, spacing=list(spacing) if spacing else None),
                                 "integrator": None}
    start = time.perf_counter()
    image, entry["integrator"] = project_volume(entry["volume"], **spec["view"], **spec["options"],
                                                integrator=entry["integrator"])
    return {"image": np.asarray(image, dtype=np.float32), "seconds": time.perf_counter() - start,
            "texture": entry["integrator"].texture_info(), "worker": f"{socket.gethostname()}:{os.getpid()}"}


def project_frames(volume: str | os.PathLike, views: Sequence[dict], options: dict, *, spacing=None,
                   workers: int | None = None, scheduler: str | None = None, retries: int = DEFAULT_RETRIES,
                   progress: bool = True) -> list[dict]:
    """Project every view of a volume (turntable frames) as tasks; results in view order.

    Runs on a local cluster of ``workers`` processes or the cluster at
    ``scheduler`` (each worker loads the volume once, by the same path). See
    :func:`mip_frame_task` for what each result holds.
    """
    specs = [{"volume": str(Path(volume).resolve()), "spacing": list(spacing) if spacing else None,
              "view": dict(view), "options": dict(options)} for view in views]
    keys = [hashlib.sha256(json.dumps(s, sort_keys=True, default=_json_default).encode()).hexdigest()
            for s in specs]
    with open_client(workers, scheduler) as client:
        return run_tasks(mip_frame_task, specs, client=client, keys=keys, retries=retries, progress=progress,
                         desc="mip frames")


# --------------------------------------------------------------------------- `pointillist render --tiles`
def render_command(args, params: dict[str, str], out: Path) -> int:
    """The ``pointillist render`` path for ``--tiles`` / ``--workers`` / ``--scheduler``."""
    from pointillist.commands.render import write_render
    from pointillist.scene import load_scene, scene_info

    tiles = args.tiles or (1, 1)
    _setup_process()
    start = time.perf_counter()
    scene = load_scene(args.scene, params)
    load_s = time.perf_counter() - start
    info = scene_info(scene)
    with open_client(args.workers, args.scheduler) as client:
        where = ("in process" if client is None else
                 f"on {len(client.scheduler_info(n_workers=-1)['workers'])} worker(s) at {client.scheduler.address}")
        result = render_tiled(args.scene, params, tiles=tiles, spp=args.spp, seed=args.seed, client=client,
                              cache=getattr(args, "cache", None), progress=True)
    spp = args.spp or info["spp"]
    timing = result.timing()
    meta = dict(info, spp=spp, seed=args.seed, tile_grid=f"{tiles[0]}x{tiles[1]}",
                tile_seeds=f"(seed*{len(result.tiles)}+tile) mod 2^32")
    write_render(out, result.image, scene, args.scene, meta, timing, png=args.png)
    print(f"wrote {out}" + (f" and {out.with_suffix('.png')}" if args.png else ""))
    print(f"{info['width']}x{info['height']} at {spp} spp as {tiles[0]}x{tiles[1]} tiles {where}, "
          f"integrator {info['integrator']}, sampler {info['sampler']}"
          + (f"; {result.cached} of {len(result.tiles)} tiles from the cache" if result.cached else ""))
    print(f"time: load {load_s:.2f} s, wall {result.wall:.2f} s; summed over tiles on the workers: "
          f"trace {timing.trace:.2f} s, JIT compile {timing.compile:.2f} s ({timing.kernels} kernels, "
          f"{timing.cache_hits} from cache), render {timing.execute:.2f} s")
    return 0
