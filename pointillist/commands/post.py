"""Post-process a render (EXR) or an 8-bit image with imaging steps, in order, and write PNG/EXR.

Only the steps asked for run. EXR input is linear light: a tone-mapping step
(``tonemap:...``) turns it into display intensities on 0..255; when the first
step that needs display intensities comes before any tone mapping,
``tonemap:clip`` (clip to 0..1, sRGB curve, scale to 255) is applied first and
said so. PNG/JPEG input is already on 0..255.

Without steps, the image is converted: ``post render.exr -o render.png`` writes the sRGB preview
that ``render --png`` writes.

Output: ``.png`` writes 8-bit (display values as they are, or an sRGB preview
of linear values when no step ran that leaves linear light); ``.exr`` writes the
float values as they are.
"""

from __future__ import annotations

import argparse
import sys

NAME = "post"
HELP = "tone-map, filter and dither a render (steps run in order)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of ``pointillist post`` to ``parser``."""
    parser.add_argument("input", nargs="?", help="input image: EXR render, or PNG/JPEG/TIFF")
    parser.add_argument("-o", "--output", help="output .png or .exr (required unless --list-steps)")
    parser.add_argument("--steps", metavar="STEPS",
                        help='steps separated by ";", e.g. "tonemap:reinhard,exposure=1;gamma:2.2"')
    parser.add_argument("--step", action="append", default=[], metavar="STEP",
                        help="one step (repeatable; runs after --steps)")
    parser.add_argument("--dither", metavar="METHOD[:ARGS]",
                        help="dither last, e.g. floyd_steinberg or ordered:levels=4")
    parser.add_argument("--report", action="store_true",
                        help="print statistics after each step (and the dither error)")
    parser.add_argument("--plot", action="store_true",
                        help="write a before/after histogram plot (OUTPUT stem + _histogram.png)")
    parser.add_argument("--plot-file", metavar="FILE", help="write the histogram plot here (implies --plot)")
    parser.add_argument("--list-steps", action="store_true", help="list the known steps and exit")



def run(args: argparse.Namespace) -> int:
    """Run ``pointillist post`` with the parsed ``args``; returns the exit status."""
    from pointillist.post import post_process, step_list

    if args.list_steps:
        print("\n".join(step_list()))
        return 0
    result = post_process(args.input, args.output, steps=args.steps or "", step=args.step, dither=args.dither,
                          report=args.report, plot=args.plot, plot_file=args.plot_file)
    for name, stats, extra in result.reports:
        print(f"{name}: {stats}")
        for key, value in extra.items():
            print(f"  {key}: {value:.6g}")
    for note in result.notes:
        print(f"pointillist post: warning: {note}", file=sys.stderr)
    print(f"wrote {result.output} ({'; '.join(result.done) or 'converted, no step'})")
    if result.plot is not None:
        print(f"wrote {result.plot}")
    return 0
