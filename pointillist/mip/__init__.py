"""Maximum (minimum, average) intensity projections of volumes: views, framing, frames.

Views are anatomical: the volume is posed in patient space (LPS: x = patient's left,
y = posterior, z = superior; :mod:`pointillist.imaging.orientation`) by its
voxel-to-patient directions, and the named views follow the radiological convention of
radiology viewers (3D Slicer, ITK-SNAP, OsiriX/Horos): axial seen from the feet (patient's
right on the image's left, anterior up), coronal from the front (right on the left,
superior up), sagittal from the patient's left (anterior on the left, superior up).
``neurological`` mirrors left and right in the views that have a left-right axis (axial, coronal and
oblique views; a sagittal view has none and is the same in both, as in 3D Slicer and ITK-SNAP).

* :mod:`pointillist.mip.views`: :func:`view_axes` gives the camera's ``(right, up, forward)`` in
  LPS for a named view (:data:`NAMED_VIEWS`) or an azimuth/elevation; :func:`view_frame` fits
  the volume's box into the image (or, ``native``, one pixel per voxel column);
  :func:`project_volume` renders one raw projection with the ``mip`` integrator
  (:mod:`pointillist.plugins.integrators.mip`), reusing its texture across views.
* :mod:`pointillist.mip.frames`: :func:`project_frames` renders turntable frames as Dask tasks
  (:func:`mip_frame_task`, :func:`pointillist.distributed.run_tasks`).
* This module: :func:`render_mip` is ``pointillist mip``: load a volume, project every view,
  window and colour-map it (:mod:`pointillist.imaging.window`) and write PNG/EXR.
"""

from __future__ import annotations

import math
import os
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pointillist.core import signals
from pointillist.core.errors import UsageError
from pointillist.mip.frames import MAX_TURNTABLE_FRAMES, mip_frame_task, project_frames
from pointillist.mip.views import (NAMED_VIEWS, NORMAL_EXTENT, PERSPECTIVE_MIN_FOV, PLAIN_EXTENT,
                                   check_perspective, normalised_volume, patient_view, project_volume,
                                   view_axes, view_frame)

__all__ = ["NAMED_VIEWS", "PERSPECTIVE_MIN_FOV", "check_perspective", "view_axes", "view_frame", "patient_view",
           "normalised_volume", "project_volume", "mip_frame_task", "project_frames", "MipResult", "render_mip",
           "PLAIN_EXTENT", "NORMAL_EXTENT", "MAX_TURNTABLE_FRAMES"]


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
    """The views to project: one named or azimuth/elevation view, or ``turntable`` frames about z.

    Without a view, one projection is axial; a turntable orbits upright from the coronal view
    (elevation 0: the patient stands and turns, as a viewer's spin does; about z from the axial
    view the frames would only turn in the image plane)."""
    if azimuth is None and elevation is None:
        views = [dict(view=view or ("coronal" if turntable else "axial"))]
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
