"""Compact Dr.Jit 3-D textures of volumes (half precision for 8- and 16-bit data)."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Any

import numpy as np

from pointillist.imaging.volumes._model import Volume

#: Integers a float16 holds exactly: -2048..2048 (11-bit significand).
_HALF_EXACT = 2048


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
