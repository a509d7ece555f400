"""Window medians by radix selection: the median of large windows (:func:`pointillist.imaging.filters.median`).

A sorting network (the small windows' median) is compiled for the whole window: its
kernel grows as n log^2 n in the n = size^2 values, and 31x31 took 25 s to compile. Here
every pixel finds the median of its window by *radix selection* instead: the window's
values as order-preserving integer keys (the float32 bits with the sign bit flipped, and
all other bits too for negative numbers), the median's key is found one bit at a time,
from the top: a bit of the answer is 0 when at least ``rank + 1`` of the window's keys
that agree with the answer so far have a 0 there, otherwise it is 1 and those keys are
skipped. Each bit is one pass over the window (a Dr.Jit loop: the kernel's size does not
depend on the window), so a pixel costs ``bits x n`` loads: 32 bits for float data, 8
when every value is an integer in 0..255 (8-bit images), where the key is the value.

The image is first padded on the host by the border mode (the padded modes read outside
the image as the module :mod:`pointillist.imaging.neighbourhood` documents; ``zero``,
``keep`` and ``crop`` use clamped reads and then set, keep or drop the ring).
"""

from __future__ import annotations

import drjit as dr
import numpy as np
from drjit.llvm.ad import Float, UInt32

from pointillist.imaging.arrays import TensorXf
from pointillist.imaging.neighbourhood import PADDED_BORDERS, _source_index

__all__ = ["radix_median"]


def _keys(values: np.ndarray) -> tuple[np.ndarray, int]:
    """Order-preserving uint32 keys of float32 ``values`` and the number of key bits to search."""
    finite = np.isfinite(values)
    if finite.all() and values.size and values.min() >= 0 and values.max() <= 255 and \
            np.array_equal(values, np.round(values)):
        return values.astype(np.uint32), 8
    bits = values.astype(np.float32).view(np.uint32)
    flip = np.where(bits & np.uint32(0x80000000), np.uint32(0xFFFFFFFF), np.uint32(0x80000000))
    return bits ^ flip, 32


@dr.syntax
def _select(keys: UInt32, base: UInt32, size: int, row: int, channels: int, bits: int, rank: int) -> UInt32:
    """The ``rank``-th smallest key (0-based) in each window ``base + (dy * row + dx) * channels``."""
    n = size * size
    width = dr.width(base)
    answer = dr.zeros(UInt32, width)
    remaining = dr.full(UInt32, rank, width)
    bit = dr.full(UInt32, bits, width)
    while bit > 0:
        bit -= 1
        low = UInt32(1) << bit                       # the bit decided now
        high = ~((low << 1) - 1)                     # the bits decided before (none at the top)
        high = dr.select(bit == 31, UInt32(0), high)
        count = dr.zeros(UInt32, width)
        i = dr.zeros(UInt32, width)
        while i < n:
            dy = i // size
            dx = i - dy * size
            key = dr.gather(UInt32, keys, base + (dy * row + dx) * channels)
            agree = ((key ^ answer) & high) == 0
            count += dr.select(agree & ((key & low) == 0), UInt32(1), UInt32(0))
            i += 1
        one = remaining >= count                     # fewer than rank + 1 keys have a 0 here
        answer = dr.select(one, answer | low, answer)
        remaining = dr.select(one, remaining - count, remaining)
    return answer


def radix_median(tensor: TensorXf, size: int, border: str) -> tuple[Float, np.ndarray]:
    """The median of every ``size`` x ``size`` window of ``tensor`` (H, W[, C]) under ``border``.

    Returns the flat full-size result (``crop``'s ring not yet dropped: the caller's
    ``window_result`` does it) and the input as numpy. ``zero`` sets the ring to 0, ``keep``
    keeps the input there.
    """
    source = np.asarray(tensor, dtype=np.float32)
    shape = source.shape
    H, W = shape[0], shape[1]
    C = shape[2] if len(shape) == 3 else 1
    r = size // 2
    image = source.reshape(H, W, C)
    mode = border if border in PADDED_BORDERS else "clamp"
    rows = _source_index(np.arange(-r, H + r), H, mode)
    cols = _source_index(np.arange(-r, W + r), W, mode)
    padded = image[np.maximum(rows, 0)][:, np.maximum(cols, 0)]
    if mode == "constant":
        padded = np.where(((rows < 0)[:, None] | (cols < 0)[None, :])[..., None], np.float32(0.0), padded)
    keys, bits = _keys(np.ascontiguousarray(padded, dtype=np.float32).reshape(-1))
    row = W + 2 * r
    element = dr.arange(UInt32, H * W * C)
    pixel = element // C if C > 1 else element
    channel = element - pixel * C if C > 1 else 0
    y = pixel // W
    x = pixel - y * W
    base = (y * row + x) * C + channel
    answer = _select(UInt32(keys), base, size, row, C, bits, (size * size - 1) // 2)
    if bits == 8:
        values = Float(answer)
    else:
        flip = dr.select((answer & 0x80000000) != 0, UInt32(0x80000000), UInt32(0xFFFFFFFF))
        values = dr.reinterpret_array(Float, answer ^ flip)
    if border in ("zero", "keep"):
        inside = (y >= r) & (y + r < H) & (x >= r) & (x + r < W)
        values = dr.select(inside, values, 0.0 if border == "zero" else Float(source.reshape(-1)))
    dr.eval(values)
    return values, source
