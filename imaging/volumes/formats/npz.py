"""numpy ``.npz`` archives holding one 3-D array (Z, Y, X)."""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

import numpy as np

from pointillist.imaging.volumes._model import Volume
from pointillist.imaging.volumes._registry import VolumeReader, register

__all__ = ["read_npz"]


def read_npz(path: str | os.PathLike) -> Volume:
    """Read the one 3-D array of a ``.npz`` archive (spacing 1, voxel axes x, y, z taken as L, P, S)."""
    path = Path(path)
    if not zipfile.is_zipfile(path):  # np.load would take it for a pickle
        raise ValueError(f"volume: {path}: not a readable .npz file (not a zip archive)")
    try:
        with np.load(path, allow_pickle=False) as archive:
            if len(archive.files) != 1:
                raise ValueError(f"volume: {path}: expected one array in the .npz, got {archive.files}")
            data = archive[archive.files[0]]
    except (OSError, zipfile.BadZipFile) as error:
        raise ValueError(f"volume: {path}: not a readable .npz file ({error})") from None
    if data.ndim != 3:
        raise ValueError(f"volume: {path}: expected a 3-D array, got shape {data.shape}")
    return Volume(data, metadata={"format": "npz"})


register(VolumeReader(name="numpy archive (one 3-D array)", label="numpy archive", suffixes=(".npz",),
                      read=read_npz, spacing_from="``spacing=`` argument (default 1)", order=25))
