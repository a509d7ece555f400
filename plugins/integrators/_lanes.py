"""Generic helpers on Dr.Jit lanes for the integrators that schedule their own rays.

Morton (Z-order) bit spreading, stream compaction with the prefix sum kept, and
deterministic per-owner sums (no atomics), on the Mitsuba variant's types.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

__all__ = ["part1by1", "compact1by1", "compact_flags", "add_blocks", "add_by_pixel", "all_finite"]


def part1by1(x):
    """Spread the low 16 bits of a UInt32 to the even bits (Morton code helper)."""
    x = x & 0x0000FFFF
    x = (x | (x << 8)) & 0x00FF00FF
    x = (x | (x << 4)) & 0x0F0F0F0F
    x = (x | (x << 2)) & 0x33333333
    x = (x | (x << 1)) & 0x55555555
    return x


def compact1by1(x):
    """Gather the even bits of a UInt32 into its low 16 bits (inverse of ``part1by1``)."""
    x = x & 0x55555555
    x = (x | (x >> 1)) & 0x33333333
    x = (x | (x >> 2)) & 0x0F0F0F0F
    x = (x | (x >> 4)) & 0x00FF00FF
    x = (x | (x >> 8)) & 0x0000FFFF
    return x


def compact_flags(flags):
    """Indices of the nonzero ``flags`` (UInt32 0 / 1) in order, and the exclusive prefix
    sum ``pos`` (the index in that list of each flagged lane); ``(None, None)`` when no
    flag is set. One prefix sum and one scatter: like ``dr.compress``, but ``pos`` is
    kept for the next level's neighbour look-ups."""
    dr.eval(flags)
    inclusive = dr.cumsum(flags)
    total = int(inclusive[dr.width(flags) - 1])
    if total == 0:
        return None, None
    pos = inclusive - flags
    dr.eval(pos)
    sel = dr.empty(mi.UInt32, total)
    dr.scatter(sel, dr.arange(mi.UInt32, dr.width(flags)), pos, flags != 0)
    dr.eval(sel)
    return sel, pos


def add_blocks(totals, owner, values, block: int) -> None:
    """``totals[c][owner[b]] +=`` the sum of block ``b`` (``block`` consecutive lanes) of
    ``values[c]``, in place; ``owner`` holds unique indices. Deterministic (no atomics)."""
    updated = [dr.gather(mi.Float, total, owner) + dr.block_sum(value, block)
               for total, value in zip(totals, values)]
    dr.eval(updated)
    for total, value in zip(totals, updated):
        dr.scatter(total, value, owner)
    dr.eval(totals)


def add_by_pixel(totals, pixel, values, n) -> None:
    """``totals[c][pixel[s]] += values[c][s]`` for ``pixel`` sorted ascending, in place.

    Deterministic: the first square of each run of equal pixels sums the run in order
    (a symbolic loop), then adds it with a scatter-add whose targets are unique, in the
    same kernel.
    """
    width = dr.width(pixel)
    index = dr.arange(mi.UInt32, width)
    first = (index == 0) | (pixel != dr.gather(mi.UInt32, pixel, index - 1, index > 0))

    def cond(i, *partial):
        return first & (i < n) & (dr.gather(mi.UInt32, pixel, i, i < n) == pixel)

    def body(i, *partial):
        return (i + 1, *[p + dr.gather(mi.Float, v, i) for p, v in zip(partial, values)])

    state = dr.while_loop(state=(mi.UInt32(index), *[dr.zeros(mi.Float, width) for _ in values]),
                          cond=cond, body=body, label="adaptive_pixel_sum")
    for total, partial in zip(totals, state[1:]):
        dr.scatter_add(total, partial, pixel, first, mode=dr.ReduceMode.NoConflicts)
    dr.eval(totals)


def all_finite(channels) -> mi.Bool:
    """True where every channel of a sample is finite (neither NaN nor +-inf)."""
    ok = dr.isfinite(channels[0])
    for channel in channels[1:]:
        ok &= dr.isfinite(channel)
    return ok
