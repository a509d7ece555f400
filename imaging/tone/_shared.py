"""What the tone operations share: their argument checks, the non-finite policy and the
uint8 table path of the point operations."""

from __future__ import annotations

from typing import Any, Callable

import drjit as dr
from drjit.llvm.ad import Float, UInt8, UInt32

from pointillist.core import checks
from pointillist.imaging.arrays import (TensorXf, TensorXu8, as_tensor, is_uint8, replace_non_finite, to_uint8,
                                        uint8_array, warn_non_finite)

# --------------------------------------------------------------------------- argument checks

def _positive(value: Any, name: str) -> float:
    """A real > 0 that float32 holds (:func:`pointillist.core.checks.real`)."""
    return checks.real(value, name, low=0.0, low_open=True)


def _levels(value: Any, name: str = "levels", high: int = 1 << 24) -> int:
    return checks.integer(value, name, low=2, high=high)


def _white(max_value: Any, levels: int) -> float:
    """``max_value`` checked with the two scales a ``levels``-step operation derives from it:
    (levels - 1) / max_value (value -> level) and max_value x (levels - 1), both finite in float32."""
    max_value = _positive(max_value, "max_value")
    checks.float32_finite((levels - 1) / max_value, "max_value", f"(levels - 1) / max_value with {levels} levels")
    checks.float32_finite((levels - 1) * max_value, "max_value", f"max_value x (levels - 1) with {levels} levels")
    return max_value


# --------------------------------------------------------------------------- shared machinery

def _u8_indices(image: Any, name: str = "image") -> tuple[UInt32, tuple[int, ...]]:
    """Per-pixel UInt32 values of a uint8 image, read in place (no float conversion, no gather).

    The bytes are shared with Dr.Jit as a ``UInt8`` array (zero copy for C-contiguous input)
    and widened inside the consuming kernel, so reading them costs no pass of its own.
    Returns ``(values, shape)``.
    """
    image = uint8_array(image, name)
    return UInt32(UInt8(image.reshape(-1))), tuple(image.shape)


def _sanitize(values: Float, white: float | Float) -> tuple[Float, UInt32]:
    """NaN -> 0, +inf -> ``white``, -inf -> 0; also returns a counter of the replaced values."""
    return replace_non_finite(values, white)


def _done(result: TensorXf | TensorXu8) -> TensorXf | TensorXu8:
    """Evaluate ``result`` and wait for it: uint8 input is read in place, so the kernel must have
    finished before the caller may change or free the array."""
    dr.eval(result)
    dr.sync_thread()
    return result


def _finish(result: TensorXf | TensorXu8, count: UInt32, where: str) -> TensorXf | TensorXu8:
    """Evaluate ``result`` together with the non-finite counter and warn with the count."""
    return warn_non_finite(result, count, where, stacklevel=4)


def _look_up_bytes(table: UInt32, index: UInt32) -> UInt8:
    """``table[index]`` for a table of byte values held as UInt32: gathered as 32-bit words, then
    narrowed (LLVM scalarises a gather of bytes: about 4x slower than the 32-bit hardware gather)."""
    return UInt8(dr.gather(UInt32, table, index))


#: Evaluated uint8 tables of the point operations, by curve (:func:`_curve_key`): a repeated call
#: with the same parameters launches one kernel (the look-up), as ``cv2.LUT`` with a prepared table.
_BYTE_TABLES: dict[tuple, UInt32] = {}


def _curve_key(function: Callable[[Float], Float]) -> tuple | None:
    """What determines a curve: its code and the values it captures (Python scalars, and the
    one-element opaque Dr.Jit scalars by value, floats by their bits), or None (not cached) when
    it captures anything else."""
    values = []
    for cell in function.__closure__ or ():
        value = cell.cell_contents
        if dr.is_array_v(value) and dr.width(value) == 1:
            value = (type(value).__name__, value.numpy()[0].item())
        elif not isinstance(value, (bool, int, float, str)):
            return None
        values.append(value.hex() if isinstance(value, float) else
                      (value[0], value[1].hex()) if isinstance(value, tuple) and isinstance(value[1], float)
                      else value)
    return function.__code__, tuple(values)


def _pointwise(image: Any, function: Callable[[Float], Float], max_value: float,
               where: str) -> TensorXf | TensorXu8:
    """Apply ``function`` per value; uint8 input through a 256-entry table of the same function,
    rounded to uint8 (:func:`~pointillist.imaging.arrays.to_uint8`), giving uint8 output (the
    table is cached by :func:`_curve_key`)."""
    if is_uint8(image):
        key = _curve_key(function)
        table = _BYTE_TABLES.get(key) if key is not None else None
        if table is None:
            table = UInt32(to_uint8(function(dr.arange(Float, 256))))
            dr.eval(table)
            if key is not None:
                if len(_BYTE_TABLES) >= 64:
                    _BYTE_TABLES.clear()
                _BYTE_TABLES[key] = table
        values, shape = _u8_indices(image)
        return _done(TensorXu8(_look_up_bytes(table, values), shape))
    tensor = as_tensor(image)
    clean, count = _sanitize(tensor.array, max_value)
    return _finish(TensorXf(function(clean), tensor.shape), count, where)

