"""The ``pointillist`` console script and ``python -m pointillist``.

SIGINT and SIGTERM are blocked on this module's first line (held pending, not lost), the signal
boundary (:mod:`pointillist.core.signals`) is installed, and only then are they let through: from
here on a signal at any moment of the process, start-up included, ends it with 130 / 143 and
one line. Then :func:`pointillist.cli.main` runs the command.

Before this first line runs (the interpreter's own start-up, tens of milliseconds) a signal gets
Python's defaults: SIGTERM ends the process (a shell reports 143), Ctrl-C makes Python print
``KeyboardInterrupt``.
"""

from __future__ import annotations

import signal

# The first thing the process does once it is ours: hold the two signals until they are handled.
_HELD = (signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
         if hasattr(signal, "pthread_sigmask") else None)

import contextlib  # noqa: E402 - after the signals are held
import os  # noqa: E402
import sys  # noqa: E402

__all__ = ["main"]


def main() -> None:
    """Run ``pointillist`` with ``sys.argv`` and end the process with the command's exit status."""
    from pointillist.core import signals

    signals.install("pointillist", deadline=True)
    if _HELD is not None:
        # let the two through (a signal held so far is recorded now), also when the process was
        # started with them blocked: an inherited mask would otherwise hold them for ever
        signal.pthread_sigmask(signal.SIG_SETMASK, _HELD - {signal.SIGINT, signal.SIGTERM})
    try:
        from pointillist.cli import main as command_line

        status = command_line()
    except SystemExit as done:  # argparse: --help, --version, a usage error (already printed)
        status = done.code if isinstance(done.code, int) else (0 if done.code is None else 2)
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    # the last thing before the exit: a signal that landed up to here makes the status 130 / 143
    # (other threads may still take a signal after it: microseconds before the exit)
    status = signals.finish(status)
    # os._exit, not sys.exit: the status decided with the signals blocked is the one the process
    # ends with (no signal can land in the interpreter's tear-down); every output is closed by now.
    os._exit(status)
