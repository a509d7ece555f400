"""NRRD ``.nrrd`` / ``.nhdr`` files (pynrrd), placed in LPS."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from pointillist.core.errors import one_line
from pointillist.imaging.volumes._model import Volume, _check_claimed_size, _warn
from pointillist.imaging.volumes._registry import VolumeReader, optional_package, register

__all__ = ["read_nrrd", "nrrd_data_files"]

#: NRRD ``space`` values (full names and abbreviations of the NRRD spec) -> signs taking them to LPS.
_NRRD_SPACES = {
    "left-posterior-superior": (1, 1, 1), "lps": (1, 1, 1),
    "right-anterior-superior": (-1, -1, 1), "ras": (-1, -1, 1),
    "left-anterior-superior": (1, -1, 1), "las": (1, -1, 1),
}


def read_nrrd(path: str | os.PathLike) -> Volume:
    """Read a 3-D NRRD file with pynrrd, placed in LPS by ``space``, ``space directions``, ``space origin``.

    ``space`` RAS, LAS and LPS (full names or abbreviations) are converted to LPS.
    ``scanner-xyz`` (ACR-NEMA 2.0 / DICOM scanner coordinates; the NRRD spec does not pin
    its axes down) and ``3D-right-handed`` / ``3D-left-handed`` are taken as LPS, with a
    warning. A file with ``spacings`` only (no orientation) keeps its voxel axes as L, P, S
    with a warning, and so does a file whose ``space directions`` are ``none`` (NRRD's word for an
    axis without a direction in space) for two or three axes; a single ``none`` axis is completed
    as the right-handed normal of the other two (its ``spacings`` entry long, else 1), with a
    warning. The header's claimed data size is checked against the file's before reading. The
    array is read in C order: ``data[z, y, x]`` with NRRD's first (fastest) axis as x; ``space
    directions`` row n is axis n's step.
    """
    nrrd = optional_package("nrrd", "NRRD", "pynrrd")
    path = Path(path)
    try:
        header = nrrd.read_header(str(path))
        _check_nrrd_size(path, header)
        _check_inflated_size(path, header, nrrd)
        data, header = nrrd.read(str(path), index_order="C")
    except ValueError as error:
        if str(error).startswith("volume:"):
            raise
        raise ValueError(f"volume: {path}: not a readable NRRD file ({one_line(error) or type(error).__name__})") \
            from None
    except Exception as error:  # noqa: BLE001 - pynrrd raises NRRDError, OSError, zlib.error...
        raise ValueError(f"volume: {path}: not a readable NRRD file ({one_line(error) or type(error).__name__})") \
            from None
    if data.ndim != 3:
        raise ValueError(f"volume: {path}: expected a 3-D NRRD, got {data.ndim} dimensions")
    meta = {"format": "nrrd"}
    space = str(header.get("space", "")).strip().lower()
    origin = _nrrd_vector(header.get("space origin"))
    directions, assumed = _nrrd_directions(header.get("space directions"), header.get("spacings"))
    try:
        if directions is not None:
            if assumed:
                _warn(f"volume: {path}: {assumed}")
            signs = _NRRD_SPACES.get(space)
            if signs is None:
                _warn(f"volume: {path}: NRRD space {space or '(none)'!r} has no anatomical axes; taken as LPS")
                signs = (1, 1, 1)
            meta["space"] = space
            affine = np.eye(4)
            affine[:3, :3] = directions.T * np.asarray(signs, dtype=np.float64)[:, None]
            affine[:3, 3] = (origin if origin is not None else np.zeros(3)) * signs
            return Volume(np.ascontiguousarray(data), metadata=meta, affine=affine)
        spacing = (1.0, 1.0, 1.0)
        if header.get("spacings") is not None:
            spacing = tuple(float(s) for s in header["spacings"])
        assumed = assumed or "NRRD without 'space directions'"
        _warn(f"volume: {path}: {assumed}; voxel axes x, y, z taken as L, P, S")
        return Volume(np.ascontiguousarray(data), spacing, tuple(origin) if origin is not None else (0.0, 0.0, 0.0),
                      meta)
    except ValueError as error:
        raise ValueError(f"volume: {path}: {error}") from None


#: Bytes per value of each NRRD ``type`` (every spelling the NRRD format allows).
_NRRD_ITEMSIZE = {
    **dict.fromkeys(("signed char", "int8", "int8_t", "uchar", "unsigned char", "uint8", "uint8_t"), 1),
    **dict.fromkeys(("short", "short int", "signed short", "signed short int", "int16", "int16_t", "ushort",
                     "unsigned short", "unsigned short int", "uint16", "uint16_t"), 2),
    **dict.fromkeys(("int", "signed int", "int32", "int32_t", "uint", "unsigned int", "uint32", "uint32_t",
                     "float"), 4),
    **dict.fromkeys(("longlong", "long long", "long long int", "signed long long", "signed long long int", "int64",
                     "int64_t", "ulonglong", "unsigned long long", "unsigned long long int", "uint64", "uint64_t",
                     "double"), 8),
}


def _check_nrrd_size(path: Path, header: dict) -> None:
    """The claimed data size against the file's, before pynrrd allocates it (for data in the file
    itself, raw or compressed; a detached ``data file`` is pynrrd's to check)."""
    if header.get("data file") or header.get("datafile"):
        return
    sizes = [int(n) for n in np.atleast_1d(header.get("sizes", []))]
    kind = " ".join(str(header.get("type", "")).lower().split())
    itemsize = _NRRD_ITEMSIZE.get(kind, 1)  # an unknown or block type: pynrrd's own error follows
    encoding = str(header.get("encoding", "raw")).strip().lower()
    if encoding in ("txt", "text", "ascii"):
        itemsize = 2  # a digit and a separator at least
    if any(n < 1 for n in sizes):
        raise ValueError(f"volume: {path}: NRRD sizes must be positive, got {sizes}")
    _check_claimed_size(path, int(np.prod(sizes, dtype=object)) * itemsize,
                        f"{'x'.join(map(str, sizes))} values of type {kind}",
                        compressed=encoding in ("gzip", "gz", "bzip2", "bz2"))


#: Compressed NRRD data is measured this many bytes at a time (the most held at once).
_INFLATE_CHUNK = 1 << 20


def _check_inflated_size(path: Path, header: dict, nrrd) -> None:
    """ValueError when compressed (gzip, bzip2) data inflates to more bytes than the header's sizes
    and type claim, found by streaming through it a megabyte at a time before pynrrd inflates it
    whole (a 3 MB file that inflates to 3 GB asked 6.4 GB of memory before its size error).
    Data that does not decompress is left to pynrrd to report."""
    import bz2
    import zlib

    encoding = str(header.get("encoding", "raw")).strip().lower()
    if encoding not in ("gzip", "gz", "bzip2", "bz2"):
        return
    sizes = [int(n) for n in np.atleast_1d(header.get("sizes", []))]
    itemsize = _NRRD_ITEMSIZE.get(" ".join(str(header.get("type", "")).lower().split()))
    if itemsize is None or any(n < 1 for n in sizes):
        return  # pynrrd's own error follows
    expected = int(np.prod(sizes, dtype=object)) * itemsize + max(int(header.get("byte skip", 0) or 0), 0)
    source, offset = _data_start(path, header, nrrd)
    inflate = (zlib.decompressobj(zlib.MAX_WBITS | 32) if encoding in ("gzip", "gz") else bz2.BZ2Decompressor())
    total, pending = 0, b""
    try:
        with open(source, "rb") as stream:
            stream.seek(offset)
            while not inflate.eof:
                if not pending:
                    pending = stream.read(_INFLATE_CHUNK)
                    if not pending and (not isinstance(inflate, bz2.BZ2Decompressor) or inflate.needs_input):
                        return
                total += len(inflate.decompress(pending, _INFLATE_CHUNK))
                pending = inflate.unconsumed_tail if hasattr(inflate, "unconsumed_tail") else b""
                if total > expected:
                    raise ValueError(f"volume: {path}: its {encoding} data inflates to more than the {expected} "
                                     "bytes its header's sizes and type claim; a damaged or hostile file")
    except (OSError, EOFError, zlib.error):
        return


def _data_file(path: Path, header: dict) -> Path | None:
    """The detached data file the NRRD header of ``path`` names (``data file``), resolved against the
    header's folder as pynrrd resolves it; None for data inside the file."""
    name = header.get("data file") or header.get("datafile")
    if not name or not str(name).strip():
        return None
    data = Path(str(name).strip())
    return data if data.is_absolute() else path.parent / data


def _data_start(path: Path, header: dict, nrrd) -> tuple[Path, int]:
    """Where an NRRD's data starts: after the header in the file itself, or at the start of its
    detached data file (after its ``line skip`` lines)."""
    data = _data_file(path, header)
    if data is not None:
        with open(data, "rb") as stream:
            for _ in range(max(int(header.get("line skip", 0) or 0), 0)):
                stream.readline()
            return data, stream.tell()
    with open(path, "rb") as stream:
        nrrd.read_header(stream)
        return path, stream.tell()


def _nrrd_vector(value: Any) -> np.ndarray | None:
    """A finite 3-vector of a NRRD header (``space origin``), or None."""
    if value is None:
        return None
    try:
        vector = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        return None
    return vector if vector.shape == (3,) and np.all(np.isfinite(vector)) else None


def _nrrd_directions(value: Any, spacings: Any) -> tuple[np.ndarray | None, str | None]:
    """NRRD ``space directions`` as ``(3x3 array or None, what was assumed or None)``; row n is axis n's step.

    ``none`` marks an axis without a direction in space (NRRD's word for a non-spatial axis). With
    one such axis of three, it is completed as the right-handed normal of the other two, its length
    the axis's ``spacings`` entry (else 1); with more, or other unusable values, the orientation is
    left out (None: the caller takes the voxel axes as L, P, S).
    """
    if value is None:
        return None, None
    try:
        rows = [np.asarray(row, dtype=np.float64).reshape(-1) for row in value]
    except (TypeError, ValueError):
        rows = []
    usable = [row.shape == (3,) and bool(np.all(np.isfinite(row))) and bool(np.any(row)) for row in rows]
    if len(rows) == 3 and all(usable):
        return np.array(rows), None
    if len(rows) == 3 and sum(usable) == 2:
        missing = usable.index(False)
        normal = np.cross(rows[(missing + 1) % 3], rows[(missing + 2) % 3])  # (x, y, z) right-handed
        if np.linalg.norm(normal) > 0:
            try:
                step = float(np.atleast_1d(np.asarray(spacings, dtype=np.float64))[missing])
            except (TypeError, ValueError, IndexError):
                step = float("nan")
            length = step if np.isfinite(step) and step > 0 else 1.0
            rows[missing] = normal / np.linalg.norm(normal) * length
            return np.array(rows), (f"NRRD axis {missing} has no space direction ('none'); taken as the "
                                    f"right-handed normal of the other two, {length:g} long")
    given = ", ".join("a direction" if ok else "none" for ok in usable) or "nothing"
    return None, f"NRRD 'space directions' give {given}"


def nrrd_data_files(path: Path) -> list[Path]:
    """The detached data file an NRRD header names (``data file``), resolved as pynrrd resolves it
    (against the header's folder); none for data inside the file, or a header that does not read
    (its reading reports that). A data file outside the header's folder (an absolute name, ``..``)
    is said in a warning: a header can point a command at any file."""
    nrrd = optional_package("nrrd", "NRRD", "pynrrd")
    try:
        header = nrrd.read_header(str(path))
    except Exception:  # noqa: BLE001 - reading the volume reports it
        return []
    data = _data_file(path, header)
    if data is None:
        return []
    inside = os.path.realpath(path.parent)
    if os.path.commonpath([inside, os.path.realpath(data)]) != inside:
        _warn(f"volume: {path}: its data file {data} lies outside the header's folder")
    return [data]


register(VolumeReader(name="NRRD", label="NRRD", suffixes=(".nrrd", ".nhdr"), read=read_nrrd,
                      spacing_from="``space directions`` or ``spacings``", needs="pynrrd", order=30,
                      files=nrrd_data_files))
