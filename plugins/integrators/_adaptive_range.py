"""The lane arithmetic of the ``adaptive`` integrator's range criterion (a helper, not a plugin).

The integrator (:mod:`pointillist.plugins.integrators.adaptive`) traces the rays and keeps the
statistics; these functions do the rest on Dr.Jit lanes, one call per step of a refinement level:
the pixel sums over the first lattice (:func:`lattice_sums`), the first squares to split
(:func:`first_squares`), each level's point counts (:func:`point_counts`), the positions of its new
points (:func:`new_points`), what splitting its squares adds to their pixels (:func:`split_squares`)
and the sub-squares to split next (:func:`next_squares`). The state between them is typed
(:class:`PixelSums`, :class:`Squares`, :class:`Split`).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import drjit as dr
import mitsuba as mi

from pointillist.imaging.arrays import divmod_u32
from pointillist.plugins.integrators._lanes import all_finite, compact1by1, compact_flags, part1by1

__all__ = ["PixelSums", "Squares", "Split", "lattice_sums", "first_squares", "point_counts", "new_points",
           "split_squares", "next_squares", "shown", "spread"]

#: New points of a refined square, on the doubled lattice of the next level, relative to
#: (2i, 2j): the midpoints of the edges y = j and x = i, the centre, the midpoints of the
#: edges x = i + 1 and y = j + 1.
_NEW_DX = (1, 0, 1, 2, 1)
_NEW_DY = (0, 1, 1, 1, 2)
#: Point on the 3 x 3 doubled lattice of a square (code u + 3 v) -> index of the new
#: point (0..4); the four corners (codes 0, 2, 6, 8) are the parent's corners.
_CODE_TO_NEW = (0, 0, 0, 1, 2, 3, 0, 4, 0)


class PixelSums(NamedTuple):
    """What each pixel has gathered (one lane per pixel): the weighted sums of its samples' channels,
    the weight of its valid samples, and how many samples it took."""

    sums: list             # mi.Float per channel
    valid_n: Any           # mi.Float
    count: Any             # mi.Float


class Squares(NamedTuple):
    """The squares of one level to split, in key order (pixel, then the Morton code inside it)."""

    i: Any                 # mi.UInt32: column on the level's grid (2^level squares a pixel side)
    j: Any                 # mi.UInt32: row
    quad: list             # the four corners (00, 10, 01, 11): each its sample's channels, display values last
    found_r: Any           # mi.Bool: the right neighbour is split at this level too ...
    index_r: Any           # mi.UInt32: ... at this index of the level's list
    found_t: Any           # mi.Bool: likewise the neighbour below
    index_t: Any           # mi.UInt32


class Split(NamedTuple):
    """What splitting a level's squares gives (evaluated): per square, the channel sums, weight and
    sample count it adds to its pixel, then (but at the last level) the mask of its sub-squares to
    split next and the slots of its points 3 and 4; and ``start_of(square, active)``, where a
    square's points start in the level's ray batch."""

    outputs: list
    start_of: Any


def shown(values) -> mi.Color3f:
    """The display colour carried as the last three channels of a sample."""
    return mi.Color3f(values[-3], values[-2], values[-1])


def spread(quad) -> mi.Float:
    """Largest per-channel max - min of four display colours, ignoring NaN (invalid)
    entries; 0 when fewer than one entry is valid."""
    low = mi.Color3f(dr.inf)
    high = mi.Color3f(-dr.inf)
    for value in quad:
        ok = ~dr.isnan(value)
        low = dr.select(ok, dr.minimum(low, value), low)
        high = dr.select(ok, dr.maximum(high, value), high)
    difference = dr.select(high >= low, high - low, 0.0)
    return dr.maximum(dr.maximum(difference.x, difference.y), difference.z)


def lattice_sums(lattice, finite, size: tuple[int, int], min_depth: int, stride: int, channels: int,
                 area: bool) -> PixelSums:
    """Pixel sums over the (2^m + 1)^2 lattice points of each pixel (m = ``min_depth``; the
    lattice's rows are ``stride`` points long): trapezoidal weights w(u) w(v) h^2 (w = 1/2 on the
    pixel border, 1 inside, h = 2^-m) with ``area``, else 1. One lane per pixel, a symbolic loop over
    its points; evaluated."""
    width, height = size
    m, nc = min_depth, channels
    side = 1 << m
    n_pixels = width * height
    o_stride = dr.opaque(mi.UInt32, stride)
    o_shift = dr.opaque(mi.UInt32, m)
    o_side = dr.opaque(mi.UInt32, side)
    py, px = divmod_u32(dr.arange(mi.UInt32, n_pixels), width)
    base = (py << o_shift) * o_stride + (px << o_shift)
    h2 = dr.opaque(mi.Float, 0.25 ** m)

    def cond(u, v, *acc):
        return v <= o_side

    def body(u, v, *acc):
        at = base + v * o_stride + u
        ok = dr.gather(mi.Bool, finite, at)
        if area:
            weight = (dr.select((u == 0) | (u == o_side), 0.5, 1.0)
                      * dr.select((v == 0) | (v == o_side), 0.5, 1.0) * h2)
        else:
            weight = mi.Float(1.0)
        updated = [a + dr.select(ok, weight * dr.gather(mi.Float, channel, at, ok), 0.0)
                   for a, channel in zip(acc[:-1], lattice[:nc])]
        wrap = u == o_side
        return (dr.select(wrap, 0, u + 1), dr.select(wrap, v + 1, v), *updated,
                acc[-1] + dr.select(ok, weight, 0.0))

    zero = dr.zeros(mi.UInt32, n_pixels)
    state = dr.while_loop(state=(zero, zero, *[dr.zeros(mi.Float, n_pixels) for _ in range(nc + 1)]),
                          cond=cond, body=body, label="adaptive_lattice_sum")
    pixels = PixelSums(list(state[2:-1]), state[-1], dr.full(mi.Float, float((side + 1) ** 2), n_pixels))
    dr.eval(pixels.sums, pixels.valid_n, pixels.count)
    return pixels


def first_squares(lattice, size: tuple[int, int], min_depth: int, stride: int, threshold) -> Squares | None:
    """The squares of level ``min_depth`` whose corners differ by more than ``threshold`` (an
    opaque mi.Float), with their neighbours split too; None when there are none (one host read).
    A square's lane before the compaction is pixel * 4^m + its Morton code inside the pixel, so
    the order is by pixel and the four children of a square follow each other."""
    width, height = size
    m = min_depth
    side = 1 << m
    o_width = dr.opaque(mi.UInt32, width)
    o_stride = dr.opaque(mi.UInt32, stride)
    o_shift = dr.opaque(mi.UInt32, m)
    local_mask = dr.opaque(mi.UInt32, side * side - 1)
    coordinate_mask = dr.opaque(mi.UInt32, side - 1)
    two_m = dr.opaque(mi.UInt32, 2 * m)
    cells = (width * height) << (2 * m)

    def lattice_square(lane):
        sy, sx = divmod_u32(lane >> two_m, width)
        i = (sx << o_shift) | compact1by1(lane & local_mask)
        j = (sy << o_shift) | compact1by1((lane & local_mask) >> 1)
        c00 = j * o_stride + i
        corners = (c00, c00 + 1, c00 + o_stride, c00 + o_stride + 1)
        return i, j, [[dr.gather(mi.Float, channel, at) for channel in lattice] for at in corners]

    def lane_of(i, j):  # the inverse of lattice_square
        pixel = (j >> o_shift) * o_width + (i >> o_shift)
        return (pixel << two_m) | part1by1(i & coordinate_mask) | (part1by1(j & coordinate_mask) << 1)

    quad = lattice_square(dr.arange(mi.UInt32, cells))[2]
    flags = dr.select(spread([shown(values) for values in quad]) > threshold, mi.UInt32(1), 0)
    sel, pos = compact_flags(flags)
    if sel is None:
        return None
    i, j, quad = lattice_square(sel)
    cells_x = dr.opaque(mi.UInt32, width << m)
    cells_y = dr.opaque(mi.UInt32, height << m)
    inside_r, inside_t = i + 1 < cells_x, j + 1 < cells_y
    lane_r = lane_of(dr.select(inside_r, i + 1, i), j)
    lane_t = lane_of(i, dr.select(inside_t, j + 1, j))
    return Squares(i, j, quad, inside_r & (dr.gather(mi.UInt32, flags, lane_r) != 0), dr.gather(mi.UInt32, pos, lane_r),
                   inside_t & (dr.gather(mi.UInt32, flags, lane_t) != 0), dr.gather(mi.UInt32, pos, lane_t))


def point_counts(squares: Squares, shift, width: int):
    """Step 1 of a level: each square's pixel and the number of points it traces: 3 (two edge
    midpoints and the centre) plus the midpoints of its right and lower edges, unless the neighbour
    there is split at the same level too and owns that point (its k = 1 or k = 0 point).
    ``(pixel, points_of, owned_r, owned_t)``, evaluated."""
    owned_r, owned_t = ~squares.found_r, ~squares.found_t
    points_of = 3 + dr.select(owned_r, mi.UInt32(1), 0) + dr.select(owned_t, mi.UInt32(1), 0)
    pixel = (squares.j >> shift) * dr.opaque(mi.UInt32, width) + (squares.i >> shift)
    dr.eval(squares.i, squares.j, pixel, squares.quad, squares.found_r, squares.index_r, squares.found_t,
            squares.index_t, points_of)
    return pixel, points_of, owned_r, owned_t


def new_points(squares: Squares, start, total: int, level: int) -> mi.Point2f:
    """Step 3 of a level: the film positions of its ``total`` new points. Lane t belongs to square
    s = the number of squares s' > 0 whose points start (``start``) at or before t (marks at the
    starts, then an inclusive prefix sum); its point is the square's k-th (k = 3 is the lower
    midpoint when the right one belongs to the neighbour)."""
    lane = dr.arange(mi.UInt32, total)
    marks = dr.zeros(mi.UInt32, total)
    dr.scatter(marks, mi.UInt32(1), start, start > 0)
    s = dr.cumsum(marks)
    k = lane - dr.gather(mi.UInt32, start, s)
    k = dr.select((k == 3) & dr.gather(mi.Bool, squares.found_r, s), mi.UInt32(4), k)
    dx = dr.gather(mi.UInt32, mi.UInt32(_NEW_DX), k)
    dy = dr.gather(mi.UInt32, mi.UInt32(_NEW_DY), k)
    step = dr.opaque(mi.Float, 0.5 ** (level + 1))
    gx = 2 * dr.gather(mi.UInt32, squares.i, s) + dx
    gy = 2 * dr.gather(mi.UInt32, squares.j, s) + dy
    return mi.Point2f(mi.Float(gx) * step, mi.Float(gy) * step)


def split_squares(squares: Squares, points, finite, start, end, points_of, owned_r, owned_t, shift, level: int,
                  channels: int, threshold, weighting: str, last_level: bool) -> Split:
    """Step 4 of a level, per square: the slots of its five new points (``points``: their channels,
    ``finite``: valid), what the split adds to its pixel (channel sums, weight, sample count) and,
    unless at the last level, which of its four sub-squares are split next. Evaluated."""
    nc = channels
    i, j, quad = squares.i, squares.j, squares.quad

    def start_of(at, active):
        return dr.gather(mi.UInt32, end, at, active) - dr.gather(mi.UInt32, points_of, at, active)

    slots = [start, start + 1, start + 2,
             dr.select(owned_r, start + 3, start_of(squares.index_r, squares.found_r) + 1),
             dr.select(owned_t, start + 3 + dr.select(owned_r, mi.UInt32(1), 0),
                       start_of(squares.index_t, squares.found_t))]
    new = [[dr.gather(mi.Float, channel, slot) for channel in points] for slot in slots]
    ok_new = [dr.gather(mi.Bool, finite, slot) for slot in slots]
    # Sample count: each distinct position once per pixel. A point on the edge shared
    # with a split neighbour in the same pixel is counted by the neighbour (as its
    # k = 0 / 1 point); across a pixel border both pixels count it.
    same_r = ((i + 1) >> shift) == (i >> shift)
    same_t = ((j + 1) >> shift) == (j >> shift)
    distinct = [True, True, True, owned_r | ~same_r, owned_t | ~same_t]
    area = dr.opaque(mi.Float, 0.25 ** level)
    deltas = [mi.Float(0.0) for _ in range(nc)]
    weight_sum = mi.Float(0.0)
    for k in range(5):
        ok = ok_new[k]
        if weighting == "equal":
            ok &= distinct[k]
            weight = mi.Float(1.0)
        else:  # area: edge midpoints gain A/8, the centre A/4 (A: the square's area) ...
            weight = (0.25 if k == 2 else 0.125) * area
        for c in range(nc):
            deltas[c] += dr.select(ok, weight * new[k][c], 0.0)
        weight_sum += dr.select(ok, weight, 0.0)
    if weighting == "area":  # ... and each corner goes from A/4 to A/16.
        minus = -3.0 / 16.0 * area
        for values in quad:
            good = all_finite(values[:nc])
            for c in range(nc):
                deltas[c] += dr.select(good, minus * values[c], 0.0)
            weight_sum += dr.select(good, minus, 0.0)
    added = mi.Float(3.0) + dr.select(distinct[3], 1.0, 0.0) + dr.select(distinct[4], 1.0, 0.0)
    outputs = deltas + [weight_sum, added]
    if not last_level:
        # The 3 x 3 points of the split square (code u + 3 v) on the display scale;
        # sub-square q = (cx, cy) is split again when its corners differ.
        display = [shown(new[_CODE_TO_NEW[code]]) for code in range(9)]
        for p, code in enumerate((0, 2, 6, 8)):
            display[code] = shown(quad[p])
        mask = mi.UInt32(0)
        for q in range(4):
            cx, cy = q & 1, q >> 1
            codes = [(cx + a) + 3 * (cy + b) for b in (0, 1) for a in (0, 1)]
            keep = spread([display[code] for code in codes]) > threshold
            mask |= dr.select(keep, mi.UInt32(1 << q), 0)
        outputs += [mask, slots[3], slots[4]]
    dr.eval(outputs)
    return Split(outputs, start_of)


def next_squares(squares: Squares, split: Split, points, n: int) -> Squares | None:
    """Step 6 of a level: the sub-squares of its ``n`` squares to split at the next level (children
    follow their parent: key order), their corners and their split neighbours; None when there are
    none (one host read)."""
    i, j, quad, found_r, index_r, found_t, index_t = squares
    mask, slot3, slot4 = split.outputs[-3:]
    start_of = split.start_of
    child = dr.arange(mi.UInt32, 4 * n)
    flags = (dr.gather(mi.UInt32, mask, child >> 2) >> (child & 3)) & 1
    sel, pos = compact_flags(flags)
    if sel is None:
        return None
    ps, q = sel >> 2, sel & 3
    cx, cy = q & 1, q >> 1
    child_quad = []
    for p in range(4):  # corner p = (a, b) of the child: the parent's corner when p == q
        a, b = p & 1, p >> 1
        parent = q == p
        code = (cx + a) + 3 * (cy + b)
        k = dr.gather(mi.UInt32, mi.UInt32(_CODE_TO_NEW), code)
        at = dr.select(k < 3, start_of(ps, ~parent) + k,
                       dr.select(k == 3, dr.gather(mi.UInt32, slot3, ps, ~parent),
                                 dr.gather(mi.UInt32, slot4, ps, ~parent)))
        child_quad.append([dr.select(parent, dr.gather(mi.Float, quad[p][c], ps),
                                     dr.gather(mi.Float, channel, at, ~parent))
                           for c, channel in enumerate(points)])
    # Neighbours: the right one of a left child (cx = 0) is its sibling; that of a
    # right child is the left child in the same row of the parent's right neighbour
    # (if that one was split too). Likewise below.
    parent_r = dr.gather(mi.Bool, found_r, ps)
    lane_r = dr.select(cx == 0, sel + 1, 4 * dr.gather(mi.UInt32, index_r, ps, parent_r) + (q - 1))
    has_r = (cx == 0) | parent_r
    parent_t = dr.gather(mi.Bool, found_t, ps)
    lane_t = dr.select(cy == 0, sel + 2, 4 * dr.gather(mi.UInt32, index_t, ps, parent_t) + (q - 2))
    has_t = (cy == 0) | parent_t
    return Squares(2 * dr.gather(mi.UInt32, i, ps) + cx, 2 * dr.gather(mi.UInt32, j, ps) + cy, child_quad,
                   has_r & (dr.gather(mi.UInt32, flags, lane_r, has_r) != 0), dr.gather(mi.UInt32, pos, lane_r, has_r),
                   has_t & (dr.gather(mi.UInt32, flags, lane_t, has_t) != 0), dr.gather(mi.UInt32, pos, lane_t, has_t))
