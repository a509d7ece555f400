"""Maximum (minimum, average) intensity projections of volumes: views, framing, frames.

Views are anatomical: the volume is posed in patient space (LPS: x = patient's left,
y = posterior, z = superior; :mod:`pointillist.imaging.orientation`) by its
voxel-to-patient directions, and the named views follow the radiological convention of
radiology viewers (3D Slicer, ITK-SNAP, OsiriX/Horos): axial seen from the feet (patient's
right on the image's left, anterior up), coronal from the front (right on the left,
superior up), sagittal from the patient's left (anterior on the left, superior up).
``neurological`` mirrors left and right in the views that have a left-right axis (axial, coronal and
oblique views; a sagittal view has none and is the same in both, as in 3D Slicer and ITK-SNAP).

* :func:`view_axes` gives the camera's ``(right, up, forward)`` in LPS for a named view
  (:data:`NAMED_VIEWS`) or an azimuth/elevation; :func:`view_frame` fits the
  volume's box into the image (or, ``native``, one pixel per voxel column).
* :func:`project_volume` renders one raw projection with the ``mip`` integrator
  (:mod:`pointillist.plugins.integrators.mip`), reusing its texture across views.
* :func:`project_frames` renders turntable frames as Dask tasks
  (:func:`mip_frame_task`, :func:`pointillist.distributed.run_tasks`).
* :func:`render_mip` is ``pointillist mip``: load a volume, project every view,
  window and colour-map it (:mod:`pointillist.imaging.window`) and write PNG/EXR.
"""

from __future__ import annotations

import math
import os
import socket
import time
import warnings
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pointillist.core import checks
from pointillist.core import signals
from pointillist.core.digests import json_key
from pointillist.distributed import DEFAULT_RETRIES, open_client, run_tasks, setup_process
from pointillist.core.errors import UsageError

__all__ = ["NAMED_VIEWS", "PERSPECTIVE_MIN_FOV", "check_perspective", "view_axes", "view_frame", "patient_view",
           "normalised_volume", "project_volume", "mip_frame_task", "project_frames", "MipResult", "render_mip",
           "PLAIN_EXTENT", "NORMAL_EXTENT", "MAX_TURNTABLE_FRAMES"]

#: The most frames of a turntable: one every tenth of a degree (a 2.4-minute GIF at 25 frames a
#: second). The GIF's frames are held in memory until it is written; 100000 frames asked for hours.
MAX_TURNTABLE_FRAMES = 3600


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


def _sensor_dict(mi, extent, axes, image_size, half_w, half_h, perspective: float | None):
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
    sensor = mi.load_dict(_sensor_dict(mi, np.asarray(volume.extent), axes, image_size, half_w, half_h,
                                       perspective), parallel=False)
    scene = mi.load_dict({"type": "scene"}, parallel=False)
    image = np.array(integrator.project(scene, sensor))
    if neurological and _has_left_right(axes[0]):
        image = np.ascontiguousarray(image[:, ::-1])
    return image, integrator


# --------------------------------------------------------------------------- `pointillist mip --turntable`
_VOLUMES: OrderedDict = OrderedDict()

def mip_frame_task(spec: dict) -> dict:
    """Project one frame of a volume in this process (a worker); picklable.

    ``spec``: ``volume`` (path), ``spacing`` (or None), ``load`` (``frame``/``series`` of
    :func:`~pointillist.imaging.volumes.load_volume`, optional), ``view`` (keyword
    arguments of the view: ``view``/``azimuth``/``elevation``) and ``options``
    (the other keyword arguments of
    :func:`project_volume`). The volume and its
    texture stay loaded per process for the next frame. Returns
    ``{"image": (H, W) float32, "seconds": projection time here,
    "texture": the integrator's texture_info(), "worker": host:pid}``.
    """
    setup_process()
    from pointillist.imaging.volumes import load_volume

    path = str(Path(spec["volume"]).resolve())
    try:
        stamp = os.stat(path).st_mtime_ns
    except OSError:
        raise UsageError(f"volume: no such file or folder: {path}") from None
    spacing = tuple(spec["spacing"]) if spec.get("spacing") else None
    load = dict(spec.get("load") or {})
    key = (path, stamp, spacing, tuple(sorted(load.items())), tuple(sorted(spec["options"].items())))
    entry = _VOLUMES.get(key)
    if entry is None:
        _VOLUMES.clear()  # one volume per process: they can be large
        entry = _VOLUMES[key] = {"volume": load_volume(path, spacing=list(spacing) if spacing else None, **load),
                                 "integrator": None}
    start = time.perf_counter()
    image, entry["integrator"] = project_volume(entry["volume"], **spec["view"], **spec["options"],
                                                integrator=entry["integrator"])
    return {"image": np.asarray(image, dtype=np.float32), "seconds": time.perf_counter() - start,
            "texture": entry["integrator"].texture_info(), "worker": f"{socket.gethostname()}:{os.getpid()}"}

def project_frames(volume: str | os.PathLike, views: Sequence[dict], options: dict, *, spacing=None,
                   load: dict | None = None, workers: int | None = None, scheduler: str | None = None,
                   retries: int = DEFAULT_RETRIES, progress: bool = True) -> list[dict]:
    """Project every view of a volume (turntable frames) as tasks; results in view order.

    Runs on a local cluster of ``workers`` processes or the cluster at
    ``scheduler`` (each worker loads the volume once, by the same path). See
    :func:`mip_frame_task` for what each result holds.
    """
    specs = [{"volume": str(Path(volume).resolve()), "spacing": list(spacing) if spacing else None,
              "load": dict(load or {}), "view": dict(view), "options": dict(options)} for view in views]
    keys = [json_key(s) for s in specs]
    with open_client(workers, scheduler, tasks=len(specs)) as client:
        return run_tasks(mip_frame_task, specs, client=client, keys=keys, retries=retries, progress=progress,
                         desc="mip frames")


# --------------------------------------------------------------------------- `pointillist mip`
@dataclass
class MipResult:
    """What :func:`render_mip` did: the files written, the volume and texture, the times."""

    outputs: list[Path]
    gif: Path | None
    volume: Any
    texture: dict[str, Any]
    window: tuple[float, float]
    load_seconds: float
    project_seconds: float
    notes: list[str] = field(default_factory=list)
    #: one-line warnings (e.g. an orientation the file lacked and what was assumed)
    warnings: list[str] = field(default_factory=list)


def _frame_views(view: str | None, azimuth: float | None, elevation: float | None,
                 turntable: int | None) -> list[dict]:
    """The views to project: one named or azimuth/elevation view, or ``turntable`` frames about z."""
    if azimuth is None and elevation is None:
        views = [dict(view=view or "axial")]
    else:
        views = [dict(view=None, azimuth=azimuth or 0.0, elevation=elevation or 0.0)]
    if not turntable:
        return views
    base = views[0]
    if base["view"] is not None:
        _, _, forward = view_axes(base["view"])
        base = dict(view=None, azimuth=math.degrees(math.atan2(forward[0], forward[1])),
                    elevation=-math.degrees(math.asin(forward[2])))
    return [dict(view=None, azimuth=base["azimuth"] + 360.0 * k / turntable, elevation=base["elevation"])
            for k in range(turntable)]


def render_mip(volume_path: str | os.PathLike, output: str | os.PathLike, *, view: str | None = None,
               azimuth: float | None = None, elevation: float | None = None, size=(512, 512),
               native: bool = False, mode: str = "mip", interpolation: str = "trilinear",
               window: str | None = None, colormap: str = "grey", step: float = 0.5,
               spacing: Sequence[float] | None = None, perspective: float | None = None,
               background: float | None = None, precision: str = "auto", turntable: int | None = None,
               neurological: bool = False, labels: bool = True, frame: int | None = None,
               series: str | None = None, workers: int | None = None, scheduler: str | None = None,
               progress: bool = True) -> MipResult:
    """Project a volume file and write the image(s): ``pointillist mip``.

    ``output`` is a ``.png`` (windowed and colour-mapped; ``window`` is ``"L,W"``
    or a preset of :data:`pointillist.imaging.window.WINDOW_PRESETS`, default the
    first frame's value range; with ``labels`` the patient-direction letters at the
    middle of each edge) or an ``.exr`` (raw projected values, one channel; its header
    records the view's patient axes: ``patient_frame`` LPS, ``view_right``/``view_up``/
    ``view_forward`` vectors, ``image_left``/``image_right``/``image_top``/``image_bottom``
    letters and ``display`` radiological or neurological). Views are anatomical and
    radiological (see the module's description); ``neurological`` mirrors left and
    right where the view has a left-right axis (not sagittal; not with ``turntable``).
    ``frame`` picks a volume of a 4-D input, ``series`` a DICOM series of a folder
    (:func:`~pointillist.imaging.volumes.load_volume`).
    ``turntable`` N writes N frames ``OUT_000.png ...`` turning about z (and
    ``OUT.gif`` when imageio is installed); ``workers``/``scheduler`` project the
    frames as Dask tasks. Other arguments as :func:`project_volume`.

    Raises
    ------
    UsageError
        For an output name or option combination that cannot work, before any work.
    """
    _check_options(native=native, perspective=perspective, turntable=turntable, neurological=neurological)
    names, gif, notes = _plan_outputs(volume_path, Path(output), turntable)
    import pointillist

    pointillist.setup()
    from pointillist.imaging.window import colormap_lut, parse_window

    display = parse_window(window) if window else None
    lut = colormap_lut(colormap)
    load = {"frame": frame, "series": series}
    volume, load_s, caught = _load(volume_path, spacing, load)
    views = _frame_views(view, azimuth, elevation, turntable)
    options = dict(size=size, native=native, mode=mode, interpolation=interpolation, step=step,
                   perspective=perspective, precision=precision, background=background, neurological=neurological)
    remote = None
    if workers or scheduler:  # every frame a task
        remote = project_frames(volume_path, views, options, spacing=spacing, load=load, workers=workers,
                                scheduler=scheduler)
    integrator, frames, project_s, display = _project_and_write(
        volume, volume_path, views, names, options, remote, display, lut, progress=progress, labels=labels)
    if gif is not None:
        _write_gif(gif, frames, volume_path)
    texture = integrator.texture_info() if remote is None else remote[0]["texture"]
    return MipResult(outputs=names, gif=gif, volume=volume, texture=texture, window=display,
                     load_seconds=load_s, project_seconds=project_s, notes=notes, warnings=caught)


def _check_options(*, native: bool, perspective: float | None, turntable: int | None, neurological: bool) -> None:
    """UsageError for an option combination that cannot work (before any work)."""
    if native and perspective:
        raise UsageError("--native-size needs an orthographic view (drop --perspective)")
    try:
        check_perspective(perspective)
    except ValueError as error:
        raise UsageError(str(error)) from None
    if turntable and turntable > MAX_TURNTABLE_FRAMES:
        raise UsageError(f"--turntable: expected at most {MAX_TURNTABLE_FRAMES} frames (one every 0.1 degree), "
                         f"got {turntable}")
    if turntable and native:
        raise UsageError("--turntable needs --size (oblique frames have no native size)")
    if turntable and neurological:
        raise UsageError("--neurological is for still views: a turntable passes through lateral views, which have "
                         "no left-right axis to mirror, so its frames would flip there")


def _plan_outputs(volume_path, out: Path, turntable: int | None) -> tuple[list[Path], Path | None, list[str]]:
    """The files to write (``OUT`` or the turntable's ``OUT_000...``, and its GIF), checked by the plan
    before any work: a ``.png`` or ``.exr`` name, writable, none of them the volume nor inside the
    folder of a DICOM series. Returns ``(frames, gif or None, notes)``."""
    import importlib.util

    from pointillist.plan import Output, Plan

    suffixes = (".png", ".exr")
    digits = max(3, len(str(turntable - 1))) if turntable else 0  # names that sort in frame order
    names = ([out.with_name(f"{out.stem}_{k:0{digits}d}{out.suffix}") for k in range(turntable)] if turntable
             else [out])
    gif = out.with_suffix(".gif") if turntable and out.suffix.lower() == ".png" else None
    notes = []
    if gif is not None and importlib.util.find_spec("imageio") is None:
        gif = None
        notes.append("imageio not installed: no GIF written")
    from pointillist.imaging.volumes import volume_files

    Plan(inputs=volume_files(volume_path),  # the file, and those it names (an NRRD header's data file)
         outputs=[Output(name, "--output", suffixes=suffixes) for name in names]
         + ([Output(gif, "--output (GIF)")] if gif else [])).check()
    return names, gif, notes


def _load(volume_path, spacing, load: dict) -> tuple[Any, float, list[str]]:
    """Load the volume; returns it, the seconds taken and the warnings its reader gave (one line each:
    e.g. an orientation the file lacked and what was assumed)."""
    from pointillist.imaging.volumes import load_volume

    start = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        volume = load_volume(volume_path, spacing=list(spacing) if spacing else None, **load)
        # slice by slice, stopping at the first finite voxel (no volume-sized mask)
        if np.issubdtype(volume.data.dtype, np.floating) and not any(np.isfinite(plane).any()
                                                                     for plane in volume.data):
            warnings.warn(f"volume: {volume_path}: no voxel is finite (all NaN or inf): the projection shows "
                          "only the background", stacklevel=2)
    signals.check()
    return volume, time.perf_counter() - start, [str(w.message) for w in caught]


def _project_and_write(volume, volume_path, views: list[dict], names: list[Path], options: dict,
                       remote: list[dict] | None, display, lut, *, progress: bool, labels: bool):
    """Project each view (or take its frame from ``remote``, the tasks' results) and write it.

    ``display``: the window ``(level, width)``, None for the first frame's value range (then used for
    every frame). Returns ``(integrator, 8-bit PNG frames, projection seconds, window)``."""
    from pointillist.core.terminal import progress_bar

    integrator, frames = None, []
    project_s = sum(r["seconds"] for r in remote) if remote is not None else 0.0
    for k, (frame_view, name) in enumerate(progress_bar(list(zip(views, names)), progress=progress and len(names) > 1,
                                                        desc="mip", unit="frame")):
        signals.check()
        if remote is not None:
            image = remote[k]["image"]
        else:
            t = time.perf_counter()
            image, integrator = project_volume(volume, **frame_view, **options, integrator=integrator)
            project_s += time.perf_counter() - t
        if display is None:  # one window for all frames: the first frame's value range
            finite = image[np.isfinite(image)]
            lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
            display = ((lo + hi) / 2, hi - lo if hi > lo else 1.0)
        frames.append(_write_frame(name, image, volume, volume_path, display, lut, frame_view, mode=options["mode"],
                                   interpolation=options["interpolation"], step=options["step"],
                                   neurological=options["neurological"], labels=labels))
    return integrator, frames, project_s, display


def _write_gif(gif: Path, frames: list[np.ndarray], volume_path) -> None:
    """The turntable's animated GIF (25 frames a second, looping)."""
    import imageio.v2 as imageio

    from pointillist.core.files import atomic_write, check_output_path

    check_output_path(gif, [volume_path], "--output (GIF)")
    atomic_write(gif, lambda tmp: imageio.mimsave(tmp, frames, format="GIF", duration=1000 / 25, loop=0))


def _write_frame(path: Path, image: np.ndarray, volume, volume_path, window, lut, view, *, mode: str,
                 interpolation: str, step: float, neurological: bool = False,
                 labels: bool = True) -> np.ndarray | None:
    """Write one frame: raw values to EXR (patient axes in the header), or windowed display RGB
    to PNG with orientation letters (returned as 8-bit)."""
    from pointillist.imaging.io import to_8bit, write_exr, write_png

    patient = patient_view(view["view"], view.get("azimuth", 0.0), view.get("elevation", 0.0),
                           neurological=neurological)
    if path.suffix.lower() == ".exr":
        meta = {"mode": mode, "interpolation": interpolation, "step": float(step),
                "volume": str(volume_path), "spacing": ",".join(f"{s:g}" for s in volume.spacing),
                "view": view["view"] or f"azimuth={view.get('azimuth', 0):g},elevation={view.get('elevation', 0):g}",
                "patient_frame": "LPS", "voxel_axes": volume.axis_codes if volume.oriented else "none (taken as LPS)",
                "display": "neurological" if neurological else "radiological"}
        for key in ("right", "up", "forward"):
            meta[f"view_{key}"] = ",".join(f"{float(c):.9g}" for c in patient[key])
        for edge, letters in patient["labels"].items():
            meta[f"image_{edge}"] = letters
        write_exr(path, image.astype(np.float32), meta, inputs=[volume_path])
        return None
    from pointillist.imaging.window import window_image

    pixels = to_8bit(window_image(image, *window, lut), srgb=False)
    if labels:
        from pointillist.imaging.orientation import draw_labels

        pixels = draw_labels(pixels, patient["labels"])
    write_png(path, pixels, srgb=False, max_value=255.0, inputs=[volume_path])
    return pixels
