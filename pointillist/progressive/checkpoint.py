"""Checkpoints of a progressive render: the accumulated passes, written atomically, and resumed
only into the render they came from.

A checkpoint (``OUT.checkpoint.npz``) holds the :class:`~pointillist.progressive.estimate.Accumulator`'s
arrays (a tiled render's: one accumulator per tile, keys ``tile{i}.``), the
:class:`~pointillist.progressive.stats.PassStats` and history rows, the render's identity
(:func:`scene_fingerprint`: the inputs' digest, ``-D`` values, seed, film, integrator, sampler) and
a SHA-256 checksum of all of it; :func:`load_checkpoint` refuses one that another version wrote,
that was changed after it was written, that another scene or setting made, or whose numbers disagree
with each other.
"""

from __future__ import annotations

import dataclasses
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
           "load_checkpoint", "load_tiled_checkpoint"]

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


def save_checkpoint(path: Path, acc: Accumulator | Sequence[Accumulator], stats: PassStats, history: list,
                    identity: dict, settle: list | None = None) -> None:
    """Write the checkpoint ``path`` atomically: ``acc``'s arrays (a sequence: a tiled render's, one
    accumulator per tile), ``stats``, the ``history`` rows
    (:data:`~pointillist.progressive.stats.HISTORY_COLUMNS`), the render's ``identity``
    (:func:`scene_fingerprint`), :data:`CHECKPOINT_VERSION` and the :func:`checksum` of it all;
    :func:`load_checkpoint` (:func:`load_tiled_checkpoint`) reads it back. ``settle``: a tiled
    render's rows for the rare-path rule (the history with the error-weighted spp)."""
    from pointillist.core.files import atomic_write

    if isinstance(acc, Accumulator):
        arrays = acc.to_numpy()
    else:
        arrays = {f"tile{i}.{key}": value for i, tile in enumerate(acc) for key, value in tile.to_numpy().items()}
        arrays["tiles"] = np.int64(len(acc))
        arrays["settle"] = np.asarray(settle if settle is not None else history,
                                      np.float64).reshape(-1, len(HISTORY_COLUMNS))
    arrays.update(history=np.asarray(history, np.float64).reshape(-1, len(HISTORY_COLUMNS)),
                  stats=np.array(json.dumps(asdict(stats))), identity=np.array(json.dumps(identity)),
                  version=np.int64(CHECKPOINT_VERSION))
    arrays["checksum"] = np.array(checksum(arrays))
    atomic_write(path, lambda tmp: np.savez(tmp, **arrays))


def _read(path: Path, identity: dict) -> tuple[dict, PassStats, list]:
    """A checkpoint's arrays, stats and history; UsageError unless this version wrote it, unchanged
    (its checksum), for the same scene and settings (``identity``)."""
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
        history = [tuple(float(v) for v in row)
                   for row in np.asarray(arrays["history"], np.float64).reshape(-1, len(HISTORY_COLUMNS))]
    except (KeyError, TypeError, ValueError) as error:
        raise UsageError(f"--resume: {path} is not a readable checkpoint ({type(error).__name__}: {error})") from None
    for key, value in identity.items():
        if saved.get(key) != value:
            what = ("another scene (the scene file or a file it reads changed)" if key == "inputs_sha256"
                    else f"other settings ({key} {saved.get(key)!r}, now {value!r})")
            raise UsageError(f"--resume: checkpoint {path} was made from {what}")
    return arrays, stats, history


def _accumulator(path: Path, arrays: dict, prefix: str = "") -> tuple[Accumulator, np.ndarray, np.ndarray, int, int]:
    """The accumulator under ``prefix`` with its stored mean, M2, spp and passes (for the checks)."""
    try:
        part = {key[len(prefix):]: value for key, value in arrays.items() if key.startswith(prefix)}
        acc = Accumulator.from_numpy(part)
        return acc, np.asarray(part["mean"]), np.asarray(part["m2"]), int(part["weight"]), int(part["passes"])
    except (KeyError, TypeError, ValueError) as error:
        raise UsageError(f"--resume: {path} is not a readable checkpoint ({type(error).__name__}: {error})") from None


def _quarters_agree(acc: Accumulator, weight: int, passes: int) -> str:
    if (acc.weight, acc.passes) != (weight, passes):
        return f"its quarters hold {acc.passes} passes of {acc.weight} spp, the whole render {passes} of {weight}"
    return ""


def load_checkpoint(path: Path, identity: dict, channels: int | None = None) -> tuple[Accumulator, PassStats, list]:
    """Read a checkpoint; UsageError unless it is one this version wrote, unchanged (its checksum),
    for the same scene and settings (``identity``), and consistent (``channels``: the render's)."""
    arrays, stats, history = _read(path, identity)
    if "tiles" in arrays:
        raise UsageError(f"--resume: checkpoint {path} is of a render in tiles; resume it with the same --tiles")
    acc, mean, m2, weight, passes = _accumulator(path, arrays)
    problem = _inconsistency(mean, m2, weight, passes, stats, history, channels) or _quarters_agree(acc, weight, passes)
    if problem:
        raise UsageError(f"--resume: checkpoint {path} is inconsistent ({problem})")
    return acc, stats, history


def load_tiled_checkpoint(path: Path, identity: dict, tiles: Sequence,
                          channels: int) -> tuple[list, PassStats, list, list]:
    """Read a tiled render's checkpoint (:func:`load_checkpoint`'s checks, per tile): one accumulator
    per tile of ``tiles`` (:class:`pointillist.tiles.Tile`), the frame's stats, history and the rows
    of the rare-path rule."""
    arrays, stats, history = _read(path, identity)
    if "tiles" not in arrays or int(arrays["tiles"]) != len(tiles):
        found = int(arrays["tiles"]) if "tiles" in arrays else "no"
        raise UsageError(f"--resume: checkpoint {path} holds {found} tiles, the render has {len(tiles)}")
    accs = []
    for tile in tiles:
        acc, mean, m2, weight, passes = _accumulator(path, arrays, f"tile{tile.index}.")
        tile_stats = dataclasses.replace(stats, passes=passes, spp=weight, width=tile.width, height=tile.height)
        problem = (_inconsistency(mean, m2, weight, passes, tile_stats, [()] * passes, channels)
                   or _quarters_agree(acc, weight, passes))
        if problem:
            raise UsageError(f"--resume: checkpoint {path} is inconsistent (tile {tile.index}: {problem})")
        accs.append(acc)
    settle = [tuple(float(v) for v in row) for row in
              np.asarray(arrays.get("settle", np.zeros((0,))), np.float64).reshape(-1, len(HISTORY_COLUMNS))]
    if len(history) != stats.passes or len(settle) != stats.passes:
        raise UsageError(f"--resume: checkpoint {path} is inconsistent ({stats.passes} rounds in the stats, "
                         f"{len(history)} rows of history, {len(settle)} of the rare-path rule)")
    return accs, stats, history, settle


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
