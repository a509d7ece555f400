"""The Dask engine: independent tasks on Dask distributed, with an on-disk result cache.

pointillist does not schedule work itself; it hands independent tasks (renders, tiles,
MIP frames) to `Dask distributed <https://distributed.dask.org>`_:

* :func:`open_client` gives a Dask client for ``--workers N`` (a
  :class:`distributed.LocalCluster` of N worker processes on loopback, one task
  thread each) or ``--scheduler ADDRESS`` (an existing cluster), or ``None``
  for the default serial, in-process run.
* :class:`PointillistWorker` (a Dask ``WorkerPlugin``) makes every worker set
  the Mitsuba variant and register pointillist's plugins itself
  (:func:`setup_process`); every task function also does so (idempotently), so a
  worker that joins later or is restarted after a crash is ready too.
* :func:`run_tasks` runs a list of tasks (serially, or on the client), keeps
  each result in an on-disk :class:`ResultCache` as soon as it arrives, and
  reuses cached results: a restarted command redoes only what is missing. A
  task whose worker dies is re-run on another worker by the scheduler (up to
  ``distributed.scheduler.allowed-failures`` times, 3 by default); a task that
  raises is retried ``retries`` times.

The tasks themselves live with their features: tiled renders in
:mod:`pointillist.tiles`, comparison renders in :mod:`pointillist.compare`, MIP
turntable frames in :mod:`pointillist.mip`.

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
import hashlib
import json
import math
import os
import re
import zipfile
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pointillist.core import checks
from pointillist.core.digests import json_default
from pointillist.core.errors import UsageError

__all__ = [
    "DEFAULT_RETRIES",
    "register_result_type",
    "CACHE_FORMAT",
    "setup_process",
    "PointillistWorker",  # noqa: F822 - made on first use (module __getattr__)
    "start_cluster",
    "connect",
    "open_client",
    "task_key",
    "ResultCache",
    "run_tasks",
]


#: How often a task that raises is re-run (``retries=`` of ``Client.submit``).
DEFAULT_RETRIES = 2

#: Version of the cache file layout and key scheme; bump to invalidate caches.
CACHE_FORMAT = 2


# --------------------------------------------------------------------------- workers and clients
def setup_process(drjit_threads: int | None = None):
    """Set the variant and register the plugins in this process (idempotent); returns ``mitsuba``."""
    import pointillist

    mi = pointillist.setup()
    if drjit_threads:
        import drjit as dr

        if dr.thread_count() != drjit_threads:
            dr.set_thread_count(drjit_threads)
    return mi

def _worker_plugin_class() -> type:
    """The ``PointillistWorker`` class, made on first use: importing Dask costs about a second,
    which commands that never distribute should not pay (``import pointillist.distributed``
    stays cheap; pickling finds the class through the module's ``__getattr__``)."""
    global _PointillistWorker
    if _PointillistWorker is None:
        _need_dask()
        from distributed import WorkerPlugin

        class PointillistWorker(WorkerPlugin):
            """Dask ``WorkerPlugin``: each worker sets ``llvm_ad_rgb`` and registers the plugins.

            ``drjit_threads`` caps Dr.Jit's thread pool of the worker (``None`` keeps
            Dr.Jit's default, one thread per core): N workers on one C-core machine
            should use about C / N threads each. Register with
            ``client.register_plugin(PointillistWorker())``; workers that join later
            (or are restarted after a crash) run it too.
            """

            name = "pointillist-setup"

            def __init__(self, drjit_threads: int | None = None):
                if drjit_threads is not None:
                    drjit_threads = checks.integer(drjit_threads, "drjit_threads", low=1)
                self.drjit_threads = drjit_threads

            def setup(self, worker):  # noqa: D401 - Dask API
                setup_process(self.drjit_threads)

        PointillistWorker.__module__ = __name__
        _PointillistWorker = PointillistWorker
    return _PointillistWorker


_PointillistWorker: type | None = None


def __getattr__(name: str) -> Any:
    if name == "PointillistWorker":
        return _worker_plugin_class()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _need_dask():
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise UsageError("--workers/--scheduler need Dask distributed: "
                         "pip install 'pointillist[distributed]'") from None


def start_cluster(n_workers: int, *, drjit_threads: int | None = None, quiet: bool = True):
    """Start a :class:`distributed.LocalCluster` of ``n_workers`` processes; return its Client.

    Loopback only (``127.0.0.1``), one task thread per worker, no dashboard.
    Each worker gets ``drjit_threads`` Dr.Jit threads (default: cores // workers,
    at least 1). Close with ``client.close(); client.cluster.close()`` or use
    :func:`open_client`.
    """
    n_workers = checks.integer(n_workers, "n_workers", low=1)
    _need_dask()
    import logging

    from distributed import Client, LocalCluster

    if drjit_threads is None:
        drjit_threads = max(1, (os.cpu_count() or 1) // int(n_workers))
    _start_resource_tracker()
    cluster = LocalCluster(n_workers=int(n_workers), threads_per_worker=1, processes=True,
                           host="127.0.0.1", dashboard_address=None,
                           silence_logs=logging.ERROR if quiet else logging.WARNING)
    client = Client(cluster)
    client.register_plugin(_worker_plugin_class()(drjit_threads))
    return client

def _start_resource_tracker() -> None:
    """Start multiprocessing's resource tracker (the process that removes the semaphores of the
    workers' queues when this process ends) without its "leaked semaphore" warning: a command
    stopped at once (:mod:`pointillist.core.signals`) ends before its cluster is closed, and the
    tracker's cleaning up after it is not news (the one line about the signal stays the only one)."""
    import sys
    from multiprocessing import resource_tracker

    option = "ignore::UserWarning:multiprocessing.resource_tracker"
    sys.warnoptions.append(option)  # the tracker starts with this process's -W options
    try:
        resource_tracker.ensure_running()
    finally:
        sys.warnoptions.remove(option)


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
    client.register_plugin(_worker_plugin_class()(drjit_threads))
    return client

@contextlib.contextmanager
def open_client(workers: int | None = None, scheduler: str | None = None, *,
                tasks: int | None = None, drjit_threads: int | None = None) -> Iterator[Any]:
    """Context manager: a Dask client for ``workers`` or ``scheduler``, or ``None`` (serial).

    Raises UsageError if both are given. The local cluster (``workers``) is
    shut down on exit; a remote cluster (``scheduler``) is only disconnected. With ``tasks`` (how
    many tasks will run), a local cluster has no more workers than tasks (a warning says so).
    ``drjit_threads``: each local worker's Dr.Jit threads (:func:`start_cluster`).
    """
    if workers is not None and scheduler is not None:
        raise UsageError("--workers and --scheduler: give one or the other, not both")
    if workers is None and scheduler is None:
        yield None
        return
    if workers is not None and tasks is not None and 0 < tasks < workers:
        import warnings

        warnings.warn(f"--workers {workers}: only {tasks} task(s) to run; starting {tasks} worker(s)", stacklevel=3)
        workers = tasks
    client = start_cluster(workers, drjit_threads=drjit_threads) if workers is not None else connect(scheduler)
    try:
        with _quiet_client():
            yield client
    finally:
        cluster = client.cluster if workers is not None else None
        with _quiet_client(), contextlib.suppress(Exception):  # a cluster that went away: nothing to close
            client.close()
        if cluster is not None:
            cluster.close()


@contextlib.contextmanager
def _quiet_client() -> Iterator[None]:
    """Dask's client logs the tracebacks of its attempts to reconnect to a scheduler that went away;
    the work that needed it says so in one line (:class:`pointillist.core.errors.ClusterError`)."""
    import logging

    logger = logging.getLogger("distributed.client")
    level = logger.level
    logger.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        logger.setLevel(level)


# --------------------------------------------------------------------------- keys, cache and task runner
def task_key(function: Callable, task: Any) -> str:
    """A stable key for ``function(task)``: SHA-256 of the function's name and the task's token.

    The token is ``task.cache_token()`` when the task has one (as
    :class:`pointillist.tiles.RenderTask` does: its fields and the hash of the
    scene's inputs, the XML and every file it reads), else the task itself,
    which must then be JSON-serialisable (numbers, strings, lists, dicts).
    """
    token = task.cache_token() if hasattr(task, "cache_token") else task
    name = f"{getattr(function, '__module__', '?')}.{getattr(function, '__qualname__', repr(function))}"
    try:
        text = json.dumps({"format": CACHE_FORMAT, "function": name, "task": token},
                          sort_keys=True, default=json_default)
    except TypeError as error:
        raise TypeError(f"task: cannot make a cache key from {type(task).__name__} ({error}); "
                        "give it a cache_token() method or pass keys=") from None
    return hashlib.sha256(text.encode()).hexdigest()

#: Classes a :class:`ResultCache` file may hold (``module:name`` -> class; :func:`register_result_type`).
_RESULT_TYPES: dict[str, type] = {}


def register_result_type(cls: type) -> type:
    """Let :class:`ResultCache` store and read back instances of the dataclass ``cls`` (its fields
    are stored as data); usable as a class decorator. Only registered classes are ever rebuilt
    from a cache file: a file naming another class counts as missing."""
    import dataclasses

    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"cls: expected a dataclass, got {cls!r}")
    _RESULT_TYPES[f"{cls.__module__}:{cls.__qualname__}"] = cls
    return cls


class ResultCache:
    """Task results on disk as data, one ``.npz`` file per key in ``directory``.

    A result (numbers, strings, lists, tuples, dicts with string keys, numpy arrays, and
    dataclasses registered with :func:`register_result_type`) is stored as numpy arrays and one JSON
    description with the SHA-256 of its contents, read back with ``allow_pickle=False``: a cache
    file is never unpickled or executed, so a shared cache folder (a cluster's) cannot make a render
    run code. A file that does not read, whose digest does not match, or that names an
    unregistered class counts as missing (its task runs again); files of another kind in the folder
    (``*.pkl``) are ignored, with one warning. Writes are atomic (temporary file, then rename).
    """

    SUFFIX = ".npz"

    def __init__(self, directory: str | os.PathLike):
        self.directory = Path(directory)
        if self.directory.exists() and not self.directory.is_dir():
            raise ValueError(f"cache: {self.directory} exists and is not a folder")
        self.directory.mkdir(parents=True, exist_ok=True)
        foreign = sorted(p.name for p in self.directory.iterdir() if p.is_file() and p.suffix != self.SUFFIX
                         and not p.name.startswith("."))
        if foreign:
            import warnings

            warnings.warn(f"cache: {self.directory}: ignoring {len(foreign)} file(s) that are not pointillist's "
                          f"results ({', '.join(foreign[:3])}{', ...' if len(foreign) > 3 else ''}); "
                          "cache files are data, never pickles", stacklevel=2)

    def path(self, key: str) -> Path:
        if not re.fullmatch(r"[0-9A-Za-z_.-]+", key):
            raise ValueError(f"key: expected letters, digits, '_', '-', '.', got {key!r}")
        return self.directory / f"{key}{self.SUFFIX}"

    def get(self, key: str, default=None):
        """The cached result for ``key``, or ``default`` if missing, unreadable or not intact."""
        try:
            with np.load(self.path(key), allow_pickle=False) as data:
                arrays = {name: data[name] for name in data.files}
            description = str(arrays.pop("__result__"))
            digest = str(arrays.pop("__sha256__"))
            if digest != _result_digest(description, arrays):
                return default
            return _decode(json.loads(description), arrays)
        except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile):
            return default

    def __contains__(self, key: str) -> bool:
        return self.path(key).is_file()

    def put(self, key: str, result) -> None:
        """Store ``result`` under ``key`` (atomically); TypeError for a value that is not data."""
        from pointillist.core.files import atomic_write

        arrays: dict[str, np.ndarray] = {}
        description = json.dumps(_encode(result, arrays), sort_keys=True)

        def write(tmp: str) -> None:
            with open(tmp, "wb") as handle:
                np.savez(handle, __result__=np.array(description), __sha256__=np.array(
                    _result_digest(description, arrays)), **arrays)

        atomic_write(self.path(key), write)

    def __len__(self) -> int:
        return sum(1 for _ in self.directory.glob(f"*{self.SUFFIX}"))


def _result_digest(description: str, arrays: dict[str, np.ndarray]) -> str:
    digest = hashlib.sha256(description.encode())
    for name in sorted(arrays):
        array = np.ascontiguousarray(arrays[name])
        digest.update(f"\0{name}:{array.dtype.str}:{array.shape}".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()


def _encode(value: Any, arrays: dict[str, np.ndarray]) -> Any:
    """``value`` as JSON, its numpy arrays moved into ``arrays`` (by name)."""
    import dataclasses

    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, np.bool_):
        number = value.item() if isinstance(value, np.generic) else value
        return number if not isinstance(number, float) or math.isfinite(number) else {"__float__": repr(number)}
    if isinstance(value, np.ndarray):
        if value.dtype.hasobject:
            raise TypeError("result: a numpy array of Python objects is not data")
        name = f"a{len(arrays)}"
        arrays[name] = value
        return {"__array__": name}
    if isinstance(value, (list, tuple)):
        items = [_encode(item, arrays) for item in value]
        return items if isinstance(value, list) else {"__tuple__": items}
    if isinstance(value, dict):
        if not all(isinstance(k, str) for k in value):
            raise TypeError("result: dict keys must be strings")
        return {"__dict__": {k: _encode(v, arrays) for k, v in value.items()}}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        name = f"{type(value).__module__}:{type(value).__qualname__}"
        if _RESULT_TYPES.get(name) is not type(value):
            raise TypeError(f"result: {name} is not a registered result type (register_result_type)")
        return {"__dataclass__": name, "fields": {f.name: _encode(getattr(value, f.name), arrays)
                                                  for f in dataclasses.fields(value)}}
    raise TypeError(f"result: cannot store a {type(value).__name__} as data")


def _decode(value: Any, arrays: dict[str, np.ndarray]) -> Any:
    if isinstance(value, list):
        return [_decode(item, arrays) for item in value]
    if not isinstance(value, dict):
        return value
    if "__array__" in value:
        return arrays[value["__array__"]]
    if "__float__" in value:
        return float(value["__float__"])
    if "__tuple__" in value:
        return tuple(_decode(item, arrays) for item in value["__tuple__"])
    if "__dict__" in value:
        return {k: _decode(v, arrays) for k, v in value["__dict__"].items()}
    if "__dataclass__" in value:
        cls = _RESULT_TYPES[value["__dataclass__"]]  # KeyError: an unregistered class is not rebuilt
        return cls(**{k: _decode(v, arrays) for k, v in value["fields"].items()})
    raise ValueError("result: an unknown entry")

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
        Show a tqdm progress bar (on a terminal only: not in a log).
    stats : dict, optional
        Filled with ``cached`` and ``computed`` counts.

    Raises
    ------
    The task's exception once its retries are spent (results that finished
    before stay in the cache); ``distributed.KilledWorker`` if a task kept
    killing its workers.
    """
    from pointillist.core.terminal import progress_bar

    tasks = list(tasks)
    retries = checks.integer(retries, "retries", low=0)
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
    bar = progress_bar(total=len(tasks), initial=len(tasks) - len(todo), desc=desc, unit="task", progress=progress)
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
