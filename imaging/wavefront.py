"""Exact parallel error diffusion: the wavefront schedule behind :mod:`pointillist.imaging.dither`.

Parallel error diffusion
------------------------
Error diffusion reads as a sequential scan, but with a raster scan pixel (y, x) depends only on
pixels of the rows above up to column x + R (R = how far left the kernel reaches in the rows
below) and on its left neighbours. Lanes of one SIMD packet each own a row of a band of P rows
(P = the Dr.Jit packet width): lane i processes column t - s i at step t of ONE symbolic loop,
where the skew s > R / dy makes every value a lane reads a value that another lane wrote in an
earlier step (the wavefront over x + s y). Lanes keep a sliding window of the errors of the rows
above in registers, so one step costs one gather of the input, one gather per source row of the
error buffer, one scatter of the error and one scatter of the output. The error buffer is a
small rolling buffer of P + 2 rows. Bands run one after another inside the same loop, so the whole
image is a single kernel launch per call (one packet per colour channel, channels in parallel).
The additions happen in exactly the order in which a sequential scan adds the contributions
(rows further up first, each row in its scan order, then the pixel's own row), in float64, with
no fused multiply-add, so the result is bit-identical to a sequential float64 reference.
Serpentine scans reverse every other row, which makes row y wait for the end of row y - 1: those
run as one sequential lane per channel (still one kernel).

Blocked schedule. For one grey image whose width is a multiple of :data:`BLOCK` (8) and a raster
scan, a loop iteration diffuses a whole block of 8 columns of each lane's row, the 8 steps
unrolled: the block's inputs arrive as one packet gather (a vector load per lane and a
transpose), each source row's next 8 errors likewise, and the block's 8 errors and 8 output
levels leave as packet scatters, instead of one hardware gather or scatter per value and step.
Lanes start 16 columns apart so that the row above has written a block one iteration before
the row below reads it. The arithmetic per pixel is the same, in the same order (same bits);
measured on a 2048^2 uint8 image under the same load, the kernel takes about 0.6x the time of the
one-column schedule and needs no widening pass for 8-bit input (``benchmarks/imaging_dither.py``).

The formulas (kernels, quantiser, threshold rule) stay in :mod:`pointillist.imaging.dither`; this
module only runs a given kernel over an image: :func:`diffuse_wavefront` takes the flat values,
the kernel as ``(dy, dx, weight)`` triples and the quantiser's tables.
"""

from __future__ import annotations

import os
import warnings
from functools import lru_cache
from typing import Any

import drjit as dr
import numpy as np
from drjit.llvm.ad import Float, Float64, Int32, UInt8, UInt32

__all__ = ["BLOCK", "blocked", "clip_intensity", "packet_width", "wavefront_schedule", "verified_lanes",
           "diffuse_wavefront"]

#: The kernel :func:`verified_lanes` probes with (Floyd-Steinberg's weights: two rows, both directions).
_PROBE_KERNEL = ((0, 1, 7 / 16), (1, -1, 3 / 16), (1, 0, 5 / 16), (1, 1, 1 / 16))


def clip_intensity(values: Float) -> Float:
    """NaN -> 0, then clip to 0..255 (so +inf -> 255 and -inf -> 0)."""
    return dr.clip(dr.select(dr.isnan(values), 0.0, values), 0.0, 255.0)


@lru_cache(maxsize=1)
def packet_width() -> int:
    """The SIMD packet width of Dr.Jit's LLVM backend on this CPU (16 AVX-512, 8 AVX, else 4).

    Dr.Jit runs a kernel of at most one packet as one work unit, whose packets run in lockstep;
    the lanes of one band must stay in one packet, so this must not overestimate the real width.
    ``POINTILLIST_DITHER_LANES`` overrides it (a power of two <= the real width is always safe).
    """
    override = os.environ.get("POINTILLIST_DITHER_LANES")
    if override:
        value = int(override)
        if value < 1 or value & (value - 1):
            raise ValueError(f"POINTILLIST_DITHER_LANES: expected a power of two, got {override!r}")
        return value
    try:
        from numpy._core._multiarray_umath import __cpu_features__ as features
    except ImportError:  # numpy < 2
        from numpy.core._multiarray_umath import __cpu_features__ as features  # type: ignore
    if features.get("AVX512VL"):
        return 16
    if features.get("AVX"):
        return 8
    return 4


def _distinct_sets(delta_bytes: int, lanes: int) -> int:
    """How many L1 cache sets (64 sets of 64-byte lines, 4 KiB period) ``lanes`` addresses ``delta`` apart hit."""
    return len({((k * delta_bytes) % 4096) // 64 for k in range(lanes)})


def wavefront_schedule(kernel: tuple[tuple[int, int, float], ...], serpentine: bool, width: int, channels: int,
              lanes: int) -> dict[str, Any]:
    """Static plan of the wavefront: source windows, skew, arrival order, buffer layout."""
    rows = sorted({dy for dy, _, _ in kernel if dy > 0})

    def offset(dy: int, dx: int) -> int:
        # Column of the source of (y, x), relative to x, in the scan coordinate of row y.
        return dx if (serpentine and dy % 2) else -dx

    right = {dy: max(offset(dy, dx) for ddy, dx, _ in kernel if ddy == dy) for dy in rows}
    left = {dy: min(offset(dy, dx) for ddy, dx, _ in kernel if ddy == dy) for dy in rows}
    for dy in rows:
        right[dy] = max(right[dy], left[dy])
    prefetch = max([0] + [right[dy] for dy in rows])
    skew = max([1] + [right[dy] // dy + 1 for dy in rows])
    if serpentine:
        lanes = 1
    if lanes > 1:
        # Lanes of a band touch addresses (W - s) C floats apart: a multiple of 4 KiB maps them all
        # onto one L1 set (conflict misses). A slightly larger skew spreads them; it stays exact.
        want = min(lanes, 64) // 2
        for candidate in range(skew, skew + 64):
            if _distinct_sets((width - candidate) * channels * 4, lanes) >= want:
                skew = candidate
                break
    # Arrival order of the contributions at a pixel: rows further up first, each row in the order
    # it was scanned (rows of the other direction arrive right to left in our coordinate), then
    # our own row, farthest first.
    order = []
    for dy in sorted(rows, reverse=True):
        items = sorted(((offset(dy, dx), w) for ddy, dx, w in kernel if ddy == dy),
                       key=lambda item: item[0], reverse=bool(serpentine and dy % 2))
        order += [(dy, o, w) for o, w in items]
    own = sorted(((dx, w) for dy, dx, w in kernel if dy == 0), reverse=True)
    depth = max([0] + rows)
    stride = width + 2 * prefetch + 2
    if lanes > 1:
        for pad in range(0, 16):
            if _distinct_sets((stride + pad - skew) * 8, lanes) >= min(lanes, 64) // 2:
                stride += pad
                break
    return dict(rows=rows, right=right, left=left, prefetch=prefetch, skew=skew, order=order, own=own,
                lanes=lanes, slots=lanes + depth, stride=stride)


@lru_cache(maxsize=1)
def verified_lanes() -> int:
    """:func:`packet_width`, verified once on this machine before it is trusted.

    The parallel schedules are only exact when a band's lanes share one SIMD packet. The width is
    read from CPU flags, not from Dr.Jit, so it is checked: small random images are diffused with
    the guessed width (by the column schedule, and by the blocked one on a width it takes) and
    with one lane (always exact); on disagreement the width is halved until they agree, with a
    warning. Costs a few milliseconds once per process.
    """
    lanes = packet_width()
    if lanes == 1 or os.environ.get("POINTILLIST_DITHER_LANES"):
        return lanes
    weights = _PROBE_KERNEL
    rng = np.random.default_rng(20261122)
    tables = (np.array([128.0]), np.array([0.0, 255.0]), np.array([0.0, 255.0]))  # 1 bit at 128
    probes = []
    for width, blocks in ((29, False), (4 * BLOCK, True)):  # the column and the blocked schedule
        height = 2 * lanes + 3
        values = Float(rng.uniform(0.0, 255.0, height * width).astype(np.float32))
        expected = diffuse_wavefront(values, height, width, 1, weights, False, tables, lanes=1).numpy()
        probes.append((values, height, width, blocks, expected))

    def exact(lanes: int) -> bool:
        return all(np.array_equal(diffuse_wavefront(values, height, width, 1, weights, False, tables, lanes=lanes,
                                                    blocks=blocks).numpy(), expected)
                   for values, height, width, blocks, expected in probes)

    guess = lanes
    while lanes > 1 and not exact(lanes):
        lanes //= 2
    if lanes != guess:
        warnings.warn(f"imaging.wavefront: Dr.Jit's SIMD packet is narrower than the {guess} lanes the CPU "
                      f"flags suggest; using {lanes} (set POINTILLIST_DITHER_LANES to choose)", RuntimeWarning,
                      stacklevel=2)
    return lanes


def _quantiser_step(tables: tuple[np.ndarray, np.ndarray, np.ndarray], eight_bit: bool):
    """``(quantise, shown_type)``: ``quantise(v, valid) -> (q, shown)`` gives a step's level in the
    working space (float64, the value its error is measured from) and as output (float32, or the
    display value rounded half to even as ``UInt8``): the level k = the number of thresholds <= v.
    The tables become opaque scalars (two levels) or small Dr.Jit arrays, once per call."""
    thresholds, work, display = tables
    levels = len(display)
    shown_type = UInt8 if eight_bit else Float
    if eight_bit:
        display = np.rint(display)
    if levels == 2:
        level_k = dr.opaque(Float64, float(thresholds[0]))
        work0, work1 = dr.opaque(Float64, float(work[0])), dr.opaque(Float64, float(work[1]))
        value = int if eight_bit else float
        disp0, disp1 = dr.opaque(shown_type, value(display[0])), dr.opaque(shown_type, value(display[1]))

        def quantise(v: Float64, valid) -> tuple[Float64, Any]:
            on = v >= level_k
            return dr.select(on, work1, work0), dr.select(on, disp1, disp0)

        return quantise, shown_type
    threshold_table = Float64(thresholds)
    work_table = Float64(work)
    display_table = shown_type(display.astype(np.uint8 if eight_bit else np.float32))
    search = [1 << b for b in reversed(range(max(1, (levels - 1).bit_length())))]

    def quantise(v: Float64, valid) -> tuple[Float64, Any]:
        k = dr.zeros(Int32, dr.width(v))
        for jump in search:
            candidate = k + jump
            fits = candidate <= levels - 1
            bound = dr.gather(Float64, threshold_table, candidate - 1, fits & valid)
            k = dr.select(fits & (bound <= v), candidate, k)
        return dr.gather(Float64, work_table, k, valid), dr.gather(shown_type, display_table, k, valid)

    return quantise, shown_type


def _next_band(t, y, slot, own, steps: Int32, slots: Int32, lanes: int, keep_own: bool = False):
    """Advance a lane's step counter; at the end of a band (``steps`` steps) move it to its row in the
    next band and the next free row of the error buffer, and forget its own row's errors (unless
    ``keep_own``). Returns ``(t, y, slot, own)``."""
    t = t + 1
    wrap = t == steps
    if own and not keep_own:
        own = [dr.select(wrap, 0.0, o) for o in own]
    nxt = slot + lanes
    nxt = dr.select(nxt >= slots, nxt - slots, nxt)
    slot = dr.select(wrap, nxt, slot)
    y = dr.select(wrap, y + lanes, y)
    t = dr.select(wrap, 0, t)
    return t, y, slot, own


def _scan(state: tuple, end: Int32, body, out, label: str):
    """Run a schedule's loop (state: step, t, y, slot, windows, own) for ``end`` steps, one kernel;
    returns ``out`` (the output levels its body scatters) evaluated."""
    dr.while_loop(state, lambda step, *rest: step < end, body, labels=("step", "t", "y", "slot", "windows", "own"),
                  mode="symbolic", label=label)
    dr.eval(out)
    return out


#: Columns a lane diffuses per loop iteration in the blocked schedule: Dr.Jit's largest packet
#: gather / scatter on the LLVM backend (8 values: one vector load or store per lane and a
#: transpose, instead of one hardware gather or scatter per value and step).
BLOCK = 8


def blocked(width: int, channels: int, serpentine: bool, carry: bool, lanes: int) -> bool:
    """Whether :func:`diffuse_wavefront` takes the blocked schedule (:func:`_diffuse_blocks`): a raster
    scan over several lanes of one grey image whose rows are whole blocks of :data:`BLOCK` pixels."""
    return not serpentine and not carry and lanes > 1 and channels == 1 and width % BLOCK == 0


def _packet(kind, source, index, mask) -> list:
    """The :data:`BLOCK` consecutive values of ``source`` at ``index * BLOCK`` (one packet gather)."""
    return list(dr.gather(kind, source, index, mask, shape=(BLOCK, dr.width(index))))


def _diffuse_blocks(values, height: int, width: int, plan: dict[str, Any],
                    tables: tuple[np.ndarray, np.ndarray, np.ndarray], clip: bool, eight_bit: bool):
    """The wavefront of :func:`diffuse_wavefront` in blocks of :data:`BLOCK` columns (one grey image,
    ``width`` a multiple of :data:`BLOCK`, raster scan).

    Each loop iteration diffuses one block of a lane's row with the steps unrolled: the block's
    input values, the next block of every source row's errors, and (at the end) the block's errors
    and output levels move as packets of :data:`BLOCK` values. The row above must have written the
    block after the one being diffused, one iteration before it is read, so lanes start
    ``2 BLOCK`` columns apart (``BLOCK`` for rows two or more above). Within the block the
    additions are those of the one-column schedule, in the same order, so the result is the same
    bit for bit.
    """
    rows, right, left, order, own_w = plan["rows"], plan["right"], plan["left"], plan["order"], plan["own"]
    lanes, slots = plan["lanes"], plan["slots"]
    if rows and (max(right.values()) > BLOCK or min(left.values()) < -BLOCK):
        raise ValueError("diffuse_wavefront: a kernel reaching more than 8 columns needs the column schedule")
    quantise, shown_type = _quantiser_step(tables, eight_bit)
    blocks = width // BLOCK
    # block skew: row y - dy has finished block b + 1 when row y starts block b (iteration counts)
    skew = max([0] + [-(-2 // dy) for dy in rows])
    lead = 1 if rows else 0  # one iteration before the row starts: read its first source block
    per_band = blocks + lead + skew * (lanes - 1)
    bands = -(-height // lanes)
    total = bands * per_band
    if total >= 2**31 or height * width >= 2**31:
        raise ValueError(f"image: too large for error diffusion ({height} x {width})")
    low = {dy: min(left[dy], 0) for dy in rows}  # carried window of row dy: columns [x0 + low, x0 + BLOCK)

    # error rows: `slots` rows of `width` float64 (64-byte aligned, so each block is one cache line),
    # read and written through two Dr.Jit arrays over the same memory (see diffuse_wavefront)
    raw = np.zeros(slots * width + BLOCK, dtype=np.float64)
    start = (-raw.ctypes.data % 64) // 8
    memory = raw[start:start + slots * width]
    errors_in, errors_out = Float64(memory), Float64(memory)
    out = dr.empty(shown_type, height * width)
    packets = dr.llvm.ad.ArrayXu8 if eight_bit else dr.llvm.ad.ArrayXf
    source_packets = dr.llvm.ad.ArrayXu8 if isinstance(values, UInt8) else dr.llvm.ad.ArrayXf

    lane = dr.arange(Int32, lanes)
    H = dr.opaque(Int32, height)
    NB = dr.opaque(Int32, blocks)
    S = dr.opaque(Int32, slots)
    T = dr.opaque(Int32, per_band)
    end = dr.opaque(Int32, total)
    delay = lane * skew + lead

    # loop state
    step = dr.zeros(Int32, lanes)
    t = dr.zeros(Int32, lanes)
    y = Int32(lane)
    slot = Int32(lane)
    windows = [[dr.zeros(Float64, lanes) for _ in range(BLOCK - low[dy])] for dy in rows]
    own = [dr.zeros(Float64, lanes) for _ in range(max([0] + [dx for dx, _ in own_w]))]

    def body(step, t, y, slot, windows, own):
        b = t - delay  # the block of the row diffused in this iteration (negative: not started)
        start = t == 0
        live = y < H
        valid = live & (b >= 0) & (b < NB)
        full = []  # per source row: columns [x0 + low, x0 + 2 BLOCK)
        for r, dy in enumerate(rows):
            carried = [dr.select(start, 0.0, v) for v in windows[r]]
            source = slot - dy
            source = dr.select(source < 0, source + S, source)
            ahead = b + 1
            mask = live & (y >= dy) & (ahead >= 0) & (ahead < NB)
            fresh = _packet(dr.llvm.ad.ArrayXf64, errors_in, UInt32(source * NB + ahead), mask)
            full.append(carried + fresh)
        read = _packet(source_packets, values, UInt32(y * NB + b), valid)
        errors, shown_block = [], []
        for k in range(BLOCK):
            v = Float64(clip_intensity(Float(read[k])) if clip else Float(read[k]))
            for dy, o, w in order:
                r = rows.index(dy)
                v = v + full[r][k + o - low[dy]] * w
            for dx, w in own_w:
                v = v + own[dx - 1] * w
            q, shown = quantise(v, valid)
            e = dr.select(valid, v - q, 0.0)
            if own:
                own = [e] + own[:-1]
            errors.append(e)
            shown_block.append(shown)
        if rows:
            dr.scatter(errors_out, dr.llvm.ad.ArrayXf64(errors), UInt32(slot * NB + b), valid)
        dr.scatter(out, packets(shown_block), UInt32(y * NB + b), valid)
        windows = [block[BLOCK:] for block in full]
        t, y, slot, own = _next_band(t, y, slot, own, T, S, lanes)
        return step + 1, t, y, slot, windows, own

    return _scan((step, t, y, slot, windows, own), end, body, out, "error_diffusion_blocks")


def diffuse_wavefront(values: Float, height: int, width: int, channels: int,
                  kernel: tuple[tuple[int, int, float], ...], serpentine: bool,
                  tables: tuple[np.ndarray, np.ndarray, np.ndarray], carry: bool = False,
                  lanes: int | None = None, clip: bool = False, eight_bit: bool = False,
                  blocks: bool | None = None) -> Float | UInt8:
    """Error diffusion of the flat (H, W, C) ``values``; returns the output levels.

    ``values``: evaluated float32 (already clipped, or raw with ``clip``: NaN -> 0 and the clip to
    0..255 then happen on each value as the loop reads it, saving a pass over the image) or
    uint8 (0..255, read as bytes). ``lanes``: rows processed together in one SIMD packet (default:
    :func:`verified_lanes`). ``eight_bit``: write the output levels as ``UInt8`` (the display
    values rounded half to even), not float32. ``blocks``: run the blocked schedule
    (:func:`_diffuse_blocks`, the default where :func:`blocked` allows it) or the one-column
    schedule (``False``); both give the same bits.
    """
    plan = wavefront_schedule(kernel, serpentine, width, channels, verified_lanes() if lanes is None else lanes)
    allowed = blocked(width, channels, serpentine, carry, plan["lanes"])
    if blocks and not allowed:
        raise ValueError("blocks: the blocked schedule needs a raster scan of one channel over several lanes, "
                         f"with a width that is a multiple of {BLOCK}")
    blocks = allowed if blocks is None else blocks
    if isinstance(values, UInt8) and (not blocks or np.asarray(values).ctypes.data % 16):
        # widened to float32 in one pass first: a per-step gather of single bytes is scalarised by
        # LLVM (measured: 19-20 ms per 2048^2 Floyd-Steinberg against 11-12 ms for float32 input;
        # the widening pass costs about 0.5 ms); the blocked schedule reads aligned bytes in packets
        values = Float(values)
        dr.eval(values)
    if blocks:
        return _diffuse_blocks(values, height, width, plan, tables, clip, eight_bit)
    rows, right, left, order, own_w = plan["rows"], plan["right"], plan["left"], plan["order"], plan["own"]
    lanes, skew, prefetch, slots, stride = plan["lanes"], plan["skew"], plan["prefetch"], plan["slots"], plan["stride"]
    quantise, shown_type = _quantiser_step(tables, eight_bit)

    steps_per_band = width + prefetch + skew * (lanes - 1)
    bands = -(-height // lanes)
    total = bands * steps_per_band
    if total >= 2**31 or height * width * channels >= 2**31:
        raise ValueError(f"image: too large for error diffusion ({height} x {width} x {channels})")

    # The error buffer: `slots` rows of `stride` float64 per channel. It is gathered and scattered
    # in the same loop through two Dr.Jit arrays over the same memory: the schedule guarantees
    # that every value is read at a later step than the one that wrote it.
    memory = np.zeros(channels * slots * stride, dtype=np.float64)
    errors_in, errors_out = Float64(memory), Float64(memory)
    out = dr.empty(shown_type, height * width * channels)

    lane = dr.arange(Int32, lanes * channels)
    index = lane % lanes
    channel = lane // lanes
    W = dr.opaque(Int32, width)
    H = dr.opaque(Int32, height)
    C = dr.opaque(Int32, channels)
    S = dr.opaque(Int32, slots)
    B = dr.opaque(Int32, stride)
    T = dr.opaque(Int32, steps_per_band)
    end = dr.opaque(Int32, total)
    buffer_base = channel * (S * B) + prefetch

    step = dr.zeros(Int32, lanes * channels)
    t = dr.zeros(Int32, lanes * channels)
    y = Int32(index)
    slot = Int32(index)
    windows = [[dr.zeros(Float64, lanes * channels) for _ in range(right[dy] - left[dy] + 1)] for dy in rows]
    own = [dr.zeros(Float64, lanes * channels) for _ in range(max([0] + [dx for dx, _ in own_w]))]

    def body(step, t, y, slot, windows, own):
        x = t - (skew * index + prefetch)
        start = t == 0
        live = y < H
        odd = (y & 1) == 1
        for r, dy in enumerate(rows):
            window = [dr.select(start, 0.0, v) for v in windows[r]][1:]
            column = x + right[dy]
            source = slot - dy
            source = dr.select(source < 0, source + S, source)
            mask = live & (y >= dy) & (column >= 0) & (column < W)
            physical = dr.select(odd, W - 1 - column, column) if serpentine else column
            window.append(dr.gather(Float64, errors_in, buffer_base + source * B + physical, mask))
            windows[r] = window
        valid = live & (x >= 0) & (x < W)
        px = dr.select(odd, W - 1 - x, x) if serpentine else x
        pixel = (y * W + px) * C + channel
        read = Float(dr.gather(type(values), values, pixel, valid))
        v = Float64(clip_intensity(read) if clip else read)
        for dy, o, w in order:
            v = v + windows[rows.index(dy)][o - left[dy]] * w
        for dx, w in own_w:
            v = v + own[dx - 1] * w
        q, shown = quantise(v, valid)
        e = dr.select(valid, v - q, 0.0)
        if rows:
            dr.scatter(errors_out, e, buffer_base + slot * B + px, valid)
        dr.scatter(out, shown, pixel, valid)
        if own:
            own = [e] + own[:-1]
        t, y, slot, own = _next_band(t, y, slot, own, T, S, lanes, keep_own=carry)
        return step + 1, t, y, slot, windows, own

    return _scan((step, t, y, slot, windows, own), end, body, out, "error_diffusion")
