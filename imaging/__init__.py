"""pointillist's imaging module: image operations on Dr.Jit tensors, and EXR/PNG I/O.

Every operation accepts a numpy array or a Dr.Jit tensor of shape ``(H, W)`` or
``(H, W, C)`` and returns a ``drjit.llvm.ad.TensorXf`` (``np.asarray(result)``
gives numpy without a copy). Intensities are on 0..255 unless a function says
otherwise; EXR renders are linear floats. 8-bit in, 8-bit out: the tone
operations that work through 256-entry tables and every dithering method
return a ``drjit.llvm.ad.TensorXu8`` for ``uint8`` input (see their modules).

Importing this package points Dr.Jit at a usable libLLVM first (see
:mod:`pointillist.core.llvm`).
"""

from pointillist.core.llvm import ensure_llvm as _ensure_llvm

_ensure_llvm()

from pointillist.imaging.arrays import as_tensor, to_numpy  # noqa: E402

__all__ = ["as_tensor", "to_numpy"]
