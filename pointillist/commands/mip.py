"""Project a CT/MRI volume: maximum (minimum, average) intensity projection to PNG or EXR.

VOLUME is a volume file (the formats are listed under `volume` below) or a folder holding
DICOM images (values in Hounsfield units; --series picks one of several series).

Patient space: every view is anatomical whatever the voxel order. Volumes are placed in
LPS (x = patient's left, y = posterior, z = superior, as DICOM and ITK) by their
voxel-to-patient transform: NIfTI's affine as nibabel resolves it (sform, else qform;
RAS+ converted to LPS), DICOM ImageOrientationPatient/ImagePositionPatient/PixelSpacing
with the slice spacing from the positions (also enhanced multi-frame files), NRRD
space/space directions/space origin (RAS, LAS, LPS; scanner-xyz and 3D-right/left-handed
taken as LPS with a warning). .vol and .npy carry no orientation: voxel axes x, y, z
(array axes 2, 1, 0) are taken as L, P, S, i.e. a DICOM axial stack's order. Sheared
(non-orthogonal, e.g. gantry-tilt) transforms are refused; a missing or degenerate
orientation tag falls back with a one-line warning saying what was assumed.

Display convention of radiology viewers (radiological by default): axial seen from the
feet (patient's right on the image's left, anterior up), coronal seen from the front
(right on the left, superior up), sagittal seen from the patient's left (anterior on the
left, superior up); --neurological mirrors left and right (axial, coronal and oblique
views; a sagittal view has no left-right axis and stays as it is). --azimuth/--elevation in
degrees turn about the patient (azimuth 0, elevation 0 is coronal; azimuth turns about
the superior axis, elevation raises the camera towards the head). PNG output is windowed
and colour-mapped, with the patient-direction letter (R/L, A/P, S/I; two or three for an
oblique edge) at the middle of each edge (--no-labels: none); EXR output holds the raw
projected values (one channel Y) and records the view's patient axes in its header.

--native-size: one pixel per voxel column when the view runs along voxel axes; for an
oblique acquisition (voxel axes not along the patient's), the in-plane voxel spacing
along the image's right and up (the two voxel axes other than the one closest to the
viewing direction) gives the pixel size and the image covers the whole volume.
4-D inputs (4-D NIfTI, DICOM series with several images per slice position) need
--frame N. --turntable N writes N frames OUT_000.png ... around the patient's superior axis
(at most 3600, one every 0.1 degree; and OUT.gif when imageio is installed), upright from the
coronal view unless a view is given.
"""

from __future__ import annotations

import argparse
import sys

from pointillist.commands._types import (add_cluster_options, finite_float, non_negative_int, positive_float,
                                         positive_int)
from pointillist.core import checks

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
    """argparse type: the voxel spacing as the ``mip`` integrator reads it (:func:`checks.spacing`)."""
    try:
        return checks.spacing(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error).removeprefix("spacing: ")) from None


class _VolumeArgument(argparse.Action):
    """The ``volume`` argument, whose help lists the formats of the volume-reader registry when the
    help is shown (building the parser imports no imaging module: Dr.Jit loads only for a command)."""

    @property
    def help(self) -> str:
        from pointillist.imaging.volumes import volume_formats

        return f"volume file or folder: {volume_formats()}"

    @help.setter
    def help(self, value: str) -> None:
        pass  # the help is the registry's

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        setattr(namespace, self.dest, values)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of ``pointillist mip`` to ``parser``."""
    from pointillist.mip import NAMED_VIEWS

    parser.add_argument("volume", action=_VolumeArgument, help="volume file or folder")
    parser.add_argument("-o", "--output", required=True, help="output .png (windowed) or .exr (raw values)")
    views = parser.add_mutually_exclusive_group()
    views.add_argument("--view", choices=sorted(NAMED_VIEWS), help="named view (default: axial)")
    views.add_argument("--azimuth", type=finite_float, help="azimuth in degrees (0 = coronal)")
    parser.add_argument("--elevation", type=finite_float, default=None, help="elevation in degrees")
    sizes = parser.add_mutually_exclusive_group()
    sizes.add_argument("--size", type=_size, default=(512, 512), metavar="N|W,H",
                       help="image size; the volume is fitted inside (default 512)")
    sizes.add_argument("--native-size", action="store_true",
                       help="one pixel per voxel column (views along the patient's axes; an oblique acquisition: "
                            "pixels of its in-plane voxel spacing)")
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
    parser.add_argument("--neurological", action="store_true",
                        help="neurological display: patient's left on the image's left in views with a left-right axis "
                             "(not sagittal, not with --turntable; default radiological)")
    parser.add_argument("--no-labels", action="store_true",
                        help="no orientation letters on the PNG's edges")
    parser.add_argument("--frame", type=non_negative_int, metavar="N",
                        help="volume N of a 4-D input (4-D NIfTI, multi-frame DICOM series); required for those")
    parser.add_argument("--series", metavar="UID|INDEX",
                        help="the DICOM series to read from a folder holding several (UID or index in the listing)")
    parser.add_argument("--turntable", type=positive_int, metavar="N",
                        help="write N frames turning about z (OUT_000.png ...; N <= 3600) and OUT.gif")
    add_cluster_options(parser, work="project the frames as tasks", shared="the workers read VOLUME by the same path")



def run(args: argparse.Namespace) -> int:
    """Run ``pointillist mip`` with the parsed ``args``; returns the exit status."""
    from pointillist.mip import render_mip

    result = render_mip(args.volume, args.output, view=args.view, azimuth=args.azimuth, elevation=args.elevation,
                        size=args.size, native=args.native_size, mode=args.mode, interpolation=args.interpolation,
                        window=args.window, colormap=args.colormap, step=args.step, spacing=args.spacing,
                        perspective=args.perspective, background=args.background, precision=args.precision,
                        turntable=args.turntable, neurological=args.neurological, labels=not args.no_labels,
                        frame=args.frame, series=args.series, workers=args.workers, scheduler=args.scheduler)
    for warning in result.warnings:
        print(f"pointillist mip: warning: {warning}", file=sys.stderr)
    for note in result.notes:
        print(note)
    if result.gif is not None:
        print(f"wrote {result.gif}")
    names = result.outputs
    print(f"wrote {names[0]}" + (f" ... {names[-1]} ({len(names)} frames)" if len(names) > 1 else ""))
    volume, info = result.volume, result.texture
    nx, ny, nz = volume.shape_xyz
    axes = f"voxel axes {volume.axis_codes}" if volume.oriented else "no orientation (voxel axes taken as LPS)"
    print(f"volume {nx}x{ny}x{nz} {volume.data.dtype} spacing {', '.join(f'{s:g}' for s in volume.spacing)}, {axes}; "
          f"texture {info['precision']} ({info['nbytes'] / 2**20:.1f} MiB, "
          f"{'exact' if info['exact'] else 'rounded'})")
    print(f"time: load {result.load_seconds:.2f} s, project {result.project_seconds:.2f} s "
          f"({len(names)} frame(s)), window {result.window[0]:g},{result.window[1]:g}")
    return 0
