"""CT display windowing and colour maps: raw volume values -> display RGB.

A window ``(level, width)`` is a clipped linear contrast stretch,
``u = clip((v - (level - width / 2)) / width, 0, 1)``, the same idea as
:func:`pointillist.imaging.tone.contrast_stretch` with the breakpoints at the window's
ends; a colour map then turns ``u`` into RGB. The ``mip`` integrator and ``pointillist mip``
both use these functions.

Notes
-----
============  ===========================  ======================
argument      domain                       range
============  ===========================  ======================
``values``    any float (NaN -> black)     ``u`` in [0, 1]
``level``     finite in float32            -
``width``     finite in float32, > 0       -
============  ===========================  ======================

The window's ends and ``1 / width`` must be finite in float32 too (the kernel's numbers): a
ValueError names the window otherwise (:func:`check_window`).
"""

from __future__ import annotations

import drjit as dr
import numpy as np
from drjit.llvm.ad import Array3f, Float

import pointillist.imaging  # noqa: F401  (libLLVM first)
from pointillist.core import checks

__all__ = ["WINDOW_PRESETS", "parse_window", "check_window", "colormap_lut", "apply_window", "window_image"]

#: The Dr.Jit float types :func:`apply_window` takes as they are (plain, and the AD flavour
#: that Mitsuba's ``llvm_ad_rgb`` integrators hold), with the RGB type it returns for each.
_RGB = {Float: Array3f, dr.llvm.ad.Float: dr.llvm.ad.Array3f}
_FLOATS = tuple(_RGB)

#: CT display windows (level, width) in Hounsfield units, as radiology viewers name them
#: (e.g. Radiopaedia, "Windowing (CT)").
WINDOW_PRESETS = {
    "brain": (40.0, 80.0),
    "subdural": (75.0, 215.0),
    "soft": (40.0, 400.0),
    "lung": (-600.0, 1500.0),
    "bone": (400.0, 1800.0),
    "angio": (300.0, 600.0),
}


def parse_window(text: str | tuple | None) -> tuple[float, float] | None:
    """``"L,W"`` or a preset name (:data:`WINDOW_PRESETS`) -> ``(level, width)``; ``None``/``""`` -> None.

    Raises ValueError unless width is a positive finite number and level finite.
    """
    if text is None or (isinstance(text, str) and not text.strip()):
        return None
    if isinstance(text, str):
        key = text.strip().lower()
        if key in WINDOW_PRESETS:
            return WINDOW_PRESETS[key]
        parts = key.split(",")
        try:
            level, width = (float(p) for p in parts)
        except ValueError:
            raise ValueError(f"window: expected 'level,width' (e.g. '40,400') or one of "
                             f"{', '.join(WINDOW_PRESETS)}, got {text!r}") from None
    else:
        level, width = text
    return check_window(level, width)


def check_window(level: float, width: float) -> tuple[float, float]:
    """``(level, width)`` checked for the float32 kernel: finite, width > 0, and the window's low
    end ``level - width / 2`` and ``1 / width`` finite in float32 (a ValueError names the level or
    the width).

    Examples
    --------
    >>> from pointillist.imaging.window import check_window
    >>> check_window(40, 400)
    (40.0, 400.0)
    >>> check_window(40, 1e-300)
    Traceback (most recent call last):
    ...
    ValueError: window width: expected a number > 0, got 1e-300 (0 in float32, the precision of the computation)
    """
    level = checks.real(level, "window level")
    width = checks.real(width, "window width", low=0.0, low_open=True)
    checks.float32_finite(level - width / 2.0, "window level", "the window's low end level - width / 2")
    checks.float32_finite(1.0 / width, "window width", "the scale 1 / width")
    return level, width


def colormap_lut(name: str = "grey", size: int = 256) -> np.ndarray | None:
    """RGB look-up table ``(size, 3)`` float32 of a matplotlib colormap; ``None`` for grey."""
    checks.integer(size, "size", low=2)
    if name in ("grey", "gray"):
        return None
    try:
        import matplotlib

        cmap = matplotlib.colormaps[name]
    except (ImportError, KeyError):
        raise ValueError(f"colormap: unknown colormap {name!r}; expected 'grey' or a matplotlib "
                         "colormap name (e.g. 'viridis', 'inferno', 'bone')") from None
    return np.ascontiguousarray(cmap(np.linspace(0.0, 1.0, size))[:, :3], dtype=np.float32)


def apply_window(values, level: float, width: float, lut: np.ndarray | None = None):
    """Map raw values to display RGB in 0..1: window, then colormap.

    ``u = clip((v - (level - width / 2)) / width, 0, 1)``; grey gives
    ``(u, u, u)``, a LUT is interpolated linearly between its entries. NaN
    maps to 0 (black). ``values`` is a Dr.Jit ``Float`` (or array-like);
    returns a Dr.Jit ``Array3f`` (of the same flavour as ``values``).
    """
    level, width = check_window(level, width)
    v = values if isinstance(values, _FLOATS) else Float(np.asarray(values, dtype=np.float32).ravel())
    F = type(v)
    RGB = _RGB[F]
    low = dr.opaque(F, level - width / 2.0)
    inv = dr.opaque(F, 1.0 / width)
    u = dr.clip((v - low) * inv, 0.0, 1.0)
    u = dr.select(dr.isnan(u), 0.0, u)
    if lut is None:
        return RGB(u, u, u)
    n = lut.shape[0]
    x = u * (n - 1)
    i0 = dr.uint32_array_t(F)(dr.minimum(dr.floor(x), n - 2))
    w = x - F(i0)
    table = F(np.ascontiguousarray(lut, dtype=np.float32).ravel())
    rgb = []
    for c in range(3):
        a = dr.gather(F, table, i0 * 3 + c)
        b = dr.gather(F, table, (i0 + 1) * 3 + c)
        rgb.append(dr.fma(w, b - a, a))
    return RGB(*rgb)


def window_image(image, level: float, width: float, lut: np.ndarray | None = None) -> np.ndarray:
    """:func:`apply_window` of a 2-D array of raw values: display RGB ``(H, W, 3)`` float32 in 0..1."""
    values = np.ascontiguousarray(image, dtype=np.float32)
    rgb = apply_window(Float(values.ravel()), level, width, lut)
    return np.stack([np.asarray(c) for c in rgb], axis=-1).reshape(*values.shape, 3)
