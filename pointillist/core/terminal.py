"""What long work shows while it runs: the one rule for drawing a progress bar.

A progress bar is drawn on standard error when the caller asks for progress and standard error
is a terminal: never into a log file, a pipe or a notebook's captured output, where its redraws
would be noise (a command there logs one line per finished step instead, if anything). Every
workflow that shows progress (``render`` in passes, ``compare``, tiles and Dask tasks, ``mip``
turntables) decides through :func:`draws_progress` and makes its bar with :func:`progress_bar`.

Examples
--------
>>> from pointillist.core.terminal import draws_progress
>>> draws_progress(False)
False
"""

from __future__ import annotations

import sys
from collections.abc import Iterable
from typing import IO, Any

__all__ = ["draws_progress", "progress_bar"]


def draws_progress(progress: bool, stream: IO[str] | None = None) -> bool:
    """Whether to draw a progress bar: ``progress`` asked for and ``stream`` (default standard
    error) a terminal."""
    stream = sys.stderr if stream is None else stream
    if not progress or stream is None:
        return False
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError, OSError):  # no isatty, or a closed stream
        return False


def progress_bar(iterable: Iterable | None = None, *, progress: bool, **options: Any):
    """A tqdm bar on standard error, drawn only where :func:`draws_progress` says so (otherwise it
    counts without drawing); ``options`` go to ``tqdm`` (``total``, ``desc``, ``unit``, ...).
    Cleared when closed (``leave=False``) unless ``options`` say otherwise.

    Examples
    --------
    >>> from pointillist.core.terminal import progress_bar
    >>> with progress_bar(range(3), progress=False, desc="frames") as bar:
    ...     total = sum(bar)
    >>> total, bar.disable
    (3, True)
    """
    from tqdm import tqdm

    options.setdefault("leave", False)
    return tqdm(iterable, disable=not draws_progress(progress), file=sys.stderr, **options)
