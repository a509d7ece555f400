"""Brick skipping for the ``mip`` integrator's oblique march: per-brick bounds of the sample values,
and the march that skips the samples they prove idle (``mip`` and ``minip``; ``average`` cannot skip)."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from pointillist.plugins.integrators._mip_volume import StoredVolume, clip_to_box

__all__ = ["BrickSkipper"]


class BrickSkipper:
    """The march of the ``mip`` integrator over ``stored``, skipping bricks whose bound cannot change
    the running maximum (``mode="mip"``) or minimum (``"minip"``): the same samples, the same bits.

    Attributes
    ----------
    flat : mi.Float or None
        Per brick, the one finite value every lookup inside it reads, NaN where the brick is not
        constant (set by :meth:`bounds`).
    """

    def __init__(self, stored: StoredVolume, mode: str):
        if mode not in ("mip", "minip"):
            raise ValueError(f"mode: brick skipping needs 'mip' or 'minip', got {mode!r}")
        self.stored = stored
        self.mode = mode
        self.flat = None
        self._bounds = None

    def bounds(self):
        """Per-brick bounds ``(upper, lower, shape)`` for skipping (built once per volume).

        ``upper`` / ``lower`` (``mi.Float``, storage units, bricks of
        :data:`~plugins.integrators._mip_accel.BRICK` voxels dilated by one voxel) bound every
        sample value a lookup from inside the brick can return. Nearest lookups return
        voxels, so the bounds are the brick's max / min. A trilinear lookup is a float32
        ``fma`` chain of 8 voxels whose weights sum to 1 only up to rounding: it can exceed the
        largest voxel by at most ``13 * 2^-24 * M`` (M = largest magnitude), so the bounds are
        widened by ``2^-16 * M`` and rounded outwards.
        """
        from pointillist.plugins.integrators._mip_accel import BRICK, brick_grid, brick_grid_words

        stored = self.stored
        if self._bounds is None:
            tex = stored.texture
            nz, ny, nx = stored.volume.data.shape
            if tex.precision == "half" and nx % 2 == 0 and stored.finite() and stored.float_ordered():
                # from the stored halves on both cores (one Dr.Jit kernel; the same values: the
                # storage holds the data less the offset, exactly or as the marches see it)
                upper, lower = brick_grid_words(stored.half_words()[0], (nz, ny, nx), brick=BRICK, normal_only=True)
            else:
                if tex.precision == "half" and not tex.exact:
                    source, offset = stored.storage().numpy().reshape(nz, ny, nx), 0.0
                else:
                    source, offset = stored.volume.data, tex.offset
                upper, lower = brick_grid(source, brick=BRICK, offset=offset)
            # flat bricks (every voxel a lookup can touch holds the same finite value c):
            # their samples are computed from c without reading voxels (see flat_sample)
            flat = np.where((upper == lower) & np.isfinite(upper), upper, np.nan).astype(np.float32)
            if not np.all(np.isnan(flat)) and not stored.finite():
                flat[:] = np.nan  # a NaN voxel would turn neighbouring lookups into NaN
            if stored.interpolation == "trilinear":
                with np.errstate(invalid="ignore"):
                    size = np.nan_to_num(np.maximum(np.abs(upper), np.abs(lower)), posinf=np.inf)
                    upper = np.where(np.isfinite(upper), upper + size * 2.0**-16, upper)
                    lower = np.where(np.isfinite(lower), lower - size * 2.0**-16, lower)
            up32 = upper.astype(np.float32)
            up32 = np.where(up32 < upper, np.nextafter(up32, np.float32(np.inf)), up32)
            lo32 = lower.astype(np.float32)
            lo32 = np.where(lo32 > lower, np.nextafter(lo32, np.float32(-np.inf)), lo32)
            self._bounds = (mi.Float(up32.ravel()), mi.Float(lo32.ravel()), upper.shape)
            self.flat = mi.Float(flat.ravel())
        return self._bounds

    def flat_sample(self, c: mi.Float, p: mi.Point3f) -> mi.Float:
        """The texture's lookup at ``p`` where all 8 voxels it reads hold ``c``, without reading them.

        Nearest returns ``c``. Trilinear repeats the float32 arithmetic of Dr.Jit's texture
        (``drjit/texture_impl.h``, ``tex_eval``): ``pos = fma(p, res, -0.5)``, ``w1 = pos -
        floor(pos)``, ``w0 = 1 - w1``, corner weights multiplied x, y, z and accumulated with
        ``fma(value, weight, out)`` over the corners in order, so the result (which can differ
        from ``c`` by float rounding) is bit for bit the texture's.
        """
        if self.stored.interpolation == "nearest":
            return mi.Float(c)
        nx, ny, nz = self.stored.volume.shape_xyz
        res = dr.opaque(mi.Vector3f, [float(nx), float(ny), float(nz)])
        w = []
        for k in range(3):
            pos_f = dr.fma(p[k], res[k], -0.5)
            w1 = pos_f - mi.Float(mi.Int32(dr.floor(pos_f)))
            w.append((1.0 - w1, w1))
        out = dr.zeros(mi.Float, dr.width(p))
        for corner in range(8):
            weight = mi.Float(1.0)
            for k in range(3):
                weight = weight * w[k][(corner >> k) & 1]
            out = dr.fma(c, weight, out)
        return out

    @dr.syntax
    def march(self, ray: mi.Ray3f, to_world, step: float, background: float,
              active=True) -> tuple[mi.Float, mi.Bool]:
        """The integrator's march (same samples, same order) skipping provably idle samples;
        ``(value, valid)`` per ray, ``background`` where no sample was valid.

        Before evaluating sample k the brick holding its position is looked up; when the
        brick's upper bound cannot raise the running maximum (``upper <= acc``; for minip
        ``lower >= acc``), all samples up to the ray's exit from that brick are skipped: each
        lies inside the brick's box (or within float rounding of it, far less than the one
        voxel of dilation), so its value is bounded and ``max(acc, v) == acc``. A brick of NaN
        voxels only (bounds -inf / +inf) holds only NaN samples, which the march skips too. A brick
        that is not skipped takes two samples an iteration (k and k + 1 when k + 1 is still in the
        run: one brick look-up for both; the second is taken even if the first already made the
        brick idle, which cannot change the result).

        A *flat* brick (every voxel its lookups can touch holds one finite value c) is not
        skipped unless its bound allows it, but its samples are computed from c
        (:meth:`flat_sample`, the texture's own arithmetic, bit for bit) in a tight inner
        loop without reading voxels; with nearest lookups they all equal c and the whole run
        collapses to one ``max``. Trilinear lookups in a constant region differ from c by an
        ulp or two (weights rounded), so a ray whose maximum lies in such a region (air
        around a phantom) must still compute those samples to get the march's exact bits.
        """
        from pointillist.plugins.integrators._mip_accel import BRICK

        stored = self.stored
        upper, lower, grid = self.bounds()
        bounds = upper if self.mode == "mip" else lower
        flat = self.flat
        to_tex = stored.world_to_texture(to_world)
        o = to_tex @ ray.o
        d = to_tex @ ray.d
        t0, t1, hit = clip_to_box(o, d, ray.maxt, active)
        segments, dt = stored.schedule(d, t0, t1, hit, step)
        count = mi.UInt32(segments) + dr.select(hit, 1, 0)
        lookup = stored.lookup()
        nx, ny, nz = stored.volume.shape_xyz
        cells = mi.Vector3i(grid[2], grid[1], grid[0])
        # texture coordinates -> brick coordinates, and brick size in texture coordinates
        to_cell = dr.opaque(mi.Vector3f, [nx / BRICK, ny / BRICK, nz / BRICK])
        cell_size = dr.opaque(mi.Vector3f, [BRICK / nx, BRICK / ny, BRICK / nz])
        inv_d = dr.rcp(d)
        maximum = self.mode == "mip"
        nearest = stored.interpolation == "nearest"
        acc = dr.full(mi.Float, -dr.inf if maximum else dr.inf, dr.width(o))
        seen = dr.zeros(mi.UInt32, dr.width(o))
        k = dr.zeros(mi.UInt32, dr.width(o))
        while dr.hint(k < count, label="mip_bricks"):
            t = dr.fma(mi.Float(k), dt, t0)
            p = dr.fma(d, t, o)
            cell = dr.clip(mi.Vector3i(dr.floor(p * to_cell)), 0, cells - 1)
            index = mi.UInt32((cell.z * cells.y + cell.y) * cells.x + cell.x)
            bound = dr.gather(mi.Float, bounds, index)
            c = dr.gather(mi.Float, flat, index)
            if dr.hint(maximum, mode="scalar"):
                idle = bound <= acc
            else:
                idle = bound >= acc
            # the samples up to the ray's exit from the brick's box (texture coordinates)
            low = mi.Vector3f(cell) * cell_size
            exit_plane = dr.select(d > 0, low + cell_size, low)
            t_exit = dr.select(d != 0, (exit_plane - o) * inv_d, dr.inf)
            t_out = dr.minimum(dr.minimum(t_exit.x, t_exit.y), t_exit.z)
            ahead = dr.minimum(dr.floor((t_out - t0) / dt) + 1.0, mi.Float(count))  # samples with t <= t_out
            end = dr.maximum(mi.UInt32(dr.maximum(ahead, 0.0)), k + 1)
            if idle:
                k = end
            elif dr.hint(nearest, mode="scalar") & ~dr.isnan(c):
                # nearest in a flat brick: every sample up to the exit returns c exactly
                if dr.hint(maximum, mode="scalar"):
                    acc = dr.maximum(acc, c)
                else:
                    acc = dr.minimum(acc, c)
                seen += end - k
                k = end
            elif ~dr.isnan(c):
                # a flat brick: its samples from the constant, no voxel reads, in a tight loop
                # (a sample rounding just past the exit still reads only this brick's value c)
                while dr.hint(k < end, label="mip_flat"):
                    q = dr.fma(d, dr.fma(mi.Float(k), dt, t0), o)
                    v = self.flat_sample(c, mi.Point3f(q))
                    if dr.hint(maximum, mode="scalar"):
                        acc = dr.maximum(acc, v)
                    else:
                        acc = dr.minimum(acc, v)
                    seen += 1
                    k += 1
            else:
                # sample k and, when the run has it, sample k + 1 (the same brick: one brick look-up
                # for two samples; taking it even if sample k raised acc past the bound is harmless)
                second = k + 1 < end
                for j in range(2):
                    v = lookup(p if j == 0 else dr.fma(d, dr.fma(mi.Float(k + 1), dt, t0), o))
                    ok = ~dr.isnan(v) if j == 0 else ~dr.isnan(v) & second
                    if dr.hint(maximum, mode="scalar"):
                        acc = dr.select(ok, dr.maximum(acc, v), acc)
                    else:
                        acc = dr.select(ok, dr.minimum(acc, v), acc)
                    seen += dr.select(ok, 1, 0)
                k = dr.select(second, k + 2, k + 1)
        valid = seen > 0
        offset = dr.opaque(mi.Float, stored.texture.offset)
        value = dr.select(valid, acc + offset, dr.opaque(mi.Float, background))
        return value, valid

