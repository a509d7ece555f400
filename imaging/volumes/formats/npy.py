"""numpy ``.npy`` arrays (3-D, Z, Y, X), read slab by slab."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from pointillist.imaging.volumes._model import Volume
from pointillist.imaging.volumes._registry import VolumeReader, register

__all__ = ["read_npy"]

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


register(VolumeReader(name="numpy array (3-D)", label="numpy", suffixes=(".npy",), read=read_npy,
                      spacing_from="``spacing=`` argument (default 1)", order=20))
