"""The error the command line turns into exit status 2 and one line on stderr."""

from __future__ import annotations

__all__ = ["UsageError", "Terminated"]


class UsageError(ValueError):
    """Bad input from the user (file, option, scene): exit status 2, one line on stderr."""


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised like Ctrl-C's KeyboardInterrupt by ``pointillist``'s handler: the same clean-up
    runs (temporary files removed, clusters closed) and the command exits with status 143."""
