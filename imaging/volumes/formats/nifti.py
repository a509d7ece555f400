"""NIfTI-1/2 ``.nii`` / ``.nii.gz`` images (nibabel), placed in LPS."""

from __future__ import annotations

import gzip
import os
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from pointillist.core import checks
from pointillist.core.errors import one_line
from pointillist.imaging.orientation import LPS_FROM_RAS
from pointillist.imaging.volumes._model import Volume, _check_claimed_size, _pick_frame, _warn
from pointillist.imaging.volumes._registry import VolumeReader, optional_package, register

__all__ = ["read_nifti"]



def _check_scaled_range(path, proxy, index, data: np.ndarray, slope: float, inter: float) -> None:
    """ValueError when ``scl_slope`` and ``scl_inter`` took a stored value beyond float32 (|x| <=
    3.4e38): ``data`` (scaled, float32) holds more non-finite values than the stored data (the
    DICOM reader refuses the same)."""
    bad = np.count_nonzero(~np.isfinite(data))
    if bad == 0:
        return
    raw = np.asanyarray(proxy.get_unscaled()[index]) if hasattr(proxy, "get_unscaled") else None
    stored = 0 if raw is None or not np.issubdtype(raw.dtype, np.floating) else np.count_nonzero(~np.isfinite(raw))
    if bad > stored:
        raise ValueError(f"volume: {path}: scl_slope {slope:g} and scl_inter {inter:g} take its values beyond "
                         "float32 (|x| <= 3.4e38)")


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
    if frame is not None:
        checks.integer(frame, "frame", low=0)
    nibabel = optional_package("nibabel", "NIfTI", "nibabel")
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
            with np.errstate(over="ignore", invalid="ignore"):  # beyond float32: refused below, not warned
                data = np.asarray(proxy[index], dtype=np.float32)
            _check_scaled_range(path, proxy, index, data, float(slope), float(inter))
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



register(VolumeReader(name="NIfTI-1 or -2", label="NIfTI", suffixes=(".nii", ".nii.gz"),
                      read=read_nifti, spacing_from="the affine's column norms", needs="nibabel", options=("frame",),
                      order=40))
