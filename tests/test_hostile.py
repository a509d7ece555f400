"""Hostile input: every command with malformed files, degenerate parameters and outputs
that cannot be written.

Most cases run in ONE subprocess (tests/_hostile_driver.py calls :func:`pointillist.cli.main` for
each argument list with file descriptors 1 and 2 captured, so that C++ libraries' output is seen);
each case is then checked on its own: a refused input exits 2 with exactly one line on stderr
naming the command, no traceback and no file left in its output folder (nor a temporary one), and
an input with a defined result exits 0. The subprocess has a timeout: a hang fails the cases it
had not finished. A few cases need a process of their own (SIGTERM, an abort in flip-evaluator).
Property-based tests of the imaging API live in tests/test_properties*.py.
"""

from __future__ import annotations

import json
import os
import shutil
import struct
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT, SCENES

DRIVER = Path(__file__).with_name("_hostile_driver.py")

#: The driver's timeout: far above what the cases take (about 30 s here), far below a hang.
DRIVER_TIMEOUT = 300

#: ``{d}`` the folder of hostile inputs, ``{o}`` the case's own (empty) output folder, ``{ro}`` a
#: folder that cannot be written, ``{scenes}`` the repository's scenes.
ERROR, OK = "error", "ok"

SMALL = ["-D", "res=8", "-D", "spp=1"]
CMP = ["--spp", "1", "--samplers", "grid", "--no-progress", "--reference-spp", "4"]

CASES: list[tuple[str, list[str], str]] = [
    # ------------------------------------------------------------------ render
    ("render-missing", ["render", "{d}/nope.xml", "-o", "{o}/x.exr"], ERROR),
    ("render-folder", ["render", "{d}", "-o", "{o}/x.exr"], ERROR),
    ("render-empty", ["render", "{d}/empty.xml", "-o", "{o}/x.exr"], ERROR),
    ("render-binary", ["render", "{d}/binary.xml", "-o", "{o}/x.exr"], ERROR),
    ("render-truncated", ["render", "{d}/truncated.xml", "-o", "{o}/x.exr"], ERROR),
    ("render-no-sensor", ["render", "{d}/nosensor.xml", "-o", "{o}/x.exr"], ERROR),
    ("render-include-cycle", ["render", "{d}/cycle_a.xml", "-o", "{o}/x.exr"], ERROR),
    ("render-unknown-plugin", ["render", "{d}/badplugin.xml", "-o", "{o}/x.exr"], ERROR),
    ("render-huge-xml-attribute", ["render", "{d}/hugeattr.xml", "-o", "{o}/x.exr"], OK),  # radius 1e1000000
    ("render-film-zero", ["render", "{scenes}/default.xml", "-D", "res=0", "-o", "{o}/x.exr"], ERROR),
    ("render-film-huge", ["render", "{scenes}/default.xml", "-D", "res=100000", "-D", "spp=1000",
                          "-o", "{o}/x.exr"], ERROR),
    ("render-define-bad", ["render", "{scenes}/default.xml", "-D", "=3", "-o", "{o}/x.exr"], ERROR),
    ("render-define-not-number", ["render", "{scenes}/default.xml", "-D", "res=abc", "-o", "{o}/x.exr"], ERROR),
    ("render-spp-zero", ["render", "{scenes}/default.xml", "--spp", "0", "-o", "{o}/x.exr"], ERROR),
    ("render-spp-2^32", ["render", "{scenes}/default.xml", "--spp", "4294967296", "-o", "{o}/x.exr"], ERROR),
    ("render-spp-nan", ["render", "{scenes}/default.xml", "--spp", "nan", "-o", "{o}/x.exr"], ERROR),
    ("render-seed-negative", ["render", "{scenes}/default.xml", "--seed", "-1", "-o", "{o}/x.exr"], ERROR),
    ("render-tiles-zero", ["render", "{scenes}/default.xml", *SMALL, "--tiles", "0x1", "-o", "{o}/x.exr"], ERROR),
    ("render-tiles-more-than-pixels", ["render", "{scenes}/default.xml", *SMALL, "--tiles", "100x100",
                                       "-o", "{o}/x.exr"], ERROR),
    ("render-output-png", ["render", "{scenes}/default.xml", *SMALL, "-o", "{o}/x.png"], ERROR),
    ("render-output-no-folder", ["render", "{scenes}/default.xml", *SMALL, "-o", "{o}/no/x.exr"], ERROR),
    ("render-output-folder", ["render", "{scenes}/default.xml", *SMALL, "-o", "{o}/sub.exr"], ERROR),
    ("render-output-proc", ["render", "{scenes}/default.xml", *SMALL, "-o", "/proc/hostile.exr"], ERROR),
    ("render-output-unwritable", ["render", "{scenes}/default.xml", *SMALL, "-o", "{ro}/x.exr"], ERROR),
    # ------------------------------------------------------------------ compare
    ("compare-missing", ["compare", "{d}/nope.xml", "--out", "{o}/c", *CMP], ERROR),
    ("compare-folder", ["compare", "{d}", "--out", "{o}/c", *CMP], ERROR),
    ("compare-binary", ["compare", "{d}/binary.xml", "--out", "{o}/c", *CMP], ERROR),
    ("compare-no-sensor", ["compare", "{d}/nosensor.xml", "--out", "{o}/c", *CMP], ERROR),
    ("compare-include-cycle", ["compare", "{d}/cycle_a.xml", "--out", "{o}/c", *CMP], ERROR),
    ("compare-reference-missing", ["compare", "{d}/dark.xml", "--out", "{o}/c", "--spp", "1",
                                   "--reference", "{d}/nope.exr"], ERROR),
    ("compare-reference-wrong-size", ["compare", "{d}/dark.xml", "--out", "{o}/c", "--spp", "1",
                                      "--reference", "{d}/small4.exr"], ERROR),
    ("compare-reference-truncated", ["compare", "{d}/dark.xml", "--out", "{o}/c", "--spp", "1",
                                     "--reference", "{d}/truncated.exr"], ERROR),
    ("compare-reference-text", ["compare", "{d}/dark.xml", "--out", "{o}/c", "--spp", "1",
                                "--reference", "{d}/text.exr"], ERROR),
    ("compare-out-is-file", ["compare", "{d}/dark.xml", "--out", "{d}/good.exr", *CMP], ERROR),
    ("compare-out-proc", ["compare", "{d}/dark.xml", "--out", "/proc/hostile", *CMP], ERROR),
    ("compare-out-unwritable", ["compare", "{d}/dark.xml", "--out", "{ro}/c", *CMP], ERROR),
    ("compare-spp-zero", ["compare", "{d}/dark.xml", "--out", "{o}/c", "--spp", "0"], ERROR),
    ("compare-spp-text", ["compare", "{d}/dark.xml", "--out", "{o}/c", "--spp", "a,b"], ERROR),
    ("compare-spp-too-many-samples", ["compare", "{d}/dark.xml", "--out", "{o}/c", "--spp", "100000000"], ERROR),
    ("compare-sampler-unknown", ["compare", "{d}/dark.xml", "--out", "{o}/c", "--samplers", "nope"], ERROR),
    ("compare-seeds-zero", ["compare", "{d}/dark.xml", "--out", "{o}/c", "--seeds", "0"], ERROR),
    ("compare-reference-spp-zero", ["compare", "{d}/dark.xml", "--out", "{o}/c", "--reference-spp", "0"], ERROR),
    # Regression (defect 1): a black scene's own reference and an all-NaN or all-zero reference aborted.
    ("compare-black-scene", ["compare", "{d}/dark.xml", "--out", "{o}/c", *CMP], OK),
    # a reference with NaN or +-inf made every error NaN, or failed after the sweep: refused.
    ("compare-nan-reference", ["compare", "{d}/dark.xml", "--out", "{o}/c", "--spp", "1", "--samplers", "grid",
                               "--no-progress", "--reference", "{d}/nan8.exr"], ERROR),
    ("compare-inf-reference", ["compare", "{d}/dark.xml", "--out", "{o}/c", "--spp", "1", "--samplers", "grid",
                               "--no-progress", "--reference", "{d}/inf8.exr"], ERROR),
    ("compare-zero-reference", ["compare", "{scenes}/default.xml", "-D", "res=8", "--out", "{o}/c", "--spp", "1",
                                "--samplers", "grid", "--no-progress", "--reference", "{d}/zero8.exr"], OK),
    # ------------------------------------------------------------------ post
    ("post-missing", ["post", "{d}/nope.exr", "-o", "{o}/x.png", "--steps", "gamma:2"], ERROR),
    ("post-folder", ["post", "{d}", "-o", "{o}/x.png", "--steps", "gamma:2"], ERROR),
    ("post-empty-exr", ["post", "{d}/empty.exr", "-o", "{o}/x.png", "--steps", "gamma:2"], ERROR),
    ("post-empty-png", ["post", "{d}/empty.png", "-o", "{o}/x.png", "--steps", "gamma:2"], ERROR),
    ("post-truncated-exr", ["post", "{d}/truncated.exr", "-o", "{o}/x.png", "--steps", "gamma:2"], ERROR),
    ("post-truncated-exr-header", ["post", "{d}/truncated_header.exr", "-o", "{o}/x.png", "--steps", "gamma:2"],
     ERROR),
    ("post-truncated-png", ["post", "{d}/truncated.png", "-o", "{o}/x.png", "--steps", "gamma:2"], ERROR),
    ("post-text-as-exr", ["post", "{d}/text.exr", "-o", "{o}/x.png", "--steps", "gamma:2"], ERROR),
    ("post-png-as-exr", ["post", "{d}/png_as.exr", "-o", "{o}/x.png", "--steps", "gamma:2"], ERROR),
    ("post-exr-as-png", ["post", "{d}/exr_as.png", "-o", "{o}/x.png", "--steps", "gamma:2"], ERROR),
    ("post-exr-huge-data-window", ["post", "{d}/hugewindow.exr", "-o", "{o}/x.png", "--steps", "gamma:2"], ERROR),
    ("post-exr-huge-attribute", ["post", "{d}/hugeattr.exr", "-o", "{o}/x.png", "--steps", "gamma:2"], ERROR),
    ("post-exr-no-rgb", ["post", "{d}/layers.exr", "-o", "{o}/x.png", "--steps", "gamma:2"], ERROR),
    ("post-no-output", ["post", "{d}/good.png", "--steps", "gamma:2"], ERROR),
    ("post-output-jpg", ["post", "{d}/good.png", "-o", "{o}/x.jpg", "--steps", "gamma:2"], ERROR),
    ("post-output-is-input", ["post", "{d}/good.png", "-o", "{d}/good.png", "--steps", "gamma:2"], ERROR),
    ("post-output-folder", ["post", "{d}/good.png", "-o", "{o}/sub.png", "--steps", "gamma:2"], ERROR),
    ("post-output-proc", ["post", "{d}/good.png", "-o", "/proc/hostile.png", "--steps", "gamma:2"], ERROR),
    ("post-output-unwritable", ["post", "{d}/good.png", "-o", "{ro}/x.png", "--steps", "gamma:2"], ERROR),
    ("post-plot-proc", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "gamma:2",
                        "--plot-file", "/proc/hostile.png"], ERROR),
    ("post-no-steps", ["post", "{d}/good.png", "-o", "{o}/x.png"], OK),  # a conversion
    ("post-no-steps-output-is-input", ["post", "{d}/good.png", "-o", "{d}/good.png"], ERROR),
    ("post-unknown-step", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "nope"], ERROR),
    ("post-step-syntax", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "gamma:=;;:"], ERROR),
    ("post-gamma-text", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "gamma:abc"], ERROR),
    ("post-gamma-negative", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "gamma:-1"], ERROR),
    ("post-gamma-nan", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "gamma:nan"], ERROR),
    ("post-gamma-inf", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "gamma:inf"], ERROR),
    ("post-resize-huge", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "resize:100000,100000"], ERROR),
    ("post-resize-zero", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "resize:0,4"], ERROR),
    ("post-resize-method", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "resize:4,4,lanczos"], ERROR),
    ("post-median-even", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "median:4"], ERROR),
    ("post-median-zero", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "median:0"], ERROR),
    ("post-median-31", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "median:31"], OK),  # took 25 s
    ("post-median-63", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "median:63"], OK),  # never ended
    ("post-median-9999", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "median:9999"], ERROR),
    ("post-median-larger-than-image", ["post", "{d}/one.png", "-o", "{o}/x.png", "--steps", "median:9,wrap"], OK),
    ("post-quantize-mode", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "quantize:4,round"], ERROR),
    ("post-normalize-ring", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "sobel;normalize:ring=-1"],
     ERROR),
    ("post-quantize-one", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "quantize:1"], ERROR),
    ("post-quantize-huge", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "quantize:1000000000"], ERROR),
    ("post-threshold-nan", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "threshold:nan"], ERROR),
    ("post-stretch-reversed", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "stretch:200,0,100,255"],
     ERROR),
    ("post-hsv-on-grey", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "hsv:hue=30"], ERROR),
    ("post-tonemap-on-png", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "tonemap:reinhard"], ERROR),
    ("post-tonemap-unknown", ["post", "{d}/good.exr", "-o", "{o}/x.png", "--steps", "tonemap:nope"], ERROR),
    ("post-tonemap-exposure-nan", ["post", "{d}/good.exr", "-o", "{o}/x.png", "--steps",
                                   "tonemap:reinhard,exposure=nan"], ERROR),
    ("post-correlate-kernel", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "correlate:nope"], ERROR),
    ("post-correlate-border", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "correlate:sobel_x,nope"],
     ERROR),
    ("post-lut-missing", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "lut:{d}/nope.txt"], ERROR),
    ("post-lut-empty", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "lut:{d}/empty.txt"], ERROR),
    ("post-lut-short", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "lut:{d}/short.txt"], ERROR),
    ("post-lut-nan", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "lut:{d}/nan.txt"], ERROR),
    ("post-dither-unknown", ["post", "{d}/good.png", "-o", "{o}/x.png", "--dither", "nope"], ERROR),
    ("post-dither-levels-one", ["post", "{d}/good.png", "-o", "{o}/x.png", "--dither", "ordered:levels=1"], ERROR),
    ("post-equalize-levels-zero", ["post", "{d}/good.png", "-o", "{o}/x.png", "--steps", "equalize:0"], ERROR),
    # defined results on non-finite and degenerate images
    ("post-nan-exr", ["post", "{d}/nan8.exr", "-o", "{o}/x.png", "--steps", "tonemap:reinhard;median:3;sobel",
                      "--dither", "floyd_steinberg"], OK),
    ("post-inf-exr", ["post", "{d}/inf8.exr", "-o", "{o}/x.png", "--steps",
                      "tonemap:aces;equalize;normalize;quantize:4", "--report"], OK),
    ("post-inf-exr-to-exr", ["post", "{d}/inf8.exr", "-o", "{o}/x.exr", "--steps", "tonemap:log;gamma:2.2"], OK),
    ("post-one-pixel", ["post", "{d}/one.png", "-o", "{o}/x.png", "--steps",
                        "sobel;median:3;laplacian;resize:3,2,bicubic;equalize", "--dither", "ordered"], OK),
    ("post-rgba", ["post", "{d}/rgba.png", "-o", "{o}/x.png", "--steps", "gamma:2.2"], OK),
    # ------------------------------------------------------------------ mip
    ("mip-missing", ["mip", "{d}/nope.npy", "-o", "{o}/x.png"], ERROR),
    ("mip-empty-folder", ["mip", "{d}/emptydir", "-o", "{o}/x.png"], ERROR),
    ("mip-not-dicom", ["mip", "{d}/notdicom", "-o", "{o}/x.png"], ERROR),
    ("mip-unknown-format", ["mip", "{d}/good.png", "-o", "{o}/x.png"], ERROR),
    ("mip-output-jpg", ["mip", "{d}/vol/ok.npy", "-o", "{o}/x.jpg"], ERROR),
    ("mip-output-proc", ["mip", "{d}/vol/ok.npy", "-o", "/proc/hostile.png", "--size", "8"], ERROR),
    ("mip-output-unwritable", ["mip", "{d}/vol/ok.npy", "-o", "{ro}/x.png", "--size", "8"], ERROR),
    ("mip-output-is-input", ["mip", "{d}/vol/ok.npy", "-o", "{d}/vol/ok.npy"], ERROR),
    ("mip-spacing-zero", ["mip", "{d}/vol/ok.npy", "-o", "{o}/x.png", "--spacing", "0,1,1"], ERROR),
    ("mip-spacing-negative", ["mip", "{d}/vol/ok.npy", "-o", "{o}/x.png", "--spacing", "-1,1,1"], ERROR),
    ("mip-spacing-nan", ["mip", "{d}/vol/ok.npy", "-o", "{o}/x.png", "--spacing", "nan,1,1"], ERROR),
    ("mip-spacing-two", ["mip", "{d}/vol/ok.npy", "-o", "{o}/x.png", "--spacing", "1,1"], ERROR),
    ("mip-spacing-anisotropic", ["mip", "{d}/vol/ok.npy", "-o", "{o}/x.png", "--spacing", "1e-20,1,1"], ERROR),
    ("mip-step-tiny", ["mip", "{d}/vol/ok.npy", "-o", "{o}/x.png", "--size", "32", "--step", "1e-7"], ERROR),
    ("mip-step-zero", ["mip", "{d}/vol/ok.npy", "-o", "{o}/x.png", "--step", "0"], ERROR),
    ("mip-size-zero", ["mip", "{d}/vol/ok.npy", "-o", "{o}/x.png", "--size", "0"], ERROR),
    ("mip-size-huge", ["mip", "{d}/vol/ok.npy", "-o", "{o}/x.png", "--size", "100000"], ERROR),
    ("mip-perspective-180", ["mip", "{d}/vol/ok.npy", "-o", "{o}/x.png", "--perspective", "180"], ERROR),
    ("mip-native-perspective", ["mip", "{d}/vol/ok.npy", "-o", "{o}/x.png", "--native-size",
                                "--perspective", "30"], ERROR),
    ("mip-native-oblique", ["mip", "{d}/vol/ok.npy", "-o", "{o}/x.png", "--native-size", "--azimuth", "30"], ERROR),
    ("mip-turntable-native", ["mip", "{d}/vol/ok.npy", "-o", "{o}/x.png", "--native-size", "--turntable", "4"],
     ERROR),
    ("mip-azimuth-nan", ["mip", "{d}/vol/ok.npy", "-o", "{o}/x.png", "--azimuth", "nan"], ERROR),
    ("mip-window-text", ["mip", "{d}/vol/ok.npy", "-o", "{o}/x.png", "--window", "abc"], ERROR),
    ("mip-window-zero-width", ["mip", "{d}/vol/ok.npy", "-o", "{o}/x.png", "--window", "40,0"], ERROR),
    ("mip-colormap-unknown", ["mip", "{d}/vol/ok.npy", "-o", "{o}/x.png", "--colormap", "nope"], ERROR),
    ("mip-background-inf", ["mip", "{d}/vol/ok.npy", "-o", "{o}/x.png", "--background", "inf"], ERROR),
    # defined results
    ("mip-all-nan", ["mip", "{d}/vol/allnan.npy", "-o", "{o}/x.png", "--size", "8"], OK),
    ("mip-inf", ["mip", "{d}/vol/inf.npy", "-o", "{o}/x.exr", "--size", "8", "--azimuth", "20"], OK),
    ("mip-one-voxel", ["mip", "{d}/vol/one.npy", "-o", "{o}/x.png", "--size", "4", "--mode", "average"], OK),
    ("mip-flat-vol-box", ["mip", "{d}/vol/flatbox.vol", "-o", "{o}/x.png", "--size", "8"], OK),
    # Regression (defect 6): a uniform spacing must not change the projection (checked below).
    ("mip-spacing-1", ["mip", "{d}/vol/ok.npy", "-o", "{o}/x.exr", "--size", "16", "--azimuth", "30",
                       "--elevation", "20"], OK),
    ("mip-spacing-1e-10", ["mip", "{d}/vol/ok.npy", "-o", "{o}/x.exr", "--size", "16", "--azimuth", "30",
                           "--elevation", "20", "--spacing", "1e-10,1e-10,1e-10"], OK),
    ("mip-spacing-1e-20", ["mip", "{d}/vol/ok.npy", "-o", "{o}/x.exr", "--size", "16", "--azimuth", "30",
                           "--elevation", "20", "--spacing", "1e-20,1e-20,1e-20"], OK),
    ("mip-spacing-1e30", ["mip", "{d}/vol/ok.npy", "-o", "{o}/x.exr", "--size", "16", "--azimuth", "30",
                          "--elevation", "20", "--spacing", "1e30,1e30,1e30"], OK),
]

#: Malformed volume files: each one case of ``mip`` expecting an error.
BAD_VOLUMES = ["empty.npy", "text.npy", "truncated.npy", "hugeheader.npy", "flat.npy", "four.npy", "object.npy",
               "complex.npy", "strings.npy", "empty.vol", "hugedims.vol", "negdims.vol", "zerodims.vol",
               "encoding.vol", "channels.vol", "short.vol", "empty.nrrd", "bad.nrrd", "huge.nrrd", "gzip.nrrd",
               "empty.nii", "text.nii.gz"]
CASES += [(f"mip-file-{name}", ["mip", f"{{d}}/vol/{name}", "-o", "{o}/x.png", "--size", "8"], ERROR)
          for name in BAD_VOLUMES]


# ------------------------------------------------------------------------------ the inputs
def _write(path: Path, data: bytes | str) -> None:
    path.write_bytes(data.encode() if isinstance(data, str) else data)


def _scene(body: str, film: str = '<film type="hdrfilm"><integer name="width" value="8"/>'
           '<integer name="height" value="8"/></film>', sensor: bool = True) -> str:
    camera = (f'<sensor type="perspective">{film}<sampler type="independent">'
              '<integer name="sample_count" value="2"/></sampler></sensor>') if sensor else ""
    return f'<scene version="3.0.0"><integrator type="path"/>{camera}{body}</scene>'


def _vol(path: Path, res, channels=1, encoding=1, payload=b"", bbox=(0, 0, 0, 1, 1, 1)) -> None:
    header = (b"VOL" + bytes([3]) + struct.pack("<i", encoding) + struct.pack("<3i", *res)
              + struct.pack("<i", channels) + struct.pack("<6f", *bbox))
    path.write_bytes(header + payload)


def make_inputs(d: Path) -> None:
    """Write every hostile input file into ``d``."""
    from PIL import Image

    from pointillist.imaging.io import write_exr

    rng = np.random.default_rng(17)
    # scenes
    _write(d / "empty.xml", "")
    _write(d / "binary.xml", bytes(range(256)) * 4)
    good = _scene('<shape type="sphere"><emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>')
    _write(d / "truncated.xml", good[: len(good) // 2])
    _write(d / "nosensor.xml", _scene('<shape type="sphere"/>', sensor=False))
    _write(d / "dark.xml", _scene('<shape type="sphere"/>'))
    _write(d / "cycle_a.xml", '<scene version="3.0.0"><include filename="cycle_b.xml"/></scene>')
    _write(d / "cycle_b.xml", '<scene version="3.0.0"><include filename="cycle_a.xml"/></scene>')
    _write(d / "badplugin.xml", _scene('<shape type="sphere"><bsdf type="no_such_bsdf"/></shape>'))
    _write(d / "hugeattr.xml", _scene(f'<shape type="sphere"><float name="radius" value="{"9" * 1_000_000}"/>'
                                      '</shape>'))
    # images
    _write(d / "empty.exr", b"")
    _write(d / "empty.png", b"")
    _write(d / "text.exr", "not an image\n" * 10)
    write_exr(d / "good.exr", rng.random((8, 8, 3)).astype(np.float32))
    write_exr(d / "small4.exr", np.ones((4, 4, 3), np.float32))
    write_exr(d / "nan8.exr", np.full((8, 8, 3), np.nan, np.float32))
    write_exr(d / "zero8.exr", np.zeros((8, 8, 3), np.float32))
    inf = rng.random((8, 8, 3)).astype(np.float32)
    inf[0, 0], inf[1, 1], inf[2, 2] = np.inf, -np.inf, np.nan
    write_exr(d / "inf8.exr", inf)
    big = d / "big.exr"
    write_exr(big, rng.random((64, 64, 3)).astype(np.float32))
    data = big.read_bytes()
    _write(d / "truncated.exr", data[: len(data) // 8])
    _write(d / "truncated_header.exr", data[:200])
    big.unlink()
    window = b"dataWindow\x00box2i\x00"
    small = (d / "small4.exr").read_bytes()
    at = small.index(window) + len(window)
    _write(d / "hugewindow.exr", small[:at + 4] + struct.pack("<4i", 0, 0, 2**30, 2**30) + small[at + 20:])
    _write(d / "hugeattr.exr", small[:at] + struct.pack("<i", 2**31 - 1) + small[at + 4:])
    import OpenEXR

    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                      {"U": np.zeros((4, 4), np.float32), "V": np.zeros((4, 4), np.float32)}) as exr:
        exr.write(str(d / "layers.exr"))
    Image.fromarray((rng.random((8, 8)) * 255).astype(np.uint8)).save(d / "good.png")
    png = (d / "good.png").read_bytes()
    _write(d / "truncated.png", png[: len(png) // 2])
    _write(d / "png_as.exr", png)
    _write(d / "exr_as.png", small)
    Image.fromarray(np.full((1, 1), 77, np.uint8)).save(d / "one.png")
    rgba = np.zeros((8, 8, 4), np.uint8)
    rgba[..., 0], rgba[..., 3] = 200, 128
    Image.fromarray(rgba, "RGBA").save(d / "rgba.png")
    # look-up tables
    _write(d / "empty.txt", "")
    _write(d / "short.txt", "1 2 3\n")
    _write(d / "nan.txt", "\n".join(["nan"] + ["1"] * 255))
    # folders and volumes
    (d / "emptydir").mkdir()
    (d / "notdicom").mkdir()
    _write(d / "notdicom" / "a.dcm", "not DICOM")
    v = d / "vol"
    v.mkdir()
    ramp = np.arange(8 * 8 * 8, dtype=np.float32).reshape(8, 8, 8)
    np.save(v / "ok.npy", ramp)
    ok = (v / "ok.npy").read_bytes()
    _write(v / "empty.npy", b"")
    _write(v / "text.npy", "garbage\n")
    _write(v / "truncated.npy", ok[: len(ok) // 2])
    _write(v / "hugeheader.npy", ok.replace(b"(8, 8, 8)", b"(99999999, 99999999, 9)"))
    np.save(v / "flat.npy", np.zeros((4, 4)))
    np.save(v / "four.npy", np.zeros((2, 2, 2, 2)))
    np.save(v / "object.npy", np.array([[[None]]], dtype=object), allow_pickle=True)
    np.save(v / "complex.npy", np.zeros((2, 2, 2), complex))
    np.save(v / "strings.npy", np.full((2, 2, 2), "a"))
    np.save(v / "allnan.npy", np.full((8, 8, 8), np.nan, np.float32))
    infs = ramp.copy()
    infs[0, 0, 0], infs[1, 1, 1], infs[2, 2, 2] = np.inf, -np.inf, np.nan
    np.save(v / "inf.npy", infs)
    np.save(v / "one.npy", np.ones((1, 1, 1), np.float32))
    _write(v / "empty.vol", b"")
    _vol(v / "hugedims.vol", (2**30, 2**30, 2**30))
    _vol(v / "negdims.vol", (-1, 4, 4))
    _vol(v / "zerodims.vol", (0, 4, 4))
    _vol(v / "encoding.vol", (2, 2, 2), encoding=7, payload=b"\0" * 32)
    _vol(v / "channels.vol", (2, 2, 2), channels=3, payload=b"\0" * 96)
    _vol(v / "short.vol", (4, 4, 4), payload=b"\0" * 10)
    _vol(v / "flatbox.vol", (2, 2, 2), payload=np.arange(8, dtype=np.float32).tobytes(), bbox=(0, 0, 0, 0, 0, 0))
    _write(v / "empty.nrrd", b"")
    _write(v / "bad.nrrd", "NRRD0004\ntype: float\ndimension: 3\nsizes: 2 2\nencoding: raw\n\n")
    _write(v / "huge.nrrd", "NRRD0004\ntype: float\ndimension: 3\nsizes: 100000 100000 100000\n"
                            "endian: little\nencoding: raw\n\n")
    _write(v / "gzip.nrrd", "NRRD0004\ntype: float\ndimension: 3\nsizes: 4 4 4\nendian: little\n"
                            "encoding: gzip\n\nxxxx")
    _write(v / "empty.nii", b"")
    _write(v / "text.nii.gz", "not gzip")


def _unwritable(path: Path) -> bool:
    """Make ``path`` a folder nobody can create files in (immutable as root, mode 555 otherwise);
    True when that worked."""
    path.mkdir()
    path.chmod(0o555)
    if os.geteuid() == 0 and shutil.which("chattr"):
        subprocess.run(["chattr", "+i", str(path)], capture_output=True)
    try:
        (path / "probe").write_text("x")
    except OSError:
        return True
    (path / "probe").unlink()
    return False


def _snapshot(folder: Path) -> dict[str, tuple[int, int]]:
    return {str(p.relative_to(folder)): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def hostile(tmp_path_factory):
    """Run every case of :data:`CASES` through the driver; returns
    ``(results by id, output folder by id, input snapshot before, after, unwritable folder ok)``."""
    root = tmp_path_factory.mktemp("hostile")
    d, outs = root / "in", root / "out"
    d.mkdir()
    outs.mkdir()
    make_inputs(d)
    ro = root / "readonly"
    ro_ok = _unwritable(ro)
    before = _snapshot(d)
    cases, folders = [], {}
    for name, argv, _ in CASES:
        folder = outs / name
        folder.mkdir()
        (folder / "sub.exr").mkdir() if name == "render-output-folder" else None
        (folder / "sub.png").mkdir() if name == "post-output-folder" else None
        folders[name] = folder
        cases.append({"id": name, "argv": [a.format(d=d, o=folder, ro=ro, scenes=SCENES) for a in argv]})
    (root / "cases.json").write_text(json.dumps(cases))
    results_path = root / "results.jsonl"
    env = {k: v for k, v in os.environ.items() if k != "POINTILLIST_DEBUG"}
    try:
        subprocess.run([sys.executable, str(DRIVER), str(root / "cases.json"), str(results_path)], cwd=root,
                       env=env, timeout=DRIVER_TIMEOUT, capture_output=True)
    except subprocess.TimeoutExpired:
        pass  # the unfinished cases fail below
    finally:
        if ro_ok and os.geteuid() == 0 and shutil.which("chattr"):
            subprocess.run(["chattr", "-i", str(ro)], capture_output=True)
        ro.chmod(0o755)
    results = {}
    for line in results_path.read_text().splitlines() if results_path.exists() else []:
        entry = json.loads(line)
        results[entry["id"]] = entry
    return results, folders, before, _snapshot(d), ro_ok


def _leftovers(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*")
                  if p.name not in ("sub.exr", "sub.png"))


@pytest.mark.parametrize("name, argv, expect", CASES, ids=[c[0] for c in CASES])
def test_hostile_case(hostile, name, argv, expect):
    results, folders, _, _, ro_ok = hostile
    if "{ro}" in " ".join(argv) and not ro_ok:
        pytest.skip("no folder could be made unwritable here")
    result = results.get(name)
    assert result is not None, f"{name}: the driver never reached this case (an abort or a hang before it)"
    assert "rc" in result, f"{name}: started but did not finish within {DRIVER_TIMEOUT} s (a hang or an abort)"
    stderr = result["stderr"]
    assert "Traceback" not in stderr and "Traceback" not in result["stdout"], stderr
    assert not str(result["rc"]).startswith("escaped"), stderr
    if expect == ERROR:
        assert result["rc"] == 2, (result["rc"], stderr)
        lines = stderr.splitlines()
        assert len(lines) == 1 and lines[0].strip(), f"expected one line on stderr, got {stderr!r}"
        assert lines[0].startswith("pointillist"), lines[0]
        assert len(lines[0]) <= 600, f"a {len(lines[0])}-character error line"
        assert _leftovers(folders[name]) == [], "a refused command left files behind"
    else:
        assert result["rc"] == 0, (result["rc"], stderr)
        assert not [p for p in _leftovers(folders[name]) if ".tmp" in p], "a temporary file was left behind"


def test_hostile_inputs_untouched(hostile):
    """No case wrote into, or over, the folder of inputs."""
    _, _, before, after, _ = hostile
    assert after == before


def test_hostile_flip_and_filter(hostile):
    """A black scene (its own reference) and an all-zero reference: every row gets a finite FLIP
    (defect 1: these aborted with exit 134; an all-NaN one is refused now), and the
    output and results.md say which film filter the scene uses (only a box filter is the course's
    plain average)."""
    import csv

    results, folders, *_ = hostile
    for name in ("compare-black-scene", "compare-zero-reference"):
        with open(folders[name] / "c" / "results.csv") as handle:
            rows = list(csv.DictReader(handle))
        assert rows and all(np.isfinite(float(row["flip"])) for row in rows), rows
    assert "film filter: GaussianFilter[stddev=0.50, radius=2.00]: a pixel is a weighted sum" in \
        results["compare-black-scene"]["stdout"]
    assert "film filter: BoxFilter[] (box: each pixel is the plain average of its samples)" in \
        (folders["compare-zero-reference"] / "c" / "results.md").read_text()


def test_hostile_mip_uniform_spacing(hostile):
    """Scaling the spacing uniformly does not change the projection (defect 6: 1e-10 gave wrong
    values, 1e-20 ran for minutes)."""
    from pointillist.imaging.io import read_exr

    _, folders, *_ = hostile
    reference = read_exr(folders["mip-spacing-1"] / "x.exr").image
    assert np.isfinite(reference).all() and reference.max() > 500  # the ramp's voxels reach 511
    for name in ("mip-spacing-1e-10", "mip-spacing-1e-20", "mip-spacing-1e30"):
        image = read_exr(folders[name] / "x.exr").image
        np.testing.assert_allclose(image, reference, rtol=1e-4, atol=1e-3, err_msg=name)


def test_hostile_include_cycle_is_short(hostile):
    results, *_ = hostile
    line = results["render-include-cycle"]["stderr"].strip()
    assert "nested <include>s of cycle_b.xml, cycle_a.xml" in line and "recursion depth" in line
    assert len(line) < 400


def test_hostile_rgba_alpha_is_said(hostile):
    results, *_ = hostile
    assert "alpha channel is dropped" in results["post-rgba"]["stderr"]


# ------------------------------------------------------------------------------ own processes
_SIGNAL_DRIVER = textwrap.dedent("""
    import os, signal, sys, time
    from PIL import Image
    from pointillist.console import main

    SIGNAL, COUNT = getattr(signal, sys.argv[1]), int(sys.argv[2])

    def save(self, fp, *args, **kwargs):  # the signals land in the middle of the write
        with open(fp, "w") as handle:
            handle.write("first half, ")
            for _ in range(COUNT):
                os.kill(os.getpid(), SIGNAL)
                time.sleep(0.3)
            handle.write("second half")

    Image.Image.save = save
    sys.argv = ["pointillist"] + sys.argv[3:]
    main()
""")


@pytest.mark.parametrize("name, status, word", [("SIGTERM", 143, "terminated"), ("SIGINT", 130, "interrupted")])
@pytest.mark.parametrize("count", [1, 2], ids=["one-signal", "two-signals"])
def test_signal_during_write_leaves_no_file(tmp_path, name, status, word, count):
    """Defect 7: SIGTERM (like Ctrl-C) during a write exits 143 (130) with one line and no
    temporary file. a signal is only recorded where it lands, so the write in flight
    completes (the file is whole, never cut) and the command stops after it; a second signal ends
    the process at once: the temporary file is removed and nothing is written."""
    from PIL import Image

    source = tmp_path / "in.png"
    Image.fromarray(np.arange(64, dtype=np.uint8).reshape(8, 8)).save(source)
    out = tmp_path / "out"
    out.mkdir()
    done = subprocess.run([sys.executable, "-c", _SIGNAL_DRIVER, name, str(count), "post", str(source), "-o",
                           str(out / "x.png"), "--steps", "gamma:2"], capture_output=True, text=True, timeout=120)
    assert done.returncode == status, done.stderr
    line = f"pointillist post: {word}" + (" (SIGTERM)" if status == 143 else "")
    if count == 1:
        assert done.stderr.splitlines() == [line]
        assert [(p.name, p.read_text()) for p in out.iterdir()] == [("x.png", "first half, second half")]
    else:
        assert done.stderr.splitlines() == [line + "; stopped at once (second signal)"]
        assert list(out.iterdir()) == []


def test_flip_never_aborts_the_process():
    """Defect 1 at the API: flip-evaluator exits the process when its exposure range is empty (a
    black, NaN, negative, constant or nearly black reference: max luminance below FLT_EPSILON, even
    in one pixel); every such reference now gets a finite FLIP. In a process of its own: a
    regression would end it."""
    code = textwrap.dedent("""
        import math
        import numpy as np
        from pointillist.imaging.metrics import FLIP_MIN_LUMINANCE, image_errors
        image = np.full((8, 8, 3), 0.5, np.float32)
        pixel = np.zeros((8, 8, 3)); pixel[2, 2] = 1e-30
        blue = np.zeros((8, 8, 3)); blue[2, 2, 2] = FLIP_MIN_LUMINANCE / 0.0722 * 0.9
        for name, ref in [("zeros", np.zeros((8, 8, 3))), ("nan", np.full((8, 8, 3), np.nan)),
                          ("negative", np.full((8, 8, 3), -1.0)), ("tiny", np.full((8, 8, 3), 1e-30)),
                          ("-inf", np.full((8, 8, 3), -np.inf)), ("one tiny pixel", pixel),
                          ("blue under the bound", blue), ("constant 1e-7", np.full((8, 8, 3), 1e-7)),
                          ("constant 0.3", np.full((8, 8, 3), 0.3)), ("grey zeros", np.zeros((8, 8)))]:
            errors = image_errors(image if ref.ndim == 3 else image[..., 0], ref)
            assert math.isfinite(errors["flip"]) and 0 <= errors["flip"] <= 1, (name, errors)
        print("ok")
    """)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr[-2000:]


def test_one_line_from_a_real_process(tmp_path):
    """The console entry point itself: a scene without a sensor (defect 2) is one line, exit 2,
    with nothing on stdout (Mitsuba's log included)."""
    scene = tmp_path / "nosensor.xml"
    scene.write_text(_scene('<shape type="sphere"/>', sensor=False))
    done = subprocess.run([sys.executable, "-m", "pointillist", "render", str(scene), "-o", str(tmp_path / "x.exr")],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert done.returncode == 2
    assert done.stderr == f"pointillist render: error: scene {scene}: has no <sensor> (a camera to render from)\n"
    assert done.stdout == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == ["nosensor.xml"]


# ------------------------------------------------------------------------------ API
def test_resize_refuses_huge_sizes_up_front():
    """Defect 5: Dr.Jit's raw jit_var_counter error became a ValueError naming the limit."""
    from pointillist.imaging.resample import MAX_RESIZE_VALUES, resize

    for image, size, method in [((4, 4), (100_000, 100_000), "bilinear"), ((4, 4, 3), (40_000, 40_000), "nearest"),
                                ((30_000, 4, 3), (30_000, 2), "bicubic")]:
        with pytest.raises(ValueError, match=r"size: .* values, more than one resize produces \(2147483647"):
            resize(np.zeros(image, np.float32), size, method)
    assert MAX_RESIZE_VALUES == 2**31 - 1
    assert np.asarray(resize(np.ones((2, 2), np.float32), (3, 1), "nearest")).tolist() == [[1.0, 1.0, 1.0]]


def test_atomic_write_cleans_up_and_names_the_path(tmp_path):
    from pointillist.core.files import atomic_write

    def fail(tmp):
        Path(tmp).write_text("half")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        atomic_write(tmp_path / "x.txt", fail)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(OSError, match="cannot write /proc/hostile.txt") as caught:
        atomic_write("/proc/hostile.txt", lambda tmp: None)
    assert caught.value.filename == "/proc/hostile.txt"


def test_mitsuba_message_collapses_include_chains():
    from pointillist.scene import MAX_MESSAGE, mitsuba_message

    link = "Error while loading /s/{} (line 2, col 4): while processing <include>: "
    text = "".join(link.format("a.xml" if i % 2 == 0 else "b.xml") for i in range(15))
    line = mitsuba_message(RuntimeError(text + "Exceeded maximum include recursion depth of 15"))
    assert line == (link.format("a.xml") + "[14 nested <include>s of b.xml, a.xml] Exceeded maximum include "
                    "recursion depth of 15")
    assert mitsuba_message(RuntimeError("x" * 5000)) == "x" * (MAX_MESSAGE - 3) + "..."
    assert mitsuba_message(RuntimeError("[xml.cpp:12] plain\n  second")) == "plain second"


def test_normalised_volume_is_exact_and_leaves_plain_volumes():
    from pointillist.imaging.volumes import Volume
    from pointillist.mip import normalised_volume

    plain = Volume(np.zeros((4, 4, 4)), (0.5, 0.5, 2.0))
    assert normalised_volume(plain) is plain
    tiny = normalised_volume(Volume(np.zeros((4, 4, 4)), (1e-10, 1e-10, 3e-10)))
    assert 64 <= max(tiny.extent) < 128
    scale = tiny.spacing[0] / 1e-10
    assert scale == 2.0 ** round(np.log2(scale))  # a power of two: exact
    assert tiny.spacing == (1e-10 * scale, 1e-10 * scale, 3e-10 * scale)


def test_median_large_windows_and_windows_larger_than_the_image():
    """Defect 4: a 31x31 median took 25 s, 63x63 never finished (the sorting network is compiled for
    the whole window). Above 9x9 radix selection takes over: it agrees with numpy (np.pad + median of
    every window) for float and 8-bit data, every border and windows larger than the image (there
    scipy's ``reflect`` stops repeating the reflection: 31x31 on 3x4 differs); past
    MEDIAN_MAX_LOADS a ValueError names the bound."""
    from numpy.lib.stride_tricks import sliding_window_view
    from scipy import ndimage

    from pointillist.imaging.filters import MEDIAN_MAX_LOADS, MEDIAN_NETWORK_MAX_SIZE, median

    def reference(img, size, mode):
        r = size // 2
        planes = img[..., None] if img.ndim == 2 else img
        out = [np.median(sliding_window_view(np.pad(planes[..., c], r, mode=mode), (size, size)), axis=(-2, -1))
               for c in range(planes.shape[2])]
        return np.stack(out, axis=-1).reshape(img.shape).astype(np.float32)

    rng = np.random.default_rng(4)
    modes = {"clamp": "edge", "reflect": "symmetric", "mirror": "reflect", "wrap": "wrap", "constant": "constant"}
    for img in ((rng.standard_normal((9, 12)) * 100).astype(np.float32),          # float keys (32 bits)
                rng.integers(0, 256, (10, 7, 3)).astype(np.float32),              # 8-bit values (8 bits)
                rng.random((3, 4)).astype(np.float32)):                           # smaller than the windows
        for size in (MEDIAN_NETWORK_MAX_SIZE + 2, 13, 31):
            for border, mode in modes.items():
                np.testing.assert_array_equal(np.asarray(median(img, size, border=border)),
                                              reference(img, size, mode), err_msg=f"{img.shape} {size} {border}")
    img = (rng.standard_normal((20, 18)) * 100).astype(np.float32)
    np.testing.assert_array_equal(np.asarray(median(img, 11, border="reflect")),
                                  ndimage.median_filter(img, size=11, mode="reflect"))   # scipy where it repeats
    img = rng.integers(0, 256, (16, 16)).astype(np.float32)
    r = 5
    ring = np.ones(img.shape, bool)
    ring[r:-r, r:-r] = False
    inner = ndimage.median_filter(img, size=11, mode="nearest")
    zero, keep = np.asarray(median(img, 11, border="zero")), np.asarray(median(img, 11, border="keep"))
    np.testing.assert_array_equal(zero[~ring], inner[~ring])
    assert (zero[ring] == 0).all() and np.array_equal(keep[ring], img[ring])
    np.testing.assert_array_equal(np.asarray(median(img, 11, border="crop")), inner[r:-r, r:-r])
    with pytest.raises(ValueError, match="nothing is left"):
        median(img, 17, border="crop")
    with pytest.raises(ValueError, match="MEDIAN_MAX_LOADS"):
        median(np.zeros((64, 64), np.float32), 2 * int((MEDIAN_MAX_LOADS / 32 / 4096) ** 0.5) + 1)
