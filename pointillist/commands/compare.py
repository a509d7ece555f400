"""Compare sampling patterns on one scene: error against a reference versus run time and spp.

Renders SCENE with each sampler at each sample count (and seed), measures each
render's wall time (JIT compilation reported apart) and its RMSE, relative MSE and
FLIP against a high-sample reference, and writes DIR/results.csv, DIR/results.md
(table, fitted slopes, equal-time and equal-error rankings), DIR/error_vs_time.png,
DIR/error_vs_spp.png and the renders (DIR/renders/*.exr). Finished renders are
kept: running the same command again resumes an interrupted sweep.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pointillist.commands._types import positive_int
from pointillist.errors import UsageError

NAME = "compare"
HELP = "compare samplers: error vs time and spp against a reference"


def spp_list(text: str) -> list[int]:
    """argparse type: comma-separated positive integers (``1,4,16``)."""
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated positive integers, got {text!r}") from None
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"expected comma-separated positive integers, got {text!r}")
    if max(values) >= 2**32:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers in 1..2^32-1, got {text!r}")
    return sorted(set(values))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from pointillist.compare import DEFAULT_METHODS, DEFAULT_SPP

    parser.add_argument("scene", help="Mitsuba scene XML file")
    parser.add_argument("--samplers", default=",".join(DEFAULT_METHODS),
                        help="comma-separated samplers: grid, jitter, random, poisson, and Mitsuba's "
                             "independent, stratified, multijitter, orthogonal, ldsampler; or adaptive "
                             "(adaptive super-sampling around the scene's integrator, sweeping its threshold "
                             "instead of --spp) (default "
                             f"{','.join(DEFAULT_METHODS)})")
    parser.add_argument("--spp", type=spp_list, default=list(DEFAULT_SPP),
                        help=f"samples per pixel to sweep (default {','.join(map(str, DEFAULT_SPP))})")
    parser.add_argument("--seeds", type=positive_int, default=1,
                        help="renders per point with seeds 0..K-1; mean and spread reported (default 1)")
    reference = parser.add_mutually_exclusive_group()
    reference.add_argument("--reference-spp", type=positive_int, default=4096,
                           help="samples per pixel of the reference render, Mitsuba's stratified "
                                "sampler, cached in DIR/reference (default 4096)")
    reference.add_argument("--reference", metavar="FILE.exr", help="use this EXR as the reference")
    parser.add_argument("--out", metavar="DIR", help="output folder (default out/compare/<scene name>)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    cluster = parser.add_mutually_exclusive_group()
    cluster.add_argument("--workers", type=positive_int, metavar="N",
                         help="render on a local Dask cluster of N worker processes, one task per render, "
                              "timed on the worker (default: serial, in process)")
    cluster.add_argument("--scheduler", metavar="ADDRESS",
                         help="render on an existing Dask cluster (e.g. tcp://host:8786); the scene and "
                              "--out must be on a file system the workers share")
    parser.add_argument("-D", dest="defines", action="append", default=[], metavar="KEY=VALUE",
                        help="override a scene parameter ($KEY in the XML); repeatable")


def run(args: argparse.Namespace) -> int:
    from pointillist.compare import METHODS, Task, render_reference, resolve_methods, run_sweep, write_report
    from pointillist.scene import check_sample_count, parse_defines

    params = parse_defines(args.defines)
    methods = resolve_methods(args.samplers)
    scene = Path(args.scene)
    if not scene.is_file():
        raise UsageError(f"scene: no such file: {scene}")
    out = Path(args.out) if args.out else Path("out") / "compare" / scene.stem
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out: {out} exists and is not a folder")
    if args.reference and not Path(args.reference).is_file():
        raise UsageError(f"--reference: no such file: {args.reference}")

    tasks = []
    for method in methods:
        values = args.spp if method.parameter == "spp" else list(method.values)
        if not values:
            raise UsageError(f"--samplers: {method.name} sweeps {method.parameter}, which has no values")
        tasks += [Task(method.name, v, seed) for v in values for seed in range(args.seeds)]
    size = _scene_size(scene, params)
    for spp in [t.value for t in tasks if METHODS[t.method].parameter == "spp"] + (
            [] if args.reference else [args.reference_spp]):
        check_sample_count(*size, int(spp))  # before any render starts (and its progress bar)
    if args.reference:
        _check_reference(Path(args.reference), size)
    out.mkdir(parents=True, exist_ok=True)

    if args.workers or args.scheduler:
        from pointillist.distributed import open_client, prerender_sweep

        with open_client(args.workers, args.scheduler) as client:
            new = prerender_sweep(client, scene, tasks, params=params, out_dir=out,
                                  reference_spp=None if args.reference else args.reference_spp,
                                  progress=not args.no_progress)
        print(f"{new} renders done on the cluster", flush=True)

    if args.reference:
        reference = Path(args.reference)
    else:
        print(f"reference: {args.reference_spp} spp with Mitsuba's stratified sampler "
              f"(cached in {out / 'reference'})", flush=True)
        reference = render_reference(str(scene), params, str(out), args.reference_spp)
        _check_reference(reference, size)

    records = run_sweep(str(scene), tasks, params=params, out_dir=str(out), reference=reference,
                        progress=not args.no_progress)
    paths = write_report(records, out, scene=str(scene), reference=str(reference),
                         title=f"Sampler comparison: {scene.name}")
    done = sum(1 for r in records if not r.cached)
    print(f"{len(records)} renders ({done} new, {len(records) - done} reused) in {out}")
    print(f"wrote {paths['csv']}, {paths['md']}, {paths['time_plot']}, {paths['spp_plot']}")
    return 0


def _scene_size(scene: Path, params: dict) -> tuple[int, int]:
    """``(width, height)`` the scene renders (loads it once: bad scenes fail before any render)."""
    import pointillist

    pointillist.setup()
    from pointillist.scene import load_scene, scene_info

    info = scene_info(load_scene(scene, params))
    return info["width"], info["height"]


def _check_reference(reference: Path, size: tuple[int, int]) -> None:
    """The reference must have the render size ``(width, height)``."""
    from pointillist.imaging.io import read_exr

    try:
        image = read_exr(reference).image
    except ValueError as error:
        raise UsageError(f"--reference: {error}") from None
    if image.shape[:2] != (size[1], size[0]):
        raise UsageError(f"--reference: {reference} is {image.shape[1]}x{image.shape[0]}, the scene "
                         f"renders {size[0]}x{size[1]}")


__all__ = ["NAME", "HELP", "add_arguments", "run", "spp_list"]
