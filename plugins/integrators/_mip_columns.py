"""The ``mip`` integrator's axis-aligned fast path: reduce voxel columns of the stored volume instead
of marching, only where that provably gives the march's result bit for bit."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from pointillist.plugins.integrators._mip_volume import StoredVolume, clip_to_box

__all__ = ["ColumnProjector"]


class ColumnProjector:
    """Projects axis-aligned orthographic rays by column reductions of ``stored``'s storage.

    :meth:`project` is used only when it provably gives the march's result bit for bit, checked
    on the actual rays with the march's own float32 arithmetic:

    * every ray's texture-space direction has one nonzero component ``a`` (the same value for all
      rays), its origin along ``a`` and its ``maxt`` are shared, so all rays that hit have the same
      sample parameters along ``a``;
    * the sample positions along ``a`` (the march's ``fma`` sequence, mapped by the texture's own
      index arithmetic) visit every voxel of the column:

      - nearest, mip/minip: every voxel index 0..n-1 is sampled (and no other);
      - nearest, average: every voxel is sampled the same number m of times (m <= 8), so the
        march's running sum adds each voxel m times in ray order;
      - trilinear, mip/minip: every sample lies exactly on a voxel centre (weight 0) or exactly
        half-way between two (weights 1/2, 1/2), every centre is sampled, the rays pass exactly
        through voxel-column centres across the axis, and the volume has no NaN/inf. A centre
        sample returns the voxel, a half-way sample ``fma(b, 1/2, a / 2)`` lies between its two
        voxels, so the max (min) over the samples is the column's max (min). Average with
        trilinear has no such identity and always marches.
    """

    def __init__(self, stored: StoredVolume, mode: str):
        self.stored = stored
        self.mode = mode

    def project(self, ray: mi.Ray3f, to_world, step: float, background: float):
        """``(value, valid)`` per ray as the march gives them, or ``None`` where the march must run."""
        stored, volume = self.stored, self.stored.volume
        trilinear = stored.interpolation == "trilinear"
        if trilinear and (self.mode == "average" or not stored.finite()):
            return None
        to_tex = stored.world_to_texture(to_world)
        o, d = to_tex @ ray.o, to_tex @ ray.d
        maxt = mi.Float(ray.maxt)
        dr.eval(o, d, maxt)
        if dr.width(maxt) == 0:
            return None
        # reductions over the rays (Dr.Jit, both cores) rather than numpy copies of them
        moving = [k for k in range(3) if bool(dr.any(d[k] != 0))]
        if len(moving) != 1:
            return None
        a = moving[0]
        first_o, first_d, first_t = (float(values[0]) for values in (o[a], d[a], maxt))
        if not bool(dr.all((d[a] == first_d) & (o[a] == first_o) & (maxt == first_t))):
            return None
        b, c = [k for k in range(3) if k != a]
        res = tuple(volume.shape_xyz)
        # one representative ray: inside across the axis, so its slab test equals every hit ray's
        rep_o = [0.5, 0.5, 0.5]
        rep_o[a] = first_o
        rep_d = [0.0, 0.0, 0.0]
        rep_d[a] = first_d
        ro, rd = mi.Point3f(*rep_o), mi.Vector3f(*rep_d)
        t0, t1, hit = clip_to_box(ro, rd, mi.Float(first_t))
        segments, dt = stored.schedule(rd, t0, t1, hit, step)
        average = self.mode == "average"
        dr.eval(t0, segments, dt, hit)
        if not bool(hit[0]):
            return None
        count = int(segments[0]) + (0 if average else 1)
        if count > 1 << 22:
            return None
        k = dr.arange(mi.Float, count) + (0.5 if average else 0.0)
        t = dr.fma(k, dt, t0)
        p = dr.fma(dr.opaque(mi.Float, rep_d[a]), t, dr.opaque(mi.Float, rep_o[a]))
        n_a = res[a]
        res_a = dr.opaque(mi.Float, float(n_a))
        pos_f = dr.fma(p, res_a, -0.5) if trilinear else p * res_a
        pos_i = mi.Int32(dr.floor(pos_f))
        frac = pos_f - mi.Float(pos_i)
        index = dr.clip(pos_i, 0, n_a - 1)
        dr.eval(frac, index)
        frac, index = frac.numpy(), index.numpy()
        repeats = 1
        if trilinear:
            if not np.all((frac == 0.0) | (frac == 0.5)):
                return None
            if not np.array_equal(np.unique(index[frac == 0.0]), np.arange(n_a)):
                return None
        elif average:
            hits = np.bincount(index, minlength=n_a)
            repeats = int(hits[0])
            if not (1 <= repeats <= 8 and np.all(hits == repeats)):
                return None
        elif not np.array_equal(np.unique(index), np.arange(n_a)):
            return None
        # per ray: the column it runs through (the texture's index arithmetic across the axis)
        inside = mi.Bool(True)
        column = mi.Int32(0)
        exact = mi.Bool(True)
        for axis, scale in ((c, res[b]), (b, 1)):
            q = o[axis]
            inside &= (q >= 0) & (q <= 1)
            n_q = dr.opaque(mi.Float, float(res[axis]))
            q_f = dr.fma(q, n_q, -0.5) if trilinear else q * n_q
            q_i = mi.Int32(dr.floor(q_f))
            exact &= ~inside | (q_f == mi.Float(q_i))
            column = column + dr.clip(q_i, 0, res[axis] - 1) * scale
        if trilinear and not bool(dr.all(exact)):
            return None
        values, seen = self.column_values(a, reverse=rep_d[a] < 0, repeats=repeats)
        column = mi.UInt32(dr.select(inside, column, 0))
        acc = dr.gather(mi.Float, values, column, inside)
        seen = dr.gather(mi.UInt32, seen, column, inside)
        valid = inside & (seen > 0)
        offset = dr.opaque(mi.Float, stored.texture.offset)
        if average:
            acc = acc / mi.Float(dr.maximum(seen, 1))
        value = dr.select(valid, acc + offset, dr.opaque(mi.Float, background))
        return value, valid

    def column_values(self, axis: int, *, reverse: bool, repeats: int):
        """Column reductions of the stored volume along ``axis``: ``(acc, seen)`` per column."""
        from pointillist.plugins.integrators._mip_accel import reduce_columns, reduce_half_words

        stored = self.stored
        shape = stored.volume.data.shape
        finite = stored.finite()
        if stored.texture.precision == "half" and finite and self.mode != "average" and shape[2] % 2 == 0:
            words, slices = stored.half_words()
            values = reduce_half_words(words, shape, axis, self.mode, floats=stored.float_ordered(), slices=slices)
            return values, dr.full(mi.UInt32, 1, dr.width(values))
        return reduce_columns(stored.storage(), shape, axis, self.mode, reverse=reverse, repeats=repeats,
                              has_nan=not finite)
