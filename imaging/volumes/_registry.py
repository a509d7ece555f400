"""The volume readers by suffix: one registry behind :func:`load_volume`, its error message, the
table of the package docstring and the help of ``pointillist mip``.

A reader is one module of :mod:`pointillist.imaging.volumes.formats` that ends with
``register(VolumeReader(...))``; every module of that package is imported when
:mod:`pointillist.imaging.volumes` is.
"""

from __future__ import annotations

import importlib
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from pointillist.core import checks
from pointillist.imaging.volumes._model import Volume


def optional_package(module: str, label: str, package: str):
    """Import ``module`` for the ``label`` reader; ValueError naming the package and the extra
    that installs it (``pointillist[medical]``) when it is missing."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise ValueError(f"volume: reading {label} needs {package} (pip install 'pointillist[medical]')") from None


@dataclass(frozen=True)
class VolumeReader:
    """One volume format: how it is named, the suffixes that select it and its read function.

    Attributes
    ----------
    name : str
        The format as the docstring table shows it (reStructuredText; its suffixes get a column).
    label : str
        Short name (``"NIfTI"``); a folder reader is offered as "a LABEL folder".
    suffixes : tuple of str
        Lower-case file-name endings that select the reader (``".nii.gz"``).
    read : callable
        ``read(path, **options) -> Volume``.
    spacing_from : str
        Where the voxel spacing comes from (the table's second column).
    needs : str
        The package the reader imports (``"-"``: none beyond numpy).
    options : tuple of str
        The keyword arguments of :func:`load_volume` that ``read`` takes (``"frame"``, ``"series"``).
    folder : bool
        The reader reads a folder; a file with one of its suffixes stands for its folder.
    order : int
        Place in every list (the error message, the table, ``mip -h``).
    files : callable, optional
        ``files(path) -> list of Path``: the other files a volume file names and its reading reads
        (an NRRD header's detached data file), inputs of a command's plan like the file itself.
    """

    name: str
    label: str
    suffixes: tuple[str, ...]
    read: Callable[..., Volume]
    spacing_from: str
    needs: str = "-"
    options: tuple[str, ...] = ()
    folder: bool = False
    order: int = 100
    files: Callable[[Path], list[Path]] | None = None


_READERS: dict[str, VolumeReader] = {}


def register(reader: VolumeReader) -> VolumeReader:
    """Add ``reader`` to the registry (a suffix claimed twice is an error)."""
    for suffix in reader.suffixes:
        if suffix != suffix.lower() or not suffix.startswith("."):
            raise ValueError(f"suffix: expected a lower-case suffix starting with '.', got {suffix!r}")
        other = next((r for r in _READERS.values() if suffix in r.suffixes and r.label != reader.label), None)
        if other is not None:
            raise ValueError(f"suffix: {suffix} is already read by the {other.label} reader")
    _READERS[reader.label] = reader
    return reader


def volume_files(path: str | os.PathLike) -> list[Path]:
    """Every file reading the volume ``path`` reads: the file itself, then the files it names (its
    reader's ``files``: an NRRD header's detached data file). A command's plan takes them all as
    inputs, so that none is ever written over."""
    path = Path(path)
    reader = _reader_for(path.name.lower())
    extra = reader.files(path) if reader is not None and reader.files is not None and path.is_file() else []
    return [path, *extra]


def volume_readers() -> tuple[VolumeReader, ...]:
    """The registered readers in their listing order."""
    return tuple(sorted(_READERS.values(), key=lambda reader: (reader.order, reader.label)))


def volume_formats() -> str:
    """What :func:`load_volume` accepts, in words (every suffix, then "or a DICOM folder")."""
    readers = volume_readers()
    suffixes = ", ".join(suffix for reader in readers for suffix in reader.suffixes)
    folders = [f"a {reader.label} folder" for reader in readers if reader.folder]
    return " or ".join([suffixes, *folders]) if folders else suffixes


def reader_table() -> str:
    """The reStructuredText table of the readers (format, files, spacing from, needs)."""
    rows = [("format", "files", "spacing from", "needs")]
    for reader in volume_readers():
        files = " ".join(f"``{suffix}``" for suffix in reader.suffixes) + (" or a folder" if reader.folder else "")
        rows.append((reader.name, files, reader.spacing_from, reader.needs))
    widths = [max(len(row[column]) for row in rows) + 2 for column in range(len(rows[0]))]
    rule = "  ".join("=" * width for width in widths)
    lines = [rule, "  ".join(cell.ljust(width) for cell, width in zip(rows[0], widths)).rstrip(), rule]
    lines += ["  ".join(cell.ljust(width) for cell, width in zip(row, widths)).rstrip() for row in rows[1:]]
    return "\n".join([*lines, rule])


def _reader_for(name: str) -> VolumeReader | None:
    """The reader whose longest suffix ends ``name`` (lower case), or None."""
    matches = [(len(suffix), reader) for reader in _READERS.values() for suffix in reader.suffixes
               if name.endswith(suffix)]
    return max(matches, key=lambda match: match[0])[1] if matches else None


def load_volume(path: str | os.PathLike, *, spacing: Any = None, frame: int | None = None,
                series: str | int | None = None) -> Volume:
    """Read a volume: a file of one of the formats the registry holds, or a DICOM series folder.

    The reader is picked by the file's suffix (the table of :mod:`pointillist.imaging.volumes`).
    Every reader gives the voxel-to-patient transform in LPS (``Volume.affine``, see
    :mod:`pointillist.imaging.orientation`); ``.vol`` and ``.npy`` files carry none and
    their voxel axes x, y, z are taken as L, P, S (a DICOM axial stack's order).

    Parameters
    ----------
    path : str or path-like
        The file, or a folder of DICOM files (a ``.dcm`` file stands for its folder).
    spacing : float or sequence of 3 floats, optional
        Override the voxel spacing ``(sx, sy, sz)`` the file gives (or lacks); directions are kept.
    frame : int, optional
        The volume to read from a 4-D input (a 4-D NIfTI, a DICOM series with several
        volumes at each slice position); required for those, 0 is accepted for 3-D ones.
    series : str or int, optional
        A DICOM folder holding several series: the SeriesInstanceUID or its index in the
        list the error message shows (sorted by UID).

    Raises
    ------
    ValueError
        For a missing, unknown, corrupt or truncated file, naming it; a sheared orientation;
        a 4-D input without ``frame`` (the message says how many frames there are).

    Warns
    -----
    OrientationWarning
        One line, when an orientation tag is missing or degenerate, saying what was assumed.

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> from pointillist.imaging.volumes import load_volume
    >>> path = os.path.join(tempfile.mkdtemp(), "v.npy")
    >>> np.save(path, np.zeros((2, 3, 4), np.int16))
    >>> vol = load_volume(path, spacing=(0.5, 0.5, 2.0))
    >>> vol.shape_xyz, vol.extent, vol.axis_codes
    ((4, 3, 2), (2.0, 1.5, 4.0), 'LPS')
    """
    path = Path(path)
    name = path.name.lower()
    if frame is not None:
        checks.integer(frame, "frame", low=0)
    folder_readers = [reader for reader in volume_readers() if reader.folder]
    if path.is_dir() and folder_readers:
        reader, source = folder_readers[0], path
    elif not path.exists():
        raise ValueError(f"volume: no such file or folder: {path}")
    else:
        reader = _reader_for(name)
        if reader is None:
            raise ValueError(f"volume: {path}: unknown format; expected {volume_formats()}")
        source = path.parent if reader.folder else path
    options = {"frame": frame, "series": series}
    volume = reader.read(source, **{option: options[option] for option in reader.options})
    if frame not in (None, 0) and volume.metadata.get("frames", 1) == 1:
        raise ValueError(f"frame: {path} is a 3-D volume (one frame); got frame={frame}")
    if series is not None and not reader.folder:
        raise ValueError(f"series: only a DICOM folder holds series; {path} is not one")
    if spacing is not None:
        volume = volume.respaced(spacing)
    return volume
