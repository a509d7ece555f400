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

import os
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "Volume", "load_volume", "read_vol", "write_vol", "read_npy", "read_nrrd", "read_nifti",
    "read_dicom_series", "shepp_logan_phantom", "volume_texture", "VolumeTexture", "SHEPP_LOGAN_HU",
]

#: Voxels per slab when the phantom is evaluated (bounds its temporary memory).
_PHANTOM_SLAB_VOXELS = 8 << 20

#: Integers a float16 holds exactly: -2048..2048 (11-bit significand).
_HALF_EXACT = 2048


@dataclass
class Volume:
    """A scalar volume: ``data[z, y, x]`` with voxel spacing ``(sx, sy, sz)``.

    Attributes
    ----------
    data : numpy.ndarray
        3-D array (Z, Y, X), any real dtype.
    spacing : tuple of float
        Voxel size along x, y, z (physical units, > 0).
    origin : tuple of float
        Position of the centre of voxel (0, 0, 0) in the file's space (metadata only).
    metadata : dict
        What the format said (e.g. DICOM modality, NIfTI affine).
    """

    data: np.ndarray
    spacing: tuple[float, float, float] = (1.0, 1.0, 1.0)
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    metadata: dict[str, Any] = field(default_factory=dict)

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
        self.spacing = _check_spacing(self.spacing)
        self.origin = tuple(float(o) for o in self.origin)  # type: ignore[assignment]

    @property
    def shape_xyz(self) -> tuple[int, int, int]:
        """Voxel counts (nx, ny, nz)."""
        nz, ny, nx = self.data.shape
        return nx, ny, nz

    @property
    def extent(self) -> tuple[float, float, float]:
        """Physical size of the volume's box along x, y, z (counts x spacing)."""
        return tuple(n * s for n, s in zip(self.shape_xyz, self.spacing))  # type: ignore[return-value]


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

def load_volume(path: str | os.PathLike, *, spacing: Any = None) -> Volume:
    """Read a volume from a ``.vol``, ``.npy``, NRRD or NIfTI file or a DICOM series folder.

    Parameters
    ----------
    path : str or path-like
        The file, or a folder of DICOM slices.
    spacing : float or sequence of 3 floats, optional
        Override the voxel spacing ``(sx, sy, sz)`` the file gives (or lacks).

    Raises
    ------
    ValueError
        For a missing, unknown, corrupt or truncated file, naming it.

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> from pointillist.imaging.volumes import load_volume
    >>> path = os.path.join(tempfile.mkdtemp(), "v.npy")
    >>> np.save(path, np.zeros((2, 3, 4), np.int16))
    >>> vol = load_volume(path, spacing=(0.5, 0.5, 2.0))
    >>> vol.shape_xyz, vol.extent
    ((4, 3, 2), (2.0, 1.5, 4.0))
    """
    path = Path(path)
    name = path.name.lower()
    if path.is_dir():
        volume = read_dicom_series(path)
    elif not path.exists():
        raise ValueError(f"volume: no such file or folder: {path}")
    elif name.endswith(".vol"):
        volume = read_vol(path)
    elif name.endswith(".npy"):
        volume = read_npy(path)
    elif name.endswith((".nrrd", ".nhdr")):
        volume = read_nrrd(path)
    elif name.endswith((".nii", ".nii.gz")):
        volume = read_nifti(path)
    elif name.endswith(".dcm"):
        volume = read_dicom_series(path.parent)
    else:
        raise ValueError(f"volume: {path}: unknown format; expected .vol, .npy, .nrrd, .nhdr, "
                         ".nii, .nii.gz or a DICOM folder")
    if spacing is not None:
        volume.spacing = _check_spacing(spacing)
    return volume


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


def read_nrrd(path: str | os.PathLike) -> Volume:
    """Read a 3-D NRRD file with pynrrd; spacing from ``space directions`` or ``spacings``."""
    try:
        import nrrd
    except ImportError:
        raise ValueError("volume: reading NRRD needs pynrrd (pip install 'pointillist[medical]')") from None
    path = Path(path)
    try:
        data, header = nrrd.read(str(path), index_order="C")
    except Exception as error:  # noqa: BLE001 - pynrrd raises NRRDError, ValueError, OSError...
        raise ValueError(f"volume: {path}: not a readable NRRD file ({error or type(error).__name__})") from None
    if data.ndim != 3:
        raise ValueError(f"volume: {path}: expected a 3-D NRRD, got {data.ndim} dimensions")
    spacing = (1.0, 1.0, 1.0)
    directions = header.get("space directions")
    if directions is not None:
        directions = np.asarray(directions, dtype=np.float64)
        if directions.shape == (3, 3) and np.all(np.isfinite(directions)):
            spacing = tuple(np.linalg.norm(directions, axis=1))
    elif header.get("spacings") is not None:
        spacing = tuple(float(s) for s in header["spacings"])
    origin = tuple(header.get("space origin", (0.0, 0.0, 0.0)))
    return Volume(np.ascontiguousarray(data), spacing, origin, {"format": "nrrd"})


def read_nifti(path: str | os.PathLike) -> Volume:
    """Read a 3-D NIfTI image with nibabel; spacing = norms of the affine's first three columns.

    The array is transposed from NIfTI's (i, j, k) to (k, j, i). Scaled data
    (scl_slope / scl_inter) is read as float32; unscaled data keeps its dtype.
    """
    try:
        import nibabel
    except ImportError:
        raise ValueError("volume: reading NIfTI needs nibabel (pip install 'pointillist[medical]')") from None
    path = Path(path)
    try:
        image = nibabel.load(str(path))
        proxy = image.dataobj
        slope = getattr(proxy, "slope", 1.0)
        inter = getattr(proxy, "inter", 0.0)
        if (slope in (1.0, None) or np.isnan(slope)) and (inter in (0.0, None) or np.isnan(inter)):
            data = np.asanyarray(proxy.get_unscaled() if hasattr(proxy, "get_unscaled") else proxy)
        else:
            data = np.asarray(image.get_fdata(dtype=np.float32))
    except Exception as error:  # noqa: BLE001 - nibabel raises many kinds
        raise ValueError(f"volume: {path}: not a readable NIfTI file ({error})") from None
    if data.ndim == 4 and data.shape[3] == 1:
        data = data[..., 0]
    if data.ndim != 3:
        raise ValueError(f"volume: {path}: expected a 3-D NIfTI image, got shape {data.shape}")
    affine = np.asarray(image.affine, dtype=np.float64)
    spacing = tuple(np.linalg.norm(affine[:3, :3], axis=0))
    return Volume(np.ascontiguousarray(data.transpose(2, 1, 0)), spacing, tuple(affine[:3, 3]),
                  {"format": "nifti", "affine": affine.tolist()})


def read_dicom_series(folder: str | os.PathLike) -> Volume:
    """Read a folder of DICOM slices (one series) as Hounsfield units.

    Files that are not DICOM or carry no pixel data are skipped. Slices are
    sorted by ImagePositionPatient projected on the slice normal (the cross
    product of ImageOrientationPatient's row and column directions), else by
    InstanceNumber. Values = stored * RescaleSlope + RescaleIntercept, kept
    int16 when slope and intercept are integers and the result fits, float32
    otherwise. Spacing: PixelSpacing (column, row) and the median distance
    between slice positions (SliceThickness for a single slice).
    """
    try:
        import pydicom
        from pydicom.errors import InvalidDicomError
    except ImportError:
        raise ValueError("volume: reading DICOM needs pydicom (pip install 'pointillist[medical]')") from None
    folder = Path(folder)
    slices = []
    problems = []
    for file in sorted(p for p in folder.iterdir() if p.is_file()):
        try:
            ds = pydicom.dcmread(str(file))
        except (InvalidDicomError, OSError, EOFError) as error:
            problems.append(f"{file.name}: {error}")
            continue
        if "PixelData" in ds:
            slices.append((file, ds))
    if not slices:
        detail = f" ({problems[0]})" if problems else ""
        raise ValueError(f"volume: {folder}: no DICOM slices with pixel data{detail}")
    first = slices[0][1]
    try:
        orientation = np.asarray(first.get("ImageOrientationPatient", [1, 0, 0, 0, 1, 0]), dtype=np.float64)
        normal = np.cross(orientation[:3], orientation[3:])
        positions = []
        for _, ds in slices:
            if "ImagePositionPatient" in ds:
                positions.append(float(np.dot(np.asarray(ds.ImagePositionPatient, dtype=np.float64), normal)))
            else:
                positions.append(float(ds.get("InstanceNumber", len(positions))))
        order = np.argsort(positions, kind="stable")
        slope = float(first.get("RescaleSlope", 1.0))
        intercept = float(first.get("RescaleIntercept", 0.0))
        rows, cols = int(first.Rows), int(first.Columns)
        integral = slope.is_integer() and intercept.is_integer()
        data = np.empty((len(slices), rows, cols), dtype=np.float32)
        for z, index in enumerate(order):
            ds = slices[index][1]
            pixels = ds.pixel_array
            if pixels.shape != (rows, cols):
                raise ValueError(f"slice {slices[index][0].name} is {pixels.shape}, expected {(rows, cols)}")
            s = float(ds.get("RescaleSlope", slope))
            b = float(ds.get("RescaleIntercept", intercept))
            integral = integral and s.is_integer() and b.is_integer()
            data[z] = pixels.astype(np.float32) * s + b
    except ValueError as error:
        raise ValueError(f"volume: {folder}: bad DICOM series ({error})") from None
    except Exception as error:  # noqa: BLE001 - pydicom decoding errors of truncated files
        raise ValueError(f"volume: {folder}: unreadable DICOM slice ({type(error).__name__}: {error})") from None
    if integral and data.min() >= -32768 and data.max() <= 32767:
        data = data.astype(np.int16)
    pixel_spacing = [float(v) for v in first.get("PixelSpacing", [1.0, 1.0])]
    sorted_pos = np.asarray(positions, dtype=np.float64)[order]
    if len(slices) > 1:
        dz = float(np.median(np.diff(sorted_pos)))
        if not dz > 0:
            raise ValueError(f"volume: {folder}: slices share one position; cannot stack them")
    else:
        dz = float(first.get("SliceThickness", 1.0) or 1.0)
    origin = tuple(float(v) for v in slices[order[0]][1].get("ImagePositionPatient", (0.0, 0.0, 0.0)))
    meta = {"format": "dicom", "slices": len(slices), "modality": str(first.get("Modality", "")),
            "rescale_slope": slope, "rescale_intercept": intercept}
    return Volume(data, (pixel_spacing[1], pixel_spacing[0], dz), origin, meta)


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
    The half texture is filled slab by slab into one float16 buffer that Dr.Jit
    shares without a copy: peak memory is the source array plus 2 bytes a voxel.
    Interpolation runs in float32 either way.
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
    lo, hi = _nan_range(data)
    integer = np.issubdtype(data.dtype, np.integer)
    offset = 0.0
    exact = True
    if integer and np.isfinite(lo):
        offset = float(np.floor((lo + hi) / 2.0))
        fits = (hi - offset) <= _HALF_EXACT and (offset - lo) <= _HALF_EXACT
    elif data.dtype == np.float16:
        fits = True
    elif np.isfinite(lo) and _integer_valued(data):
        offset = float(np.floor((lo + hi) / 2.0))
        fits = (hi - offset) <= _HALF_EXACT and (offset - lo) <= _HALF_EXACT
    else:
        fits = False
    use_half = precision == "half" or (precision == "auto" and fits)
    mode = dr.FilterMode.Linear if filter == "linear" else dr.FilterMode.Nearest
    nz, ny, nx = data.shape
    if use_half:
        exact = fits
        buffer = np.empty((nz, ny, nx, 1), dtype=np.float16)
        for z in range(0, nz, 32):
            slab = data[z:z + 32]
            buffer[z:z + 32, ..., 0] = (slab.astype(np.float32) - np.float32(offset)) if offset else slab
        tensor = TensorXf16(buffer)
        texture = Texture3f16(tensor, use_accel=False, filter_mode=mode, wrap_mode=dr.WrapMode.Clamp)
        kind, nbytes = "half", buffer.nbytes
    else:
        offset = 0.0
        buffer = np.ascontiguousarray(data, dtype=np.float32).reshape(nz, ny, nx, 1)
        texture = Texture3f(TensorXf(buffer), use_accel=False, filter_mode=mode, wrap_mode=dr.WrapMode.Clamp)
        kind, nbytes = "single", buffer.nbytes
    return VolumeTexture(texture, offset, kind, lo, hi, nbytes, exact)
