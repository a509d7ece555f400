"""Check that scenes render in pointillist as in Mitsuba: bit-identical images, and every plugin runs.

Each scene (a file, or every scene XML under a folder) is rendered by ``pointillist render`` and by
Mitsuba alone (``mi.load_file`` + ``mi.render``, same spp and seed) and the images compared bit
for bit; then with the ``whitted`` integrator, with each of pointillist's samplers, through a small
``compare`` sweep and a progressive ``--time`` render. Each scene runs in a process of its own, so
a crash is reported and the other scenes still run. Exit status 0 when every check passed, 1 when
one failed.
"""

from __future__ import annotations

import argparse

from pointillist.commands._types import non_negative_int, positive_int

NAME = "verify"
HELP = "check scenes render as in Mitsuba (bit-identical) and with every pointillist plugin"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of ``pointillist verify`` to ``parser``."""
    parser.add_argument("scenes", nargs="+", metavar="SCENE", help="scene XML files, or folders of them")
    parser.add_argument("--spp", type=positive_int, default=2, help="samples per pixel of each render (default 2)")
    parser.add_argument("--seed", type=non_negative_int, default=0, help="sample seed (default 0)")
    parser.add_argument("-D", dest="defines", action="append", default=[], metavar="KEY=VALUE",
                        help="override a scene parameter ($KEY in the XML) in every scene; repeatable")
    parser.add_argument("--only", metavar="STEPS",
                        help="comma-separated checks to run "
                             "(default all: mitsuba,whitted,samplers,compare,progressive)")


def run(args: argparse.Namespace) -> int:
    """Run ``pointillist verify`` with the parsed ``args``; returns the exit status."""
    from pointillist.differential import STEPS, verify_scenes
    from pointillist.core.errors import UsageError
    from pointillist.scene import parse_defines

    steps = STEPS if args.only is None else tuple(s.strip() for s in args.only.split(",") if s.strip())
    unknown = [s for s in steps if s not in STEPS]
    if unknown or not steps:
        raise UsageError(f"--only: expected some of {','.join(STEPS)}, got {args.only!r}")
    reports = verify_scenes(args.scenes, spp=args.spp, seed=args.seed, params=parse_defines(args.defines),
                            steps=steps)
    for report in reports:
        print(f"{'ok  ' if report.ok else 'FAIL'} {report.path}")
        for check in report.checks:
            print(f"     {'ok  ' if check.ok else 'FAIL'} {check.name}: {check.detail}")
    failed = sum(not report.ok for report in reports)
    refused = sum(report.ok and report.refused for report in reports)
    both = f" ({refused} of them refused by Mitsuba and pointillist alike: nothing rendered)" if refused else ""
    print(f"{len(reports) - failed} passed{both}, {failed} failed")
    return 1 if failed else 0
