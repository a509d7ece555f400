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

import drjit as dr
import mitsuba as mi
import numpy as np

__all__ = ["BRICK", "column_layout", "reduce_columns", "reduce_half_keys", "brick_grid"]

#: Voxels per brick side of the skipping grid. 8 is the usual choice of empty-space skipping
#: in GPU ray casters (e.g. Hadwiger et al., "Real-Time Volume Graphics", 2006, ch. 8): small
#: enough to hug structures, large enough that the grid (1/512 of the voxels) stays in cache.
BRICK = 8

#: Lanes sharing a row in the x reduction (neighbouring lanes read neighbouring packets).
X_INTERLEAVE = 16

#: Slices per partial reduction of the z (axial) columns read as contiguous streams (one zero-copy
#: array per slice, ``STREAM_GROUP`` of them per kernel): no gather at all, every lane reads its own
#: word of each slice. Measured on a noisy 512^3: 45 (27) ms median (min) against 65 (42) ms for the
#: packet-gather kernel and 32 (31) ms for a bare OR over the same streams (``mip.py --bounds``).
STREAM_GROUP = 64

#: Words per lane and load in the half-key reductions: each lane reads ``PACKET`` consecutive
#: 32-bit words (8 float16 voxels) with one packet gather (Dr.Jit's PacketOps: a vector load and
#: a transpose instead of a hardware gather of single words, which is what bounds the reduction
#: here: 1.7-2.5x faster on 512^3, bit-identical). Rows whose word count is not a multiple read
#: single words.
PACKET = 4


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


def _reduce_z_streams(words, shape_zyx, pick, group: int):
    """z columns (axial) of packed half keys from contiguous slice streams; see :data:`STREAM_GROUP`.

    Slice z is the zero-copy array of words ``[z P, (z + 1) P)`` (P = words per slice); ``group``
    slices are reduced per kernel into one packed partial (low and high keys in one word), then the
    partials. Returns the column values (``mi.Float``, storage units) in column order.
    """
    nz, ny, nx = shape_zyx
    plane = ny * nx // 2
    flat = np.asarray(words)  # the same memory (LLVM arrays are host memory)
    kind = type(words)

    def reduce(arrays, unpack):
        lo = hi = None
        for array in arrays:
            k0, k1 = unpack(array)
            lo = k0 if lo is None else pick(lo, k0)
            hi = k1 if hi is None else pick(hi, k1)
        return lo, hi

    partial = []
    for first in range(0, nz, group):
        lo, hi = reduce((kind(flat[z * plane:(z + 1) * plane]) for z in range(first, min(nz, first + group))),
                        _half_key)
        packed = lo | (hi << 16)
        dr.eval(packed)  # one kernel per group: `group` sequential streams at a time
        partial.append(packed)
    lo, hi = reduce(partial, lambda word: (word & 0xFFFF, word >> 16))
    values = dr.empty(mi.Float, 2 * plane)
    pair = dr.arange(mi.UInt32, plane)
    dr.scatter(values, _key_to_float(lo), 2 * pair)  # pair p holds columns 2p, 2p + 1
    dr.scatter(values, _key_to_float(hi), 2 * pair + 1)
    return values


def _load_words(words, index, packet: int) -> list:
    """The ``packet`` consecutive words at ``index * packet`` (one packet gather), or one word."""
    if packet == 1:
        return [dr.gather(mi.UInt32, words, index)]
    if packet != 4:
        raise ValueError(f"packet: expected 1 or 4 words, got {packet}")
    v = dr.gather(_array4(words), words, index)
    return [v[0], v[1], v[2], v[3]]


def _array4(words) -> type:
    """The 4-wide static array type of the backend of ``words`` (UInt32, plain or AD)."""
    return (dr.llvm.ad if dr.is_diff_v(words) else dr.llvm).Array4u


def _key_to_float(key):
    """Float32 value of 16-bit keys (:func:`_half_key`) of finite float16 values, in Dr.Jit.

    ``h`` = the half's bits. A normal half's exponent and mantissa shifted left by 13 and
    rebiased by 127 - 15 = 112 are the float32's; a subnormal half (exponent 0) is
    ``mantissa * 2^-24``, computed in float arithmetic (the bit trick would make a float32
    subnormal, which the LLVM backend flushes to zero). The sign bit moves to bit 31.
    """
    bits = dr.select((key & 0x8000) != 0, key ^ 0x8000, ~key & 0xFFFF)
    body = bits & 0x7FFF
    magnitude = dr.select(body < 0x0400, mi.Float(body) * 2.0**-24,
                          dr.reinterpret_array(mi.Float, (body << 13) + (112 << 23)))
    return dr.reinterpret_array(mi.Float, dr.reinterpret_array(mi.UInt32, magnitude) | ((bits & 0x8000) << 16))


def _decode_keys(keys: np.ndarray) -> np.ndarray:
    keys = keys.astype(np.uint32)
    bits = np.where(keys & 0x8000, keys ^ 0x8000, ~keys & 0xFFFF).astype(np.uint16)
    return bits.view(np.float16).astype(np.float32)


def reduce_half_keys(words, shape_zyx, axis: int, mode: str, *, chunk: int | None = None):
    """Column max / min of NaN-free float16 storage viewed as packed ``UInt32`` pairs.

    Two halves per 32-bit word and integer keys (:func:`_half_key`) instead of float
    conversions: about 2x faster than :func:`reduce_columns` on float16. Needs an even
    row length ``nx`` (and so aligned pairs). Max and min are exact in any order, so z
    and y columns are reduced in chunks of ``chunk`` voxels, then across chunks: z columns
    from contiguous slice streams (:data:`STREAM_GROUP` slices a kernel, no gathers), y columns
    (64 rows a chunk) and x rows with packet gathers (:data:`PACKET` words a lane).
    Returns the column values (``mi.Float``, storage units).
    """
    nz, ny, nx = shape_zyx
    if nx % 2:
        raise ValueError(f"reduce_half_keys: needs an even x size, got {nx}")
    n_a, stride, n_b, n_c = column_layout(shape_zyx, axis)
    pick = dr.maximum if mode == "mip" else dr.minimum
    start = 0 if mode == "mip" else 0xFFFF
    if axis == 0:  # along the rows: both halves of a word go into one key
        rows = ny * nz
        half = nx // 2
        packet = PACKET if half % PACKET == 0 else 1
        units = half // packet  # packets (or words) per row
        # lanes (row, j0) read packets j0, j0 + J, ... of their row, so neighbouring lanes read
        # neighbouring packets (one cache line per SIMD gather instead of one line per lane)
        interleave = X_INTERLEAVE if units % X_INTERLEAVE == 0 else 1
        lanes = rows * interleave
        lane = dr.arange(mi.UInt32, lanes)
        index = (lane // interleave) * units + lane % interleave if interleave > 1 else lane * units
        count = dr.opaque(mi.UInt32, units // interleave)

        def body(j, index, acc):
            for word in _load_words(words, index, packet):
                lo, hi = _half_key(word)
                acc = pick(acc, pick(lo, hi))
            return j + 1, index + interleave, acc

        _, _, acc = dr.while_loop((mi.UInt32(0), index, dr.full(mi.UInt32, start, lanes)),
                                  lambda j, i, a: j < count, body, label="mip_keys_x")
        if interleave > 1:
            index = dr.arange(mi.UInt32, rows) * interleave
            count = dr.opaque(mi.UInt32, interleave)

            def merge(j, index, a):
                return j + 1, index + 1, pick(a, dr.gather(mi.UInt32, acc, index))

            _, _, acc = dr.while_loop((mi.UInt32(0), index, dr.full(mi.UInt32, start, rows)),
                                      lambda j, i, a: j < count, merge, label="mip_keys_x_merge")
        return _key_to_float(acc)
    if axis == 2 and nz > 1:
        return _reduce_z_streams(words, shape_zyx, pick, chunk or STREAM_GROUP)
    if chunk is None:  # (z with several slices went to the slice streams above)
        chunk = 64
    inner = stride // 2  # word pairs across x
    outer = (nx * ny * nz) // (n_a * stride)
    chunks = -(-n_a // chunk)
    packet = PACKET if inner % PACKET == 0 else 1
    units = inner // packet  # a lane reads `packet` consecutive words of a row per step
    lanes = outer * chunks * units
    lane = dr.arange(mi.UInt32, lanes)
    i = lane % units
    oc = lane // units
    c = oc % chunks
    o = oc // chunks
    first = c * chunk
    length = dr.minimum(dr.opaque(mi.UInt32, n_a) - first, chunk)
    index = o * (n_a * units) + first * units + i
    step = dr.opaque(mi.UInt32, units)

    def body(a, index, lo, hi):
        lo, hi = list(lo), list(hi)
        for k, word in enumerate(_load_words(words, index, packet)):
            k0, k1 = _half_key(word)
            lo[k], hi[k] = pick(lo[k], k0), pick(hi[k], k1)
        return a + 1, index + step, lo, hi

    start_keys = [dr.full(mi.UInt32, start, lanes) for _ in range(packet)]
    _, _, lo, hi = dr.while_loop((mi.UInt32(0), index, start_keys, [dr.full(mi.UInt32, start, lanes)
                                                                    for _ in range(packet)]),
                                 lambda a, *state: a < length, body, label="mip_keys_chunk")
    pairs = outer * inner
    # across chunks: partial (o, c, i) -> (o, i). Both 16-bit keys packed in one word: one
    # evaluated array (two separate outputs ran the reduction twice as long here); a lane's
    # `packet` words are consecutive, so the partial keeps the word layout (o, c, word)
    packed = [lo[k] | (hi[k] << 16) for k in range(packet)]
    partial = dr.ravel(_array4(words)(*packed)) if packet == 4 else packed[0]
    lane = dr.arange(mi.UInt32, pairs)
    i = lane % inner
    o = lane // inner
    index = o * (chunks * inner) + i
    count = dr.opaque(mi.UInt32, chunks)
    row = dr.opaque(mi.UInt32, inner)

    def merge(k, index, a, b):
        word = dr.gather(mi.UInt32, partial, index)
        return k + 1, index + row, pick(a, word & 0xFFFF), pick(b, word >> 16)

    _, _, klo, khi = dr.while_loop((mi.UInt32(0), index, dr.full(mi.UInt32, start, pairs),
                                    dr.full(mi.UInt32, start, pairs)), lambda k, i, a, b: k < count, merge,
                                   label="mip_keys_merge")
    values = dr.empty(mi.Float, 2 * pairs)
    pair = dr.arange(mi.UInt32, pairs)
    dr.scatter(values, _key_to_float(klo), 2 * pair)  # pair p holds columns 2p, 2p + 1
    dr.scatter(values, _key_to_float(khi), 2 * pair + 1)
    return values


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
