"""Render a Mitsuba scene XML with pointillist's plugins and write an EXR (and a PNG preview).

Prints the time split into scene loading, graph tracing, JIT compilation and
kernel execution. Extra film channels (AOVs, e.g. a per-pixel sample count)
are written as extra EXR layers.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from pointillist.commands._types import non_negative_int, positive_int
from pointillist.errors import UsageError

NAME = "render"
HELP = "render a scene XML to EXR (+ PNG preview)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", help="Mitsuba scene XML file")
    parser.add_argument("-o", "--output", help="output EXR (default: out/<scene name>.exr)")
    parser.add_argument("--spp", type=positive_int, help="samples per pixel (default: the scene's)")
    parser.add_argument("--seed", type=non_negative_int, default=0, help="sample seed (default 0)")
    parser.add_argument("--png", action="store_true", help="also write an sRGB PNG preview beside the EXR")
    parser.add_argument("-D", dest="defines", action="append", default=[], metavar="KEY=VALUE",
                        help="override a scene parameter ($KEY in the XML); repeatable")
    dist = parser.add_argument_group("tiles and Dask distributed (pointillist.distributed)")
    dist.add_argument("--tiles", type=tiles_arg, metavar="RxC",
                      help="split the film into R x C crop-window tiles, one task each, tile i seeded "
                           "(seed*R*C + i) mod 2^32 (default: one untiled render)")
    dist.add_argument("--workers", type=positive_int, metavar="N",
                      help="render the tiles on a local Dask cluster of N worker processes")
    dist.add_argument("--scheduler", metavar="ADDRESS",
                      help="render the tiles on an existing Dask cluster (e.g. tcp://host:8786)")
    dist.add_argument("--cache", metavar="DIR",
                      help="keep finished tiles in DIR; a rerun renders only the missing ones")


def tiles_arg(text: str) -> tuple[int, int]:
    """argparse type: ``RxC`` tiles (rows x columns)."""
    from pointillist.distributed import parse_tiles

    try:
        return parse_tiles(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error).removeprefix("tiles: ")) from None


def output_path(scene: str, output: str | None) -> Path:
    """The EXR path to write: ``output`` or ``out/<scene stem>.exr``; checks it is not the scene."""
    path = Path(output) if output else Path("out") / (Path(scene).stem + ".exr")
    if path.suffix.lower() != ".exr":
        raise UsageError(f"--output: expected a .exr file name, got {path}")
    if not output:
        path.parent.mkdir(parents=True, exist_ok=True)
    if path.exists() and Path(scene).exists() and path.resolve() == Path(scene).resolve():
        raise UsageError(f"--output: refusing to overwrite the input {path}")
    return path


def run(args: argparse.Namespace) -> int:
    from pointillist.scene import parse_defines

    params = parse_defines(args.defines)
    out = output_path(args.scene, args.output)
    if not out.parent.is_dir():
        raise UsageError(f"--output: folder {out.parent} does not exist")
    if args.tiles or args.workers or args.scheduler or args.cache:
        from pointillist.distributed import render_command

        return render_command(args, params, out)

    import pointillist
    from pointillist.scene import load_scene, scene_info, timed_render

    mi = pointillist.setup()
    start = time.perf_counter()
    scene = load_scene(args.scene, params)
    load_s = time.perf_counter() - start
    info = scene_info(scene)
    image, timing = timed_render(scene, spp=args.spp, seed=args.seed)
    spp = args.spp or info["spp"]
    write_render(out, image, scene, args.scene, dict(info, spp=spp, seed=args.seed), timing,
                 png=args.png)
    print(f"wrote {out}" + (f" and {out.with_suffix('.png')}" if args.png else ""))
    print(f"{info['width']}x{info['height']} at {spp} spp, integrator {info['integrator']}, "
          f"sampler {info['sampler']}")
    print(f"time: load {load_s:.2f} s, trace {timing.trace:.2f} s, JIT compile {timing.compile:.2f} s "
          f"({timing.kernels} kernels, {timing.cache_hits} from cache), render {timing.execute:.2f} s, "
          f"total {load_s + timing.total:.2f} s")
    del mi
    return 0


def write_render(out: Path, image, scene, scene_path: str, info: dict, timing, *, png: bool) -> None:
    """Write a render's EXR (extra channels as layers, metadata in the header) and PNG preview."""
    import numpy as np

    from pointillist.imaging.io import write_exr, write_png

    pixels = np.asarray(image)
    names = list(scene.integrator().aov_names())
    base = pixels.shape[2] - len(names)
    layers = {name: pixels[..., base + i] for i, name in enumerate(names)}
    metadata = dict(info, scene=str(scene_path), render_seconds=timing.total,
                    compile_seconds=timing.compile, execute_seconds=timing.execute,
                    trace_seconds=timing.trace)
    write_exr(out, pixels[..., :base], metadata, layers=layers, inputs=[scene_path])
    if png:
        write_png(out.with_suffix(".png"), pixels[..., :min(base, 3)], inputs=[scene_path])
        if SAMPLE_COUNT_LAYER in layers:
            write_sample_heatmap(out.with_suffix(f".{SAMPLE_COUNT_LAYER}.png"), layers[SAMPLE_COUNT_LAYER],
                                 inputs=[scene_path])


#: The EXR layer of a per-pixel sample count (written by the ``adaptive`` integrator).
SAMPLE_COUNT_LAYER = "sample_count"


def write_sample_heatmap(path: Path, counts, *, inputs=()) -> None:
    """Write a per-pixel sample count as a heat map PNG (viridis, with a colour bar)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from pointillist.imaging.io import atomic_write, check_output_path

    path = check_output_path(path, inputs, name="sample-count heat map")
    counts = np.asarray(counts, dtype=np.float64)
    height, width = counts.shape
    scale = 6.0 / max(height, width)
    fig, ax = plt.subplots(figsize=(max(width * scale, 2.5) + 1.2, max(height * scale, 2.0)), dpi=110)
    shown = ax.imshow(counts, cmap="viridis", interpolation="nearest",
                      vmin=float(counts.min()), vmax=max(float(counts.max()), float(counts.min()) + 1))
    fig.colorbar(shown, ax=ax, label="samples per pixel")
    ax.set_title(f"samples per pixel: mean {counts.mean():.1f}, max {counts.max():.0f}", fontsize=9)
    ax.set_axis_off()
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))
    plt.close(fig)
