"""``pointillist render``: load a scene, render it (whole, or as tiles on Dask), write EXR + PNG.

:func:`render_file` is the one entry point of the command; it returns a
:class:`RenderSummary` of what was rendered and how long each part took (scene
loading, graph tracing, JIT compilation, kernel execution), which the command prints.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pointillist.core.errors import UsageError
from pointillist.render_output import check_preview, output_path, render_outputs, write_render

__all__ = ["RenderSummary", "render_file"]


@dataclass
class RenderSummary:
    """What :func:`render_file` did.

    ``timing`` is a :class:`pointillist.scene.RenderTiming` (for tiles: sums over the
    tiles, ``total`` the wall time); ``where`` says where tiles ran (``None``
    untiled); ``cached`` how many tiles came from the cache; ``progressive`` the
    :class:`pointillist.progressive.ProgressiveResult` of a render in passes (else ``None``);
    ``recentring`` the :class:`pointillist.camera_relative.Recentring` the scene was loaded with.
    """

    exr: Path
    png: Path | None
    info: dict[str, Any]
    spp: int
    timing: Any
    load_seconds: float
    tiles: tuple[int, int] | None = None
    where: str | None = None
    cached: int = 0
    progressive: Any = None
    recentring: Any = None


def render_file(scene: str | os.PathLike, output: str | os.PathLike | None = None, *, spp: int | None = None,
                seed: int = 0, png: bool = False, params: dict[str, str] | None = None,
                tiles: tuple[int, int] | None = None, workers: int | None = None, scheduler: str | None = None,
                cache: str | os.PathLike | None = None, time_budget: float | None = None,
                target_error: float | None = None, pass_spp: int | None = None, variance_layer: bool = False,
                checkpoint: float | None = None, resume: bool = False, threads: int | None = None) -> RenderSummary:
    """Render ``scene`` to ``output`` (default ``out/<scene name>.exr``) and a PNG preview with ``png``.

    ``spp`` defaults to the scene's. ``threads`` sets the render's thread count (default all cores;
    1 renders the same image to the last bit on every run: :func:`pointillist.scene.thread_count`).
    ``tiles`` ``(rows, cols)``, ``workers``,
    ``scheduler`` or ``cache`` render the film as crop-window tiles
    (:func:`pointillist.tiles.render_tiled`), on a Dask cluster with the latter two.

    Progressive rendering (:mod:`pointillist.progressive`; in tiles, on a cluster with ``workers``
    or ``scheduler``: :mod:`pointillist.progressive.tiled`): with ``time_budget`` (seconds),
    ``target_error`` (estimated relMSE), ``pass_spp``, ``checkpoint`` (seconds between writes of
    ``OUT.checkpoint.npz``) or ``resume``, the render runs in passes until the budget is spent
    (``spp`` caps it; with neither time nor error budget, ``spp`` or the scene's is the total),
    writes ``OUT.progress.csv`` (and ``OUT.progress.png`` with ``png``) and, with
    ``variance_layer``, an EXR layer ``variance``. Ctrl-C / SIGTERM end it early, keeping the
    passes done (``interrupted`` in the header).

    Raises
    ------
    UsageError
        For a missing or invalid scene, an output that is not ``.exr``, is the scene
        itself, or lies in a folder that does not exist.
    """
    import pointillist
    from pointillist.core import signals
    from pointillist.camera_relative import make_camera_relative, offset_text
    from pointillist.channels import channel_layout
    from pointillist.plan import Output, Plan, scene_inputs
    from pointillist.scene import check_scene_file, instantiate_scene, parse_scene, scene_info, timed_render

    params = dict(params or {})
    progressive = (time_budget is not None or target_error is not None or pass_spp is not None or variance_layer
                   or checkpoint is not None or resume)
    tiled = bool(tiles or workers or scheduler or cache)
    if threads is not None:
        from pointillist.core.checks import integer

        threads = integer(threads, "threads", low=1, high=1024)
        if progressive or tiled:
            raise UsageError("--threads: only for a render in one piece (not with passes or tiles)")
    if progressive and cache:
        raise UsageError("--cache: not with progressive rendering (--time, --target-error, --pass-spp, "
                         "--variance-layer, --checkpoint, --resume); --checkpoint keeps its passes")
    if progressive and workers is not None and scheduler is not None:
        raise UsageError("--workers and --scheduler: give one or the other, not both")
    scene = check_scene_file(scene)
    out = output_path(str(scene), None if output is None else str(output))
    default = output is None
    # The plan, before any work: every output is checked writable now, and (once the scene is
    # parsed) none of them may be a file the scene reads.
    outputs = render_outputs(out, png=png, default=default)
    if progressive:
        from pointillist.progressive import checkpoint_path, progress_paths

        csv_path, plot_path = progress_paths(out)
        outputs.append(Output(csv_path, "progress log", make_parent=default))
        if png:
            outputs.append(Output(plot_path, "progress plot", make_parent=default))
        if checkpoint is not None or workers is not None or scheduler is not None:
            # on a cluster the checkpoint is also where the rounds done go when the scheduler is lost
            outputs.append(Output(checkpoint_path(out), "--checkpoint", make_parent=default))
    if cache:
        outputs.append(Output(Path(cache), "--cache", folder=True))
    plan = Plan(inputs=[scene], outputs=outputs)
    plan.check()
    pointillist.setup()
    start = time.perf_counter()
    # load_scene's steps, keeping the parsed scene: the header records the offset removed
    parsed = make_camera_relative(parse_scene(scene, params))
    plan.add(inputs=scene_inputs(parsed))
    loaded = instantiate_scene(parsed)
    load_s = time.perf_counter() - start
    info = dict(scene_info(loaded), origin_offset=offset_text(parsed.recentring))
    layout = channel_layout(loaded)
    check_preview(layout, png)
    plan.add(outputs=[o for o in render_outputs(out, png=png, layout=layout, default=default)
                      if o.path not in {p.path for p in plan.outputs}])
    png_path = out.with_suffix(".png") if png else None
    with plan.writing():
        if progressive:
            summary = _render_progressive(loaded, scene, out, png_path, info, params, seed=seed, png=png,
                                          load_s=load_s, time_budget=time_budget, target_error=target_error, spp=spp,
                                          pass_spp=pass_spp, variance_layer=variance_layer, checkpoint=checkpoint,
                                          resume=resume, plan=plan, layout=layout, tiles=tiles, workers=workers,
                                          scheduler=scheduler)
            summary.recentring = parsed.recentring
            return summary
        spp = spp or info["spp"]
        if not tiled:
            image, timing = timed_render(loaded, spp=spp, seed=seed, threads=threads)
            signals.check()  # stopped during the render: nothing is written
            _warn_nonfinite(image, layout)
            write_render(out, image, loaded, str(scene), dict(info, spp=spp, seed=seed), timing, png=png,
                         layout=layout, inputs=plan.inputs)
            return RenderSummary(exr=out, png=png_path, info=info, spp=spp, timing=timing, load_seconds=load_s,
                                 recentring=parsed.recentring)

        from pointillist.distributed import open_client
        from pointillist.plan import inputs_digest
        from pointillist.tiles import render_tiled

        tiles = tiles or (1, 1)
        with open_client(workers, scheduler, tasks=tiles[0] * tiles[1]) as client:
            where = _where(client)
            result = render_tiled(scene, params, tiles=tiles, spp=spp, seed=seed, client=client, cache=cache,
                                  progress=True, inputs_sha256=inputs_digest(plan.inputs, params))
        signals.check()
        _warn_nonfinite(result.image, layout)
        timing = result.timing()
        meta = dict(info, spp=spp, seed=seed, tile_grid=f"{tiles[0]}x{tiles[1]}",
                    tile_seeds=f"(seed*{len(result.tiles)}+tile) mod 2^32")
        write_render(out, result.image, loaded, str(scene), meta, timing, png=png, layout=layout, inputs=plan.inputs)
        return RenderSummary(exr=out, png=png_path, info=info, spp=spp, timing=timing, load_seconds=load_s,
                             tiles=tiles, where=where, cached=result.cached, recentring=parsed.recentring)


def _where(client) -> str:
    """Where tiles run, for the summary line: ``in process`` or ``on N worker(s) at ADDRESS``."""
    if client is None:
        return "in process"
    return f"on {len(client.scheduler_info(n_workers=-1)['workers'])} worker(s) at {client.scheduler.address}"


def _warn_nonfinite(image, layout) -> None:
    """A warning when the colour of some pixels is NaN or inf (a scene or integrator that gives
    non-finite values; they are written as they are), as a progressive render warns."""
    import warnings

    if not layout.colour:
        return
    colour = layout.pick(image, layout.colour)  # (H, W, 1 or 3), a Dr.Jit tensor or numpy
    pixels = int(colour.shape[0]) * int(colour.shape[1])
    if hasattr(colour, "array"):  # per pixel: how many of its channels are NaN or inf, then how many pixels have one
        import drjit as dr

        values = colour.array
        counter = dr.uint32_array_t(type(values))
        flags = dr.select(dr.isfinite(values), counter(0), counter(1))
        bad = int(dr.count(dr.block_sum(flags, int(colour.shape[2])) > 0)[0])
    else:
        import numpy as np

        bad = int(np.count_nonzero(~np.isfinite(colour).all(axis=-1)))
    if bad:
        warnings.warn(f"{bad} of {pixels} pixels are NaN or inf (the scene or its integrator gives non-finite "
                      "values); they stay so in the image", stacklevel=3)


def _render_progressive(loaded, scene, out: Path, png_path: Path | None, info: dict, params: dict, *, seed: int,
                        png: bool, load_s: float, time_budget, target_error, spp, pass_spp, variance_layer: bool,
                        checkpoint, resume: bool, plan, layout, tiles=None, workers=None,
                        scheduler=None) -> RenderSummary:
    """The progressive branch of :func:`render_file`: passes, EXR with their metadata, progress log.

    With ``tiles``, ``workers`` or ``scheduler`` the passes are tiles' passes in rounds
    (:func:`pointillist.progressive.tiled.render_progressive_tiled`), on a Dask cluster with the
    latter two (default tiles :data:`~pointillist.progressive.tiled.DEFAULT_TILES`). A second signal
    during the passes abandons the pass in flight: the EXR and the progress log of the passes done
    are written then (no PNG: the process ends at once).
    """
    from pointillist.core import signals
    from pointillist.progressive import Budget, checkpoint_path, render_progressive, write_progress

    if time_budget is None and target_error is None:
        spp = spp or info["spp"]
    budget = Budget(seconds=time_budget, target_error=target_error, spp=spp, pass_spp=pass_spp)

    def write(result, *, png: bool) -> None:
        layers = {"variance": result.variance} if variance_layer else {}
        if result.spp_map is not None:   # in tiles: where the samples went
            layers["tile_spp"] = result.spp_map
        write_render(out, result.image, loaded, str(scene), dict(info, **result.metadata), result.timing, png=png,
                     extra_layers=layers, layout=layout, inputs=plan.inputs)
        write_progress(out, result.history, png=png, inputs=plan.inputs)

    where = None
    if tiles or workers is not None or scheduler is not None:
        from pointillist.distributed import open_client
        from pointillist.progressive.tiled import DEFAULT_TILES, render_progressive_tiled

        tiles = tiles or DEFAULT_TILES
        cluster = workers is not None or scheduler is not None
        with open_client(workers, scheduler, drjit_threads=1) as client:
            where = _where(client)
            result = render_progressive_tiled(
                loaded, scene, budget, tiles=tiles, params=params, seed=seed, client=client,
                checkpoint_seconds=checkpoint,
                checkpoint_file=checkpoint_path(out) if checkpoint is not None or resume or cluster else None,
                resume=resume, progress=True, inputs=plan.inputs, layout=layout,
                abandon=lambda partial: write(partial, png=False))
    else:
        result = render_progressive(loaded, scene, budget, params=params, seed=seed, checkpoint_seconds=checkpoint,
                                    checkpoint_file=checkpoint_path(out) if checkpoint is not None or resume else None,
                                    resume=resume, progress=True, inputs=plan.inputs, layout=layout,
                                    abandon=lambda partial: write(partial, png=False))
    with signals.on_abandon(lambda: write(result, png=False)):  # a second signal while writing: the EXR still is
        write(result, png=png)
    return RenderSummary(exr=out, png=png_path, info=info, spp=result.stats.spp, timing=result.timing,
                         load_seconds=load_s, progressive=result, tiles=tiles, where=where)
