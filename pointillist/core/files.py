"""Writing files: the output check, atomic writes and figures, for every layer.

The project's one way to write a file, whatever it holds (an image, a checkpoint, a CSV log, a
cache entry, a plot):

* :func:`check_output_path` says whether a path may be written: not a folder nor a device, not an
  input (the same file by device and inode, through ``..`` and links too; the files this process
  read as inputs count: :func:`mark_input`), not inside an input folder, in a folder that exists
  (or may be made) and takes new files. A command's plan (:class:`pointillist.plan.Plan`) runs it
  on every output before any work; each write runs it again.
* :func:`atomic_write` writes through a temporary file beside the target, renamed over it: a
  reader never sees a half-written file, and whatever stops the write leaves no temporary file.
* :func:`save_figure` writes a matplotlib figure that way.

Examples
--------
>>> import os, tempfile
>>> from pathlib import Path
>>> from pointillist.core.files import atomic_write, check_output_path
>>> folder = Path(tempfile.mkdtemp())
>>> atomic_write(folder / "log.csv", lambda tmp: Path(tmp).write_text("pass,spp\\n"))
>>> sorted(os.listdir(folder))
['log.csv']
>>> check_output_path(folder / "log.csv", inputs=[folder / "log.csv"], name="--output")
Traceback (most recent call last):
...
pointillist.core.errors.UsageError: --output: refusing to overwrite the input file .../log.csv
"""

from __future__ import annotations

import os
import stat
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from pointillist.core import signals
from pointillist.core.errors import UsageError

__all__ = ["file_id", "mark_input", "input_file", "unwritable", "existing_ancestor", "check_output_path",
           "atomic_write", "save_figure", "shown_in"]

#: (st_dev, st_ino) of every file this process read as an input (:func:`mark_input`).
_READ: set[tuple[int, int]] = set()


def file_id(path: str | os.PathLike) -> tuple[int, int] | None:
    """``(st_dev, st_ino)`` of the file at ``path`` (links followed), None when there is none."""
    try:
        stat = os.stat(path)
    except OSError:
        return None
    return stat.st_dev, stat.st_ino


def mark_input(path: str | os.PathLike) -> None:
    """Remember that this process read ``path`` as an input: no later write may replace it."""
    ident = file_id(path)
    if ident is not None:
        _READ.add(ident)


def input_file(path: str | os.PathLike, name: str = "path") -> Path:
    """``path`` as a Path, checked to be a file to read: a UsageError naming ``name`` when it is
    empty, missing, a folder, or not a regular file (a device, a pipe or a socket may never end).

    Examples
    --------
    >>> from pointillist.core.files import input_file
    >>> input_file("/", "--reference")
    Traceback (most recent call last):
    ...
    pointillist.core.errors.UsageError: --reference: / is a folder, expected a file
    """
    text = os.fspath(path)
    if not text:
        raise UsageError(f"{name}: expected a file name, got an empty one")
    path = Path(text)
    try:
        mode = path.stat().st_mode
    except OSError:
        raise UsageError(f"{name}: no such file: {path}") from None
    if stat.S_ISDIR(mode):
        raise UsageError(f"{name}: {path} is a folder, expected a file")
    if not stat.S_ISREG(mode):
        raise UsageError(f"{name}: {path} is not a regular file (a device, a pipe or a socket: it may never end)")
    return path


def unwritable(folder: str | os.PathLike) -> str:
    """Why no new file can be created in ``folder`` ('' when one can): a file is created there and
    removed, since permission bits do not tell for root, an immutable folder or ``/proc``."""
    try:
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as error:
        return str(error.strerror or error)
    return ""


def existing_ancestor(path: str | os.PathLike) -> Path:
    """The nearest folder at or above ``path`` that exists (``path`` itself when it does)."""
    current = Path(os.path.abspath(path))
    while not current.exists() and current != current.parent:
        current = current.parent
    return current


def check_output_path(path: str | os.PathLike, inputs: Iterable[str | os.PathLike] = (), name: str = "path", *,
                      make_parent: bool = False) -> Path:
    """Check that the file ``path`` may be written now; returns it as a :class:`~pathlib.Path`.

    Parameters
    ----------
    path : path-like
        The file to write.
    inputs : iterable of path-like
        Files the write may not replace and folders it may not write into (besides the files this
        process read: :func:`mark_input`).
    name : str
        What the messages call the output (an option such as ``--output``).
    make_parent : bool
        The file's folder may be missing (it is made when the work starts); a folder above it must
        then take new files.

    Raises
    ------
    pointillist.core.errors.UsageError
        (a ``ValueError``) naming ``name``: ``path`` is a folder, exists and is not a regular file,
        is an input or lies in an input folder, its name is too long for the temporary file written
        first (the file system's limit, 255 bytes on most, less 14 and the suffix), its folder is
        missing (unless ``make_parent``) or takes no new file (a file is created and removed there
        to find out: permission bits do not tell for root, an immutable folder or ``/proc``).
    """
    path = Path(path)
    if path.is_dir():
        raise UsageError(f"{name}: {path} is a folder, expected a file name")
    if path.exists() and not path.is_file():  # a device, a FIFO, a socket: never replaced
        raise UsageError(f"{name}: {path} exists and is not a regular file")
    inputs = [Path(p) for p in inputs]
    target = file_id(path)
    if target is not None and (target in _READ or target in {file_id(p) for p in inputs if not p.is_dir()}):
        raise UsageError(f"{name}: refusing to overwrite the input file {path}")
    real = Path(os.path.realpath(path))
    for folder in (Path(os.path.realpath(p)) for p in inputs if p.is_dir()):
        if folder in real.parents:
            raise UsageError(f"{name}: {path} lies in the input folder {folder}")
    parent = path.parent
    if not parent.is_dir():
        if parent.exists():
            raise UsageError(f"{name}: {parent} is not a folder")
        if not make_parent:
            raise UsageError(f"{name}: folder {parent} does not exist")
        parent = existing_ancestor(parent)
        if not parent.is_dir():
            raise UsageError(f"{name}: {parent} is not a folder")
    refused = unwritable(parent)
    if refused:
        raise UsageError(f"{name}: cannot write {path} ({refused})")
    longest = _name_max(parent) - _TEMPORARY_EXTRA - len(os.fsencode(path.suffix))
    if len(os.fsencode(path.name)) > longest:
        raise UsageError(f"{name}: the file name {path.name[:40]}... is {len(os.fsencode(path.name))} bytes long; "
                         f"at most {longest} fit in {parent} (the temporary file written first has a longer name)")
    return path


#: Bytes the temporary file's name adds to the output's (``.NAME.XXXXXXXX.tmp`` + the suffix again).
_TEMPORARY_EXTRA = len(".") + len(".") + 8 + len(".tmp")


def _name_max(folder: Path) -> int:
    """The longest file name the file system of ``folder`` takes, in bytes (255 where it does not say)."""
    try:
        return int(os.pathconf(folder, "PC_NAME_MAX"))
    except (OSError, ValueError):
        return 255


def atomic_write(path: str | os.PathLike, write: Callable[[str], Any]) -> None:
    """Call ``write(tmp_path)`` on a temporary file beside ``path``, then rename it over ``path``.

    The one way this project writes files: a reader never sees a half-written file, and a
    failed or interrupted write (an exception, Ctrl-C, SIGTERM, a second signal that ends
    ``pointillist`` at once) leaves the old file (if any) and no temporary file behind. An
    ``OSError`` (a folder that cannot be written, a full disk, a target that is a folder) is
    raised again with ``filename`` the target and a message naming it, never the temporary file.
    """
    path = Path(path)
    tmp = None
    try:
        # SIGINT/SIGTERM are held while the temporary file is created and its name bound, so that a
        # KeyboardInterrupt (Python's own handler, outside pointillist's signal boundary) always
        # finds `tmp` set and removes the file; under the boundary, a second signal that ends the
        # process at once removes it too (the name is registered as the file is made).
        with signals.held():
            tmp = signals.temporary_file(lambda: _temporary(path))
        try:
            write(tmp)
            os.chmod(tmp, 0o644)
            os.replace(tmp, path)
        except OSError as error:
            raise _naming(error, path) from None
    except BaseException:
        if tmp is not None:
            try:
                os.unlink(tmp)
            except OSError:
                pass
        raise
    finally:
        if tmp is not None:
            signals.forget_file(tmp)


def _temporary(path: Path) -> str:
    """A new empty file beside ``path`` (closed); its name."""
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp" + path.suffix, dir=path.parent)
    except OSError as error:
        raise _naming(error, path) from None
    os.close(fd)
    return tmp


def _naming(error: OSError, path: Path) -> OSError:
    """``error`` as the same OSError type naming ``path`` (the target), not a temporary file."""
    reason = error.strerror or str(error)
    if error.errno is None:
        return type(error)(f"cannot write {path}: {reason}")
    return type(error)(error.errno, f"cannot write {path}: {reason}", str(path))


def save_figure(fig, path: str | os.PathLike, *, inputs: Iterable[str | os.PathLike] = (), name: str = "path",
                **savefig: Any) -> None:
    """Write a matplotlib figure as PNG (:func:`check_output_path`, then :func:`atomic_write`) and
    close it (also on failure).

    ``inputs`` and ``name`` go to :func:`check_output_path`; ``savefig`` to ``Figure.savefig``
    (e.g. ``dpi``)."""
    import matplotlib.pyplot as plt

    try:
        path = check_output_path(path, inputs, name)
        atomic_write(path, lambda tmp: fig.savefig(tmp, format="png", **savefig))
    finally:
        plt.close(fig)


def shown_in(path: str | os.PathLike, folder: str | os.PathLike) -> str:
    """``path`` as a page written into ``folder`` shows it: relative to ``folder`` when it lies inside
    (a reference cached in the output folder reads ``reference/renders/...``, wherever the folder
    is), else as given.

    Examples
    --------
    >>> shown_in("/tmp/run/reference/a.exr", "/tmp/run"), shown_in("ref.exr", "/tmp/run")
    ('reference/a.exr', 'ref.exr')
    """
    inside = Path(os.path.abspath(path))
    try:
        return inside.relative_to(Path(os.path.abspath(folder))).as_posix()
    except ValueError:
        return os.fspath(path)
