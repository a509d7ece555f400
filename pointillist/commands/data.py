"""``pointillist data DIR``: write the sample inputs the guides use by name into DIR."""

from __future__ import annotations

import argparse

NAME = "data"
HELP = "write the sample inputs the guides use (a scene, a photo, CT volumes in every format) into a folder"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``pointillist data`` to ``parser``."""
    parser.add_argument("folder", metavar="DIR",
                        help="folder to write into (made when missing; no existing file is replaced)")


def run(args: argparse.Namespace) -> int:
    """Run ``pointillist data`` with the parsed ``args``; returns the exit status."""
    from pointillist.data import write_sample_data

    written = write_sample_data(args.folder)
    print(f"wrote {len(written)} sample inputs in {args.folder}: {', '.join(p.name for p in written)}")
    return 0
