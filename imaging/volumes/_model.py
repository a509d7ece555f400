"""The volume model shared by the readers: :class:`Volume`, :class:`OrientationWarning` and the
checks every reader makes (a header's claimed size against the file, a 4-D input's frame)."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pointillist.imaging.orientation import axis_codes, check_affine, snap_directions


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

class OrientationWarning(UserWarning):
    """A file's orientation was missing or degenerate and something was assumed (the message says what)."""


def _warn(message: str) -> None:
    warnings.warn(message, OrientationWarning, stacklevel=3)


def _pick_frame(path: Path, frames: int, frame: int | None) -> int:
    """Check ``frame`` against a 4-D input's ``frames`` count (a clear error without one)."""
    if frame is None:
        raise ValueError(f"volume: {path} is 4-D with {frames} frames; choose one with frame=0..{frames - 1} "
                         f"(--frame N)")
    if frame >= frames:
        raise ValueError(f"frame: {path} has {frames} frames (0..{frames - 1}), got frame={frame}")
    return int(frame)


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


