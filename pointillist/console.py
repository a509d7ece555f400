"""The ``pointillist`` console script and ``python -m pointillist``.

The signal boundary (:mod:`pointillist.signals`) is installed before anything else is imported, so
that a SIGINT or SIGTERM at any moment of the process, start-up included, ends it with 130 / 143
and one line; then :func:`pointillist.cli.main` runs the command.
"""

from __future__ import annotations

import contextlib
import os
import sys

__all__ = ["main"]


def main() -> None:
    """Run ``pointillist`` with ``sys.argv`` and end the process with the command's exit status."""
    from pointillist import signals

    signals.install("pointillist")
    try:
        from pointillist.cli import main as command_line

        status = command_line()
    except SystemExit as done:  # argparse: --help, --version, a usage error (already printed)
        status = done.code if isinstance(done.code, int) else (0 if done.code is None else 2)
    status = signals.finish(status)
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    # os._exit, not sys.exit: the status decided with the signals blocked is the one the process
    # ends with (no signal can land in the interpreter's tear-down); every output is closed by now.
    os._exit(status)
