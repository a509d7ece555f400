"""Acceleration kernels of the ``mip`` integrator (shared helpers, not a plugin).

* Column reductions: the maximum / minimum / sum of every voxel column along one
  axis of the compact volume storage, read directly (no texture), used by the
  axis-aligned fast path of :class:`plugins.integrators.mip.MIPIntegrator`.
* Brick grids: per-brick maxima and minima (bricks of ``BRICK`` voxels a side,
  dilated by one voxel), used to skip samples along oblique rays that cannot
  change the running maximum (minimum).

Layouts. The storage is the texture's flat array in ``(Z, Y, X)`` C order.
Axes are numbered in ``(x, y, z)`` order (0, 1, 2). Reducing along axis ``a``
gives one value per column, indexed ``column = i_c * n_b + i_b`` where ``b < c``
are the two other axes (so axial = (y, x) rows, coronal = (z, x), sagittal =
(z, y)).

Kernel sizes (voxel counts) are kernel constants: a kernel compiles once per
volume shape (and is then cached by Dr.Jit on disk); loop bounds that change
between calls are opaque.
"""

from __future__ import annotations

from typing import NamedTuple

import drjit as dr
import mitsuba as mi
import numpy as np

__all__ = ["BRICK", "HalfSampler", "SliceStreams", "column_layout", "reduce_columns", "reduce_half_words",
           "half_slices", "float_ordered", "brick_grid", "brick_grid_words"]

#: Voxels per brick side of the skipping grid. 8 is the usual choice of empty-space skipping
#: in GPU ray casters (e.g. Hadwiger et al., "Real-Time Volume Graphics", 2006, ch. 8): small
#: enough to hug structures, large enough that the grid (1/512 of the voxels) stays in cache.
BRICK = 8

#: Slices an array of the axial (z) reduction holds: a zero-copy view of Z_STACK consecutive slices is
#: folded like one slice (every lane reads its own word, no gather), so Python traces one operation per
#: Z_STACK slices (512 slices: 64 folds instead of 512, about 3 ms less a call); the Z_STACK planes of
#: the result are folded at the end.
Z_STACK = 8

#: Arrays a kernel of the axial reduction folds into a partial (then the partials are folded): each is
#: a contiguous stream. 64 chunks of 8 slices: a 512-slice volume in one kernel (no partials); measured
#: on a noisy 512^3 at load 3-4 against 16 and 32 a kernel: the lowest tenth percentile and minimum
#: (24 / 10.5 ms; the floor, one read of the volume, 9-10 ms).
Z_GROUP = 64

#: Words a lane reads at once in the y and x reductions: one packet gather (Dr.Jit's PacketOps: a
#: vector load per lane and a transpose instead of one hardware gather per word); 8 is the most
#: the LLVM backend loads at once. Rows whose word count it does not divide use 4, 2 or 1.
PACKET = 8


def column_layout(shape_zyx: tuple[int, int, int], axis: int) -> tuple[int, int, int, int]:
    """``(n_a, stride, n_b, n_c)`` of a reduction along ``axis`` (0 = x, 1 = y, 2 = z).

    ``stride`` is the distance in elements between neighbours along the axis.
    """
    nz, ny, nx = shape_zyx
    n = (nx, ny, nz)
    stride = (1, nx, nx * ny)[axis]
    b, c = [k for k in range(3) if k != axis]
    return n[axis], stride, n[b], n[c]


def reduce_columns(storage, shape_zyx, axis: int, mode: str, *, reverse: bool = False,
                   repeats: int = 1, has_nan: bool = True):
    """Reduce every voxel column along ``axis`` exactly as the ray march would.

    Parameters
    ----------
    storage : drjit Float16 or Float
        The flat ``(Z, Y, X)`` storage of the texture.
    mode : {"mip", "minip", "average"}
        Maximum, minimum, or sum (each voxel added ``repeats`` times in a row).
    reverse : bool
        Visit the column from the last voxel to the first (a ray going towards -axis);
        only the sum depends on the order.
    has_nan : bool
        Skip NaN voxels (like the march); ``False`` drops the test for speed.

    Returns
    -------
    (acc, seen) : (mi.Float, mi.UInt32)
        Per column: the running max / min (``-inf`` / ``+inf`` when every voxel is NaN)
        or the sum, and the number of non-NaN samples (``repeats`` per voxel).
    """
    n_a, stride, n_b, n_c = column_layout(shape_zyx, axis)
    columns = n_b * n_c
    source_type = type(storage)
    col = dr.arange(mi.UInt32, columns)
    base = (col // stride) * (n_a * stride) + col % stride if stride > 1 else col * n_a
    if mode == "mip":
        acc = dr.full(mi.Float, -dr.inf, columns)
    elif mode == "minip":
        acc = dr.full(mi.Float, dr.inf, columns)
    else:
        acc = dr.zeros(mi.Float, columns)
    seen = dr.zeros(mi.UInt32, columns)
    count = dr.opaque(mi.UInt32, n_a)
    step = dr.opaque(mi.UInt32, stride)
    if reverse:
        index = base + (n_a - 1) * stride
    else:
        index = mi.UInt32(base)

    def body(a, index, acc, seen):
        v = mi.Float(dr.gather(source_type, storage, index))
        ok = ~dr.isnan(v) if has_nan else True
        if mode == "mip":
            acc = dr.select(ok, dr.maximum(acc, v), acc) if has_nan else dr.maximum(acc, v)
        elif mode == "minip":
            acc = dr.select(ok, dr.minimum(acc, v), acc) if has_nan else dr.minimum(acc, v)
        else:
            for _ in range(repeats):  # the march adds each voxel once per sample, in ray order
                acc = dr.select(ok, acc + v, acc) if has_nan else acc + v
        seen = seen + (dr.select(ok, repeats, 0) if has_nan else repeats)
        index = index - step if reverse else index + step
        return a + 1, index, acc, seen

    _, _, acc, seen = dr.while_loop((mi.UInt32(0), index, acc, seen), lambda a, i, x, s: a < count, body,
                                    labels=("a", "index", "acc", "seen"), label="mip_columns")
    return acc, seen


def _half_key(word):
    """Order-preserving 16-bit keys of the two float16 values packed in a UInt32.

    key(h) = h | 0x8000 for a positive half, ~h & 0xFFFF for a negative one; larger keys
    are larger values (-0 < +0, like IEEE ``maximum``). NaN must not occur.
    """
    mask = ((word >> 15) & 0x00010001) * 0x7FFF
    key = word ^ mask ^ 0x80008000
    return key & 0xFFFF, key >> 16


def _key_bits(key):
    """The float16 bits of a 16-bit key (:func:`_half_key`): the inverse of the key transform."""
    return dr.select((key & 0x8000) != 0, key ^ 0x8000, ~key & 0xFFFF)


def _half_bits_to_float(bits):
    """Float32 value of float16 bits (the low 16 bits of a UInt32; finite values), in Dr.Jit.

    A normal half's exponent and mantissa shifted left by 13 and rebiased by 127 - 15 = 112 are
    the float32's; a subnormal half (exponent 0) is ``mantissa * 2^-24``, computed in float
    arithmetic (the bit trick would make a float32 subnormal, which the LLVM backend flushes to
    zero). The sign bit moves to bit 31.
    """
    body = bits & 0x7FFF
    magnitude = dr.select(body < 0x0400, mi.Float(body) * 2.0**-24,
                          dr.reinterpret_array(mi.Float, (body << 13) + (112 << 23)))
    return dr.reinterpret_array(mi.Float, dr.reinterpret_array(mi.UInt32, magnitude) | ((bits & 0x8000) << 16))


def _half_bits_to_float_normal(bits):
    """:func:`_half_bits_to_float` for bits of +-0 or normal halves above 2^-17 (``float_ordered``
    data): the magnitude bits shifted into a float32 and scaled by 2^112 (exact), no select."""
    shifted = ((bits & 0x7FFF) << 13) | ((bits & 0x8000) << 16)
    return dr.reinterpret_array(mi.Float, shifted) * 2.0**112


class HalfSampler:
    """Lookups in half-precision texture storage through 32-bit word gathers, the same float32 bits
    as the texture's own ``eval``.

    Dr.Jit gathers a float16 texel with a 16-bit gather, which x86 has no instruction for: LLVM
    splits it into 16 scalar loads a packet, 8 times per trilinear lookup. Here the two texels
    (x0, x0 + 1) of each of the 4 rows a lookup touches are one 32-bit word when x0 is even, and
    the high half of one word and the low half of the next when it is odd: a hardware gather
    (and a second one for the odd lanes). The arithmetic is the texture's
    (``drjit/texture_impl.h``, ``tex_eval``, clamp wrapping): ``pos = fma(p, res, -0.5)``,
    ``i = floor(pos)``, ``w1 = pos - i``, ``w0 = 1 - w1``, corner weights multiplied in x, y, z
    order and accumulated with ``fma(texel, weight, out)`` over the corners in order; nearest:
    ``i = floor(p res)``, the texel. Needs finite storage with an even voxel count (whole words).
    """

    def __init__(self, words, shape_xyz: tuple[int, int, int], *, nearest: bool, normal_only: bool):
        self.words = words
        self.shape = shape_xyz
        self.nearest = nearest
        self.to_float = _half_bits_to_float_normal if normal_only else _half_bits_to_float

    def _pair(self, element, edge):
        """Float16 bits of texels ``element`` and ``element + 1`` (the same texel where ``edge``)."""
        first = dr.gather(mi.UInt32, self.words, element >> 1)
        odd = (element & 1) != 0
        low = dr.select(odd, first >> 16, first & 0xFFFF)
        second = dr.gather(mi.UInt32, self.words, (element >> 1) + 1, odd & ~edge)
        high = dr.select(edge, low, dr.select(odd, second & 0xFFFF, first >> 16))
        return low, high

    def __call__(self, p) -> mi.Float:
        nx, ny, nz = self.shape
        res = (nx, ny, nz)
        if self.nearest:
            i = [dr.clip(mi.Int32(dr.floor(p[k] * dr.opaque(mi.Float, float(res[k])))), 0, res[k] - 1)
                 for k in range(3)]
            element = mi.UInt32((i[2] * ny + i[1]) * nx + i[0])
            word = dr.gather(mi.UInt32, self.words, element >> 1)
            return self.to_float(dr.select((element & 1) != 0, word >> 16, word & 0xFFFF))
        low, w = [], []
        for k in range(3):
            pos = dr.fma(p[k], dr.opaque(mi.Float, float(res[k])), -0.5)
            i = mi.Int32(dr.floor(pos))
            w1 = pos - mi.Float(i)
            low.append(i)
            w.append((1.0 - w1, w1))
        x0 = dr.clip(low[0], 0, nx - 1)
        edge = x0 == dr.clip(low[0] + 1, 0, nx - 1)
        texels = [None] * 8
        for bz in range(2):
            z = dr.clip(low[2] + bz, 0, nz - 1)
            for by in range(2):
                y = dr.clip(low[1] + by, 0, ny - 1)
                a, b = self._pair(mi.UInt32((z * ny + y) * nx + x0), edge)
                texels[4 * bz + 2 * by], texels[4 * bz + 2 * by + 1] = a, b
        out = dr.zeros(mi.Float, dr.width(p))
        for corner in range(8):
            weight = mi.Float(1.0)
            for k in range(3):
                weight = weight * w[k][(corner >> k) & 1]
            out = dr.fma(self.to_float(texels[corner]), weight, out)
        return out


def _key_to_float(key):
    """Float32 value of 16-bit keys (:func:`_half_key`) of finite float16 values, in Dr.Jit."""
    return _half_bits_to_float(_key_bits(key))


def float_ordered(bits: np.ndarray) -> bool:
    """Whether float16 ``bits`` (uint16) can be compared as the float32 words they start (see
    :class:`_WordOrder`): every value is +0 or has an exponent field above 2^-17's, i.e. no -0
    and no value smaller in magnitude than 2^-17 (their words are float32 subnormals, which the
    LLVM backend treats as zero, or -0, which compares equal to +0)."""
    return not bool(np.any(((bits & 0x7F80) == 0) & (bits != 0)))


class _WordOrder:
    """How the two float16 values of a storage word are compared, and the running state.

    ``floats=True`` (needs :func:`float_ordered` data): the word itself, read as float32, orders
    like its high half (both are sign-magnitude and the low 16 bits only break ties; a finite
    half's exponent never reaches float32's inf/NaN exponent), and the word shifted left by 16
    orders like its low half: one shift and two float compares a word. Otherwise 16-bit integer
    keys (:func:`_half_key`, exact for every finite half, -0 < +0): about 9 integer operations.
    The state of a column pair is ``(low, high)``; ``pack`` turns it back into a storage word (two
    float16 values), so partial results reduce like slices.
    """

    def __init__(self, floats: bool, mode: str):
        self.floats = floats
        self.maximum = mode == "mip"

    def start(self, width: int):
        if self.floats:
            return [dr.full(mi.Float, -dr.inf if self.maximum else dr.inf, width) for _ in range(2)]
        return [dr.full(mi.UInt32, 0 if self.maximum else 0xFFFF, width) for _ in range(2)]

    def split(self, word):
        if self.floats:
            return dr.reinterpret_array(mi.Float, word << 16), dr.reinterpret_array(mi.Float, word)
        return _half_key(word)

    def pick(self, a, b):
        return dr.select(b > a, b, a) if self.maximum else dr.select(b < a, b, a)

    def fold(self, state, word):
        low, high = self.split(word)
        return [low, high] if state is None else [self.pick(state[0], low), self.pick(state[1], high)]

    def bits(self, value):
        """The float16 bits of one state value (a UInt32 holding them in its low 16 bits)."""
        return dr.reinterpret_array(mi.UInt32, value) >> 16 if self.floats else _key_bits(value)

    def pack(self, state):
        return self.bits(state[0]) | (self.bits(state[1]) << 16)

    def values(self, state) -> list:
        """The float32 values of the state: the low half's column, then the high half's."""
        return [_half_bits_to_float(self.bits(value)) for value in state]


class SliceStreams(NamedTuple):
    """Zero-copy views of half storage viewed as words, for the axial fold: ``chunks`` of ``stack``
    consecutive slices each (``stack * plane`` words) and the ``rest`` slices, one a view."""

    chunks: list
    rest: list
    plane: int
    stack: int


def half_slices(words, shape_zyx, stack: int = Z_STACK) -> SliceStreams:
    """:class:`SliceStreams` of ``words`` (evaluated) in chunks of ``stack`` slices.

    A chunk is folded like one slice ``stack`` times as wide (one Dr.Jit operation for ``stack``
    slices: the tracing cost of the axial fold is per chunk), and its ``stack`` planes are folded at
    the end. Callers that reduce one volume repeatedly keep the views."""
    nz, ny, nx = shape_zyx
    plane = ny * nx // 2
    flat = np.asarray(words)  # the same memory (LLVM arrays are host memory)
    kind = type(words)
    whole = nz // stack
    chunks = [kind(flat[c * stack * plane:(c + 1) * stack * plane]) for c in range(whole)]
    rest = [kind(flat[z * plane:(z + 1) * plane]) for z in range(whole * stack, nz)]
    return SliceStreams(chunks, rest, plane, stack)


def _packet_size(count: int) -> int:
    """Words a lane reads at once: the largest of :data:`PACKET`, 4, 2, 1 that divides ``count``."""
    size = PACKET
    while count % size:
        size //= 2
    return size


def _gather_words(words, index, size: int) -> list:
    """The ``size`` consecutive words at ``index * size``: one packet gather (a vector load per
    lane and a transpose; ``words`` must be 64-byte aligned, as Dr.Jit's own arrays are)."""
    if size == 1:
        return [dr.gather(type(words), words, index)]
    array = (dr.llvm.ad if dr.is_diff_v(words) else dr.llvm).ArrayXu
    return list(dr.gather(array, words, index, shape=(size, dr.width(index))))


def _interleaved(values: list, lanes: int):
    """Write each lane's ``values`` to consecutive entries (lane l at ``l * len(values)``)."""
    out = dr.empty(mi.Float, lanes * len(values))
    dr.scatter(out, dr.llvm.ad.ArrayXf(values), dr.arange(mi.UInt32, lanes))
    return out


def _fold_streams(arrays: list, order: _WordOrder, group: int):
    """The state of ``arrays`` (equally long word arrays) folded: ``group`` of them a kernel into a
    partial (storage words, evaluated), then the partials (lazy)."""
    if len(arrays) <= group:
        state = None
        for word in arrays:
            state = order.fold(state, word)
        return state
    parts = []
    for first in range(0, len(arrays), group):
        part = order.pack(_fold_streams(arrays[first:first + group], order, group))
        dr.eval(part)  # one kernel: `group` sequential streams at a time
        parts.append(part)
    return _fold_streams(parts, order, group)


def _z_columns(streams: SliceStreams, order: _WordOrder, group: int):
    """z columns (axial): fold the chunks of slices as contiguous streams (:func:`_fold_streams`), then
    the planes of the folded chunk and the rest slices; returns the column values in column order."""
    planes = list(streams.rest)
    if streams.chunks:
        folded = order.pack(_fold_streams(streams.chunks, order, group))
        dr.eval(folded)
        flat = np.asarray(folded)
        planes += [type(folded)(flat[i * streams.plane:(i + 1) * streams.plane]) for i in range(streams.stack)]
    state = _fold_streams(planes, order, group)
    return _interleaved(order.values(state), streams.plane)


def _y_columns(words, shape_zyx, order: _WordOrder):
    """y columns (coronal): a lane takes a packet of a row's words in one slice and folds it down
    the rows; returns the column values (z, x) in column order."""
    nz, ny, nx = shape_zyx
    row = nx // 2
    size = _packet_size(row)
    segments = row // size
    lanes = nz * segments
    lane = dr.arange(mi.UInt32, lanes)
    index = (lane // segments) * (ny * segments) + lane % segments
    count = dr.opaque(mi.UInt32, ny)
    step = dr.opaque(mi.UInt32, segments)

    def body(k, index, state):
        for i, word in enumerate(_gather_words(words, index, size)):
            state[i] = order.fold(state[i], word)
        return k + 1, index + step, state

    _, _, state = dr.while_loop((mi.UInt32(0), index, [order.start(lanes) for _ in range(size)]),
                                lambda k, i, s: k < count, body, label="mip_words_y")
    return _interleaved([value for pair in state for value in order.values(pair)], lanes)


def _x_rows(words, shape_zyx, order: _WordOrder):
    """x rows (sagittal): a lane folds one row, a packet of words at a time; returns the row values."""
    nz, ny, nx = shape_zyx
    row = nx // 2
    size = _packet_size(row)
    rows = nz * ny
    index = dr.arange(mi.UInt32, rows) * (row // size)
    count = dr.opaque(mi.UInt32, row // size)

    def body(k, index, state):
        for word in _gather_words(words, index, size):
            state = order.fold(state, word)
        return k + 1, index + 1, state

    _, _, state = dr.while_loop((mi.UInt32(0), index, order.start(rows)), lambda k, i, s: k < count, body,
                                label="mip_words_x")
    return order.values([order.pick(*state)])[0]


def reduce_half_words(words, shape_zyx, axis: int, mode: str, *, floats: bool = False, slices=None,
                      group: int = Z_GROUP):
    """Column max / min of NaN-free float16 storage viewed as ``UInt32`` words (two voxels each).

    Parameters
    ----------
    words : mi.UInt32
        The storage's words, evaluated; 64-byte aligned for the packet loads (Dr.Jit's own
        arrays are); ``nx`` must be even (aligned pairs).
    axis, mode :
        As :func:`reduce_columns` (``mip`` or ``minip``).
    floats : bool
        Compare words as float32 (:class:`_WordOrder`; only for :func:`float_ordered` data),
        else as 16-bit integer keys (any finite halves).
    slices : SliceStreams, optional
        :func:`half_slices` of ``words`` (built here when not given).
    group : int
        Arrays a kernel of the axial (z) reduction folds (:data:`Z_GROUP`).

    z columns fold contiguous streams of chunks of slices (no gathers); y columns and x rows fold packets of
    up to :data:`PACKET` words a lane. Max and min are exact in any order. Returns the column
    values (``mi.Float``, storage units) in column order.
    """
    nz, ny, nx = shape_zyx
    if nx % 2:
        raise ValueError(f"reduce_half_words: needs an even x size, got {nx}")
    if mode not in ("mip", "minip"):
        raise ValueError(f"mode: expected 'mip' or 'minip', got {mode!r}")
    order = _WordOrder(floats, mode)
    if axis == 2:
        return _z_columns(half_slices(words, shape_zyx) if slices is None else slices, order, group)
    if axis == 1:
        return _y_columns(words, shape_zyx, order)
    return _x_rows(words, shape_zyx, order)


def brick_grid_words(words, shape_zyx, *, brick: int = BRICK, normal_only: bool = False):
    """:func:`brick_grid` of finite half storage (``words``: its UInt32 view, even ``nx``), in one
    Dr.Jit kernel: a lane per brick folds the ``brick + 2`` rows of ``brick + 2`` slices its
    dilated box covers, ``brick / 2 + 2`` words a row (word gathers), into its max and min.

    The values are the stored ones (storage units), so the result equals :func:`brick_grid` of the
    data less the texture's offset when the storage is exact. ``normal_only``: the storage has no
    -0 and no value below 2^-17 (:func:`float_ordered`; faster half conversion). Returns float64
    ``(maximum, minimum)`` of shape ``(ceil(nz / brick), ceil(ny / brick), ceil(nx / brick))``.
    """
    nz, ny, nx = shape_zyx
    if nx % 2 or brick % 2:
        raise ValueError(f"brick_grid_words: needs an even x size and brick, got {nx} and {brick}")
    grid = tuple(-(-n // brick) for n in shape_zyx)
    bricks = grid[0] * grid[1] * grid[2]
    to_float = _half_bits_to_float_normal if normal_only else _half_bits_to_float
    lane = dr.arange(mi.UInt32, bricks)
    bx = lane % grid[2]
    by = (lane // grid[2]) % grid[1]
    bz = lane // (grid[2] * grid[1])
    x_first = mi.Int32(bx * brick) - 1  # the dilated box: [b brick - 1, (b + 1) brick] on each axis
    y_first = mi.Int32(by * brick) - 1
    z_first = mi.Int32(bz * brick) - 1
    side = brick + 2
    row_words = nx // 2
    width = brick // 2 + 2  # words a row: x from b brick - 2 (one half outside) to (b + 1) brick + 1

    def body(k, high, low):
        z = z_first + mi.Int32(k // side)
        y = y_first + mi.Int32(k % side)
        row = (z >= 0) & (z < nz) & (y >= 0) & (y < ny)
        first = mi.Int32(bx * (brick // 2)) - 1  # the row's first word
        for j in range(width):
            inside = row & (first + j >= 0) & (first + j < row_words)
            word = dr.gather(mi.UInt32, words, mi.UInt32((z * ny + y) * row_words + first + j), inside)
            for half in range(2):
                x = x_first - 1 + 2 * j + half
                use = row & (x >= x_first) & (x <= x_first + brick + 1) & (x >= 0) & (x < nx)
                value = to_float((word >> 16) if half else (word & 0xFFFF))
                high = dr.select(use & (value > high), value, high)
                low = dr.select(use & (value < low), value, low)
        return k + 1, high, low

    rows = dr.opaque(mi.UInt32, side * side)
    _, high, low = dr.while_loop((mi.UInt32(0), dr.full(mi.Float, -dr.inf, bricks), dr.full(mi.Float, dr.inf, bricks)),
                                 lambda k, *bounds: k < rows, body, label="mip_brick_grid")
    dr.eval(high, low)
    return (high.numpy().astype(np.float64).reshape(grid), low.numpy().astype(np.float64).reshape(grid))


def _dilated_block_reduce(array: np.ndarray, axis: int, brick: int, fn) -> np.ndarray:
    """Reduce ``array`` along ``axis`` over blocks of ``brick`` widened by one element each side."""
    n = array.shape[axis]
    blocks = -(-n // brick)
    pad = blocks * brick - n
    if pad:
        widths = [(0, 0)] * array.ndim
        widths[axis] = (0, pad)
        array = np.pad(array, widths, mode="edge")  # repeats the last element: no new extremes
    shape = array.shape[:axis] + (blocks, brick) + array.shape[axis + 1:]
    out = fn.reduce(array.reshape(shape), axis=axis + 1)
    first = np.take(array, np.arange(blocks) * brick, axis=axis)  # first element of each block
    last = np.take(array, np.arange(blocks) * brick + brick - 1, axis=axis)
    lead = [slice(None)] * array.ndim
    if blocks > 1:
        lo, hi = list(lead), list(lead)
        lo[axis], hi[axis] = slice(1, None), slice(None, -1)
        out[tuple(lo)] = fn(out[tuple(lo)], last[tuple(hi)])  # one voxel of the previous block
        out[tuple(hi)] = fn(out[tuple(hi)], first[tuple(lo)])  # one voxel of the next block
    return out


def brick_grid(data: np.ndarray, *, brick: int = BRICK, offset: float = 0.0, slab: int = 64):
    """Per-brick maximum and minimum of a ``(Z, Y, X)`` volume, each brick dilated by one voxel.

    Brick ``(bz, by, bx)`` covers voxels ``[b * brick - 1, (b + 1) * brick]`` (clipped) along
    each axis: every voxel a trilinear or nearest lookup can touch from a point inside the
    brick's box, or within half a voxel of it. NaN voxels are ignored (a brick of NaN only
    gets max -inf and min +inf). Values are ``data - offset`` (the texture's storage units),
    float64. Reads ``data`` in slabs of ``slab`` slices (no full-size temporary).

    Returns
    -------
    (maximum, minimum) : numpy.ndarray, shape ``(ceil(nz / brick), ceil(ny / brick), ceil(nx / brick))``
    """
    nz = data.shape[0]
    partial = {np.fmax: [], np.fmin: []}
    for z in range(0, nz, slab):
        block = data[z:z + slab]
        for fn in partial:  # x and y within the slab (they need no other slab): 1/64 of its size
            partial[fn].append(_dilated_block_reduce(_dilated_block_reduce(block, 2, brick, fn), 1, brick, fn))
    result = []
    for fn, parts in partial.items():
        reduced = np.concatenate(parts, axis=0)
        reduced = _dilated_block_reduce(reduced, 0, brick, fn).astype(np.float64) - offset
        result.append(reduced)
    maximum, minimum = result
    empty = np.isnan(maximum)
    maximum[empty], minimum[empty] = -np.inf, np.inf
    return maximum, minimum
