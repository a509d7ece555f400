"""Compare sampling patterns on one scene: error against a reference versus run time and spp.

Renders SCENE with each sampler at each sample count (and seed), measures each
render's wall time (JIT compilation reported apart) and its RMSE, relative MSE and
FLIP against a high-sample reference, and writes DIR/results.csv, DIR/results.md
(table, fitted slopes, equal-time and equal-error rankings), DIR/error_vs_time.png,
DIR/error_vs_spp.png, the renders (EXR files in DIR/renders/) and DIR/report.html, a
self-contained page (open it from disk in a browser) with the table, interactive
plots and the renders and error maps side by side. Finished renders and their
scores are kept: running the same command again resumes an interrupted sweep, and
leaves the report's files alone while what they show is unchanged.
"""

from __future__ import annotations

import argparse

from pointillist.core.checks import UINT32_MAX
from pointillist.commands._types import add_cluster_options, positive_int

NAME = "compare"
HELP = "compare samplers: error vs time and spp against a reference"

__all__ = ["NAME", "HELP", "add_arguments", "run", "spp_list"]


def spp_list(text: str) -> list[int]:
    """argparse type: comma-separated positive integers (``1,4,16``)."""
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated positive integers, got {text!r}") from None
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"expected comma-separated positive integers, got {text!r}")
    if max(values) > UINT32_MAX:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers in 1..{UINT32_MAX}, got {text!r}")
    return sorted(set(values))



def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of ``pointillist compare`` to ``parser``."""
    from pointillist.compare import DEFAULT_METHODS, DEFAULT_SPP  # (cheap: no Mitsuba, no Dask)
    from pointillist.compare.methods import describe_methods

    parser.add_argument("scene", help="Mitsuba scene XML file")
    parser.add_argument("--samplers", default=",".join(DEFAULT_METHODS),
                        help=f"comma-separated samplers: {describe_methods()} (default {','.join(DEFAULT_METHODS)})")
    parser.add_argument("--spp", type=spp_list, default=list(DEFAULT_SPP),
                        help=f"samples per pixel to sweep (default {','.join(map(str, DEFAULT_SPP))})")
    parser.add_argument("--seeds", type=positive_int, default=1,
                        help="renders per point with seeds 0..K-1, K <= 1000; mean and spread reported (default 1)")
    reference = parser.add_mutually_exclusive_group()
    reference.add_argument("--reference-spp", type=positive_int, default=4096,
                           help="samples per pixel of the reference render, Mitsuba's stratified "
                                "sampler, cached in DIR/reference (default 4096)")
    reference.add_argument("--reference", metavar="FILE.exr", help="use this EXR as the reference")
    parser.add_argument("--out", metavar="DIR", help="output folder (default out/compare/<scene name>)")
    parser.add_argument("--no-progress", action="store_true",
                        help="no progress (default: a bar on a terminal, else one line per finished render)")
    parser.add_argument("--no-report", action="store_true",
                        help="do not write DIR/report.html (the interactive page of renders and error maps)")
    add_cluster_options(parser, work="render each (sampler, spp, seed) as a task timed on its worker (default: "
                        "in process)", shared="the scene and --out must be on a file system the workers share")
    parser.add_argument("-D", dest="defines", action="append", default=[], metavar="KEY=VALUE",
                        help="override a scene parameter ($KEY in the XML); repeatable")



def run(args: argparse.Namespace) -> int:
    """Run ``pointillist compare`` with the parsed ``args``; returns the exit status."""
    from pointillist.compare import compare_scene
    from pointillist.scene import parse_defines

    result = compare_scene(args.scene, methods=args.samplers, spp=args.spp, seeds=args.seeds,
                           reference_spp=args.reference_spp, reference=args.reference, out_dir=args.out,
                           params=parse_defines(args.defines), workers=args.workers, scheduler=args.scheduler,
                           progress=not args.no_progress, report=not args.no_report,
                           log=lambda line: print(line, flush=True))
    records, paths = result.records, result.paths
    print(f"{len(records)} renders ({result.new} new, {len(records) - result.new} reused) in {result.out_dir}")
    report = [k for k in ("csv", "md", "time_plot", "spp_plot", "spectrum_plot") if k in paths]
    written, kept = [k for k in report if k not in result.kept], [k for k in report if k in result.kept]
    if written:
        print("wrote " + ", ".join(str(paths[k]) for k in written))
    if kept:
        print("kept " + ", ".join(str(paths[k]) for k in kept) + " (what they show has not changed)")
    if "html" in paths:
        kept_page = ", kept: unchanged" if "html" in result.kept else ""
        print(f"report: {paths['html']} ({result.notes[-1]}{kept_page})")  # the other notes were logged
    return 0
