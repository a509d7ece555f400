"""Checkpoints of a progressive render: the accumulated passes, written atomically, and resumed
only into the render they came from.

A checkpoint (``OUT.checkpoint.npz``) holds the :class:`~pointillist.progressive.estimate.Accumulator`'s
arrays, the :class:`~pointillist.progressive.stats.PassStats` and history rows, the render's
identity (:func:`scene_fingerprint`: the inputs' digest, ``-D`` values, seed, film, integrator,
sampler) and a SHA-256 checksum of all of it; :func:`load_checkpoint` refuses one that another
version wrote, that was changed after it was written, that another scene or setting made, or whose
numbers disagree with each other.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from pointillist.core.checks import UINT32_MAX
from pointillist.core.errors import UsageError
from pointillist.progressive.estimate import Accumulator
from pointillist.progressive.stats import HISTORY_COLUMNS, PassStats
from pointillist.scene import scene_info

__all__ = ["CHECKPOINT_VERSION", "checkpoint_path", "scene_fingerprint", "checksum", "save_checkpoint",
           "load_checkpoint"]

#: Format version of the checkpoint file (2: the inputs' digest and a checksum of the contents;
#: 3: the four quarters' means and the longer history rows of the error estimate).
CHECKPOINT_VERSION = 3

def checkpoint_path(out: str | Path) -> Path:
    """``OUT.checkpoint.npz`` beside the EXR ``OUT.exr``."""
    return Path(out).with_suffix(".checkpoint.npz")
def scene_fingerprint(scene, scene_path: str | Path, params: dict[str, str] | None, seed: int,
                      sensor: int = 0, *, inputs: Sequence[str | Path] | None = None) -> dict[str, Any]:
    """What a checkpoint must match to be resumed: the SHA-256 of the scene's inputs (the scene file
    and every file it reads: includes, textures, meshes, volumes; :func:`pointillist.plan.inputs_digest`)
    with the ``-D`` values, the seed, the film, integrator and sampler.

    ``inputs``: the scene's inputs when known (:func:`pointillist.plan.scene_inputs`); else the
    scene file is parsed again to list them.
    """
    import mitsuba as mi

    from pointillist.plan import inputs_digest, scene_inputs
    from pointillist.scene import parse_scene

    if inputs is None:
        inputs = scene_inputs(parse_scene(scene_path, params))
    info = scene_info(scene, sensor)
    return {"inputs_sha256": inputs_digest(inputs, params),
            "params": json.dumps(dict(sorted((params or {}).items()))), "seed": int(seed), "sensor": int(sensor),
            "film": f"{info['width']}x{info['height']}", "integrator": info["integrator"],
            "sampler": info["sampler"], "variant": mi.variant()}


def checksum(arrays: dict[str, Any]) -> str:
    """SHA-256 of a checkpoint's contents (every entry but the checksum, by name, dtype, shape, bytes)."""
    digest = hashlib.sha256()
    for name in sorted(arrays):
        if name == "checksum":
            continue
        value = np.ascontiguousarray(np.asarray(arrays[name]))
        digest.update(f"{name}|{value.dtype.str}|{value.shape}|".encode())
        digest.update(value.tobytes())
    return digest.hexdigest()


def save_checkpoint(path: Path, acc: Accumulator, stats: PassStats, history: list, identity: dict) -> None:
    """Write the checkpoint ``path`` atomically: ``acc``'s arrays, ``stats``, the ``history`` rows
    (:data:`~pointillist.progressive.stats.HISTORY_COLUMNS`), the render's ``identity``
    (:func:`scene_fingerprint`), :data:`CHECKPOINT_VERSION` and the :func:`checksum` of it all;
    :func:`load_checkpoint` reads it back."""
    from pointillist.core.files import atomic_write

    arrays = dict(acc.to_numpy(), history=np.asarray(history, np.float64).reshape(-1, len(HISTORY_COLUMNS)),
                  stats=np.array(json.dumps(asdict(stats))), identity=np.array(json.dumps(identity)),
                  version=np.int64(CHECKPOINT_VERSION))
    arrays["checksum"] = np.array(checksum(arrays))
    atomic_write(path, lambda tmp: np.savez(tmp, **arrays))


def load_checkpoint(path: Path, identity: dict, channels: int | None = None) -> tuple[Accumulator, PassStats, list]:
    """Read a checkpoint; UsageError unless it is one this version wrote, unchanged (its checksum),
    for the same scene and settings (``identity``), and consistent (``channels``: the render's)."""
    if not path.is_file():
        raise UsageError(f"--resume: no checkpoint {path} (write one with --checkpoint SECONDS)")
    try:
        with np.load(path, allow_pickle=False) as data:
            if "version" not in data.files or int(data["version"]) != CHECKPOINT_VERSION:
                version = int(data["version"]) if "version" in data.files else "none"
                raise UsageError(f"--resume: checkpoint {path} has format version {version}, "
                                 f"expected {CHECKPOINT_VERSION}")
            arrays = {name: data[name] for name in data.files}
    except UsageError:
        raise
    except Exception as error:  # noqa: BLE001 - any unreadable file is a usage error here
        raise UsageError(f"--resume: {path} is not a readable checkpoint ({type(error).__name__}: {error})") from None
    if "checksum" not in arrays or str(arrays["checksum"]) != checksum(arrays):
        raise UsageError(f"--resume: checkpoint {path} was changed or damaged after it was written "
                         "(its checksum does not match its contents)")
    try:
        saved = json.loads(str(arrays["identity"]))
        stats = PassStats(**{key: value for key, value in json.loads(str(arrays["stats"])).items()
                             if key not in ("sizes", "size_compile_seconds")})  # compiled in that process
        mean, m2 = np.asarray(arrays["mean"]), np.asarray(arrays["m2"])
        weight, passes = int(arrays["weight"]), int(arrays["passes"])
        history = [tuple(float(v) for v in row)
                   for row in np.asarray(arrays["history"], np.float64).reshape(-1, len(HISTORY_COLUMNS))]
        acc = Accumulator.from_numpy(arrays)
    except (KeyError, TypeError, ValueError) as error:
        raise UsageError(f"--resume: {path} is not a readable checkpoint ({type(error).__name__}: {error})") from None
    for key, value in identity.items():
        if saved.get(key) != value:
            what = ("another scene (the scene file or a file it reads changed)" if key == "inputs_sha256"
                    else f"other settings ({key} {saved.get(key)!r}, now {value!r})")
            raise UsageError(f"--resume: checkpoint {path} was made from {what}")
    problem = _inconsistency(mean, m2, weight, passes, stats, history, channels)
    if not problem and (acc.weight, acc.passes) != (weight, passes):
        problem = (f"its quarters hold {acc.passes} passes of {acc.weight} spp, the whole render {passes} of "
                   f"{weight}")
    if problem:
        raise UsageError(f"--resume: checkpoint {path} is inconsistent ({problem})")
    return acc, stats, history


def _inconsistency(mean, m2, weight: int, passes: int, stats: PassStats, history: list,
                   channels: int | None) -> str:
    """What is wrong with a checkpoint's numbers ('' when nothing is): counts in range and agreeing
    with each other, arrays of the film's shape, times finite."""
    if mean.ndim != 3 or m2.shape != mean.shape or mean.dtype != np.float64 or m2.dtype != np.float64:
        return f"sums of shape {mean.shape} and {m2.shape}, expected two equal (H, W, C) float64 arrays"
    if tuple(mean.shape[:2]) != (stats.height, stats.width) or (channels is not None and mean.shape[2] != channels):
        return f"sums of shape {mean.shape}, the render is {stats.height}x{stats.width}x{channels or mean.shape[2]}"
    largest = max(UINT32_MAX // max(stats.width * stats.height, 1), 1)
    if not 1 <= passes <= weight <= passes * largest:
        return f"{passes} passes of {weight} spp in all (each pass takes 1..{largest} spp)"
    if stats.passes != passes or stats.spp != weight or len(history) != passes:
        return (f"{passes} passes and {weight} spp in the sums, {stats.passes} and {stats.spp} in the stats, "
                f"{len(history)} rows of history")
    if not (math.isfinite(stats.seconds) and stats.seconds >= 0 and math.isfinite(stats.compile_seconds)):
        return f"render seconds {stats.seconds}"
    return ""
