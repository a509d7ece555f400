"""Mitsuba ``.vol`` grids (version 3, float32, one channel): read and write."""

from __future__ import annotations

import os
import struct
from pathlib import Path
from typing import Any

import numpy as np

from pointillist.imaging.volumes._model import Volume
from pointillist.imaging.volumes._registry import VolumeReader, register

__all__ = ["read_vol", "write_vol"]

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
    from pointillist.core.files import atomic_write, check_output_path

    path = check_output_path(path, name="path")

    def write(tmp: str) -> None:
        with open(tmp, "wb") as f:
            f.write(_VOL_HEADER.pack(b"VOL", 3, 1, nx, ny, nz, 1, 0.0, 0.0, 0.0, ex, ey, ez))
            for z in range(nz):  # slab-wise: no float32 copy of a whole 16-bit volume
                f.write(np.ascontiguousarray(volume.data[z], dtype="<f4").tobytes())

    atomic_write(path, write)


register(VolumeReader(name="Mitsuba grid (float32, one channel)", label="Mitsuba .vol", suffixes=(".vol",),
                      read=read_vol, spacing_from="bounding box / resolution", order=10))
