"""Views of a volume: the camera's axes for a named view or an azimuth/elevation, the framing of the
volume's box in the image, the sensor, and one raw projection with the ``mip`` integrator."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from pointillist.core import checks

__all__ = ["NAMED_VIEWS", "PERSPECTIVE_MIN_FOV", "check_perspective", "view_axes", "view_frame",
           "sensor_dict", "patient_view", "normalised_volume", "project_volume", "PLAIN_EXTENT", "NORMAL_EXTENT"]

#: Named views: (right, up, forward) unit vectors in patient LPS (x = left, y = posterior,
#: z = superior), radiological: axial from the feet (image right = patient's left, up =
#: anterior), coronal from the front (right = left, up = superior), sagittal from the
#: patient's left (right = posterior, up = superior).
NAMED_VIEWS = {
    "axial": ((1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0)),
    "coronal": ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, 1.0, 0.0)),
    "sagittal": ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0), (-1.0, 0.0, 0.0)),
}

def view_axes(view: str | None = None, azimuth: float = 0.0, elevation: float = 0.0):
    """Camera ``(right, up, forward)`` unit vectors (numpy) for a named view or azimuth/elevation.

    In patient LPS: forward = (sin A cos E, cos A cos E, -sin E) (azimuth 0, elevation 0 looks
    from the front along +y, posterior: coronal; azimuth turns about the patient's superior
    axis, elevation raises the camera towards the head); right = forward x z normalised
    (``(cos A, -sin A, 0)`` when looking straight along z); up = right x forward.
    Directions within 1e-12 of an axis are snapped to it.
    """
    if view is not None:
        if view not in NAMED_VIEWS:
            raise ValueError(f"view: expected one of {', '.join(NAMED_VIEWS)}, got {view!r}")
        return tuple(np.array(v) for v in NAMED_VIEWS[view])
    if not (math.isfinite(azimuth) and math.isfinite(elevation)):
        raise ValueError(f"azimuth/elevation: expected finite degrees, got {azimuth}, {elevation}")
    a, e = math.radians(azimuth), math.radians(elevation)
    forward = np.array([math.sin(a) * math.cos(e), math.cos(a) * math.cos(e), -math.sin(e)])
    forward[np.abs(forward) < 1e-12] = 0.0
    right = np.cross(forward, [0.0, 0.0, 1.0])
    if np.linalg.norm(right) < 1e-9:
        right = np.array([math.cos(a), -math.sin(a), 0.0])
    right /= np.linalg.norm(right)
    right[np.abs(right) < 1e-12] = 0.0
    up = np.cross(right, forward)
    up[np.abs(up) < 1e-12] = 0.0
    return right, up / np.linalg.norm(up), forward / np.linalg.norm(forward)

def view_frame(extent, axes, *, size=(512, 512), native: bool = False, counts=None, spacing=None):
    """Image size and the half-width/half-height (world units) of the orthographic view rectangle.

    ``axes`` are the view's (right, up, forward) in the volume's voxel axes. ``size``
    (W, H): the box's projection is fitted inside with square pixels. ``native``: a
    view along voxel axes has one pixel per voxel column (W, H = voxel counts across
    the view) and the rectangle is the box's face, so each pixel's ray passes through a
    voxel column centre. A view not along voxel axes (an anatomical view of an oblique
    acquisition) with ``native`` and ``spacing``: the voxel axis closest to the viewing
    direction is the through-plane one; the other two (the in-plane voxel axes), matched
    to the image's right and up, give the pixel width and height, and the image covers the
    box's projection (rounded up to whole pixels).
    """
    right, up, forward = axes
    extent = np.asarray(extent, dtype=np.float64)
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * extent / 2
    half_w = float(np.abs(corners @ right).max())
    half_h = float(np.abs(corners @ up).max())
    if native:
        axis_r, axis_u = np.flatnonzero(np.abs(right) == 1.0), np.flatnonzero(np.abs(up) == 1.0)
        if len(axis_r) == 1 and len(axis_u) == 1 and np.count_nonzero(forward) == 1:
            width, height = int(counts[axis_r[0]]), int(counts[axis_u[0]])
            return (width, height), half_w, half_h
        if spacing is None:
            raise ValueError("native-size: needs an axis-aligned view (axial, coronal, sagittal or "
                             "azimuth/elevation multiples of 90 degrees)")
        through = int(np.argmax(np.abs(forward)))
        in_plane = [k for k in range(3) if k != through]
        if abs(right[in_plane[0]]) + abs(up[in_plane[1]]) < abs(right[in_plane[1]]) + abs(up[in_plane[0]]):
            in_plane.reverse()
        pixel_w, pixel_h = float(spacing[in_plane[0]]), float(spacing[in_plane[1]])
        width = max(1, math.ceil(2 * half_w / pixel_w - 1e-6))
        height = max(1, math.ceil(2 * half_h / pixel_h - 1e-6))
        return (width, height), width * pixel_w / 2, height * pixel_h / 2
    width, height = size
    per_pixel = max(2 * half_w / width, 2 * half_h / height)
    return (width, height), width * per_pixel / 2, height * per_pixel / 2

#: The narrowest perspective field of view (degrees): the camera stands radius / sin(fov / 2) from the
#: volume's centre, and beyond 4096 radii its float32 ray positions would be off by more than
#: 2^-24 x 4096 = 2^-12 radius (a voxel of a 4096-voxel volume); narrower views are orthographic.
PERSPECTIVE_MIN_FOV = 2.0 * math.degrees(math.asin(2.0**-12))


def check_perspective(perspective: float | None) -> float | None:
    """``perspective`` (a field of view in degrees, or None: orthographic) checked: in
    [:data:`PERSPECTIVE_MIN_FOV`, 180); a ValueError names ``--perspective`` otherwise."""
    if perspective is None:
        return None
    return checks.real(perspective, "--perspective", low=PERSPECTIVE_MIN_FOV, high=180.0, high_open=True)


def sensor_dict(mi, extent, axes, image_size, half_w, half_h, perspective: float | None):
    """The Mitsuba sensor (a dict for ``mi.load_dict``) of a view: orthographic, or perspective with a
    ``perspective`` field of view in degrees, looking along ``axes`` at a box of ``extent`` centred
    on the origin, framing ``half_w`` x ``half_h`` (world units) in ``image_size`` pixels."""
    right, up, forward = axes
    width, height = image_size
    radius = float(np.linalg.norm(extent)) / 2
    if perspective is None:
        # camera distance and near clip are powers of two: for axis-aligned views of boxes with
        # power-of-two sides the ray parameters and sample positions are then exact floats, so
        # half-voxel steps land exactly on voxel centres (see the mip integrator's fast path)
        distance = 2.0 ** math.ceil(math.log2(radius * 2 + 1.0))
        to_world = (mi.ScalarTransform4f().look_at(origin=(-forward * distance).tolist(), target=[0, 0, 0],
                                                    up=up.tolist())
                    @ mi.ScalarTransform4f().scale([half_w, half_h * width / height, 1.0]))
        sensor = {"type": "orthographic", "to_world": to_world, "near_clip": distance / 1024.0,
                  "far_clip": 4 * distance}
    else:
        distance = radius / math.sin(math.radians(perspective) / 2)
        to_world = mi.ScalarTransform4f().look_at(origin=(-forward * distance).tolist(), target=[0, 0, 0],
                                                  up=up.tolist())
        sensor = {"type": "perspective", "fov": perspective, "fov_axis": "smaller", "to_world": to_world,
                  "near_clip": 1e-3 * distance, "far_clip": 4 * distance}
    sensor["film"] = {"type": "hdrfilm", "width": int(width), "height": int(height),
                      "rfilter": {"type": "box"}, "pixel_format": "rgb"}
    sensor["sampler"] = {"type": "independent", "sample_count": 1}
    return sensor

def patient_view(view: str | None = None, azimuth: float = 0.0, elevation: float = 0.0, *,
                 neurological: bool = False) -> dict[str, Any]:
    """The displayed image's patient axes: LPS vectors and radiology letters of its edges.

    Returns ``{"right", "up", "forward"}`` (LPS unit vectors of the image's right, up and
    viewing direction; ``neurological`` mirrors right where the image has a left-right axis,
    so not in a sagittal view) and ``"labels"``
    (:func:`pointillist.imaging.orientation.view_labels`: letters for each edge).

    Examples
    --------
    >>> from pointillist.mip import patient_view
    >>> patient_view("axial")["labels"]
    {'left': 'R', 'right': 'L', 'top': 'A', 'bottom': 'P'}
    >>> patient_view("axial", neurological=True)["labels"]["left"]
    'L'
    >>> patient_view("sagittal", neurological=True)["labels"]["left"]  # no left-right axis: as radiological
    'A'
    """
    from pointillist.imaging.orientation import view_labels

    right, up, forward = view_axes(view, azimuth, elevation)
    if neurological and _has_left_right(right):
        right = 0.0 - right  # (0.0 - 0.0 is +0.0: no "-0" in headers)
    return {"right": right, "up": up, "forward": forward, "labels": view_labels(right, up)}


def _has_left_right(right) -> bool:
    """Whether an image whose horizontal axis is ``right`` (LPS) has a left-right axis, the one the
    neurological display mirrors: axial and coronal views do, a sagittal view does not (its
    horizontal axis runs anterior-posterior). 3D Slicer and ITK-SNAP flip axial and coronal views
    only between the two display conventions."""
    return abs(float(right[0])) > 1e-9


def _along_patient_axes(axes) -> bool:
    return all(np.count_nonzero(a) == 1 for a in axes)


#: Volumes whose box's largest side (world units) lies in [lo, hi) are projected as they are; others
#: are scaled by a power of two (exactly) into :data:`NORMAL_EXTENT` (:func:`normalised_volume`).
PLAIN_EXTENT = (1.0, 2.0**16)
NORMAL_EXTENT = (64.0, 128.0)


def normalised_volume(volume):
    """``volume`` with its spacing scaled by a power of two when its box is very small or very large.

    A projection does not depend on the volume's scale (the views are fitted to its box and the
    step counts voxels), but float32 ray arithmetic does: a box of 1e-8 mm seen from the camera
    distance of a 1 mm box loses every digit (a MIP of 82.6 instead of 601), and 1e30 mm overflows.
    A box whose largest side lies outside :data:`PLAIN_EXTENT` is therefore scaled so that side
    lies in :data:`NORMAL_EXTENT` (other volumes are returned unchanged); scaling by a power of two
    is exact, so spacings differing by one project identically.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.volumes import Volume
    >>> normalised_volume(Volume(np.zeros((2, 2, 4)), (1e-10, 1e-10, 2e-10))).spacing
    (27.4877906944, 27.4877906944, 54.9755813888)
    """
    largest = max(volume.extent)
    if PLAIN_EXTENT[0] <= largest < PLAIN_EXTENT[1]:
        return volume
    k = math.floor(math.log2(NORMAL_EXTENT[0])) - math.floor(math.log2(largest))
    return volume.respaced(tuple(math.ldexp(s, k) for s in volume.spacing))  # directions kept


def project_volume(volume, *, view: str | None = "axial", azimuth: float = 0.0, elevation: float = 0.0,
                   size=(512, 512), native: bool = False, mode: str = "mip",
                   interpolation: str = "trilinear", step: float = 0.5, perspective: float | None = None,
                   precision: str = "auto", background: float | None = None, neurological: bool = False,
                   integrator=None):
    """Render the raw projection ``(H, W)`` (numpy float32) of a volume from a view.

    ``volume`` is a :class:`pointillist.imaging.volumes.Volume` or a (Z, Y, X) array.
    The view is anatomical (see the module's description): the camera's axes are in
    patient LPS and the integrator poses the volume by its directions. A view that is
    along voxel axes after that pose (any axis-aligned acquisition, whatever its voxel
    order) keeps the one-pixel-per-voxel-column ``native`` framing and the integrator's
    column fast path. ``neurological`` mirrors the image left-right where it has a left-right
    axis (not a sagittal view). Pass ``integrator``
    (a ``mip`` integrator holding the volume) to reuse its texture across views (the views
    are then framed on the volume it holds). A very small or large volume is projected in a
    rescaled frame (:func:`normalised_volume`), so that scaling the spacing uniformly does not
    change the projection. Returns ``(image, integrator)``.
    """
    import pointillist

    if integrator is None:
        mi = pointillist.setup()
    else:  # already set up (a mip integrator exists): skip re-registering the plugins (~10 ms)
        import mitsuba as mi
    from pointillist.imaging.volumes import Volume

    if not isinstance(volume, Volume):
        volume = Volume(np.asarray(volume))
    if integrator is None:
        props = {"type": "mip", "mode": mode, "interpolation": interpolation, "step": float(step),
                 "precision": precision}
        if background is not None:
            props["background"] = float(background)
        try:
            integrator = mi.load_dict(props, parallel=False)
        except RuntimeError as error:  # a property the integrator refused, wrapped by Mitsuba
            from pointillist.scene import mitsuba_message

            raise ValueError(mitsuba_message(error)) from None
        integrator.set_volume(normalised_volume(volume))
    volume = integrator.volume
    perspective = check_perspective(perspective)
    axes = view_axes(view, azimuth, elevation)  # patient LPS
    if native and not _along_patient_axes(axes):
        raise ValueError("native-size: needs an axis-aligned view along the patient's axes (axial, coronal, "
                         "sagittal or azimuth/elevation multiples of 90 degrees)")
    from pointillist.imaging.orientation import inverse_directions

    directions = volume.directions if getattr(integrator, "patient_space", True) else np.eye(3)
    inverse = inverse_directions(directions)  # exact for an axis-aligned acquisition
    voxel_axes = tuple(np.where(np.abs(v := inverse @ a) < 1e-12, 0.0, v) for a in axes)
    image_size, half_w, half_h = view_frame(volume.extent, voxel_axes, size=size, native=native,
                                            counts=volume.shape_xyz, spacing=volume.spacing)
    sensor = mi.load_dict(sensor_dict(mi, np.asarray(volume.extent), axes, image_size, half_w, half_h,
                                       perspective), parallel=False)
    scene = mi.load_dict({"type": "scene"}, parallel=False)
    image = np.array(integrator.project(scene, sensor))
    if neurological and _has_left_right(axes[0]):
        image = np.ascontiguousarray(image[:, ::-1])
    return image, integrator


