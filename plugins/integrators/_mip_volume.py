"""The volume as the ``mip`` integrator reads it: its texture, its pose, facts about its storage
(computed once), the texture lookup the marches use, and the march geometry every projector shares
(the box clip and the sample schedule)."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from pointillist.imaging.orientation import inverse_directions
from pointillist.imaging.volumes import Volume, volume_texture
from pointillist.plugins.properties import scalar_transform

__all__ = ["StoredVolume", "clip_to_box"]


class StoredVolume:
    """A :class:`~pointillist.imaging.volumes.Volume` stored as a Dr.Jit texture for projection.

    Parameters
    ----------
    volume : Volume
        The voxels, spacing and directions.
    interpolation : {"trilinear", "nearest"}
        The texture's lookups.
    precision : {"auto", "half", "single"}
        The texture's storage (:func:`~pointillist.imaging.volumes.volume_texture`).
    patient_space : bool
        Pose the box by the volume's voxel-to-patient directions (else identity).

    Attributes
    ----------
    volume : Volume
    texture : VolumeTexture
        The stored voxels (less ``texture.offset``) and their range.
    orientation : numpy.ndarray
        4x4: voxel axes -> world (patient LPS) directions, a rotation or reflection.
    word_gathers : bool
        Read finite half storage through 32-bit word gathers (:meth:`lookup`); False reads it
        through the texture itself (the same bits; the tests compare the two).
    """

    def __init__(self, volume: Volume, *, interpolation: str, precision: str, patient_space: bool):
        self.volume = volume
        self.interpolation = interpolation
        self.texture = volume_texture(volume, filter="linear" if interpolation == "trilinear" else "nearest",
                                      precision=precision)
        self.orientation = np.eye(4)
        if patient_space:
            self.orientation[:3, :3] = volume.directions
        self.word_gathers = True
        self._finite: bool | None = None
        self._ordered: bool | None = None
        self._words = None
        self._lookups: dict[bool, object] = {}

    # ---------------------------------------------------------------- the storage
    def storage(self):
        """The texture's flat (Z, Y, X) storage (Float16 or Float, shared, no copy)."""
        return self.texture.texture.tensor().array

    def finite(self) -> bool:
        """Whether every stored voxel is finite (no NaN / inf); computed once."""
        if self._finite is None:
            data = self.volume.data
            if np.issubdtype(data.dtype, np.integer) and self.texture.exact:
                self._finite = True  # integers stored exactly: finite by construction
            else:
                flat = self.storage().numpy().reshape(data.shape[0], -1)
                self._finite = all(bool(np.isfinite(flat[z:z + 64]).all()) for z in range(0, len(flat), 64))
        return self._finite

    def float_ordered(self) -> bool:
        """Whether the half storage's words compare as float32 (no -0, nothing below 2^-17 in
        magnitude: ``_mip_accel.float_ordered``); computed once. Integers stored exactly (16-bit
        CT less its integer offset) are by construction; other data is scanned once."""
        from pointillist.plugins.integrators._mip_accel import float_ordered

        if self._ordered is None:
            data = self.volume.data
            if np.issubdtype(data.dtype, np.integer) and self.texture.exact:
                self._ordered = True
            else:
                bits = self.storage().numpy().view(np.uint16).reshape(data.shape[0], -1)
                self._ordered = all(float_ordered(bits[z:z + 64]) for z in range(0, len(bits), 64))
        return self._ordered

    def half_words(self):
        """``(words, slices)``: the half storage as UInt32 words (the same memory, two voxels a word)
        and its zero-copy z slices, made once (needs an even voxel count)."""
        from pointillist.plugins.integrators._mip_accel import half_slices

        if self._words is None:
            words = mi.UInt32(self.storage().numpy().view(np.uint32))
            self._words = (words, half_slices(words, self.volume.data.shape))
        return self._words

    def lookup(self):
        """The texture lookup of the marches: ``p -> value`` (float32, the texture's bits).

        Finite half storage with an even voxel count is read through 32-bit word gathers
        (``_mip_accel.HalfSampler``: hardware gathers instead of 16-bit gathers that LLVM splits
        into scalar loads) when :attr:`word_gathers`; anything else through the texture itself."""
        from pointillist.plugins.integrators._mip_accel import HalfSampler

        words = (self.word_gathers and self.texture.precision == "half" and self.volume.data.size % 2 == 0
                 and self.finite())
        if words not in self._lookups:
            if words:
                self._lookups[words] = HalfSampler(self.half_words()[0], self.volume.shape_xyz,
                                                   nearest=self.interpolation == "nearest",
                                                   normal_only=self.float_ordered())
            else:
                tex = self.texture.texture
                self._lookups[words] = lambda p: tex.eval(mi.Point3f(p))[0]
        return self._lookups[words]

    # ---------------------------------------------------------------- the geometry
    def world_to_texture(self, to_world) -> mi.Transform4f:
        """World -> texture coordinates (the box is [0, 1]^3) for the pose ``to_world``."""
        extent = self.volume.extent
        scalar = (mi.ScalarTransform4f().translate([0.5, 0.5, 0.5])
                  @ mi.ScalarTransform4f().scale([1.0 / e for e in extent])
                  @ scalar_transform(inverse_directions(self.orientation))
                  @ to_world.inverse())
        transform = mi.Transform4f(scalar)
        dr.make_opaque(transform)
        return transform

    def ray_samples(self, step: float) -> float:
        """The most samples a ray takes: the box's diagonal over ``step`` voxels of the smallest spacing."""
        extent = np.asarray(self.volume.extent, dtype=np.float64)
        return float(np.linalg.norm(extent / min(self.volume.spacing))) / step

    def schedule(self, d, t0, t1, hit, step: float):
        """Segment count and parametric step ``(segments, dt)`` of the march (0 segments on a miss):
        ``n = ceil(length / step)`` for the physical length inside the box, ``step`` in voxels of
        the smallest spacing."""
        extent = dr.opaque(mi.Vector3f, self.volume.extent)
        physical = dr.opaque(mi.Float, step * min(self.volume.spacing))
        length = (t1 - t0) * dr.norm(mi.Vector3f(d) * extent)  # physical length inside the box
        # forgiving float rounding of 1e-3 steps so that a ray through n whole voxels gets exactly n / step segments
        segments = dr.maximum(dr.ceil(length / physical - 1e-3), 1.0)
        segments = dr.select(hit, dr.minimum(segments, 2.0**24), 0.0)
        dt = (t1 - t0) / segments
        return segments, dt


def clip_to_box(o, d, maxt, active=True):
    """Parametric entry/exit ``(t0, t1, hit)`` of texture-space rays against the closed unit box
    (faces and edges count as inside; a ray starting inside enters at ``t0 = 0``)."""
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
