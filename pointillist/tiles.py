"""Tiled renders: a film split into crop-window tiles, each a task, assembled into one image.

* :func:`render_task` renders one :class:`RenderTask` (scene, parameters, spp,
  seed, optional crop window) and measures its timing in the process that runs
  it (a Dask worker or this one), so error-against-time tables stay honest.
* :func:`render_tiled` splits the film into ``rows x cols`` tiles with
  Mitsuba's crop window (``film.crop_offset`` / ``film.crop_size``), renders
  each tile as a task (:func:`pointillist.distributed.run_tasks`) with its own
  seed and assembles the image (:func:`assemble_tiles`).

Seeds of tiles
--------------
Tile ``i`` of ``K = rows * cols`` tiles renders with seed
``(seed * K + i) mod 2^32`` (:func:`tile_seed`): distinct for every tile of
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
"""

from __future__ import annotations

import dataclasses
import os
import re
import socket
import time
from collections import OrderedDict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pointillist.core import checks
from pointillist.distributed import DEFAULT_RETRIES, ResultCache, register_result_type, run_tasks, setup_process
from pointillist.core.errors import UsageError

__all__ = [
    "Tile",
    "parse_tiles",
    "tile_grid",
    "tile_seed",
    "RenderTask",
    "RenderResult",
    "render_task",
    "TiledRender",
    "assemble_tiles",
    "render_tiled",
]


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
    width, height, rows, cols = (checks.integer(value, name, low=1) for name, value in
                                 (("width", width), ("height", height), ("rows", rows), ("cols", cols)))
    if rows > height or cols > width:
        raise ValueError(f"tiles: {rows}x{cols} tiles do not fit a {width}x{height} film "
                         "(at most one tile per pixel row/column)")
    xs = [x + (j * width) // cols for j in range(cols + 1)]
    ys = [y + (i * height) // rows for i in range(rows + 1)]
    return [Tile(i * cols + j, xs[j], ys[i], xs[j + 1] - xs[j], ys[i + 1] - ys[i])
            for i in range(rows) for j in range(cols)]

def tile_seed(seed: int, index: int, count: int) -> int:
    """The sample seed of tile ``index`` of ``count``: ``(seed * count + index) mod 2^32``.

    Distinct for the ``count`` tiles of one render; ``count == 1`` gives ``seed``.

    Examples
    --------
    >>> [tile_seed(3, i, 4) for i in range(4)]
    [12, 13, 14, 15]
    """
    if not 0 <= index < count:
        raise ValueError(f"index: expected 0 <= index < {count}, got {index}")
    seed = checks.seed(seed)
    return (seed * count + index) & checks.UINT32_MAX


# --------------------------------------------------------------------------- render tasks
@register_result_type
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
    inputs_sha256 : str
        :func:`pointillist.plan.inputs_digest` of the scene's inputs (the scene file and every
        file it reads) and params; '' computes it when needed (:meth:`cache_token`).
    """

    scene: str
    params: tuple[tuple[str, str], ...] = ()
    spp: int | None = None
    seed: int = 0
    sensor: int = 0
    crop: tuple[int, int, int, int] | None = None
    inputs_sha256: str = ""

    def __post_init__(self):
        params = self.params
        if isinstance(params, dict):
            params = tuple(sorted((str(k), str(v)) for k, v in params.items()))
        else:
            params = tuple(sorted((str(k), str(v)) for k, v in params))
        object.__setattr__(self, "params", params)
        object.__setattr__(self, "scene", str(self.scene))
        if self.spp is not None:
            object.__setattr__(self, "spp", checks.integer(self.spp, "spp", low=1, high=checks.UINT32_MAX))
        object.__setattr__(self, "seed", checks.seed(self.seed))
        if self.crop is not None:
            crop = tuple(int(v) for v in self.crop)
            if len(crop) != 4 or min(crop[:2]) < 0 or min(crop[2:]) < 1:
                raise ValueError(f"crop: expected (offset_x >= 0, offset_y >= 0, width >= 1, height >= 1), "
                                 f"got {self.crop!r}")
            object.__setattr__(self, "crop", crop)

    def cache_token(self) -> dict[str, Any]:
        """What identifies the result: the fields, with the SHA-256 of the scene's inputs (a changed
        texture, mesh or included file is another task). Parses the scene when ``inputs_sha256``
        is empty (Mitsuba set up: :func:`pointillist.setup`)."""
        token = dataclasses.asdict(self)
        if not self.inputs_sha256:
            from pointillist.plan import scene_digest

            token["inputs_sha256"] = scene_digest(self.scene, dict(self.params))
        return token

@register_result_type
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

def _scene_for(task: RenderTask, *, merge_meshes: bool = True):
    """Load (or reuse) the task's scene in this process; returns (scene, sensor params, window, load s).
    ``merge_meshes``: :func:`pointillist.scene.parse_scene`'s."""
    import mitsuba as mi

    from pointillist.scene import load_scene

    path = Path(task.scene)
    try:
        stamp = path.stat().st_mtime_ns
    except OSError:
        raise UsageError(f"scene: no such file: {path}") from None
    key = (str(path.resolve()), stamp, task.params, task.inputs_sha256, merge_meshes)
    entry = _SCENES.get(key)
    load_s = 0.0
    if entry is None:
        start = time.perf_counter()
        scene = load_scene(path, dict(task.params), merge_meshes=merge_meshes)
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

def render_task(task: RenderTask, *, exact: bool = False) -> RenderResult:
    """Render one :class:`RenderTask` in this process (a Dask worker or the client).

    Sets up Mitsuba if needed, loads the scene (the last two scenes stay
    loaded per process), sets the film's crop window, renders with
    :func:`pointillist.scene.timed_render` and returns the image as numpy with the timing measured
    here. ``exact``: the same image to the last bit in every process: the scene loaded without
    Mitsuba's mesh merging (which orders emitters differently in each process,
    :func:`pointillist.scene.parse_scene`) and rendered on one thread.

    Raises
    ------
    UsageError
        For a missing or invalid scene file.
    ValueError
        For a sensor index or crop window outside the scene's film.
    """
    mi = setup_process()
    from pointillist.scene import timed_render

    scene, params, window, size, load_s = _scene_for(task, merge_meshes=not exact)
    _set_crop(mi, params, task.crop or window, size)
    image, timing = timed_render(scene, spp=task.spp, seed=task.seed, sensor=task.sensor, threads=1 if exact else None)
    pixels = np.array(image, dtype=np.float32, copy=True)
    del image
    return RenderResult(image=pixels, timing=dict(timing.as_dict(), load=load_s),
                        worker=f"{socket.gethostname()}:{os.getpid()}", task=task)


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
                 progress: bool = True, inputs_sha256: str = "") -> TiledRender:
    """Render a scene as ``rows x cols`` crop-window tiles (tasks) and assemble the image.

    Tile ``i`` renders with seed :func:`tile_seed` ``(seed, i, rows * cols)``.
    The tiles cover the scene's own crop window (the whole film unless the
    scene sets one); the image has that window's size. ``inputs_sha256``: the digest of
    the scene's inputs (:func:`pointillist.plan.inputs_digest`; computed when empty), which
    keys the cache and each worker's loaded scene.

    Examples
    --------
    >>> from pointillist.tiles import render_tiled
    >>> result = render_tiled("scenes/default.xml", {"res": "8"}, tiles=(2, 2), spp=1,
    ...                       progress=False)
    >>> result.image.shape, len(result.tiles)
    ((8, 8, 3), 4)
    """
    rows, cols = tiles
    path = Path(scene).resolve()
    setup_process()
    if not inputs_sha256:
        from pointillist.plan import scene_digest

        inputs_sha256 = scene_digest(path, params)
    probe = RenderTask(str(path), params or {}, spp, seed, sensor, inputs_sha256=inputs_sha256)
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
