"""Render a Mitsuba scene XML with pointillist's plugins and write an EXR (and a PNG preview).

Prints the time split into scene loading, graph tracing, JIT compilation and
kernel execution. Extra film channels (AOVs, e.g. a per-pixel sample count)
are written as extra EXR layers.
"""

from __future__ import annotations

import argparse
import sys

from pointillist.commands._types import add_cluster_options, non_negative_int, positive_float, positive_int

NAME = "render"
HELP = "render a scene XML to EXR (+ PNG preview)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of ``pointillist render`` to ``parser``."""
    parser.add_argument("scene", help="Mitsuba scene XML file")
    parser.add_argument("-o", "--output", help="output EXR (default: out/<scene name>.exr)")
    parser.add_argument("--spp", type=positive_int, help="samples per pixel (default: the scene's)")
    parser.add_argument("--seed", type=non_negative_int, default=0, help="sample seed (default 0)")
    parser.add_argument("--png", action="store_true", help="also write an sRGB PNG preview beside the EXR")
    parser.add_argument("--threads", type=positive_int, metavar="N",
                        help="render on N threads (default: every core); 1 gives the same image to the last bit "
                             "on every run, as Mitsuba's own render on one thread")
    parser.add_argument("-D", dest="defines", action="append", default=[], metavar="KEY=VALUE",
                        help="override a scene parameter ($KEY in the XML); repeatable")
    prog = parser.add_argument_group(
        "progressive rendering (pointillist.progressive): passes with their own seeds, a running relMSE estimate "
        "from the spread between passes; --spp caps the total; writes OUT.progress.csv (+ .png with --png)")
    prog.add_argument("--time", type=positive_float, metavar="SECONDS", dest="time_budget",
                      help="render passes until SECONDS of rendering are spent")
    prog.add_argument("--target-error", type=positive_float, metavar="E",
                      help="render passes until the estimated relMSE (epsilon 0.01, as in compare) is at most E "
                           "and trusted (its two halves of passes agree)")
    prog.add_argument("--pass-spp", type=positive_int, metavar="N",
                      help="samples per pixel of each pass (default: powers of two, passes of about 2 s); with --time, "
                           "the most a pass takes (no pass outlasts the budget)")
    prog.add_argument("--variance-layer", action="store_true",
                      help="add an EXR layer 'variance': per-pixel variance of the mean (colour channels averaged)")
    prog.add_argument("--checkpoint", type=positive_float, metavar="SECONDS",
                      help="write the running state to OUT.checkpoint.npz every SECONDS (atomically)")
    prog.add_argument("--resume", action="store_true",
                      help="continue from OUT.checkpoint.npz (same scene file, -D values, seed; budgets count "
                           "the resumed passes)")
    dist = parser.add_argument_group("tiles and Dask distributed (pointillist.tiles)")
    dist.add_argument("--tiles", type=tiles_arg, metavar="RxC",
                      help="split the film into R x C crop-window tiles, one task each, tile i seeded "
                           "(seed*R*C + i) mod 2^32 (default: one untiled render); with progressive rendering, "
                           "rounds of tile passes, pass k of tile i seeded (TEA(seed, i) + k) mod 2^32, each on one "
                           "thread (the same EXR on any number of workers), --target-error giving the passes to "
                           "the noisiest tiles (default on a cluster: 4x4)")
    add_cluster_options(dist, work="render the tiles", shared="the workers read the scene by the same path")
    dist.add_argument("--cache", metavar="DIR",
                      help="keep finished tiles in DIR; a rerun renders only the missing ones")



def tiles_arg(text: str) -> tuple[int, int]:
    """argparse type: ``RxC`` tiles (rows x columns)."""
    from pointillist.tiles import parse_tiles

    try:
        return parse_tiles(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error).removeprefix("tiles: ")) from None



def run(args: argparse.Namespace) -> int:
    """Run ``pointillist render`` with the parsed ``args``; returns the exit status."""
    from pointillist.render import render_file
    from pointillist.scene import parse_defines

    done = render_file(args.scene, args.output, spp=args.spp, seed=args.seed, png=args.png,
                       params=parse_defines(args.defines), tiles=args.tiles, workers=args.workers,
                       scheduler=args.scheduler, cache=args.cache, time_budget=args.time_budget,
                       target_error=args.target_error, pass_spp=args.pass_spp, variance_layer=args.variance_layer,
                       checkpoint=args.checkpoint, resume=args.resume, threads=args.threads)
    info, timing = done.info, done.timing
    print(f"wrote {done.exr}" + (f" and {done.png}" if done.png else ""))
    if done.recentring is not None and done.recentring.moved:
        print(f"camera-relative: positions re-expressed relative to {info['origin_offset']} "
              f"({done.recentring.reason}; EXR header origin_offset)")
    if done.progressive is not None:
        result, stats = done.progressive, done.progressive.stats
        for warning in result.warnings:
            print(f"pointillist render: warning: {warning}", file=sys.stderr)
        tiles = (f" as {done.tiles[0]}x{done.tiles[1]} tiles {done.where} ({result.metadata['tile_spp']} spp per "
                 f"tile; passes are rounds)" if done.tiles else "")
        print(f"{info['width']}x{info['height']}, integrator {info['integrator']}, sampler {info['sampler']}{tiles}: "
              f"{stats.spp} spp in {stats.passes} passes, {stats.seconds:.2f} s (JIT compile "
              f"{stats.compile_seconds:.2f} s), estimated relMSE {stats.estimated_relmse:.4g} "
              f"({stats.estimate_state}), stopped by {result.stop}"
              + (f" (resumed from {result.resumed_from} passes)" if result.resumed_from else ""))
        if result.interrupted:  # the passes done are written, but it is not done: 130 (Ctrl-C) / 143 (SIGTERM)
            from pointillist.core import signals

            print(f"pointillist render: {signals.message(result.signum)}", file=sys.stderr)
            return signals.status(result.signum) if result.signum is not None else 130
        return 0
    if done.tiles is None:
        print(f"{info['width']}x{info['height']} at {done.spp} spp, integrator {info['integrator']}, "
              f"sampler {info['sampler']}")
        print(f"time: load {done.load_seconds:.2f} s, trace {timing.trace:.2f} s, JIT compile {timing.compile:.2f} s "
              f"({timing.kernels} kernels, {timing.cache_hits} from cache), render {timing.execute:.2f} s, "
              f"total {done.load_seconds + timing.total:.2f} s")
        return 0
    rows, cols = done.tiles
    print(f"{info['width']}x{info['height']} at {done.spp} spp as {rows}x{cols} tiles {done.where}, "
          f"integrator {info['integrator']}, sampler {info['sampler']}"
          + (f"; {done.cached} of {rows * cols} tiles from the cache" if done.cached else ""))
    print(f"time: load {done.load_seconds:.2f} s, wall {timing.total:.2f} s; summed over tiles on the workers: "
          f"trace {timing.trace:.2f} s, JIT compile {timing.compile:.2f} s ({timing.kernels} kernels, "
          f"{timing.cache_hits} from cache), render {timing.execute:.2f} s")
    return 0
