"""The ``mip`` integrator: maximum (minimum, average) intensity projection of a volume.

The integrator is made of parts, made anew by :meth:`MIPIntegrator.set_volume`: ``stored`` (the
volume's texture, pose and storage facts, the lookup and the march geometry:
``_mip_volume.StoredVolume``), ``columns`` (axis-aligned orthographic views reduce voxel columns
of the stored volume directly, only when the march's own sample arithmetic is checked to visit
exactly the column's voxels: ``_mip_columns.ColumnProjector``) and ``bricks`` (``mip``/``minip``
rays skip 8^3 bricks whose bound cannot change the running result: ``_mip_bricks.BrickSkipper``).
The plain march, the definition the other two reproduce bit for bit, is ``MIPIntegrator._march``.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from pointillist.core import checks
from pointillist.imaging.volumes import Volume, load_volume
from pointillist.imaging.window import apply_window, colormap_lut, parse_window
from pointillist.plugins.integrators._common import develop_film, film_sample
from pointillist.plugins.integrators._mip_bricks import BrickSkipper
from pointillist.plugins.integrators._mip_columns import ColumnProjector
from pointillist.plugins.integrators._mip_volume import StoredVolume, clip_to_box
from pointillist.plugins.properties import (boolean_property, integer_property, number_property, scalar_transform,
                                            string_property, transform_property)

__all__ = ["MIPIntegrator", "MODES", "MAX_RAY_SAMPLES"]

#: Projection modes (the ones napari and VTK offer).
MODES = ("mip", "minip", "average")

#: :meth:`MIPIntegrator.project` casts its rays in blocks of TILE x TILE pixels (the lanes of a SIMD packet
#: a 4 x 4 block instead of 16 pixels of a row): neighbouring rays read neighbouring texels, so the
#: gathers of a packet touch fewer cache lines (same values; the gain is in benchmarks/RESULTS.md).
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
         when that is checked to give the march's result bit for bit (``ColumnProjector``).
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

    ``fast_axis`` and ``skip_bricks`` give the same float32 bits as that march (the tests
    compare them); ``last_path`` tells which ran ("columns", "bricks" or "march").

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
        #: The parts made by set_volume (None before a volume is given).
        self.stored: StoredVolume | None = None
        self.columns: ColumnProjector | None = None
        self.bricks: BrickSkipper | None = None
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
        self.stored = StoredVolume(volume, interpolation=self.interpolation, precision=self.precision,
                                   patient_space=self.patient_space)
        self.volume = volume
        self.columns = ColumnProjector(self.stored, self.mode)
        self.bricks = BrickSkipper(self.stored, self.mode) if self.mode != "average" else None

    @property
    def background(self) -> float:
        """The raw value given to rays that miss (see the ``background`` parameter)."""
        if self._background is not None:
            return self._background
        if self.stored is None:
            return 0.0
        texture = self.stored.texture
        value = texture.maximum if self.mode == "minip" else texture.minimum
        return value if math.isfinite(value) else 0.0

    def texture_info(self) -> dict:
        """Storage of the volume texture: precision, bytes, offset, exactness, value range."""
        if self.stored is None:
            return {}
        t = self.stored.texture
        return {"precision": t.precision, "nbytes": t.nbytes, "offset": t.offset, "exact": t.exact,
                "minimum": t.minimum, "maximum": t.maximum}

    # ----------------------------------------------------------------------------------------
    def ray_samples(self) -> float:
        """The most samples a ray takes: the box's diagonal over the step (``step`` voxels of the
        smallest spacing)."""
        return self.stored.ray_samples(self.step)

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
            result = self.columns.project(ray, self.to_world, self.step, self.background)
            if result is not None:
                self.last_path = "columns"
                return result
        if self.skip_bricks and self.bricks is not None:
            self.last_path = "bricks"
            return self.bricks.march(ray, self.to_world, self.step, self.background, active)
        self.last_path = "march"
        return self._march(ray, active)

    @dr.syntax
    def _march(self, ray: mi.Ray3f, active=True) -> tuple[mi.Float, mi.Bool]:
        """The projection by definition: each ray sampled evenly from entry to exit (see the
        class documentation); ``(value, valid)`` per ray. The two accelerations give its bits."""
        stored = self.stored
        to_tex = stored.world_to_texture(self.to_world)
        o = to_tex @ ray.o
        d = to_tex @ ray.d
        t0, t1, hit = clip_to_box(o, d, ray.maxt, active)
        segments, dt = stored.schedule(d, t0, t1, hit, self.step)
        average = self.mode == "average"
        count = mi.UInt32(segments) if average else mi.UInt32(segments) + dr.select(hit, 1, 0)
        shift = 0.5 if average else 0.0
        lookup = stored.lookup()
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
        offset = dr.opaque(mi.Float, stored.texture.offset)
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
        ray, _ = sensor.sample_ray(0.0, 0.0, film_sample(film, pos), mi.Point2f(0.5, 0.5))
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


#: The plugin's class, which pointillist.plugins registers with Mitsuba under this file's name.
PLUGIN_CLASS = MIPIntegrator
