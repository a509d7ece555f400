"""Volume data for maximum intensity projection: loaders, a CT phantom, compact Dr.Jit textures.

A :class:`Volume` holds a scalar 3-D array in ``(Z, Y, X)`` order (C order:
``data[z, y, x]``, x varies fastest, like Mitsuba's ``.vol`` files and Dr.Jit's
3-D textures), the voxel spacing ``(sx, sy, sz)`` in physical units (mm for
medical data, 1 per voxel when a format has none), the position of voxel
``(0, 0, 0)``'s centre (``origin``, kept as metadata) and format metadata.

Readers (:func:`load_volume` picks one by the path):

============================  ==========================================  ===================
format                        spacing from                                needs
============================  ==========================================  ===================
Mitsuba ``.vol`` (float32)    bounding box / resolution                   -
numpy ``.npy`` (3-D)          ``spacing=`` argument (default 1)           -
NRRD ``.nrrd`` / ``.nhdr``    ``space directions`` or ``spacings``        pynrrd
NIfTI ``.nii`` / ``.nii.gz``  the affine's column norms                   nibabel
DICOM series (a folder)       PixelSpacing, slice positions               pydicom
============================  ==========================================  ===================

DICOM slices are sorted by ImagePositionPatient along the slice normal and
converted to Hounsfield units with RescaleSlope / RescaleIntercept. Integer
data keeps its dtype (int16 CT stays 2 bytes a voxel); the .npy reader reads in
slabs so a file is never held twice. Corrupt or truncated files raise
ValueError naming the file.

:func:`volume_texture` turns a volume into a Dr.Jit 3-D texture: 16-bit and
8-bit data go into a half-precision texture (``drjit.llvm.Texture3f16``, 2 bytes
a voxel, shared with numpy without a copy), offset so that every integer value
is exact (float16 holds the integers -2048..2048 exactly, so any 12-bit CT
range fits); other data into float32 textures.
"""

from __future__ import annotations

import gzip
import os
import struct
import sys
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pointillist import checks
from pointillist.errors import one_line
from pointillist.imaging.orientation import LPS_FROM_RAS, axis_codes, check_affine, snap_directions

__all__ = [
    "Volume", "load_volume", "read_vol", "write_vol", "read_npy", "read_nrrd", "read_nifti",
    "read_dicom_series", "OrientationWarning", "shepp_logan_phantom", "volume_texture", "VolumeTexture",
    "SHEPP_LOGAN_HU",
]

#: Voxels per slab when the phantom is evaluated (bounds its temporary memory).
_PHANTOM_SLAB_VOXELS = 8 << 20

#: Integers a float16 holds exactly: -2048..2048 (11-bit significand).
_HALF_EXACT = 2048


@dataclass
class Volume:
    """A scalar volume: ``data[z, y, x]`` with voxel spacing ``(sx, sy, sz)`` and its place in the patient.

    Attributes
    ----------
    data : numpy.ndarray
        3-D array (Z, Y, X), any real dtype.
    spacing : tuple of float
        Voxel size along x, y, z (physical units, > 0); the column norms of ``affine``.
    origin : tuple of float
        Position of the centre of voxel (0, 0, 0) in patient LPS (``affine[:3, 3]``).
    metadata : dict
        What the format said (e.g. DICOM modality, the file's own NIfTI affine).
    affine : numpy.ndarray, optional
        4x4 voxel-to-patient transform: voxel index ``(i, j, k, 1)`` (i along x, the
        fastest axis of ``data``) to LPS millimetres (see :mod:`pointillist.imaging.orientation`).
        When given, ``spacing`` and ``origin`` are taken from it; sheared transforms are refused.
        Default: ``diag(spacing)`` + ``origin``: voxel x, y, z taken as L, P, S (no orientation).
    oriented : bool, optional
        Whether the file gave a patient orientation (default: whether ``affine`` was given).
    """

    data: np.ndarray
    spacing: tuple[float, float, float] = (1.0, 1.0, 1.0)
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    metadata: dict[str, Any] = field(default_factory=dict)
    affine: np.ndarray | None = None
    oriented: bool | None = None

    def __post_init__(self) -> None:
        data = self.data
        if not isinstance(data, np.ndarray):
            data = np.asarray(data)
        if data.ndim != 3:
            raise ValueError(f"data: expected a 3-D array (Z, Y, X), got shape {data.shape}")
        if data.size == 0:
            raise ValueError(f"data: expected a non-empty volume, got shape {data.shape}")
        if data.dtype == np.bool_:
            data = data.astype(np.uint8)
        if not np.issubdtype(data.dtype, np.number) or np.iscomplexobj(data):
            raise TypeError(f"data: expected a real numeric array, got dtype {data.dtype}")
        self.data = data
        if self.oriented is None:
            self.oriented = self.affine is not None
        if self.affine is None:
            self.spacing = _check_spacing(self.spacing)
            self.origin = tuple(float(o) for o in self.origin)  # type: ignore[assignment]
            affine = np.diag([*self.spacing, 1.0])
            affine[:3, 3] = self.origin
            self.affine = affine
        else:
            self.affine, spacing, _ = check_affine(self.affine)
            self.spacing = _check_spacing(spacing)
            self.origin = tuple(float(o) for o in self.affine[:3, 3])  # type: ignore[assignment]

    @property
    def shape_xyz(self) -> tuple[int, int, int]:
        """Voxel counts (nx, ny, nz)."""
        nz, ny, nx = self.data.shape
        return nx, ny, nz

    @property
    def extent(self) -> tuple[float, float, float]:
        """Physical size of the volume's box along x, y, z (counts x spacing)."""
        return tuple(n * s for n, s in zip(self.shape_xyz, self.spacing))  # type: ignore[return-value]

    @property
    def directions(self) -> np.ndarray:
        """Unit direction cosines (3x3, columns = voxel axes x, y, z in LPS), round-off snapped.

        Entries within 1e-6 of 0 or +-1 are exact (:func:`~pointillist.imaging.orientation.snap_directions`).
        """
        return snap_directions(self.affine[:3, :3] / np.asarray(self.spacing))

    @property
    def axis_codes(self) -> str:
        """Where voxel axes x, y, z point, e.g. ``"LPS"`` (DICOM axial) or ``"RAS"`` (see :func:`axis_codes`)."""
        return axis_codes(self.directions)

    def respaced(self, spacing: Any) -> "Volume":
        """The same volume with voxel spacing ``spacing`` (directions and origin kept)."""
        spacing = _check_spacing(spacing)
        affine = self.affine.copy()
        affine[:3, :3] = self.affine[:3, :3] / np.asarray(self.spacing) * np.asarray(spacing)
        return Volume(self.data, spacing, self.origin, self.metadata, affine, self.oriented)


def _check_spacing(spacing: Any) -> tuple[float, float, float]:
    try:
        values = tuple(float(s) for s in np.broadcast_to(np.asarray(spacing, dtype=np.float64), (3,)))
    except (TypeError, ValueError):
        raise ValueError(f"spacing: expected three positive numbers (sx, sy, sz), got {spacing!r}") from None
    if not all(np.isfinite(s) and s > 0 for s in values):
        raise ValueError(f"spacing: expected three positive finite numbers (sx, sy, sz), got {values}")
    return values  # type: ignore[return-value]


# --------------------------------------------------------------------------------------------
# Readers and writers
# --------------------------------------------------------------------------------------------

def load_volume(path: str | os.PathLike, *, spacing: Any = None, frame: int | None = None,
                series: str | int | None = None) -> Volume:
    """Read a volume from a ``.vol``, ``.npy``, NRRD or NIfTI file or a DICOM series folder.

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
    if frame is not None and (isinstance(frame, bool) or not isinstance(frame, (int, np.integer)) or frame < 0):
        raise ValueError(f"frame: expected a non-negative integer, got {frame!r}")
    if path.is_dir():
        volume = read_dicom_series(path, frame=frame, series=series)
    elif not path.exists():
        raise ValueError(f"volume: no such file or folder: {path}")
    elif name.endswith(".vol"):
        volume = read_vol(path)
    elif name.endswith(".npy"):
        volume = read_npy(path)
    elif name.endswith((".nrrd", ".nhdr")):
        volume = read_nrrd(path)
    elif name.endswith((".nii", ".nii.gz")):
        volume = read_nifti(path, frame=frame)
    elif name.endswith(".dcm"):
        volume = read_dicom_series(path.parent, frame=frame, series=series)
    else:
        raise ValueError(f"volume: {path}: unknown format; expected .vol, .npy, .nrrd, .nhdr, "
                         ".nii, .nii.gz or a DICOM folder")
    if frame not in (None, 0) and volume.metadata.get("frames", 1) == 1:
        raise ValueError(f"frame: {path} is a 3-D volume (one frame); got frame={frame}")
    if series is not None and not (path.is_dir() or name.endswith(".dcm")):
        raise ValueError(f"series: only a DICOM folder holds series; {path} is not one")
    if spacing is not None:
        volume = volume.respaced(spacing)
    return volume


class OrientationWarning(UserWarning):
    """A file's orientation was missing or degenerate and something was assumed (the message says what)."""


def _warn(message: str) -> None:
    import warnings

    warnings.warn(message, OrientationWarning, stacklevel=3)


def _pick_frame(path: Path, frames: int, frame: int | None) -> int:
    """Check ``frame`` against a 4-D input's ``frames`` count (a clear error without one)."""
    if frame is None:
        raise ValueError(f"volume: {path} is 4-D with {frames} frames; choose one with frame=0..{frames - 1} "
                         f"(--frame N)")
    if frame >= frames:
        raise ValueError(f"frame: {path} has {frames} frames (0..{frames - 1}), got frame={frame}")
    return int(frame)


_VOL_HEADER = struct.Struct("<3sB i 4i 6f")  # 'VOL', version, encoding, xres, yres, zres, ch, bbox


def read_vol(path: str | os.PathLike) -> Volume:
    """Read a Mitsuba ``.vol`` grid (version 3, float32 encoding, one channel).

    Spacing = bounding-box size / resolution per axis (1 where the box is flat);
    the origin is the centre of the first voxel.
    """
    path = Path(path)
    size = path.stat().st_size
    with open(path, "rb") as f:
        head = f.read(_VOL_HEADER.size)
        if len(head) < _VOL_HEADER.size:
            raise ValueError(f"volume: {path}: truncated .vol header ({len(head)} bytes)")
        magic, version, encoding, nx, ny, nz, ch, *bbox = _VOL_HEADER.unpack(head)
        if magic != b"VOL" or version != 3:
            raise ValueError(f"volume: {path}: not a Mitsuba .vol file (magic {magic!r}, version {version})")
        if encoding != 1:
            raise ValueError(f"volume: {path}: .vol encoding {encoding} not supported (expected 1, float32)")
        if min(nx, ny, nz) < 1 or ch < 1:
            raise ValueError(f"volume: {path}: bad .vol resolution {nx}x{ny}x{nz}x{ch}")
        if ch != 1:
            raise ValueError(f"volume: {path}: expected a one-channel volume, got {ch} channels")
        count = nx * ny * nz
        if size < _VOL_HEADER.size + 4 * count:
            raise ValueError(f"volume: {path}: truncated .vol data ({size - _VOL_HEADER.size} bytes, "
                             f"expected {4 * count})")
        data = np.fromfile(f, dtype="<f4", count=count).reshape(nz, ny, nx)
    lo, hi = np.array(bbox[:3]), np.array(bbox[3:])
    if not (np.all(np.isfinite(bbox)) and np.all(hi >= lo)):
        raise ValueError(f"volume: {path}: bad .vol bounding box {list(bbox)} (expected finite, min <= max)")
    res = np.array([nx, ny, nz], dtype=np.float64)
    spacing = np.where(hi - lo > 0, (hi - lo) / res, 1.0)
    origin = lo + 0.5 * spacing
    return Volume(data, tuple(spacing), tuple(origin), {"format": "vol", "bbox": list(bbox)})


def write_vol(path: str | os.PathLike, volume: Volume | np.ndarray, *, spacing: Any = None) -> None:
    """Write a one-channel float32 Mitsuba ``.vol`` file (readable by ``gridvolume``).

    The bounding box is ``[0, extent]`` with extent = counts x spacing.
    """
    if not isinstance(volume, Volume):
        volume = Volume(np.asarray(volume), spacing if spacing is not None else (1.0, 1.0, 1.0))
    elif spacing is not None:
        volume = Volume(volume.data, spacing)
    nx, ny, nz = volume.shape_xyz
    ex, ey, ez = volume.extent
    from pointillist.imaging.io import atomic_write, check_output_path

    path = check_output_path(path, name="path")

    def write(tmp: str) -> None:
        with open(tmp, "wb") as f:
            f.write(_VOL_HEADER.pack(b"VOL", 3, 1, nx, ny, nz, 1, 0.0, 0.0, 0.0, ex, ey, ez))
            for z in range(nz):  # slab-wise: no float32 copy of a whole 16-bit volume
                f.write(np.ascontiguousarray(volume.data[z], dtype="<f4").tobytes())

    atomic_write(path, write)


def read_npy(path: str | os.PathLike, *, spacing: Any = (1.0, 1.0, 1.0)) -> Volume:
    """Read a 3-D ``.npy`` array (Z, Y, X) slab by slab (peak memory = the array itself)."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            version = np.lib.format.read_magic(f)
            read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                           else np.lib.format.read_array_header_2_0)
            shape, fortran, dtype = read_header(f)
            offset = f.tell()
    except (ValueError, OSError, SyntaxError) as error:
        raise ValueError(f"volume: {path}: not a readable .npy file ({error})") from None
    if len(shape) != 3:
        raise ValueError(f"volume: {path}: expected a 3-D array, got shape {shape}")
    if dtype.hasobject or not np.issubdtype(dtype, np.number):
        raise ValueError(f"volume: {path}: expected a numeric array, got dtype {dtype}")
    nbytes = int(np.prod(shape)) * dtype.itemsize
    if path.stat().st_size < offset + nbytes:
        raise ValueError(f"volume: {path}: truncated .npy data ({path.stat().st_size - offset} bytes, "
                         f"expected {nbytes})")
    if fortran:
        data = np.load(path)  # rare; numpy handles the order
    else:
        data = np.empty(shape, dtype=dtype)
        flat = data.reshape(-1).view(np.uint8)
        with open(path, "rb") as f:
            f.seek(offset)
            chunk = 64 << 20
            for start in range(0, nbytes, chunk):
                f.readinto(memoryview(flat[start:start + chunk]))
        if not dtype.isnative:
            data = data.astype(dtype.newbyteorder("="))
    return Volume(data, spacing, metadata={"format": "npy"})


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
    try:
        import nrrd
    except ImportError:
        raise ValueError("volume: reading NRRD needs pynrrd (pip install 'pointillist[medical]')") from None
    path = Path(path)
    try:
        header = nrrd.read_header(str(path))
        _check_nrrd_size(path, header)
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


def _open_nifti(nibabel: Any, path: Path) -> tuple[Any, Any]:
    """``(image, stream)``: the NIfTI image of ``path`` and, for a ``.gz`` file, the gzip stream its
    data is read from (:func:`_drain` checks that stream's CRC once the data is read).

    nibabel reads a compressed file only up to the end of the voxel data, so the gzip trailer (CRC-32
    and length) is never checked and a damaged file gives a damaged volume without a word. Here the
    image reads from a ``gzip.GzipFile`` this function opens, which the caller then reads to its end.
    """
    if not path.name.lower().endswith(".gz"):
        return nibabel.load(str(path)), None
    from nibabel.fileholders import FileHolder

    stream = gzip.GzipFile(filename=str(path), mode="rb")
    try:
        head = stream.read(4)
        stream.seek(0)
        size = int.from_bytes(head, "little") if int.from_bytes(head, "little") in (348, 540) \
            else int.from_bytes(head, "big")
        kind = nibabel.Nifti2Image if size == 540 else nibabel.Nifti1Image
        holder = FileHolder(filename=str(path), fileobj=stream)
        return kind.from_file_map({"header": holder, "image": holder}, mmap=False), stream
    except BaseException:
        stream.close()
        raise


#: Deflate's largest compression ratio (zlib's technical details: 1032:1): a gzip file of n bytes
#: holds at most 1032 n bytes of data, which bounds what a compressed header may claim.
_DEFLATE_MAX_RATIO = 1032


def _check_claimed_size(path: Path, claimed: int, what: str, *, compressed: bool) -> None:
    """ValueError before anything is allocated when a header claims more data bytes than the file can
    hold (its size, or deflate's largest ratio times its size for a compressed file)."""
    size = path.stat().st_size
    limit = size * _DEFLATE_MAX_RATIO if compressed else size
    if claimed > limit:
        holds = f"at most {limit} bytes once decompressed" if compressed else f"{size} bytes"
        raise ValueError(f"volume: {path}: the header claims {what} ({claimed} bytes) but the file holds {holds}; "
                         "a damaged or truncated file")


def _drain(stream: Any) -> None:
    """Read a gzip stream to its end (its CRC-32 and length are checked there), then close it."""
    if stream is None:
        return
    try:
        while stream.read(16 << 20):
            pass
    finally:
        stream.close()


def read_nifti(path: str | os.PathLike, *, frame: int | None = None) -> Volume:
    """Read a 3-D (or one frame of a 4-D) NIfTI image with nibabel, placed in LPS.

    The affine is nibabel's (``image.affine``: the sform, else the qform, else a
    default from the voxel sizes, with a warning) converted from RAS+ to LPS with
    :data:`~pointillist.imaging.orientation.LPS_FROM_RAS`. The array is transposed from
    NIfTI's (i, j, k) to (k, j, i). Scaled data (scl_slope / scl_inter) is read as
    float32; unscaled data keeps its dtype. A 4-D image needs ``frame`` (only that
    volume is read). A ``.nii.gz`` is read to its end, so that a damaged file (its gzip
    CRC-32 or length does not match) is refused rather than read as other voxel values.
    """
    try:
        import nibabel
    except ImportError:
        raise ValueError("volume: reading NIfTI needs nibabel (pip install 'pointillist[medical]')") from None
    path = Path(path)
    stream = None
    try:
        image, stream = _open_nifti(nibabel, path)
        shape = tuple(int(n) for n in image.shape)
        dtype = image.header.get_data_dtype()
        _check_claimed_size(path, int(image.header.get_data_offset()) + int(np.prod(shape)) * dtype.itemsize,
                            f"{'x'.join(map(str, shape))} voxels of {dtype}", compressed=stream is not None)
        if len(shape) == 4 and shape[3] > 1:
            index: Any = (..., _pick_frame(path, shape[3], frame))
        elif len(shape) == 4:
            index = (..., 0)
        elif len(shape) == 3:
            if frame not in (None, 0):
                raise ValueError(f"frame: {path} is a 3-D volume (one frame); got frame={frame}")
            index = ...
        else:
            raise ValueError(f"volume: {path}: expected a 3-D or 4-D NIfTI image, got shape {shape}")
        proxy = image.dataobj
        slope = getattr(proxy, "slope", 1.0)
        inter = getattr(proxy, "inter", 0.0)
        if (slope in (1.0, None) or np.isnan(slope)) and (inter in (0.0, None) or np.isnan(inter)):
            raw = proxy.get_unscaled() if index is ... and hasattr(proxy, "get_unscaled") else proxy[index]
            data = np.asanyarray(raw)
        else:
            data = np.asarray(proxy[index], dtype=np.float32)
        _drain(stream)
    except ValueError as error:
        if str(error).startswith(("volume:", "frame:")):
            raise
        raise ValueError(f"volume: {path}: not a readable NIfTI file ({one_line(error)})") from None
    except (EOFError, zlib.error, gzip.BadGzipFile) as error:
        raise ValueError(f"volume: {path}: damaged or truncated gzip data ({one_line(error)})") from None
    except Exception as error:  # noqa: BLE001 - nibabel raises many kinds
        raise ValueError(f"volume: {path}: not a readable NIfTI file "
                         f"({one_line(error) or type(error).__name__})") from None
    finally:
        if stream is not None:
            stream.close()
    if data.ndim != 3:
        raise ValueError(f"volume: {path}: expected a 3-D NIfTI image, got shape {data.shape}")
    header = image.header
    coded = [int(code) for code in (header.get_sform(coded=True)[1], header.get_qform(coded=True)[1])] \
        if hasattr(header, "get_sform") else [1]
    if not any(coded):
        _warn(f"volume: {path}: NIfTI without sform or qform; assumed nibabel's default "
              f"(voxel sizes, {''.join(nibabel.aff2axcodes(image.affine))})")
    affine = np.asarray(image.affine, dtype=np.float64)
    try:
        return Volume(np.ascontiguousarray(data.transpose(2, 1, 0)), metadata={
            "format": "nifti", "affine": affine.tolist(), "frames": shape[3] if len(shape) == 4 else 1},
            affine=LPS_FROM_RAS @ affine)
    except ValueError as error:
        raise ValueError(f"volume: {path}: {error}") from None


@dataclass
class _Frame:
    """One 2-D DICOM image (a file, or a frame of a multi-frame file) and where it lies."""

    source: str
    pixels: Any  # callable -> (rows, cols) array
    position: np.ndarray | None
    orientation: np.ndarray | None
    pixel_spacing: tuple[float, float] | None
    slope: float
    intercept: float
    order: tuple  # temporal sort key within one slice position


def _item(ds: Any, *path: str) -> Any:
    """``ds.A[0].B[0]...`` or None (functional-group look-ups)."""
    for name in path:
        value = getattr(ds, name, None) if ds is not None else None
        if value is None:
            return None
        if name.endswith("Sequence"):
            if len(value) == 0:
                return None
            value = value[0]
        ds = value
    return ds


def _floats(value: Any, count: int) -> np.ndarray | None:
    try:
        out = np.asarray([float(v) for v in value], dtype=np.float64)
    except (TypeError, ValueError):
        return None
    return out if out.shape == (count,) and np.all(np.isfinite(out)) else None


def _dicom_number(ds: Any, file: Path, tag: str, default: float, *, integer: bool = False,
                  nonzero: bool = False) -> float | int:
    """A numeric tag of ``ds`` (``default`` when absent or empty), checked: a ValueError names the
    file and the tag for text that is not a number, a non-finite value or one float32 cannot hold."""
    value = ds.get(tag, None)
    if value is None or value == "":
        return default
    try:
        number = float(value)
        if integer and not number.is_integer():
            raise ValueError
        checks.real(number, tag)
    except (TypeError, ValueError):
        raise ValueError(f"volume: {file}: {tag} {value!r} is not a{'n integer' if integer else ' finite number'}") \
            from None
    if nonzero and number == 0:
        raise ValueError(f"volume: {file}: {tag} is 0 (every voxel would be the intercept)")
    return int(number) if integer else number


def _dicom_frame_count(file: Path, ds: Any) -> int:
    """NumberOfFrames, checked against the pixel data the file holds before anything is allocated
    (a 930-byte file claiming 4e6 frames took minutes and gigabytes before its error), and the
    image kind: one sample a pixel (grey), not palette indices."""
    count = _dicom_number(ds, file, "NumberOfFrames", 1, integer=True)
    if count < 1:
        raise ValueError(f"volume: {file}: NumberOfFrames is {count}, expected at least 1")
    rows, cols = (_dicom_number(ds, file, tag, -1, integer=True) for tag in ("Rows", "Columns"))
    if rows < 0 or cols < 0:
        raise ValueError(f"volume: {file}: pixel data without its size (no Rows or Columns)")
    if rows < 1 or cols < 1:
        raise ValueError(f"volume: {file}: expected Rows and Columns of at least 1, got {rows} x {cols}")
    samples = _dicom_number(ds, file, "SamplesPerPixel", 1, integer=True)
    photometric = str(ds.get("PhotometricInterpretation", "") or "").strip().upper()
    if samples != 1 or photometric not in ("", "MONOCHROME1", "MONOCHROME2"):
        raise ValueError(f"volume: {file}: PhotometricInterpretation {photometric or '(none)'} with {samples} "
                         "sample(s) a pixel; a volume needs one grey value a voxel (MONOCHROME1 or MONOCHROME2)")
    bits = _dicom_number(ds, file, "BitsAllocated", 16, integer=True)
    if bits not in (1, 8, 16, 32, 64):
        raise ValueError(f"volume: {file}: BitsAllocated {bits}, expected 1, 8, 16, 32 or 64")
    nbytes = len(ds.PixelData)
    syntax = getattr(getattr(ds, "file_meta", None), "TransferSyntaxUID", None)
    if syntax is not None and getattr(syntax, "is_encapsulated", False):
        need, what = 8 * count, f"{count} compressed frame(s) (8 bytes of item header each at least)"
    else:
        need, what = (rows * cols * count * bits + 7) // 8, f"{count} frame(s) of {rows} x {cols} at {bits} bits"
    if nbytes < need:
        raise ValueError(f"volume: {file}: the DICOM header claims {what} ({need} bytes) but the file holds {nbytes} "
                         "bytes of pixel data; a damaged or truncated file")
    return count


def _dicom_frames(file: Path, ds: Any) -> list[_Frame]:
    """The 2-D frames of one DICOM dataset: classic single-frame, classic multi-frame, enhanced."""
    count = _dicom_frame_count(file, ds)
    slope = _dicom_number(ds, file, "RescaleSlope", 1.0, nonzero=True)
    intercept = _dicom_number(ds, file, "RescaleIntercept", 0.0)
    if "DoseGridScaling" in ds and "RescaleSlope" not in ds:
        slope = _dicom_number(ds, file, "DoseGridScaling", 1.0, nonzero=True)  # RT Dose: stored x DoseGridScaling = Gy
    iop = _floats(ds.get("ImageOrientationPatient"), 6)
    ipp = _floats(ds.get("ImagePositionPatient"), 3)
    spacing = _floats(ds.get("PixelSpacing"), 2)
    instance = int(ds.get("InstanceNumber", 0) or 0)
    when = str(ds.get("AcquisitionTime", "") or ds.get("ContentTime", ""))
    if count == 1 and "PerFrameFunctionalGroupsSequence" not in ds:
        return [_Frame(file.name, lambda: ds.pixel_array, ipp, iop, tuple(spacing) if spacing is not None else None,
                       slope, intercept, (int(ds.get("TemporalPositionIdentifier", 0) or 0), when, instance))]
    cache: dict[str, np.ndarray] = {}

    def frame_pixels(n: int):
        def read():
            if "all" not in cache:
                pixels = ds.pixel_array
                cache["all"] = pixels.reshape((count,) + pixels.shape[-2:])
            return cache["all"][n]
        return read

    frames = []
    per_frame = ds.get("PerFrameFunctionalGroupsSequence")
    shared = _item(ds, "SharedFunctionalGroupsSequence")
    if per_frame is not None:  # enhanced multi-frame: per-frame (else shared) functional groups
        for n in range(count):
            group = per_frame[n] if n < len(per_frame) else None

            def look(*path, group=group):
                found = _item(group, *path)
                return found if found is not None else _item(shared, *path)

            position = _floats(getattr(look("PlanePositionSequence"), "ImagePositionPatient", None), 3)
            orientation = _floats(getattr(look("PlaneOrientationSequence"), "ImageOrientationPatient", None), 6)
            measures = look("PixelMeasuresSequence")
            pixel_spacing = _floats(getattr(measures, "PixelSpacing", None), 2)
            transform = look("PixelValueTransformationSequence")
            s = _dicom_number(transform, file, "RescaleSlope", slope, nonzero=True) if transform is not None \
                else slope
            b = _dicom_number(transform, file, "RescaleIntercept", intercept) if transform is not None else intercept
            content = look("FrameContentSequence")
            temporal = int(getattr(content, "TemporalPositionIndex", 0) or 0) if content is not None else 0
            stamp = str(getattr(content, "FrameAcquisitionDateTime", "") or "") if content is not None else ""
            frames.append(_Frame(f"{file.name}[{n}]", frame_pixels(n),
                                 position if position is not None else ipp,
                                 orientation if orientation is not None else iop,
                                 tuple(pixel_spacing) if pixel_spacing is not None else
                                 (tuple(spacing) if spacing is not None else None), s, b, (temporal, stamp, n)))
        return frames
    # classic multi-frame (e.g. RT Dose): frame n at ImagePositionPatient + offset[n] along the normal
    offsets = _floats(ds.get("GridFrameOffsetVector"), count)
    if offsets is None or ipp is None or iop is None:
        _warn(f"volume: {file}: multi-frame file without GridFrameOffsetVector/position/orientation; "
              "frames stacked 1 mm apart along the slice normal")
        offsets = np.arange(count, dtype=np.float64)
    for n in range(count):
        position = None
        if ipp is not None:
            normal = np.cross(iop[:3], iop[3:]) if iop is not None else np.array([0.0, 0.0, 1.0])
            position = ipp + (offsets[n] - (offsets[0] if offsets[0] != 0 else 0.0)) * normal
        frames.append(_Frame(f"{file.name}[{n}]", frame_pixels(n), position, iop,
                             tuple(spacing) if spacing is not None else None, slope, intercept, (0, "", n)))
    return frames


#: A DICOM file's 'DICM' marker ends here (after its 128-byte preamble).
_DICOM_MARKER_END = 132


def _image_storage(ds: Any) -> str | None:
    """The name of ``ds``'s SOP class when it is an image (or dose) storage class, whose files carry
    pixel data; else None (reports, structures, plans and other files a DICOM folder may hold)."""
    meta = getattr(ds, "file_meta", None)
    uid = (meta.get("MediaStorageSOPClassUID") if meta is not None else None) or ds.get("SOPClassUID")
    name = str(getattr(uid, "name", "") or "")
    return name if ("Image Storage" in name or "Dose Storage" in name) else None


def _dicom_series_label(datasets: list) -> str:
    first = datasets[0][1]
    description = str(first.get("SeriesDescription", "") or "").strip()
    frames = sum(int(ds.get("NumberOfFrames", 1) or 1) for _, ds in datasets)
    text = f"{first.get('Modality', '?')}, {len(datasets)} file(s), {frames} image(s)"
    return text + (f", {description!r}" if description else "")


def read_dicom_series(folder: str | os.PathLike, *, frame: int | None = None,
                      series: str | int | None = None) -> Volume:
    """Read a DICOM series (a folder of slices, or a multi-frame file) as Hounsfield units, placed in LPS.

    Files that are not DICOM, and DICOM files that carry no images (reports, structures,
    plans), are skipped; an image file without its pixel data is an error. A folder with several
    series (SeriesInstanceUID) needs ``series`` (the UID, or its index in the sorted
    list the error shows). Images come from single-frame files, classic multi-frame
    files (e.g. RT Dose: ``GridFrameOffsetVector``) or enhanced multi-frame files
    (per-frame or shared functional groups: PlanePositionSequence,
    PlaneOrientationSequence, PixelMeasuresSequence, PixelValueTransformationSequence).

    Geometry: voxel x runs along ImageOrientationPatient's row direction (spacing
    PixelSpacing[1]), y along its column direction (PixelSpacing[0]), z along the slice
    normal (row x column) with the slices sorted by ImagePositionPatient projected on it;
    the slice spacing is the median distance between consecutive positions (not
    SliceThickness, used only for a single slice). Slices not stacked along the normal
    (gantry tilt) are refused as sheared. Several images at each position (the same
    count everywhere) make a 4-D series: ``frame`` picks one (images at a position
    ordered by TemporalPositionIdentifier / TemporalPositionIndex, acquisition time,
    instance or frame number). When no image has a usable ImageOrientationPatient (missing, or
    not two orthogonal unit vectors) the series is taken as axial (1,0,0,0,1,0) with a one-line
    warning; when some have one and others not, it is refused, whatever the order of the files.
    A missing ImagePositionPatient falls back to InstanceNumber order, with a warning.

    Every file is checked before its pixels are read: one grey sample a pixel (MONOCHROME1/2;
    colour and palette images are refused), numeric tags that are numbers, and pixel data at least
    as long as Rows x Columns x NumberOfFrames claim. A file that is DICOM but cannot be read (cut
    short, damaged) is an error naming it, never a slice left out.

    Values = stored * RescaleSlope + RescaleIntercept, kept int16 when slope and
    intercept are integers and the result fits, float32 otherwise.
    """
    try:
        import pydicom
        from pydicom.errors import InvalidDicomError
    except ImportError:
        raise ValueError("volume: reading DICOM needs pydicom (pip install 'pointillist[medical]')") from None
    folder = Path(folder)
    datasets = []
    problems = []
    for file in sorted(p for p in folder.iterdir() if p.is_file()):
        try:
            ds = pydicom.dcmread(str(file))
        except InvalidDicomError as error:  # not DICOM (no 'DICM' marker): not part of any series...
            if file.suffix.lower() == ".dcm" and file.stat().st_size < _DICOM_MARKER_END:
                # ...unless its name says it is and it ends before the marker could: cut short
                raise ValueError(f"volume: {folder}: {file.name} ends at byte {file.stat().st_size}, before the DICOM "
                                 f"marker (byte {_DICOM_MARKER_END}); a truncated file, or remove it from the "
                                 "folder") from None
            problems.append(f"{file.name}: {one_line(error)}")
            continue
        except Exception as error:  # noqa: BLE001 - a DICOM file cut short or damaged: never drop a slice
            raise ValueError(f"volume: {folder}: unreadable DICOM file {file.name} "
                             f"({one_line(error) or type(error).__name__})") from None
        if "PixelData" in ds:
            datasets.append((file, ds))
        elif _image_storage(ds):  # pydicom reads a file cut short without a word, up to where it ends
            raise ValueError(f"volume: {folder}: {file.name} is a {_image_storage(ds)} file without pixel data; "
                             "a damaged or truncated file")
    if not datasets:
        detail = f" ({problems[0]})" if problems else ""
        raise ValueError(f"volume: {folder}: no DICOM slices with pixel data{detail}")
    groups: dict[str, list] = {}
    for file, ds in datasets:
        groups.setdefault(str(ds.get("SeriesInstanceUID", "") or ""), []).append((file, ds))
    uids = sorted(groups)
    if series is not None:
        key = str(series).strip()
        if key in groups:
            chosen = key
        elif key.isdigit() and int(key) < len(uids):
            chosen = uids[int(key)]
        else:
            listing = "; ".join(f"{n}: {uid} ({_dicom_series_label(groups[uid])})" for n, uid in enumerate(uids))
            raise ValueError(f"series: {series!r} is not a series of {folder}; it holds {listing}")
    elif len(uids) > 1:
        listing = "; ".join(f"{n}: {uid} ({_dicom_series_label(groups[uid])})" for n, uid in enumerate(uids))
        raise ValueError(f"volume: {folder} holds {len(uids)} DICOM series; choose one with series= "
                         f"(--series UID or index): {listing}")
    else:
        chosen = uids[0]
    datasets = groups[chosen]
    first = datasets[0][1]
    try:
        frames = [f for file, ds in datasets for f in _dicom_frames(file, ds)]
        return _stack_dicom(folder, frames, first, frame)
    except ValueError as error:
        if str(error).startswith(("volume:", "frame:")):
            raise
        raise ValueError(f"volume: {folder}: bad DICOM series ({one_line(error)})") from None
    except Exception as error:  # noqa: BLE001 - pydicom decoding errors of truncated files
        raise ValueError(f"volume: {folder}: unreadable DICOM slice ({type(error).__name__}: {one_line(error)})") \
            from None


def _usable_orientation(iop: np.ndarray | None) -> bool:
    """Whether ImageOrientationPatient is two orthogonal unit vectors (to 1e-3)."""
    return iop is not None and abs(np.linalg.norm(iop[:3]) - 1) <= 1e-3 and abs(np.linalg.norm(iop[3:]) - 1) <= 1e-3 \
        and abs(float(np.dot(iop[:3], iop[3:]))) <= 1e-3


def _stack_dicom(folder: Path, frames: list[_Frame], first: Any, frame: int | None) -> Volume:
    """Sort DICOM images into a volume (one frame of a 4-D series) with its LPS affine."""
    axial = np.array([1.0, 0.0, 0.0, 0.0, 1.0, 0.0])
    # One rule whatever the order of the files: every image usable (then all the same), or none.
    usable = [f for f in frames if _usable_orientation(f.orientation)]
    if not usable:
        seen = next((f.orientation for f in frames if f.orientation is not None), None)
        what = "no ImageOrientationPatient" if seen is None else f"degenerate ImageOrientationPatient {seen.tolist()}"
        _warn(f"volume: {folder}: {what}; assumed axial (1,0,0,0,1,0)")
        iop = axial
    elif len(usable) < len(frames):
        bad = next(f for f in frames if not _usable_orientation(f.orientation))
        what = "no" if bad.orientation is None else f"a degenerate {bad.orientation.tolist()}"
        raise ValueError(f"volume: {folder}: image {bad.source} has {what} ImageOrientationPatient, image "
                         f"{usable[0].source} has {usable[0].orientation.tolist()}; cannot stack them")
    else:
        iop = usable[0].orientation
        for f in usable[1:]:
            if np.abs(f.orientation - iop).max() > 1e-4:
                raise ValueError(f"volume: {folder}: images {usable[0].source} and {f.source} have different "
                                 "orientations (a localizer or several stacks); cannot stack them")
    row = iop[:3] / np.linalg.norm(iop[:3])
    col = iop[3:] - np.dot(iop[3:], row) * row
    col /= np.linalg.norm(col)
    normal = np.cross(row, col)
    if any(f.position is None for f in frames):
        _warn(f"volume: {folder}: no ImagePositionPatient; slices in instance order, 1 mm apart (or SliceThickness)")
        thickness = float(first.get("SpacingBetweenSlices", 0) or first.get("SliceThickness", 1.0) or 1.0)
        for n, f in enumerate(sorted(frames, key=lambda f: f.order[2])):
            f.position = normal * thickness * n
    distances = np.array([float(np.dot(f.position, normal)) for f in frames])
    order = np.argsort(distances, kind="stable")
    # group images at the same position (within 1e-3 mm): several per position = frames in time
    stacks: list[list[int]] = []
    for index in order:
        if stacks and abs(distances[index] - distances[stacks[-1][0]]) < 1e-3:
            stacks[-1].append(int(index))
        else:
            stacks.append([int(index)])
    counts = {len(s) for s in stacks}
    if len(counts) != 1:
        raise ValueError(f"volume: {folder}: slice positions hold different numbers of images "
                         f"({min(counts)}..{max(counts)}); cannot make a volume")
    per_position = counts.pop()
    pick = 0
    if per_position > 1:
        pick = _pick_frame(folder, per_position, frame)
    elif frame not in (None, 0):
        raise ValueError(f"frame: {folder} is a 3-D volume (one frame); got frame={frame}")
    chosen = [frames[sorted(s, key=lambda i: frames[i].order)[pick]] for s in stacks]
    first_frame = chosen[0]
    rows, cols = (int(first.Rows), int(first.Columns))
    integral = True
    data = np.empty((len(chosen), rows, cols), dtype=np.float32)
    for z, f in enumerate(chosen):
        pixels = f.pixels()
        if pixels.shape != (rows, cols):
            raise ValueError(f"slice {f.source} is {pixels.shape}, expected {(rows, cols)}")
        integral = integral and float(f.slope).is_integer() and float(f.intercept).is_integer()
        data[z] = pixels.astype(np.float32) * np.float32(f.slope) + np.float32(f.intercept)
        if not np.all(np.isfinite(data[z])):
            raise ValueError(f"volume: {folder}: image {f.source}: RescaleSlope {f.slope:g} and RescaleIntercept "
                             f"{f.intercept:g} take its values beyond float32 (|x| <= 3.4e38)")
    if integral and data.min() >= -32768 and data.max() <= 32767:
        data = data.astype(np.int16)
    pixel_spacing = first_frame.pixel_spacing
    if pixel_spacing is None or not all(s > 0 for s in pixel_spacing):
        _warn(f"volume: {folder}: no usable PixelSpacing; assumed 1 mm")
        pixel_spacing = (1.0, 1.0)
    positions = np.array([f.position for f in chosen])
    if len(chosen) > 1:
        steps = np.diff(positions, axis=0)
        along = steps @ normal
        dz = float(np.median(along))
        if not dz > 0:
            raise ValueError(f"volume: {folder}: slices share one position; cannot stack them")
        across = np.linalg.norm(steps - along[:, None] * normal, axis=1)
        if float(across.max()) > 1e-3 * max(dz, 1.0) + 1e-4:
            raise ValueError(f"volume: {folder}: slices are not stacked along their normal (sheared, e.g. a "
                             f"gantry tilt: {float(across.max()):.3g} mm sideways a slice); resample it first")
        if float(np.abs(along - dz).max()) > 0.01 * dz:
            _warn(f"volume: {folder}: uneven slice spacing ({float(along.min()):g}..{float(along.max()):g} mm); "
                  f"used the median {dz:g} mm")
    else:
        dz = float(first.get("SpacingBetweenSlices", 0) or first.get("SliceThickness", 1.0) or 1.0)
    affine = np.eye(4)
    affine[:3, 0] = row * pixel_spacing[1]
    affine[:3, 1] = col * pixel_spacing[0]
    affine[:3, 2] = normal * dz
    affine[:3, 3] = positions[0]
    meta = {"format": "dicom", "slices": len(chosen), "frames": per_position,
            "modality": str(first.get("Modality", "")), "series": str(first.get("SeriesInstanceUID", "")),
            "rescale_slope": first_frame.slope, "rescale_intercept": first_frame.intercept}
    return Volume(data, metadata=meta, affine=affine)


# --------------------------------------------------------------------------------------------
# Phantom
# --------------------------------------------------------------------------------------------

#: The ten ellipsoids of the modified 3-D Shepp-Logan phantom (geometry of
#: M. Schabel's ``phantom3d`` after Kak & Slaney, "Principles of Computerized
#: Tomographic Imaging", 1988), with additive Hounsfield-unit values chosen so
#: the sums are CT-like: air -1000 outside, skull bone 800, brain 40,
#: CSF-filled ventricles 5, lesions 70 and 100, and one 1200 HU calcification
#: (brighter than bone, so a MIP shows it through the skull). Columns: delta HU, semi-axes
#: a b c, centre x0 y0 z0 (in [-1, 1]), Euler angles phi theta psi (degrees).
SHEPP_LOGAN_HU = (
    (1800.0, 0.6900, 0.920, 0.810, 0.00, 0.0000, 0.00, 0.0, 0.0, 0.0),
    (-760.0, 0.6624, 0.874, 0.780, 0.00, -0.0184, 0.00, 0.0, 0.0, 0.0),
    (-35.0, 0.1100, 0.310, 0.220, 0.22, 0.0000, 0.00, -18.0, 0.0, 10.0),
    (-35.0, 0.1600, 0.410, 0.280, -0.22, 0.0000, 0.00, 18.0, 0.0, 10.0),
    (30.0, 0.2100, 0.250, 0.410, 0.00, 0.3500, -0.15, 0.0, 0.0, 0.0),
    (1160.0, 0.0460, 0.046, 0.050, 0.00, 0.1000, 0.25, 0.0, 0.0, 0.0),
    (60.0, 0.0460, 0.046, 0.050, 0.00, -0.1000, 0.25, 0.0, 0.0, 0.0),
    (60.0, 0.0460, 0.023, 0.050, -0.08, -0.6050, 0.00, 0.0, 0.0, 0.0),
    (60.0, 0.0230, 0.023, 0.020, 0.00, -0.6060, 0.00, 0.0, 0.0, 0.0),
    (60.0, 0.0230, 0.046, 0.020, 0.06, -0.6050, 0.00, 0.0, 0.0, 0.0),
)


def _euler(phi: float, theta: float, psi: float) -> np.ndarray:
    """Rotation matrix of phantom3d (z-x-z Euler angles in degrees)."""
    p, t, s = np.radians([phi, theta, psi])
    cp, sp, ct, st, cs, ss = np.cos(p), np.sin(p), np.cos(t), np.sin(t), np.cos(s), np.sin(s)
    return np.array([
        [cs * cp - ct * sp * ss, cs * sp + ct * cp * ss, ss * st],
        [-ss * cp - ct * sp * cs, -ss * sp + ct * cp * cs, cs * st],
        [st * sp, -st * cp, ct],
    ])


def shepp_logan_phantom(shape: int | tuple[int, int, int] = 64, *, dtype: Any = np.int16,
                        background: float = -1000.0) -> np.ndarray:
    """A 3-D Shepp-Logan head phantom in Hounsfield units, ``(Z, Y, X)``.

    Parameters
    ----------
    shape : int or (nz, ny, nx)
        Voxel counts; an int gives a cube. Each axis spans [-1, 1] (voxel centres).
    dtype : numpy dtype
        int16 (default, like CT scanners store HU) or a float type.
    background : float
        The value outside the head (air, -1000 HU).

    Returns
    -------
    numpy.ndarray
        Values -1000 (air), 800 (skull), 40 (brain), 5 (ventricles), 70 and
        100 (lesions) and 1200 (a calcification), from the additive ellipsoids
        of :data:`SHEPP_LOGAN_HU`.

    Notes
    -----
    Evaluated slab by slab with each ellipsoid restricted to the slices it
    meets, so a clinical 512 x 512 x 1800 phantom needs only its own memory.
    A one-voxel axis samples the centre plane (coordinate 0).

    Examples
    --------
    >>> from pointillist.imaging.volumes import shepp_logan_phantom
    >>> v = shepp_logan_phantom(32)
    >>> v.shape, v.dtype, int(v[0, 0, 0]), int(v[16, 16, 16])
    ((32, 32, 32), dtype('int16'), -1000, 40)
    """
    if isinstance(shape, (int, np.integer)):
        shape = (int(shape),) * 3
    shape = tuple(int(s) for s in shape)
    if len(shape) != 3 or min(shape) < 1:
        raise ValueError(f"shape: expected a positive int or three positive ints (nz, ny, nx), got {shape}")
    nz, ny, nx = shape
    out = np.empty(shape, dtype=dtype)

    def axis(n: int) -> np.ndarray:
        return (np.arange(n) + 0.5) / n * 2.0 - 1.0 if n > 1 else np.zeros(1)

    xs, ys, zs = axis(nx), axis(ny), axis(nz)
    yy, xx = np.meshgrid(ys, xs, indexing="ij")
    ellipsoids = []
    for value, a, b, c, x0, y0, z0, phi, theta, psi in SHEPP_LOGAN_HU:
        rot = _euler(phi, theta, psi)
        half_z = np.sqrt((rot[:, 2] ** 2 * np.array([a, b, c]) ** 2).sum())  # z half-extent
        ellipsoids.append((value, np.array([a, b, c]), np.array([x0, y0, z0]), rot, half_z))
    slab = max(1, _PHANTOM_SLAB_VOXELS // (nx * ny))
    for z_start in range(0, nz, slab):
        z = zs[z_start:z_start + slab]
        acc = np.full((len(z), ny, nx), background, dtype=np.float32)
        for value, axes, centre, rot, half_z in ellipsoids:
            hit = np.nonzero(np.abs(z - centre[2]) <= half_z + 1e-12)[0]
            if hit.size == 0:
                continue
            lo, hi = hit[0], hit[-1] + 1
            dz = (z[lo:hi] - centre[2])[:, None, None]
            dx, dy = (xx - centre[0])[None], (yy - centre[1])[None]
            q = np.zeros((hi - lo, ny, nx))
            for row in range(3):
                q += ((rot[row, 0] * dx + rot[row, 1] * dy + rot[row, 2] * dz) / axes[row]) ** 2
            acc[lo:hi] += np.where(q <= 1.0, value, 0.0).astype(np.float32)
        out[z_start:z_start + len(z)] = acc.astype(dtype) if np.issubdtype(np.dtype(dtype), np.integer) \
            else acc
    return out


# --------------------------------------------------------------------------------------------
# Dr.Jit textures
# --------------------------------------------------------------------------------------------

@dataclass
class VolumeTexture:
    """A Dr.Jit 3-D texture of a volume and how to read it.

    ``value = texture.eval(p)[0] + offset`` (the offset keeps 16-bit integers
    exact in half precision). ``precision`` is ``"half"`` or ``"single"``;
    ``minimum`` / ``maximum`` ignore NaN (NaN when every voxel is NaN);
    ``nbytes`` is the texture's memory.
    """

    texture: Any
    offset: float
    precision: str
    minimum: float
    maximum: float
    nbytes: int
    exact: bool


def _integer_valued(data: np.ndarray) -> bool:
    """Whether every non-NaN value of a float array is an integer (checked slab by slab)."""
    for z in range(0, data.shape[0], 64):
        slab = data[z:z + 64]
        if not np.all((slab == np.round(slab)) | np.isnan(slab)):
            return False
    return True


#: Integers float32 holds exactly: -2^24..2^24 (24-bit significand).
_SINGLE_EXACT = 1 << 24


def _check_float32_range(data: np.ndarray) -> None:
    """ValueError when a finite value of a float64 (or wider) volume is beyond float32's range: the
    projection computes in float32 and would store it as inf (checked slab by slab)."""
    if not (np.issubdtype(data.dtype, np.floating) and data.dtype.itemsize > 4):
        return
    for z in range(0, data.shape[0], 64):
        slab = data[z:z + 64]
        with np.errstate(over="ignore", invalid="ignore"):
            over = np.isfinite(slab) & ~np.isfinite(slab.astype(np.float32))
        if over.any():
            raise ValueError(f"volume: value {float(slab[over][0]):g} is beyond float32 (|x| <= 3.4e38), the "
                             "precision of the projection; rescale the data")


def _single_exact(data: np.ndarray, lo: float, hi: float) -> bool:
    """Whether a float32 texture holds every value of ``data`` exactly (checked slab by slab where the
    dtype alone does not tell: integers beyond 2^24, float64)."""
    if data.dtype in (np.float16, np.float32) or (np.issubdtype(data.dtype, np.integer)
                                                   and max(abs(lo), abs(hi)) <= _SINGLE_EXACT):
        return True
    for z in range(0, data.shape[0], 64):
        slab = data[z:z + 64]
        with np.errstate(over="ignore", invalid="ignore"):
            if not np.all((slab.astype(np.float32) == slab) | np.isnan(slab)):
                return False
    return True


def _nan_range(data: np.ndarray) -> tuple[float, float]:
    lo, hi = np.inf, -np.inf
    for z in range(0, data.shape[0], 64):
        slab = data[z:z + 64]
        if np.issubdtype(slab.dtype, np.floating):
            finite = slab[~np.isnan(slab)]
            if finite.size:
                lo, hi = min(lo, float(finite.min())), max(hi, float(finite.max()))
        else:
            lo, hi = min(lo, float(slab.min())), max(hi, float(slab.max()))
    if lo > hi:
        return float("nan"), float("nan")
    return lo, hi


def _half_of_integers(data: np.ndarray, offset: float, module: Any):
    """The half-precision storage ``data - offset`` of 8- or 16-bit integer data, converted by Dr.Jit
    on every core (a ``TensorXf16`` of shape (Z, Y, X, 1)), or None for other data.

    The same float16 values as numpy's conversion in :func:`volume_texture`: the integers are exact
    in float32, less the offset in float32 as there, then rounded to half precision to nearest even
    (exact for data the texture stores exactly). 16-bit data is read in place as 32-bit words (two
    voxels a word; a gather of 16-bit values would be split into scalar loads).
    """
    import drjit as dr

    flat = data.reshape(-1) if data.flags.c_contiguous else None
    if flat is None or flat.dtype not in (np.int16, np.uint16, np.uint8) or sys.byteorder != "little":
        return None
    index = dr.arange(module.UInt32, flat.size)
    if flat.dtype == np.uint8:
        values = module.Float(module.UInt8(flat))
    else:
        if flat.size % 2 or flat.ctypes.data % 4:
            return None
        word = dr.gather(module.UInt32, module.UInt32(flat.view(np.uint32)), index >> 1)
        bits = module.Int32((word >> ((index & 1) << 4)) << 16)  # the voxel in the top 16 bits
        values = module.Float(bits >> 16 if flat.dtype == np.int16 else module.Int32(module.UInt32(bits) >> 16))
    if offset:
        values = values - dr.opaque(module.Float, offset)
    half = module.Float16(values)
    dr.eval(half)
    return module.TensorXf16(half, shape=(*data.shape, 1))


def volume_texture(volume: Volume | np.ndarray, *, filter: str = "linear",
                   precision: str = "auto", ad: bool = True) -> VolumeTexture:
    """Build a Dr.Jit 3-D texture (clamp wrap) of ``volume``.

    Parameters
    ----------
    volume : Volume or numpy.ndarray
        The data (Z, Y, X).
    filter : {"linear", "nearest"}
        Trilinear or nearest-voxel lookups.
    precision : {"auto", "half", "single"}
        ``"auto"``: half precision (2 bytes a voxel) when every value is
        exactly representable after subtracting the offset (integer data or
        integer-valued floats spanning at most 4096 values, e.g. 12-bit CT;
        any 8-bit data), else
        single (4 bytes). ``"half"`` forces half precision (relative error up
        to 2^-11 for wider ranges); ``"single"`` forces float32.
    ad : bool
        Build ``drjit.llvm.ad`` textures (what Mitsuba's ``llvm_ad_rgb``
        variant computes with; no gradients are tracked) rather than ``drjit.llvm``.

    Notes
    -----
    The half texture of 8- and 16-bit integer data is converted by Dr.Jit on every core; other data
    is filled slab by slab into one float16 buffer that Dr.Jit shares without a copy: peak memory is
    the source array plus 2 bytes a voxel either way.
    Interpolation runs in float32 either way. ``exact`` says whether the texture holds every
    value exactly: float32 holds integers only up to 2^24 in magnitude (an int32 volume above
    that is rounded) and float64 values only where they round-trip; a finite value beyond
    float32's range is refused (ValueError), never stored as inf.
    """
    import drjit as dr

    module = dr.llvm.ad if ad else dr.llvm
    TensorXf, TensorXf16 = module.TensorXf, module.TensorXf16
    Texture3f, Texture3f16 = module.Texture3f, module.Texture3f16

    if not isinstance(volume, Volume):
        volume = Volume(np.asarray(volume))
    if filter not in ("linear", "nearest"):
        raise ValueError(f"filter: expected 'linear' or 'nearest', got {filter!r}")
    if precision not in ("auto", "half", "single"):
        raise ValueError(f"precision: expected 'auto', 'half' or 'single', got {precision!r}")
    data = volume.data
    _check_float32_range(data)
    lo, hi = _nan_range(data)
    integer = np.issubdtype(data.dtype, np.integer)
    offset = 0.0
    exact = True
    # half storage + offset is exact when the differences fit float16's integers and the sum
    # offset + stored is exact in float32 (where the lookup adds them): |values| <= 2^24
    if integer and np.isfinite(lo):
        offset = float(np.floor((lo + hi) / 2.0))
        fits = (hi - offset) <= _HALF_EXACT and (offset - lo) <= _HALF_EXACT and max(-lo, hi) <= _SINGLE_EXACT
    elif data.dtype == np.float16:
        fits = True
    elif np.isfinite(lo) and np.isfinite(hi) and max(-lo, hi) <= _SINGLE_EXACT and _integer_valued(data):
        offset = float(np.floor((lo + hi) / 2.0))
        fits = (hi - offset) <= _HALF_EXACT and (offset - lo) <= _HALF_EXACT
    else:
        fits = False
    use_half = precision == "half" or (precision == "auto" and fits)
    mode = dr.FilterMode.Linear if filter == "linear" else dr.FilterMode.Nearest
    nz, ny, nx = data.shape
    if use_half:
        exact = fits
        tensor = _half_of_integers(data, offset, module)
        if tensor is None:
            buffer = np.empty((nz, ny, nx, 1), dtype=np.float16)
            for z in range(0, nz, 32):
                slab = data[z:z + 32]
                buffer[z:z + 32, ..., 0] = (slab.astype(np.float32) - np.float32(offset)) if offset else slab
            tensor = TensorXf16(buffer)
        texture = Texture3f16(tensor, use_accel=False, filter_mode=mode, wrap_mode=dr.WrapMode.Clamp)
        kind, nbytes = "half", 2 * data.size
    else:
        offset = 0.0
        exact = _single_exact(data, lo, hi)
        buffer = np.ascontiguousarray(data, dtype=np.float32).reshape(nz, ny, nx, 1)
        texture = Texture3f(TensorXf(buffer), use_accel=False, filter_mode=mode, wrap_mode=dr.WrapMode.Clamp)
        kind, nbytes = "single", buffer.nbytes
    return VolumeTexture(texture, offset, kind, lo, hi, nbytes, exact)
