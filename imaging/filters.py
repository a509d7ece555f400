"""Spatial filters: cross-correlation, edges, median and thresholding (SPEC "Imaging definitions")."""

from __future__ import annotations

from typing import Any

import drjit as dr
import numpy as np

from imaging._array import TensorXf, as_tensor

__all__ = ["threshold"]


def threshold(image: Any, level: float = 128, *, max_value: float = 255.0) -> TensorXf:
    """Threshold: values below ``level`` become 0, values at or above it ``max_value``.

    Parameters
    ----------
    image : array_like or Dr.Jit tensor, (H, W) or (H, W, C)
        Intensities (0..255 by convention; any real values are accepted).
    level : float
        The threshold (SPEC: 128 for dithering). A value equal to ``level`` becomes ``max_value``.
    max_value : float
        The value of "on" pixels (default 255).

    Returns
    -------
    drjit.llvm.TensorXf
        Same shape as ``image``, values in {0, max_value}. NaN compares false and becomes 0.

    Examples
    --------
    >>> import numpy as np
    >>> from imaging.filters import threshold
    >>> np.asarray(threshold(np.array([[0, 127], [128, 255]]))).tolist()
    [[0.0, 0.0], [255.0, 255.0]]
    """
    if not isinstance(level, (int, float, np.integer, np.floating)) or isinstance(level, bool) or not np.isfinite(level):
        raise ValueError(f"level: expected a finite number, got {level!r}")
    if not isinstance(max_value, (int, float, np.integer, np.floating)) or not np.isfinite(max_value):
        raise ValueError(f"max_value: expected a finite number, got {max_value!r}")
    tensor = as_tensor(image)
    values = dr.select(tensor.array >= float(level), float(max_value), 0.0)
    return TensorXf(values, tensor.shape)
