"""Turntable frames as Dask tasks: each worker loads the volume once and projects its frames."""

from __future__ import annotations

import os
import socket
import time
from collections import OrderedDict
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from pointillist.core.digests import json_key
from pointillist.distributed import DEFAULT_RETRIES, open_client, run_tasks, setup_process
from pointillist.core.errors import UsageError

from pointillist.mip.views import project_volume

__all__ = ["MAX_TURNTABLE_FRAMES", "mip_frame_task", "project_frames"]

#: The most frames of a turntable: one every tenth of a degree (a 2.4-minute GIF at 25 frames a
#: second). The GIF's frames are held in memory until it is written; 100000 frames asked for hours.
MAX_TURNTABLE_FRAMES = 3600


_VOLUMES: OrderedDict = OrderedDict()

def mip_frame_task(spec: dict) -> dict:
    """Project one frame of a volume in this process (a worker); picklable.

    ``spec``: ``volume`` (path), ``spacing`` (or None), ``load`` (``frame``/``series`` of
    :func:`~pointillist.imaging.volumes.load_volume`, optional), ``view`` (keyword
    arguments of the view: ``view``/``azimuth``/``elevation``) and ``options``
    (the other keyword arguments of
    :func:`project_volume`). The volume and its
    texture stay loaded per process for the next frame. Returns
    ``{"image": (H, W) float32, "seconds": projection time here,
    "texture": the integrator's texture_info(), "worker": host:pid}``.
    """
    setup_process()
    from pointillist.imaging.volumes import load_volume

    path = str(Path(spec["volume"]).resolve())
    try:
        stamp = os.stat(path).st_mtime_ns
    except OSError:
        raise UsageError(f"volume: no such file or folder: {path}") from None
    spacing = tuple(spec["spacing"]) if spec.get("spacing") else None
    load = dict(spec.get("load") or {})
    key = (path, stamp, spacing, tuple(sorted(load.items())), tuple(sorted(spec["options"].items())))
    entry = _VOLUMES.get(key)
    if entry is None:
        _VOLUMES.clear()  # one volume per process: they can be large
        entry = _VOLUMES[key] = {"volume": load_volume(path, spacing=list(spacing) if spacing else None, **load),
                                 "integrator": None}
    start = time.perf_counter()
    image, entry["integrator"] = project_volume(entry["volume"], **spec["view"], **spec["options"],
                                                integrator=entry["integrator"])
    return {"image": np.asarray(image, dtype=np.float32), "seconds": time.perf_counter() - start,
            "texture": entry["integrator"].texture_info(), "worker": f"{socket.gethostname()}:{os.getpid()}"}

def project_frames(volume: str | os.PathLike, views: Sequence[dict], options: dict, *, spacing=None,
                   load: dict | None = None, workers: int | None = None, scheduler: str | None = None,
                   retries: int = DEFAULT_RETRIES, progress: bool = True) -> list[dict]:
    """Project every view of a volume (turntable frames) as tasks; results in view order.

    Runs on a local cluster of ``workers`` processes or the cluster at
    ``scheduler`` (each worker loads the volume once, by the same path). See
    :func:`mip_frame_task` for what each result holds.
    """
    specs = [{"volume": str(Path(volume).resolve()), "spacing": list(spacing) if spacing else None,
              "load": dict(load or {}), "view": dict(view), "options": dict(options)} for view in views]
    keys = [json_key(s) for s in specs]
    with open_client(workers, scheduler, tasks=len(specs)) as client:
        return run_tasks(mip_frame_task, specs, client=client, keys=keys, retries=retries, progress=progress,
                         desc="mip frames")


