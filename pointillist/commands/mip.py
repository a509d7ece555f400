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

from pointillist.commands._types import finite_float, positive_float, positive_int
from pointillist.mip import NAMED_VIEWS

NAME = "mip"
HELP = "maximum intensity projection of a volume (CT/MRI) to PNG or EXR"


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



def _spacing(text: str) -> tuple[float, float, float]:
    """argparse type: ``sx,sy,sz`` numbers (checked further by the volume reader)."""
    try:
        values = tuple(float(s) for s in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected sx,sy,sz numbers, got {text!r}") from None
    if len(values) != 3:
        raise argparse.ArgumentTypeError(f"expected three numbers sx,sy,sz, got {text!r}")
    return values


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
    parser.add_argument("--spacing", type=_spacing, metavar="SX,SY,SZ", help="override voxel spacing sx,sy,sz")
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
    from pointillist.mip import render_mip

    result = render_mip(args.volume, args.output, view=args.view, azimuth=args.azimuth, elevation=args.elevation,
                        size=args.size, native=args.native_size, mode=args.mode, interpolation=args.interpolation,
                        window=args.window, colormap=args.colormap, step=args.step, spacing=args.spacing,
                        perspective=args.perspective, background=args.background, precision=args.precision,
                        turntable=args.turntable, workers=args.workers, scheduler=args.scheduler)
    for note in result.notes:
        print(note)
    if result.gif is not None:
        print(f"wrote {result.gif}")
    names = result.outputs
    print(f"wrote {names[0]}" + (f" ... {names[-1]} ({len(names)} frames)" if len(names) > 1 else ""))
    volume, info = result.volume, result.texture
    nx, ny, nz = volume.shape_xyz
    print(f"volume {nx}x{ny}x{nz} {volume.data.dtype} spacing {', '.join(f'{s:g}' for s in volume.spacing)}; "
          f"texture {info['precision']} ({info['nbytes'] / 2**20:.1f} MiB, "
          f"{'exact' if info['exact'] else 'rounded'})")
    print(f"time: load {result.load_seconds:.2f} s, project {result.project_seconds:.2f} s "
          f"({len(names)} frame(s)), window {result.window[0]:g},{result.window[1]:g}")
    return 0
