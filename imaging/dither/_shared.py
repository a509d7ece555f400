"""What the dithering methods share: argument checks, the quantiser of ``levels`` outputs
(display or linear light) and the pixel input and output of 8-bit and float images."""

from __future__ import annotations

from typing import Any

import drjit as dr
import numpy as np
from drjit.llvm.ad import Float, UInt8

from pointillist.core import checks
from pointillist.imaging.arrays import (TensorXf, TensorXu8, as_tensor, is_uint8, opaque_scalar, refuse_gradients,
                                        to_uint8, uint8_array)

_MAX_LEVELS = 256


# --------------------------------------------------------------------------------------------
# argument checks


def _check_level(level: Any) -> float:
    return checks.real(level, "level")


def _check_levels(levels: Any) -> int:
    return checks.integer(levels, "levels", low=2, high=_MAX_LEVELS)


def _check_bool(value: Any, name: str) -> bool:
    return checks.boolean(value, name)


def _check_template(template: Any, name: str = "template") -> np.ndarray:
    try:
        array = np.asarray(template)
    except Exception as error:  # noqa: BLE001
        raise TypeError(f"{name}: expected a square integer array, got {type(template).__name__}") from error
    if array.ndim != 2 or array.shape[0] != array.shape[1] or array.shape[0] == 0:
        raise ValueError(f"{name}: expected a square n x n array, got shape {array.shape}")
    if not (np.issubdtype(array.dtype, np.integer) or np.issubdtype(array.dtype, np.floating)):
        raise TypeError(f"{name}: expected integer entries, got dtype {array.dtype}")
    n = array.shape[0]
    if not np.all(np.isfinite(array)) or not np.array_equal(np.sort(array.ravel()), np.arange(1, n * n + 1)):
        raise ValueError(f"{name}: expected a permutation of 1..{n * n} (a growth sequence), got {array.tolist()}")
    return array.astype(np.int64)


# --------------------------------------------------------------------------------------------
# shared pieces


def _srgb_decode_255(values: Float) -> Float:
    """Display intensities 0..255 (sRGB-encoded, already clipped: finite) -> linear light on 0..255.

    The per-value formula, lazy: the public :func:`~pointillist.imaging.colour.srgb_decode` would
    count non-finite values and evaluate to warn, splitting the dithering kernel for nothing."""
    from pointillist.imaging.colour import srgb_decode_values

    return srgb_decode_values(values / 255.0) * 255.0


def _quantiser(levels: int, level: float, linear: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tables (thresholds[levels-1], value in the working space[levels], output value[levels]), float64.

    Output levels L_k = k 255 / (levels - 1). In the working space (display, or linear light with
    ``linear``) with values V_k, the threshold between V_{k-1} and V_k lies at the fraction
    level / 255 of the gap (level 128 of 0..255: the conventional threshold for 1-bit dithering). A value v
    becomes level k = the number of thresholds <= v.
    """
    k = np.arange(levels, dtype=np.float64)
    display = k * 255.0 / (levels - 1)
    if linear:
        from pointillist.imaging.colour import srgb_decode

        work = np.asarray(srgb_decode(display[None, :] / 255.0), dtype=np.float64)[0] * 255.0
        work[0], work[-1] = 0.0, 255.0
    else:
        work = display.copy()
    if levels == 2:
        thresholds = np.array([level])
    else:
        thresholds = work[:-1] + (work[1:] - work[:-1]) * (level / 255.0)
    return thresholds, work, display




def _pixels(image: Any) -> tuple[UInt8 | Float, tuple[int, ...]]:
    """The flat pixel values and shape of ``image``: a uint8 image as its bytes (``UInt8``,
    shared, no float32 copy), anything else through :func:`as_tensor` (``Float``)."""
    refuse_gradients(image, "dithering")
    if is_uint8(image):
        array = uint8_array(image)
        return UInt8(array.reshape(-1)), tuple(array.shape)
    tensor = as_tensor(image)
    return tensor.array, tuple(tensor.shape)


def _result(values: Float, shape: tuple[int, ...], eight_bit: bool) -> TensorXf | TensorXu8:
    """The output tensor: float32 levels, or for 8-bit input the levels rounded to uint8 (same kernel)."""
    return TensorXu8(to_uint8(values), shape) if eight_bit else TensorXf(values, shape)


def _levels_1bit(up: Any, shape: tuple[int, ...], eight_bit: bool) -> TensorXf | TensorXu8:
    """1-bit output: 255 where ``up``, else 0 (uint8 for 8-bit input, float32 otherwise)."""
    kind, tensor = (UInt8, TensorXu8) if eight_bit else (Float, TensorXf)
    return tensor(dr.select(up, opaque_scalar(kind, 255), opaque_scalar(kind, 0)), shape)

