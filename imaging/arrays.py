"""Array conventions and Dr.Jit helpers shared by every imaging operation (and the plugins).

One place that turns what users pass (numpy arrays of any real dtype, Python
sequences, Dr.Jit tensors of the LLVM backend with or without AD) into the
``drjit.llvm.ad.TensorXf`` the operations compute on (Mitsuba's ``mi.TensorXf`` in the
``llvm_ad_rgb`` variant: an AD tensor, so derivatives flow through them), and checks the shape; plus the
small Dr.Jit tools several modules need: :func:`opaque_scalar` (a cached opaque
scalar) and :func:`divmod_u32` (integer division of UInt32 lanes without vector
integer division).
"""

from __future__ import annotations

import functools
from typing import Any, Callable, TypeVar

import drjit as dr
import numpy as np
from drjit.llvm.ad import Float, TensorXf, TensorXu8, UInt8  # noqa: F401 - TensorXu8 re-exported with TensorXf

from pointillist.core import checks

__all__ = ["as_tensor", "refuse_gradients", "held_extreme", "to_numpy", "eager_if_shared", "check_shape", "is_uint8",
           "uint8_array", "to_uint8", "opaque_scalar", "divmod_u32", "NonFiniteWarning", "replace_non_finite",
           "warn_non_finite"]


class NonFiniteWarning(RuntimeWarning):
    """NaN or infinite input values were replaced (NaN -> 0, +inf -> white, -inf -> 0)."""


def replace_non_finite(values: Any, white: Any, counter: Any = None) -> tuple[Any, Any]:
    """The imaging rule for non-finite input: NaN -> 0, +inf -> ``white``, -inf -> 0.

    Returns ``(clean values, counter)``: a one-entry ``UInt32`` array that the replaced
    values are added to (pass ``counter`` to add to an existing one; lazy until evaluated,
    see :func:`warn_non_finite`).

    Examples
    --------
    >>> from drjit.llvm import Float
    >>> clean, n = replace_non_finite(Float([1.0, float("nan"), float("inf"), -float("inf")]), 255.0)
    >>> clean.numpy().tolist(), int(n[0])
    ([1.0, 0.0, 255.0, 0.0], 3)
    """
    from drjit.llvm.ad import UInt32

    bad = ~dr.isfinite(values)
    count = dr.zeros(UInt32, 1) if counter is None else counter
    dr.scatter_add(count, 1, UInt32(0), active=bad)
    return dr.select(bad, dr.select(values > 0, white, 0.0), values), count


def warn_non_finite(result: Any, counter: Any, where: str, stacklevel: int = 4) -> Any:
    """Evaluate ``result`` with ``counter`` (:func:`replace_non_finite`); one :class:`NonFiniteWarning`
    giving the count when values were replaced. Returns ``result``."""
    import warnings

    dr.eval(result, counter)
    n = int(counter[0])
    if n:
        warnings.warn(f"{where}: replaced {n} non-finite value(s) (NaN -> 0, +inf -> white, -inf -> 0)",
                      NonFiniteWarning, stacklevel=stacklevel)
    return result


def as_tensor(image: Any, name: str = "image", *, channels: tuple[int, ...] | None = None,
              allow_empty: bool = False) -> TensorXf:
    """Return ``image`` as a float32 ``drjit.llvm.ad.TensorXf`` of shape (H, W) or (H, W, C).

    Gradients are kept: an AD tensor that tracks gradients comes back as itself (or cast to
    float32, a cast Dr.Jit differentiates), so the operations built on it are differentiable
    where their mathematics is; the others call :func:`refuse_gradients` first.

    Parameters
    ----------
    image : array_like or Dr.Jit tensor
        The image. numpy arrays are shared without a copy when already
        C-contiguous float32; other dtypes (and Dr.Jit tensors of other types,
        such as the ``TensorXu8`` the 8-bit operations return) are converted to
        float32 (integers keep their values: uint8 ``200`` becomes ``200.0``).
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
        tensor = TensorXf(image)          # a cast Dr.Jit differentiates (float64 -> float32 keeps gradients)
    else:
        try:
            array = np.asarray(image)
        except Exception as error:  # noqa: BLE001 - anything numpy refuses
            raise TypeError(f"{name}: expected an array-like image, got {type(image).__name__}") from error
        if array.dtype == object or not (np.issubdtype(array.dtype, np.number) or array.dtype == np.bool_):
            raise TypeError(f"{name}: expected a numeric array, got dtype {array.dtype}")
        if np.iscomplexobj(array):
            raise TypeError(f"{name}: expected a real-valued array, got dtype {array.dtype}")
        check_shape(array.shape, name, channels, allow_empty)
        tensor = TensorXf(np.ascontiguousarray(array, dtype=np.float32))
        return tensor
    check_shape(tuple(tensor.shape), name, channels, allow_empty)
    return tensor


def refuse_gradients(image: Any, operation: str, name: str = "image") -> None:
    """Raise ``TypeError`` if ``image`` is a Dr.Jit array that tracks gradients.

    For the operations whose result is piecewise constant in the input (quantisation,
    equalisation, thresholds, medians, dithering): their derivative is zero almost everywhere and
    undefined at the steps, so an optimisation through them would silently stop; saying so is
    better than returning a detached result.

    Examples
    --------
    >>> import drjit as dr
    >>> from drjit.llvm.ad import TensorXf
    >>> t = TensorXf([0.5, 0.25], shape=(1, 2))
    >>> refuse_gradients(t, "dither")           # no gradients tracked: nothing to say
    >>> dr.enable_grad(t)
    >>> refuse_gradients(t, "dither")
    Traceback (most recent call last):
    ...
    TypeError: image: dither is not differentiable (piecewise constant), but the input tracks gradients; ...
    """
    if dr.is_diff_v(image) and dr.grad_enabled(image):
        raise TypeError(f"{name}: {operation} is not differentiable (piecewise constant), but the input tracks "
                        "gradients; detach it first (drjit.detach)")


def held_extreme(values: Any, extreme: float, usable: Any = None) -> Any:
    """The element of ``values`` (a Dr.Jit array that tracks gradients) equal to ``extreme``, as a
    one-element array of the same type: its value is ``extreme``, its derivative that element's.

    For the operations that use the image's own minimum or maximum (normalisation ranges, white
    points): the derivative of ``max(v)`` is that of the element holding it. On a tie the first
    such element gets it (Dr.Jit's ``max`` would give it to every tied element, counting it as
    often as there are ties). ``usable`` (a boolean numpy mask) restricts the search.

    Examples
    --------
    >>> import drjit as dr
    >>> from drjit.llvm.ad import Float
    >>> v = Float(1.0, 3.0, 3.0)
    >>> dr.enable_grad(v)
    >>> top = held_extreme(v, 3.0)
    >>> dr.backward(top)
    >>> dr.grad(v).numpy().tolist()
    [0.0, 1.0, 0.0]
    """
    if not (dr.is_array_v(values) and dr.depth_v(values) == 1):
        raise TypeError(f"values: expected a flat Dr.Jit array, got {type(values).__name__}")
    extreme = checks.real(extreme, "extreme", allow_inf=True)
    host = np.asarray(dr.detach(values))
    found = host == host.dtype.type(extreme)
    if usable is not None:
        found &= np.asarray(usable, dtype=bool)
    at = np.flatnonzero(found)
    if not at.size:
        raise ValueError(f"extreme: {extreme!r} is not a value of the array")
    from drjit.llvm.ad import UInt32

    return dr.gather(type(values), values, UInt32(int(at[0])))


def check_shape(shape: tuple[int, ...], name: str = "image", channels: tuple[int, ...] | None = None,
                allow_empty: bool = False) -> None:
    """Check that ``shape`` is an image shape (H, W) or (H, W, C), as :func:`as_tensor` does.

    Raises
    ------
    ValueError
        If it is not 2-D or 3-D, is empty (unless ``allow_empty``) or has a channel count
        outside ``channels``.

    Examples
    --------
    >>> from pointillist.imaging.arrays import check_shape
    >>> check_shape((4, 5, 3), channels=(1, 3))
    >>> check_shape((4,))
    Traceback (most recent call last):
    ...
    ValueError: image: expected an image of shape (H, W) or (H, W, C), got shape (4,)
    """
    shape = checks.integers(shape, "shape", low=0)
    if channels is not None:
        channels = checks.integers(channels, "channels", low=1)
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


def is_uint8(image: Any) -> bool:
    """True for 8-bit images: a numpy ``uint8`` array or an LLVM ``TensorXu8`` (``drjit.llvm`` or
    ``drjit.llvm.ad``; read by the fast paths as bytes, without a float32 copy; the tone and dither
    operations return uint8 for them).

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.arrays import TensorXu8, is_uint8
    >>> is_uint8(np.zeros((2, 2), np.uint8)), is_uint8(TensorXu8(np.zeros((2, 2), np.uint8))), is_uint8(np.zeros(2))
    (True, True, False)
    """
    if isinstance(image, np.ndarray):
        return image.dtype == np.uint8
    return (dr.is_tensor_v(image) and dr.type_v(image) == dr.VarType.UInt8       # with or without AD
            and dr.backend_v(image) == dr.JitBackend.LLVM)


def uint8_array(image: Any, name: str = "image") -> np.ndarray:
    """An 8-bit image (:func:`is_uint8`) as a C-contiguous numpy uint8 array of shape (H, W) or (H, W, C).

    A ``TensorXu8`` is evaluated and shared without a copy (the LLVM backend's memory is host
    memory); a numpy array is shared when already C-contiguous. The shape is checked as by
    :func:`check_shape`.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.arrays import TensorXu8, uint8_array
    >>> uint8_array(TensorXu8(np.array([[1, 2]], np.uint8))).tolist()
    [[1, 2]]
    """
    array = np.ascontiguousarray(np.asarray(image))
    check_shape(array.shape, name)
    return array


def to_uint8(values: Any) -> Any:
    """Float32 values as ``UInt8`` the way the 8-bit writers (:func:`pointillist.imaging.io.to_8bit`
    with ``max_value=255``, ``srgb=False``) round them: clipped to 0..255, rounded half to even.

    The uint8 results of the tone and dither operations are exactly this rounding of their float32
    results. NaN becomes 0 (as in the writers).

    Examples
    --------
    >>> from drjit.llvm import Float
    >>> from pointillist.imaging.arrays import to_uint8
    >>> to_uint8(Float(-3.0, 0.5, 1.5, 127.5, 254.6, 300.0)).numpy().tolist()
    [0, 0, 2, 128, 255, 255]
    """
    clean = dr.select(dr.isnan(values), 0.0, values)
    return UInt8(dr.clip(dr.round(clean), opaque_scalar(Float, 0.0), opaque_scalar(Float, 255.0)))


_OPAQUE: dict[tuple[type, Any], Any] = {}
_OPAQUE_LIMIT = 512


def opaque_scalar(kind: type, value: Any) -> Any:
    """An opaque (evaluated) Dr.Jit scalar of type ``kind``, cached by ``(kind, value)``.

    ``dr.opaque`` makes a kernel independent of the value (no recompilation per image size or
    weight), but each call costs a one-element memset launch; a repeated call with the same
    value reuses the evaluated variable instead (Dr.Jit variables are immutable, so sharing them
    is safe). Floats are keyed by their bits, so ``-0.0`` and ``0.0`` stay distinct. The cache
    holds at most 512 values (it is emptied when full).

    Parameters
    ----------
    kind : type
        A Dr.Jit array type (``drjit.llvm.Float``, ``UInt32``, ``mi.Float64``, ...).
    value : int or float
        The value.

    Examples
    --------
    >>> from drjit.llvm import Float
    >>> from pointillist.imaging.arrays import opaque_scalar
    >>> opaque_scalar(Float, 0.5) is opaque_scalar(Float, 0.5)
    True
    >>> float(opaque_scalar(Float, 0.5)[0])
    0.5
    """
    key = (kind, value.hex() if isinstance(value, float) else value)
    variable = _OPAQUE.get(key)
    if variable is None:
        if len(_OPAQUE) >= _OPAQUE_LIMIT:
            _OPAQUE.clear()
        variable = _OPAQUE[key] = dr.opaque(kind, value)
    return variable


#: Bounds on the dividend of :func:`divmod_u32`: below 2^22 one float32 product is exact, below
#: 2^24 one float32 product and a correction step are (see the error bounds there).
FLOAT32_ROUNDED_BOUND = 1 << 22
FLOAT32_EXACT_BOUND = 1 << 24


def divmod_u32(a: Any, divisor: int, bound: int | None = None) -> tuple[Any, Any]:
    """``a // divisor, a % divisor`` for UInt32 lanes ``a`` and a Python int ``divisor >= 1``,
    without vector integer division.

    LLVM has no SIMD integer division (it runs lane by lane). A power-of-two divisor is a shift
    and a mask. Otherwise a multiplication by an opaque reciprocal (so the kernel does not depend
    on the divisor), chosen by ``bound`` (``a < bound``, known to the caller):

    - ``bound <= 2^22``: q = trunc((a + 1/2) fl(1/d)) in float32, no correction. The exact
      (a + 1/2) / d lies at least 1/(2d) from an integer; two roundings (relative 2^-24 each)
      move it by less than (a + 1/2) 2^-23 / d < 1/(2d), so the truncation is exact.
    - ``bound <= 2^24``: float32 estimate and one correction step. a is exact in float32 and, for
      divisor >= 2, the estimate of a / divisor < 2^23 is off by less than 2^23 * 2^-23 = 1.
    - otherwise (any ``a < 2^32``): q = floor((a + 1/2) fl(1/d)) in float64, no correction: the
      rounding error, below 2^-52 (a + 1/2) / d < 2^-20 / d, is smaller than the distance 1/(2d)
      from (a + 1/2) / d to the nearest integer.

    Dr.Jit emits plain IEEE operations here (no fast-math contraction), so the bounds hold; the
    tests check them exhaustively near the limits. The Dr.Jit types follow ``a`` (plain or AD).

    Examples
    --------
    >>> from drjit.llvm import UInt32
    >>> from pointillist.imaging.arrays import divmod_u32
    >>> q, r = divmod_u32(UInt32(0, 6, 7, 4000000000), 7)
    >>> q.numpy().tolist(), r.numpy().tolist()
    ([0, 0, 1, 571428571], [0, 6, 0, 3])
    """
    kind = type(a)
    if divisor == 1:
        return a, dr.zeros(kind, dr.width(a))
    if divisor & (divisor - 1) == 0:
        return a >> opaque_scalar(kind, divisor.bit_length() - 1), a & opaque_scalar(kind, divisor - 1)
    d = opaque_scalar(kind, divisor)
    if bound is not None and bound <= FLOAT32_EXACT_BOUND:
        f32 = dr.float32_array_t(kind)
        inverse = opaque_scalar(f32, float(np.float32(1.0) / np.float32(divisor)))
        if bound <= FLOAT32_ROUNDED_BOUND:
            q = kind((f32(a) + opaque_scalar(f32, 0.5)) * inverse)
            return q, a - q * d
        q = kind(f32(a) * inverse)
        i32 = dr.int32_array_t(kind)
        r = i32(a) - i32(q * d)
        q = dr.select(r < 0, q - 1, dr.select(r >= i32(d), q + 1, q))
        return q, a - q * d
    f64 = dr.float64_array_t(kind)
    q = kind(dr.floor((f64(a) + 0.5) * opaque_scalar(f64, 1.0 / divisor)))
    return q, a - q * d
