"""The error the command line turns into exit status 2 and one line on stderr."""

from __future__ import annotations

__all__ = ["UsageError", "ClusterError", "Terminated", "one_line"]


class UsageError(ValueError):
    """Bad input from the user (file, option, scene): exit status 2, one line on stderr."""


class ClusterError(RuntimeError):
    """The Dask cluster went away during the work (its scheduler stopped, or the network to it): exit
    status 1 and one line on stderr, saying what was kept (a checkpoint) and how to go on."""


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised like Ctrl-C's KeyboardInterrupt by ``pointillist``'s handler: the same clean-up
    runs (temporary files removed, clusters closed) and the command exits with status 143."""


def one_line(text: object, limit: int = 400) -> str:
    """A message as one line: its lines stripped and joined with ``" "``, cut to ``limit`` characters.

    For the messages of libraries (nibabel, pydicom, Pillow) that a ValueError passes on: the command
    line prints an error as one line.

    Examples
    --------
    >>> from pointillist.core.errors import one_line
    >>> one_line("Unable to decompress:\\n    gdcm - requires gdcm\\n    pylibjpeg - requires pylibjpeg\\n")
    'Unable to decompress: gdcm - requires gdcm pylibjpeg - requires pylibjpeg'
    """
    line = " ".join(part.strip() for part in str(text).splitlines() if part.strip())
    return line if len(line) <= limit else line[:limit - 3] + "..."
