"""Project a CT/MRI volume: maximum (minimum, average) intensity projection to PNG or EXR.

VOLUME is a Mitsuba .vol, .npy, NRRD (.nrrd/.nhdr), NIfTI (.nii/.nii.gz) file or a folder
holding one DICOM series (values in Hounsfield units). Views: axial (looking from the feet
along +z, x to the right, y down), coronal (from the front along +y, x right, z up), sagittal
(from the patient's left along -x, y right, z up), or any --azimuth/--elevation in degrees
(azimuth 0, elevation 0 is coronal; azimuth turns about z, elevation raises the camera).
EXR output holds the raw projected values (one channel Y, no window, no colormap); PNG output
is windowed and colour-mapped. --turntable N writes N frames around z (and an animated GIF
beside them when imageio is installed).
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from pointillist.commands._types import finite_float, positive_float, positive_int
from pointillist.errors import UsageError

NAME = "mip"
HELP = "maximum intensity projection of a volume (CT/MRI) to PNG or EXR"

__all__ = ["view_axes", "view_frame", "project_volume", "NAMED_VIEWS"]

#: Named views: (right, up, forward) unit vectors in the volume's (x, y, z) axes.
NAMED_VIEWS = {
    "axial": ((1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0)),
    "coronal": ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, 1.0, 0.0)),
    "sagittal": ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0), (-1.0, 0.0, 0.0)),
}


def view_axes(view: str | None = None, azimuth: float = 0.0, elevation: float = 0.0):
    """Camera ``(right, up, forward)`` unit vectors (numpy) for a named view or azimuth/elevation.

    forward = (sin A cos E, cos A cos E, -sin E); right = forward x z normalised
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

    ``size`` (W, H): the box's projection is fitted inside with square pixels.
    ``native``: axis-aligned views only; the image has one pixel per voxel column
    (W, H = voxel counts across the view) and the rectangle is the box's face, so
    each pixel's ray passes through a voxel column centre.
    """
    right, up, forward = axes
    extent = np.asarray(extent, dtype=np.float64)
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * extent / 2
    half_w = float(np.abs(corners @ right).max())
    half_h = float(np.abs(corners @ up).max())
    if native:
        axis_r, axis_u = np.flatnonzero(np.abs(right) == 1.0), np.flatnonzero(np.abs(up) == 1.0)
        if len(axis_r) != 1 or len(axis_u) != 1 or np.count_nonzero(forward) != 1:
            raise ValueError("native-size: needs an axis-aligned view (axial, coronal, sagittal or "
                             "azimuth/elevation multiples of 90 degrees)")
        width, height = int(counts[axis_r[0]]), int(counts[axis_u[0]])
        return (width, height), half_w, half_h
    width, height = size
    per_pixel = max(2 * half_w / width, 2 * half_h / height)
    return (width, height), width * per_pixel / 2, height * per_pixel / 2


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


def project_volume(volume, *, view: str | None = "axial", azimuth: float = 0.0, elevation: float = 0.0,
                   size=(512, 512), native: bool = False, mode: str = "mip",
                   interpolation: str = "trilinear", step: float = 0.5, perspective: float | None = None,
                   precision: str = "auto", background: float | None = None, integrator=None):
    """Render the raw projection ``(H, W)`` (numpy float32) of a volume from a view.

    ``volume`` is a :class:`pointillist.imaging.volumes.Volume` or a (Z, Y, X) array.
    Pass ``integrator`` (a ``mip`` integrator holding the volume) to reuse its
    texture across views. Returns ``(image, integrator)``.
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
        integrator = mi.load_dict(props)
        integrator.set_volume(volume)
    axes = view_axes(view, azimuth, elevation)
    image_size, half_w, half_h = view_frame(volume.extent, axes, size=size, native=native,
                                            counts=volume.shape_xyz)
    sensor = mi.load_dict(_sensor_dict(mi, np.asarray(volume.extent), axes, image_size, half_w, half_h,
                                       perspective))
    scene = mi.load_dict({"type": "scene"})
    image = integrator.project(scene, sensor)
    return np.array(image), integrator


# ------------------------------------------------------------------------------------------------
def _size(text: str) -> tuple[int, int]:
    parts = text.replace("x", ",").split(",")
    try:
        values = [int(p) for p in parts]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected N or W,H (positive integers), got {text!r}") from None
    if len(values) == 1:
        values = values * 2
    if len(values) != 2 or min(values) < 1 or max(values) > 16384:
        raise argparse.ArgumentTypeError(f"expected N or W,H with 1 <= N <= 16384, got {text!r}")
    return values[0], values[1]


def add_arguments(parser: argparse.ArgumentParser) -> None:

    parser.add_argument("volume", help="volume file (.vol, .npy, .nrrd, .nii[.gz]) or DICOM series folder")
    parser.add_argument("-o", "--output", required=True, help="output .png (windowed) or .exr (raw values)")
    views = parser.add_mutually_exclusive_group()
    views.add_argument("--view", choices=sorted(NAMED_VIEWS), help="named view (default: axial)")
    views.add_argument("--azimuth", type=finite_float, help="azimuth in degrees (0 = coronal)")
    parser.add_argument("--elevation", type=finite_float, default=None, help="elevation in degrees")
    sizes = parser.add_mutually_exclusive_group()
    sizes.add_argument("--size", type=_size, default=(512, 512), metavar="N|W,H",
                       help="image size; the volume is fitted inside (default 512)")
    sizes.add_argument("--native-size", action="store_true",
                       help="one pixel per voxel column (axis-aligned views only)")
    parser.add_argument("--interpolation", choices=("trilinear", "nearest"), default="trilinear")
    parser.add_argument("--mode", choices=("mip", "minip", "average"), default="mip")
    parser.add_argument("--window", metavar="L,W|PRESET",
                        help="display window level,width (e.g. 40,400) or brain|soft|lung|bone|subdural|angio "
                             "(default: the projection's value range)")
    parser.add_argument("--colormap", default="grey", help="grey or a matplotlib colormap (PNG only)")
    parser.add_argument("--step", type=positive_float, default=0.5, help="marching step in voxels (default 0.5)")
    parser.add_argument("--spacing", help="override voxel spacing sx,sy,sz")
    parser.add_argument("--perspective", type=positive_float, metavar="FOV",
                        help="perspective camera with this field of view in degrees (default orthographic)")
    parser.add_argument("--background", type=finite_float, help="raw value of rays missing the volume")
    parser.add_argument("--precision", choices=("auto", "half", "single"), default="auto",
                        help="texture storage (auto: half precision where exact)")
    parser.add_argument("--turntable", type=positive_int, metavar="N",
                        help="write N frames turning about z (OUT_000.png ...) and OUT.gif")
    cluster = parser.add_mutually_exclusive_group()
    cluster.add_argument("--workers", type=positive_int, metavar="N",
                         help="project the frames as tasks on a local Dask cluster of N worker processes")
    cluster.add_argument("--scheduler", metavar="ADDRESS",
                         help="project the frames on an existing Dask cluster (e.g. tcp://host:8786); "
                              "the workers read VOLUME by the same path")


def run(args: argparse.Namespace) -> int:
    out = Path(args.output)
    suffix = out.suffix.lower()
    if suffix not in (".png", ".exr"):
        raise UsageError(f"--output: expected a .png or .exr file name, got {out}")
    if not out.parent.is_dir():
        raise UsageError(f"--output: folder {out.parent} does not exist")
    if args.native_size and args.perspective:
        raise UsageError("--native-size needs an orthographic view (drop --perspective)")
    if args.perspective is not None and args.perspective >= 180:
        raise UsageError(f"--perspective: expected a field of view below 180 degrees, got {args.perspective}")
    if args.turntable and args.native_size:
        raise UsageError("--turntable needs --size (oblique frames have no native size)")
    import pointillist

    pointillist.setup()
    from pointillist.imaging.window import colormap_lut, parse_window

    window = parse_window(args.window) if args.window else None
    lut = colormap_lut(args.colormap)
    spacing = None
    if args.spacing:
        try:
            spacing = [float(s) for s in args.spacing.split(",")]
        except ValueError:
            raise UsageError(f"--spacing: expected sx,sy,sz numbers, got {args.spacing!r}") from None
    from pointillist.imaging.volumes import load_volume

    start = time.perf_counter()
    volume = load_volume(args.volume, spacing=spacing)
    load_s = time.perf_counter() - start
    if args.azimuth is None and args.elevation is None:
        views = [dict(view=args.view or "axial")]
    else:
        views = [dict(view=None, azimuth=args.azimuth or 0.0, elevation=args.elevation or 0.0)]
    if args.turntable:
        base = views[0]
        if base["view"] is not None:
            right, up, forward = view_axes(base["view"])
            base = dict(view=None, azimuth=math.degrees(math.atan2(forward[0], forward[1])),
                        elevation=-math.degrees(math.asin(forward[2])))
        views = [dict(view=None, azimuth=base["azimuth"] + 360.0 * k / args.turntable,
                      elevation=base["elevation"]) for k in range(args.turntable)]
        names = [out.with_name(f"{out.stem}_{k:03d}{out.suffix}") for k in range(args.turntable)]
    else:
        names = [out]
    from pointillist.imaging.io import check_output_path

    for name in names:
        check_output_path(name, [args.volume], name="--output")
    from tqdm import tqdm

    integrator = None
    frames = []
    render_s = 0.0
    remote = None
    if args.workers or args.scheduler:  # every frame a task (pointillist.distributed)
        from pointillist.distributed import project_frames

        remote = project_frames(args.volume, views, dict(
            size=args.size, native=args.native_size, mode=args.mode, interpolation=args.interpolation,
            step=args.step, perspective=args.perspective, precision=args.precision,
            background=args.background), spacing=spacing, workers=args.workers, scheduler=args.scheduler)
        render_s = sum(r["seconds"] for r in remote)
        remote_images = iter([r["image"] for r in remote])
    for view, name in tqdm(list(zip(views, names)), desc="mip", unit="frame", disable=len(names) == 1):
        if remote is not None:
            image = next(remote_images)
        else:
            t = time.perf_counter()
            image, integrator = project_volume(
                volume, **view, size=args.size, native=args.native_size, mode=args.mode,
                interpolation=args.interpolation, step=args.step, perspective=args.perspective,
                precision=args.precision, background=args.background, integrator=integrator)
            render_s += time.perf_counter() - t
        if window is None:  # one window for all frames: the first frame's value range
            finite = image[np.isfinite(image)]
            lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
            window = ((lo + hi) / 2, hi - lo if hi > lo else 1.0)
        frames.append(_write(name, image, volume, args, window, lut, view))
    if args.turntable and suffix == ".png":
        try:
            import imageio.v2 as imageio
        except ImportError:
            print("imageio not installed: no GIF written")
        else:
            gif = out.with_suffix(".gif")
            check_output_path(gif, [args.volume], name="--output")
            imageio.mimsave(gif, frames, duration=1000 / 25, loop=0)
            print(f"wrote {gif}")
    info = integrator.texture_info() if remote is None else remote[0]["texture"]
    print(f"wrote {names[0]}" + (f" ... {names[-1]} ({len(names)} frames)" if len(names) > 1 else ""))
    nx, ny, nz = volume.shape_xyz
    print(f"volume {nx}x{ny}x{nz} {volume.data.dtype} spacing {', '.join(f'{s:g}' for s in volume.spacing)}; "
          f"texture {info['precision']} ({info['nbytes'] / 2**20:.1f} MiB, "
          f"{'exact' if info['exact'] else 'rounded'})")
    print(f"time: load {load_s:.2f} s, project {render_s:.2f} s ({len(names)} frame(s)), "
          f"window {window[0]:g},{window[1]:g}")
    return 0


def _write(path: Path, image: np.ndarray, volume, args, window, lut, view) -> np.ndarray | None:
    from pointillist.imaging.io import to_8bit, write_exr, write_png

    if path.suffix.lower() == ".exr":
        meta = {"mode": args.mode, "interpolation": args.interpolation, "step": float(args.step),
                "volume": str(args.volume), "spacing": ",".join(f"{s:g}" for s in volume.spacing),
                "view": view["view"] or f"azimuth={view.get('azimuth', 0):g},elevation={view.get('elevation', 0):g}"}
        write_exr(path, image.astype(np.float32), meta, inputs=[args.volume])
        return None
    from pointillist.imaging.window import window_image

    pixels = window_image(image, *window, lut)
    write_png(path, pixels, srgb=False, max_value=1.0, inputs=[args.volume])
    return to_8bit(pixels, srgb=False)
