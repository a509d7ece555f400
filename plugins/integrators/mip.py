"""The ``mip`` integrator: maximum (minimum, average) intensity projection of a volume."""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from pointillist.core import checks
from pointillist.imaging.orientation import inverse_directions
from pointillist.imaging.volumes import Volume, load_volume, volume_texture
from pointillist.imaging.window import apply_window, colormap_lut, parse_window
from pointillist.plugins.integrators._common import develop_film
from pointillist.plugins.integrators import _mip_bricks
from pointillist.plugins.properties import (boolean_property, integer_property, number_property, scalar_transform,
                                            string_property, transform_property)

__all__ = ["MIPIntegrator", "MODES", "MAX_RAY_SAMPLES"]

#: Projection modes (the ones napari and VTK offer).
MODES = ("mip", "minip", "average")

#: :meth:`MIPIntegrator.project` casts its rays in blocks of TILE x TILE pixels (the lanes of a SIMD packet
#: a 4 x 4 block instead of 16 pixels of a row): neighbouring rays read neighbouring texels, so the
#: gathers of a packet touch fewer cache lines (oblique 512^3 views: 20-25 % faster; same values).
TILE = 4

#: The most samples one ray may take (the box's diagonal over the step): a smaller step, or a
#: spacing so anisotropic that the step (in voxels of the smallest spacing) is that fine, is refused.
MAX_RAY_SAMPLES = 2**20


class MIPIntegrator(mi.SamplingIntegrator):
    r"""
    .. _integrator-mip:

    Maximum intensity projection (``mip``)
    --------------------------------------

    .. pluginparameters::

     * - filename
       - |string|
       - Volume file: Mitsuba ``.vol``, ``.npy``, NRRD, NIfTI or a DICOM series folder
         (relative paths resolve against the scene file). Optional when the volume is
         given with :meth:`set_volume`.
     * - frame
       - |int|
       - The volume of a 4-D ``filename`` (4-D NIfTI, DICOM series with several images per
         position); required for those. (Default: none)
     * - series
       - |string|
       - The DICOM series (UID or index) of a folder holding several. (Default: none)
     * - spacing
       - |string|
       - Voxel size ``"sx,sy,sz"`` (or one number) overriding the file's. (Default: the file's)
     * - to_world
       - |transform|
       - Pose of the volume. Before it, the volume's box is centred on the origin with
         size = voxel counts x spacing and, with ``patient_space``, turned by the volume's
         direction cosines. (Default: identity)
     * - patient_space
       - |bool|
       - Pose the box in patient space (LPS: x = patient's left, y = posterior, z = superior)
         by the volume's voxel-to-patient directions (``Volume.directions``, rotation and
         reflection), so world axes are anatomical whatever the voxel order. Volumes without
         orientation (``.vol``, ``.npy``, arrays) have identity directions. (Default: true)
     * - mode
       - |string|
       - ``mip`` (maximum), ``minip`` (minimum) or ``average`` along each ray. (Default: ``mip``)
     * - interpolation
       - |string|
       - ``trilinear`` or ``nearest`` texture lookups. (Default: ``trilinear``)
     * - step
       - |float|
       - Marching step in voxels of the smallest spacing; a step giving a ray more than
         ``MAX_RAY_SAMPLES`` (2^20) samples is refused. (Default: 0.5)
     * - window
       - |string|
       - Display window ``"level,width"`` or a preset (``brain``, ``soft``, ``lung``, ``bone``,
         ``subdural``, ``angio``). Empty: the output holds the raw projected values.
         (Default: empty)
     * - colormap
       - |string|
       - ``grey`` or a matplotlib colormap name, used with a window. (Default: ``grey``)
     * - background
       - |float|
       - Raw value of rays that miss the volume (or meet only NaN voxels).
         (Default: the volume's minimum for ``mip``/``average``, maximum for ``minip``)
     * - fast_axis
       - |bool|
       - Axis-aligned orthographic views: reduce voxel columns of the stored volume directly
         when that is checked to give the march's result bit for bit (see ``_columns``).
         (Default: true)
     * - skip_bricks
       - |bool|
       - ``mip``/``minip`` elsewhere: skip samples in 8^3 bricks whose bound cannot change the
         running maximum (minimum); same result bit for bit. ``average`` cannot skip.
         (Default: true)
     * - precision
       - |string|
       - Texture storage: ``auto`` (half precision when exact: 16-bit CT), ``half``, ``single``.
         (Default: ``auto``)

    Each camera ray of the sensor (perspective or orthographic, any pose) is clipped to the
    volume's box (faces and edges count as inside; a camera inside the box starts at the
    camera) and sampled at ``n + 1`` evenly spaced points from entry to exit (``n =
    ceil(length / step)``; ``mip``/``minip``) or at the midpoints of the ``n`` segments
    (``average``). With ``spp = 1`` each pixel shoots one ray through its centre, so an
    axis-aligned orthographic view with one pixel per voxel column reproduces
    ``numpy.max(volume, axis)`` exactly for nearest lookups. NaN voxels are skipped
    (like ``numpy.nanmax``); a trilinear sample touching a NaN voxel is skipped too.
    Only volume work is traced: no surface, emitter or medium code runs.

    Two accelerations give the same float32 bits as that march (tests compare them):
    axis-aligned orthographic views reduce voxel columns of the stored volume directly
    (``fast_axis``; only when the march's own sample arithmetic is checked to visit exactly
    the column's voxels), and ``mip``/``minip`` rays skip 8^3 bricks whose bound cannot change
    the running result (``skip_bricks``). ``last_path`` tells which ran.

    .. tabs::
        .. code-tab:: xml

            <integrator type="mip">
                <string name="filename" value="phantom.vol"/>
                <string name="window" value="40,400"/>
            </integrator>
    """

    PLUGIN_NAME: str  # "mip", the file's name, given by pointillist.plugins.register()

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        self.mode = string_property(props, "mode", "mip", MODES)
        self.interpolation = string_property(props, "interpolation", "trilinear", ("trilinear", "nearest"))
        self.step = number_property(props, "step", 0.5, minimum=0.0, strict=True)  # in voxels
        self.window = parse_window(string_property(props, "window", ""))
        self.colormap = string_property(props, "colormap", "grey")
        self.lut = colormap_lut(self.colormap)
        self.precision = string_property(props, "precision", "auto", ("auto", "half", "single"))
        self._background = number_property(props, "background", 0.0, allow_inf=True) if "background" in props else None
        self.fast_axis = boolean_property(props, "fast_axis", True)
        self.skip_bricks = boolean_property(props, "skip_bricks", True)
        self.patient_space = boolean_property(props, "patient_space", True)
        #: Which algorithm the last projection used: "columns", "bricks" or "march".
        self.last_path = None
        self.to_world = transform_property(props, "to_world")
        spacing = list(checks.spacing(string_property(props, "spacing", ""))) if "spacing" in props else None
        self.volume: Volume | None = None
        self._tex = None
        filename = string_property(props, "filename", "")
        if filename:
            path = mi.file_resolver().resolve(filename)
            frame = integer_property(props, "frame", 0, 0, 2**31 - 1) if "frame" in props else None
            series = string_property(props, "series", "") or None
            self.set_volume(load_volume(str(path), spacing=spacing, frame=frame, series=series))
        elif spacing is not None:
            self._spacing_override = spacing

    # ----------------------------------------------------------------------------------------
    def set_volume(self, volume: Volume | np.ndarray, *, spacing=None, to_world=None) -> None:
        """Use ``volume`` (a :class:`~pointillist.imaging.volumes.Volume` or a (Z, Y, X) array).

        ``spacing`` overrides the volume's; ``to_world`` (a 4x4 matrix or
        ``mi.ScalarTransform4f``) replaces the pose.
        """
        if not isinstance(volume, Volume):
            volume = Volume(np.asarray(volume))
        if spacing is None:
            spacing = getattr(self, "_spacing_override", None)
        if spacing is not None:
            volume = volume.respaced(spacing)
        if to_world is not None:
            self.to_world = scalar_transform(to_world, "to_world")
        filter_mode = "linear" if self.interpolation == "trilinear" else "nearest"
        self._tex = volume_texture(volume, filter=filter_mode, precision=self.precision)
        self.volume = volume
        #: voxel axes -> world (patient LPS) directions: a 4x4 rotation / reflection
        self._orient = np.eye(4)
        if self.patient_space:
            self._orient[:3, :3] = volume.directions
        self._finite = None  # whether the stored voxels are all finite (computed when needed)
        self._ordered = None  # whether half storage words compare as float32 (see _float_ordered)
        self._words = None  # half storage as UInt32 words and its slice views (column reductions)
        self._sampler = None  # the marches' texture lookup (see _lookup)
        self._bricks = None  # per-brick maxima / minima (built on the first oblique projection)
        self._flat = None  # per-brick constant value, NaN where the brick is not constant

    @property
    def background(self) -> float:
        """The raw value given to rays that miss (see the ``background`` parameter)."""
        if self._background is not None:
            return self._background
        if self._tex is None:
            return 0.0
        value = self._tex.maximum if self.mode == "minip" else self._tex.minimum
        return value if math.isfinite(value) else 0.0

    def texture_info(self) -> dict:
        """Storage of the volume texture: precision, bytes, offset, exactness, value range."""
        t = self._tex
        if t is None:
            return {}
        return {"precision": t.precision, "nbytes": t.nbytes, "offset": t.offset, "exact": t.exact,
                "minimum": t.minimum, "maximum": t.maximum}

    # ----------------------------------------------------------------------------------------
    def _world_to_texture(self) -> mi.Transform4f:
        ext = self.volume.extent
        scalar = (mi.ScalarTransform4f().translate([0.5, 0.5, 0.5])
                  @ mi.ScalarTransform4f().scale([1.0 / e for e in ext])
                  @ scalar_transform(inverse_directions(self._orient))
                  @ self.to_world.inverse())
        transform = mi.Transform4f(scalar)
        dr.make_opaque(transform)
        return transform

    def ray_samples(self) -> float:
        """The most samples a ray takes: the box's diagonal over the step (``step`` voxels of the
        smallest spacing)."""
        extent = np.asarray(self.volume.extent, dtype=np.float64)
        return float(np.linalg.norm(extent / min(self.volume.spacing))) / self.step

    def project_rays(self, ray: mi.Ray3f, active=True) -> tuple[mi.Float, mi.Bool]:
        """Raw projected value along each ray and whether it met a (non-NaN) sample.

        Raises ValueError when a ray would take more than :data:`MAX_RAY_SAMPLES` samples.
        """
        if self.volume is None:
            raise RuntimeError("mip: no volume; give a 'filename' or call set_volume()")
        samples = self.ray_samples()
        if not samples <= MAX_RAY_SAMPLES:
            smallest = min(self.volume.spacing)
            raise ValueError(
                f"step: {self.step:g} voxel(s) of the smallest spacing {smallest:g} is up to {samples:.3g} samples "
                f"per ray, more than {MAX_RAY_SAMPLES} (2^20); use a step of at least "
                f"{self.step * samples / MAX_RAY_SAMPLES:.3g}" + (
                    "" if max(self.volume.spacing) <= 1e3 * smallest else " or a less anisotropic spacing"))
        if self.fast_axis and active is True:
            result = self._columns(ray)
            if result is not None:
                self.last_path = "columns"
                return result
        if self.skip_bricks and self.mode != "average":
            self.last_path = "bricks"
            return self._march_bricks(ray, active)
        self.last_path = "march"
        return self._march(ray, active)

    # ----------------------------------------------------------------------------------------
    # brick skipping of the oblique march (plugins/integrators/_mip_bricks.py)
    brick_bounds = _mip_bricks.brick_bounds
    _flat_sample = _mip_bricks.flat_sample
    _march_bricks = _mip_bricks.march_bricks

    # ----------------------------------------------------------------------------------------
    def _storage(self):
        """The texture's flat (Z, Y, X) storage (Float16 or Float, shared, no copy)."""
        return self._tex.texture.tensor().array

    def storage_finite(self) -> bool:
        """Whether every stored voxel is finite (no NaN / inf); computed once per volume."""
        if self._finite is None:
            data = self.volume.data
            if np.issubdtype(data.dtype, np.integer) and self._tex.exact:
                self._finite = True  # integers stored exactly: finite by construction
            else:
                flat = self._storage().numpy().reshape(data.shape[0], -1)
                self._finite = all(bool(np.isfinite(flat[z:z + 64]).all()) for z in range(0, len(flat), 64))
        return self._finite

    def _columns(self, ray: mi.Ray3f):
        """Axis-aligned fast path: reduce voxel columns of the storage instead of marching.

        Used only when it provably gives the march's result bit for bit, checked on the
        actual rays with the march's own float32 arithmetic:

        * every ray's texture-space direction has one nonzero component ``a`` (the same
          value for all rays), its origin along ``a`` and its ``maxt`` are shared, so all
          rays that hit have the same sample parameters along ``a``;
        * the sample positions along ``a`` (the march's ``fma`` sequence, mapped by the
          texture's own index arithmetic) visit every voxel of the column:
          - nearest, mip/minip: every voxel index 0..n-1 is sampled (and no other);
          - nearest, average: every voxel is sampled the same number m of times (m <= 8),
            so the march's running sum adds each voxel m times in ray order;
          - trilinear, mip/minip: every sample lies exactly on a voxel centre (weight 0)
            or exactly half-way between two (weights 1/2, 1/2), every centre is sampled,
            the rays pass exactly through voxel-column centres across the axis, and the
            volume has no NaN/inf. A centre sample returns the voxel, a half-way sample
            ``fma(b, 1/2, a / 2)`` lies between its two voxels, so the max (min) over the
            samples is the column's max (min). Average with trilinear has no such identity
            and always marches.

        Returns ``None`` (march) when a condition fails.
        """
        trilinear = self.interpolation == "trilinear"
        if trilinear and (self.mode == "average" or not self.storage_finite()):
            return None
        to_tex = self._world_to_texture()
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
        nx, ny, nz = self.volume.shape_xyz
        res = (nx, ny, nz)
        # one representative ray: inside across the axis, so its slab test equals every hit ray's
        rep_o = [0.5, 0.5, 0.5]
        rep_o[a] = first_o
        rep_d = [0.0, 0.0, 0.0]
        rep_d[a] = first_d
        ro, rd = mi.Point3f(*rep_o), mi.Vector3f(*rep_d)
        t0, t1, hit = self._clip(ro, rd, mi.Float(first_t))
        segments, dt = self._schedule(rd, t0, t1, hit)
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
        if trilinear:
            pos_f = dr.fma(p, res_a, -0.5)
        else:
            pos_f = p * res_a
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
        if trilinear:
            if not bool(dr.all(exact)):
                return None
        values, seen = self._column_values(a, reverse=rep_d[a] < 0, repeats=repeats)
        column = mi.UInt32(dr.select(inside, column, 0))
        acc = dr.gather(mi.Float, values, column, inside)
        seen = dr.gather(mi.UInt32, seen, column, inside)
        valid = inside & (seen > 0)
        offset = dr.opaque(mi.Float, self._tex.offset)
        if average:
            acc = acc / mi.Float(dr.maximum(seen, 1))
        value = dr.select(valid, acc + offset, dr.opaque(mi.Float, self.background))
        return value, valid

    def _float_ordered(self) -> bool:
        """Whether the half storage's words compare as float32 (no -0, nothing below 2^-17 in
        magnitude: ``_mip_accel.float_ordered``); computed once per volume. Integers stored exactly
        (16-bit CT less its integer offset) are by construction; other data is scanned once."""
        from pointillist.plugins.integrators._mip_accel import float_ordered

        if self._ordered is None:
            data = self.volume.data
            if np.issubdtype(data.dtype, np.integer) and self._tex.exact:
                self._ordered = True
            else:
                bits = self._storage().numpy().view(np.uint16).reshape(data.shape[0], -1)
                self._ordered = all(float_ordered(bits[z:z + 64]) for z in range(0, len(bits), 64))
        return self._ordered

    def _half_words(self):
        """``(words, slices)``: the half storage as UInt32 words (the same memory, two voxels a word)
        and its zero-copy z slices, made once per volume (needs an even voxel count)."""
        from pointillist.plugins.integrators._mip_accel import half_slices

        if self._words is None:
            words = mi.UInt32(self._storage().numpy().view(np.uint32))
            self._words = (words, half_slices(words, self.volume.data.shape))
        return self._words

    def _lookup(self):
        """The texture lookup of the marches: ``p -> value`` (float32, the texture's bits).

        Finite half storage with an even voxel count is read through 32-bit word gathers
        (``_mip_accel.HalfSampler``: hardware gathers instead of 16-bit gathers that LLVM splits
        into scalar loads); anything else through the texture itself."""
        from pointillist.plugins.integrators._mip_accel import HalfSampler

        if self._sampler is None:
            tex = self._tex.texture
            self._sampler = lambda p: tex.eval(mi.Point3f(p))[0]
            if self._tex.precision == "half" and self.volume.data.size % 2 == 0 and self.storage_finite():
                self._sampler = HalfSampler(self._half_words()[0], self.volume.shape_xyz,
                                            nearest=self.interpolation == "nearest",
                                            normal_only=self._float_ordered())
        return self._sampler

    def _column_values(self, axis: int, *, reverse: bool, repeats: int):
        """Column reductions of the stored volume along ``axis``: ``(acc, seen)`` per column."""
        from pointillist.plugins.integrators._mip_accel import reduce_columns, reduce_half_words

        shape = self.volume.data.shape
        storage = self._storage()
        finite = self.storage_finite()
        if (self._tex.precision == "half" and finite and self.mode != "average" and shape[2] % 2 == 0):
            words, slices = self._half_words()
            values = reduce_half_words(words, shape, axis, self.mode, floats=self._float_ordered(), slices=slices)
            return values, dr.full(mi.UInt32, 1, dr.width(values))
        return reduce_columns(storage, shape, axis, self.mode, reverse=reverse, repeats=repeats,
                              has_nan=not finite)

    def _clip(self, o, d, maxt, active=True):
        """Parametric entry/exit ``(t0, t1, hit)`` of texture-space rays against the closed unit box."""
        t0 = dr.zeros(mi.Float, dr.width(o))
        t1 = mi.Float(maxt)
        for i in range(3):  # slab test against [0, 1]^3 (closed box)
            inv = dr.rcp(d[i])
            ta, tb = -o[i] * inv, (1.0 - o[i]) * inv
            parallel = d[i] == 0
            inside = (o[i] >= 0) & (o[i] <= 1)
            near = dr.select(parallel, dr.select(inside, -dr.inf, dr.inf), dr.minimum(ta, tb))
            far = dr.select(parallel, dr.select(inside, dr.inf, -dr.inf), dr.maximum(ta, tb))
            t0, t1 = dr.maximum(t0, near), dr.minimum(t1, far)
        hit = mi.Bool(active) & (t0 <= t1) & dr.isfinite(t1)
        return t0, t1, hit

    def _schedule(self, d, t0, t1, hit):
        """Segment count and parametric step ``(segments, dt)`` of the march (0 segments on a miss)."""
        extent = dr.opaque(mi.Vector3f, self.volume.extent)
        step = dr.opaque(mi.Float, self.step * min(self.volume.spacing))
        length = (t1 - t0) * dr.norm(mi.Vector3f(d) * extent)  # physical length inside the box
        # n = ceil(length / step), forgiving float rounding of 1e-3 steps so that a ray
        # through n whole voxels gets exactly n / step segments
        segments = dr.maximum(dr.ceil(length / step - 1e-3), 1.0)
        segments = dr.select(hit, dr.minimum(segments, 2.0**24), 0.0)
        dt = (t1 - t0) / segments
        return segments, dt

    @dr.syntax
    def _march(self, ray: mi.Ray3f, active=True) -> tuple[mi.Float, mi.Bool]:
        to_tex = self._world_to_texture()
        o = to_tex @ ray.o
        d = to_tex @ ray.d
        t0, t1, hit = self._clip(o, d, ray.maxt, active)
        segments, dt = self._schedule(d, t0, t1, hit)
        average = self.mode == "average"
        count = mi.UInt32(segments) if average else mi.UInt32(segments) + dr.select(hit, 1, 0)
        shift = 0.5 if average else 0.0
        lookup = self._lookup()
        if self.mode == "mip":
            acc = dr.full(mi.Float, -dr.inf, dr.width(o))
        elif self.mode == "minip":
            acc = dr.full(mi.Float, dr.inf, dr.width(o))
        else:
            acc = dr.zeros(mi.Float, dr.width(o))
        seen = dr.zeros(mi.UInt32, dr.width(o))
        k = dr.zeros(mi.UInt32, dr.width(o))
        while dr.hint(k < count, label="mip_march"):
            t = dr.fma(mi.Float(k) + shift, dt, t0)
            p = dr.fma(d, t, o)
            v = lookup(p)
            ok = ~dr.isnan(v)
            if dr.hint(self.mode == "mip", mode="scalar"):
                acc = dr.select(ok, dr.maximum(acc, v), acc)
            elif dr.hint(self.mode == "minip", mode="scalar"):
                acc = dr.select(ok, dr.minimum(acc, v), acc)
            else:
                acc = dr.select(ok, acc + v, acc)
            seen += dr.select(ok, 1, 0)
            k += 1
        valid = seen > 0
        offset = dr.opaque(mi.Float, self._tex.offset)
        if average:
            acc = acc / mi.Float(dr.maximum(seen, 1))
        value = dr.select(valid, acc + offset, dr.opaque(mi.Float, self.background))
        return value, valid

    def display(self, value: mi.Float) -> mi.Color3f:
        """Raw values -> the integrator's output colour (windowed + colormap, or raw grey)."""
        if self.window is None:
            return mi.Color3f(value, value, value)
        return mi.Color3f(*apply_window(value, *self.window, self.lut))

    # ----------------------------------------------------------------------------------------
    def sample(self, scene, sampler, ray, medium=None, active=True):
        value, valid = self.project_rays(mi.Ray3f(ray), active)
        return mi.Spectrum(self.display(value)), mi.Bool(active), []

    def _sensor_rays(self, sensor, spp: int, seed: int, tile: int = 1):
        """``(ray, pos, (width, height), pixel, real)``: the sensor's rays, ``spp`` a pixel, or with
        ``tile > 1`` (``spp = 1``) one a pixel with the lanes in ``tile x tile`` blocks of pixels
        (``pixel``: each lane's pixel index; ``real``: false for the lanes that pad the blocks at
        the far edges, which repeat an edge pixel)."""
        film = sensor.film()
        width, height = (int(s) for s in film.crop_size())
        real = True
        if tile > 1:
            across, down = -(-width // tile), -(-height // tile)
            idx = dr.arange(mi.UInt32, across * down * tile * tile)
            block, within = idx // (tile * tile), idx % (tile * tile)
            x = (block % across) * tile + within % tile
            y = (block // across) * tile + within // tile
            real = (x < width) & (y < height)
            pixel = dr.minimum(y, height - 1) * width + dr.minimum(x, width - 1)
            count = dr.width(idx)
        else:
            count = width * height * spp
            idx = dr.arange(mi.UInt32, count)
            pixel = idx // spp if spp > 1 else idx
        pos = mi.Vector2f(mi.Float(pixel % width), mi.Float(pixel // width))
        if spp == 1:
            pos += 0.5
        else:
            sampler = sensor.sampler().clone()
            sampler.set_sample_count(spp)
            sampler.set_samples_per_wavefront(spp)
            sampler.seed(seed, count)
            pos += sampler.next_2d()
        pos += mi.Vector2f(film.crop_offset())
        ray, _ = sensor.sample_ray(0.0, 0.0, pos * dr.rcp(mi.ScalarVector2f(film.size())),
                                   mi.Point2f(0.5, 0.5))
        return ray, pos, (width, height), pixel, real

    def project(self, scene, sensor=0) -> mi.TensorXf:
        """Raw projected values ``(H, W)`` with one ray through each pixel centre (evaluated)."""
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        ray, _, (width, height), pixel, real = self._sensor_rays(sensor, 1, 0, TILE)
        value, _ = self.project_rays(ray)
        image = dr.empty(mi.Float, width * height)
        dr.scatter(image, value, pixel, real)
        image = mi.TensorXf(image, shape=(height, width))
        dr.eval(image)
        return image

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        film = sensor.film()
        spp = int(spp or sensor.sampler().sample_count())
        film.prepare([])
        ray, pos, *_ = self._sensor_rays(sensor, spp, seed)
        value, _ = self.project_rays(ray)
        block = film.create_block()
        block.put(pos, [], self.display(value), 1.0, 1.0)
        film.put_block(block)
        return develop_film(film, develop, evaluate)

    def aov_names(self):
        return []

    def to_string(self):
        shape = self.volume.data.shape[::-1] if self.volume is not None else None
        return (f"MIPIntegrator[mode={self.mode}, interpolation={self.interpolation}, step={self.step}, "
                f"window={self.window}, colormap={self.colormap}, volume={shape}]")


PLUGIN_CLASS = MIPIntegrator
