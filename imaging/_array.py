"""Array conventions shared by every imaging operation.

One place that turns what users pass (numpy arrays of any real dtype, Python
sequences, Dr.Jit tensors of the LLVM backend with or without AD) into the
``drjit.llvm.TensorXf`` the operations compute on, and checks the shape.
"""

from __future__ import annotations

import functools
from typing import Any, Callable, TypeVar

import drjit as dr
import numpy as np
from drjit.llvm import TensorXf

__all__ = ["as_tensor", "to_numpy", "TensorXf", "eager_if_shared"]


def as_tensor(image: Any, name: str = "image", *, channels: tuple[int, ...] | None = None,
              allow_empty: bool = False) -> TensorXf:
    """Return ``image`` as a float32 ``drjit.llvm.TensorXf`` of shape (H, W) or (H, W, C).

    Parameters
    ----------
    image : array_like or Dr.Jit tensor
        The image. numpy arrays are shared without a copy when already
        C-contiguous float32; other dtypes are converted to float32
        (integers keep their values: uint8 ``200`` becomes ``200.0``).
    name : str
        The argument's name, used in error messages.
    channels : tuple of int, optional
        Allowed channel counts C for 3-D input (2-D input is always allowed).
    allow_empty : bool
        Accept images with zero pixels.

    Raises
    ------
    TypeError
        If ``image`` is not array-like or has a non-numeric dtype.
    ValueError
        If ``image`` is not 2-D or 3-D, is empty, or has a disallowed channel count.
    """
    if isinstance(image, TensorXf):
        tensor = image
    elif dr.is_tensor_v(image):
        if dr.backend_v(image) != dr.JitBackend.LLVM:
            raise TypeError(f"{name}: expected a numpy array or an LLVM Dr.Jit tensor, got {type(image).__name__}")
        tensor = TensorXf(dr.detach(image)) if dr.is_diff_v(image) else TensorXf(image)
    else:
        try:
            array = np.asarray(image)
        except Exception as error:  # noqa: BLE001 - anything numpy refuses
            raise TypeError(f"{name}: expected an array-like image, got {type(image).__name__}") from error
        if array.dtype == object or not (np.issubdtype(array.dtype, np.number) or array.dtype == np.bool_):
            raise TypeError(f"{name}: expected a numeric array, got dtype {array.dtype}")
        if np.iscomplexobj(array):
            raise TypeError(f"{name}: expected a real-valued array, got dtype {array.dtype}")
        _check_shape(array.shape, name, channels, allow_empty)
        tensor = TensorXf(np.ascontiguousarray(array, dtype=np.float32))
        return tensor
    _check_shape(tuple(tensor.shape), name, channels, allow_empty)
    return tensor


def _check_shape(shape: tuple[int, ...], name: str, channels: tuple[int, ...] | None,
                 allow_empty: bool) -> None:
    if len(shape) not in (2, 3):
        raise ValueError(f"{name}: expected an image of shape (H, W) or (H, W, C), got shape {tuple(shape)}")
    if not allow_empty and any(s == 0 for s in shape):
        raise ValueError(f"{name}: expected a non-empty image, got shape {tuple(shape)}")
    if len(shape) == 3 and channels is not None and shape[2] not in channels:
        raise ValueError(f"{name}: expected {' or '.join(map(str, channels))} channels, got {shape[2]}")


def to_numpy(image: Any) -> np.ndarray:
    """Return ``image`` (numpy array or Dr.Jit tensor) as a numpy array (no copy where possible)."""
    if dr.is_tensor_v(image):
        return np.asarray(dr.detach(image) if dr.is_diff_v(image) else image)
    return np.asarray(image)


_F = TypeVar("_F", bound=Callable[..., Any])


def eager_if_shared(function: _F) -> _F:
    """Decorator for image operations: evaluate the result before returning when the image
    argument is not a Dr.Jit array (or another argument is a numpy array).

    :func:`as_tensor` shares a C-contiguous float32 numpy array's memory with Dr.Jit (no
    copy), and Dr.Jit evaluates lazily: without this, a caller who changes its numpy array
    after the call, before using the result, would change the result. Dr.Jit inputs stay
    lazy, so chains of operations on Dr.Jit tensors still fuse into one kernel.
    """

    @functools.wraps(function)
    def wrapper(image: Any, *args: Any, **kwargs: Any) -> Any:
        result = function(image, *args, **kwargs)
        if not dr.is_array_v(image) or any(isinstance(a, np.ndarray) for a in (*args, *kwargs.values())):
            dr.eval(result)
            dr.sync_thread()
        return result

    return wrapper  # type: ignore[return-value]
