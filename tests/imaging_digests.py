"""Digest of what every imaging operation, post step, volume reader and MIP view outputs.

A refactoring check: run it on two checkouts (this one, and e.g. ``git archive`` of an older
commit unpacked in a folder) and compare; every output must be byte-identical. Inputs are
scikit-image's photographs (``camera``, ``astronaut``, cropped), seeded noise (display values,
HDR values with NaN/inf), a Shepp-Logan phantom and nibabel's and pydicom's test files.

Usage (from the repository root)::

    .venv/bin/python tests/imaging_digests.py -o /tmp/after.json
    .venv/bin/python tests/imaging_digests.py --root /tmp/before -o /tmp/before.json
    .venv/bin/python tests/imaging_digests.py --compare /tmp/before.json /tmp/after.json

``--root DIR`` imports ``pointillist`` (and its ``imaging`` and ``plugins`` folders) from DIR
instead of this checkout. Each output is recorded as its dtype, shape and the SHA-256 of its
bytes; an error is recorded as its type and message (so a changed message shows too). Exit
status of ``--compare``: 1 when an entry differs or is missing on one side.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import importlib.abc
import importlib.util
import json
import sys
import tempfile
import warnings
from pathlib import Path


class _TreeFinder(importlib.abc.MetaPathFinder):
    """Import ``pointillist``, ``pointillist.imaging`` and ``pointillist.plugins`` from a checkout."""

    def __init__(self, root: Path):
        self.packages = {"pointillist": root / "pointillist", "pointillist.imaging": root / "imaging",
                         "pointillist.plugins": root / "plugins"}

    def find_spec(self, fullname, path, target=None):
        folder = self.packages.get(fullname)
        if folder is None:
            return None
        return importlib.util.spec_from_file_location(fullname, folder / "__init__.py",
                                                      submodule_search_locations=[str(folder)])


def _digest(value) -> object:
    import numpy as np

    if isinstance(value, tuple) and not hasattr(value, "shape"):
        return [_digest(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _digest(v) for k, v in sorted(value.items(), key=lambda kv: str(kv[0]))}
    if isinstance(value, (bool, int, float, str)) or value is None:
        return repr(value)
    if dataclasses.is_dataclass(value):
        return {f.name: _digest(getattr(value, f.name)) for f in dataclasses.fields(value)}
    array = np.ascontiguousarray(np.asarray(value))
    if array.dtype == object:
        raise TypeError(f"no digest for {type(value).__name__}")
    return f"{array.dtype} {array.shape} {hashlib.sha256(array.tobytes()).hexdigest()[:24]}"


def _cases(tmp: Path):
    """``(name, thunk)`` for every output compared."""
    import numpy as np
    from skimage import data

    from pointillist.imaging import colour, dither, filters, flip, io, metrics, resample, spectrum, tone, window
    from pointillist.imaging import volumes

    camera = data.camera()[128:320, 96:352]                       # (192, 256) uint8
    astronaut = data.astronaut()[0:160, 100:300]                   # (160, 200, 3) uint8
    rng = np.random.default_rng(28)
    noise = (rng.random((96, 128)) * 255).astype(np.float32)
    noise_rgb = (rng.random((64, 80, 3)) * 255).astype(np.float32)
    hdr = rng.lognormal(0.0, 2.0, (64, 80, 3)).astype(np.float32)
    hdr[3, 4, 0], hdr[10, 11, 1], hdr[20, 2, 2] = np.nan, np.inf, -np.inf
    grey_f = camera.astype(np.float32)
    rgb_f = astronaut.astype(np.float32)
    images = {"camera": camera, "camera_f": grey_f, "astronaut": astronaut, "astronaut_f": rgb_f,
              "noise": noise, "noise_rgb": noise_rgb}

    cases = []

    def add(name, thunk):
        cases.append((name, thunk))

    for key, image in images.items():
        add(f"tone.gamma/{key}", lambda image=image: tone.gamma(image, 2.2))
        add(f"tone.gamma_a/{key}", lambda image=image: tone.gamma(image, 0.45, 0.9))
        add(f"tone.contrast_stretch/{key}", lambda image=image: tone.contrast_stretch(image, 50, 20, 200, 235))
        add(f"tone.contrast_stretch_step/{key}", lambda image=image: tone.contrast_stretch(image, 100, 0, 100, 255))
        add(f"tone.quantize/{key}", lambda image=image: tone.quantize(image, 5))
        add(f"tone.quantize_bins/{key}", lambda image=image: tone.quantize(image, 7, mode="bins"))
        add(f"tone.lut/{key}", lambda image=image: tone.lut(image, (np.arange(256) ** 1.5) / 16.0))
        add(f"tone.histogram/{key}", lambda image=image: tone.histogram(image))
        add(f"tone.histogram64/{key}", lambda image=image: tone.histogram(image, 64))
        add(f"tone.dynamic_range/{key}", lambda image=image: tone.dynamic_range(image))
        add(f"tone.equalize/{key}", lambda image=image: tone.equalize_histogram(image))
        add(f"tone.equalize16/{key}", lambda image=image: tone.equalize_histogram(image, 16))
        for method in dither.DITHER_METHODS:
            add(f"dither.{method}/{key}", lambda image=image, method=method: dither.dither(image, method))
        add(f"dither.fs_levels/{key}", lambda image=image: dither.floyd_steinberg(image, 100, True, levels=4))
        add(f"dither.fs_linear/{key}", lambda image=image: dither.floyd_steinberg(image, linear=True))
        add(f"dither.jjn_serp/{key}", lambda image=image: dither.diffuse(image, "jarvis_judice_ninke", serpentine=True,
                                                                         levels=3))
        add(f"dither.ed_linear/{key}", lambda image=image: dither.error_diffusion(image, levels=3, linear=True))
        add(f"dither.ordered_cd/{key}", lambda image=image: dither.ordered(image, dither.clustered_dot(5), levels=3))
        add(f"dither.ordered_lin/{key}", lambda image=image: dither.ordered(image, dither.bayer(8), linear=True))
        add(f"dither.pattern_l/{key}", lambda image=image: dither.pattern(image, dither.bayer(2), levels=4))
        add(f"dither.blue_l/{key}", lambda image=image: dither.blue_noise(image, levels=3, linear=True))
        add(f"dither.halftone4/{key}", lambda image=image: dither.halftone(image, 4, template=dither.bayer(4)))
        add(f"dither.error/{key}", lambda image=image: dither.dither_error(image, dither.floyd_steinberg(image)))
        add(f"filters.threshold/{key}", lambda image=image: filters.threshold(image, 100))
        add(f"filters.median5/{key}", lambda image=image: filters.median(image, 5))
        for border in filters.BORDERS:
            add(f"filters.sobel.{border}/{key}", lambda image=image, border=border: filters.sobel(image, border=border))
        for kernel in filters.KERNELS:
            add(f"filters.correlate.{kernel}/{key}",
                lambda image=image, kernel=kernel: filters.correlate(image, kernel, border="reflect", normalize=True))
        add(f"filters.prewitt_c/{key}", lambda image=image: tuple(filters.gradient(image, "prewitt"))
            if hasattr(filters, "gradient") else filters.prewitt(image, components=True))  # its name before
        add(f"filters.laplacian/{key}", lambda image=image: filters.laplacian(image, border="mirror"))
        add(f"filters.zero_crossings/{key}",
            lambda image=image: filters.zero_crossings(filters.laplacian(image), connectivity=4))
        add(f"filters.normalize/{key}", lambda image=image: filters.normalize(image, absolute=False, ring=1))
        for method in resample.INTERPOLATIONS:
            add(f"resample.resize.{method}/{key}",
                lambda image=image, method=method: resample.resize(image, (77, 53), method))
        add(f"resample.sample/{key}", lambda image=image: resample.sample(
            image, np.linspace(-2, 300, 50), np.linspace(-3, 200, 50), "bicubic", a=-0.75, clamp=True))
        add(f"io.to_8bit/{key}", lambda image=image: io.to_8bit(image, max_value=255.0))
        add(f"window.window_image/{key}", lambda image=image: window.window_image(
            np.asarray(image, dtype=np.float32), 100.0, 150.0, window.colormap_lut("viridis")))
        add(f"spectrum.radial/{key}", lambda image=image: spectrum.radial_power_spectrum(
            np.asarray(image, dtype=np.float64)[..., 0] if np.ndim(image) == 3 else image))
    for key, image in {"astronaut": astronaut, "astronaut_f": rgb_f, "noise_rgb": noise_rgb}.items():
        add(f"colour.hsv/{key}", lambda image=image: colour.rgb_to_hsv(image, max_value=255.0))
        add(f"colour.hsv_back/{key}", lambda image=image: colour.hsv_to_rgb(colour.rgb_to_hsv(image, max_value=255.0),
                                                                            max_value=255.0))
        add(f"colour.adjust/{key}", lambda image=image: colour.adjust_hsv(image, hue=30, saturation=1.2, value=0.9,
                                                                          max_value=255.0))
        add(f"colour.luminance/{key}", lambda image=image: colour.luminance(image, max_value=255.0))
    for operator in tone.TONEMAP_OPERATORS:
        add(f"tone.tonemap.{operator}", lambda operator=operator: tone.tonemap(hdr, operator, 0.5))
        if "white" in tone.TONEMAP_OPERATORS[operator]:
            add(f"tone.tonemap.{operator}.white", lambda operator=operator: tone.tonemap(hdr[..., 0], operator, -1,
                                                                                         white=3.0))
    add("colour.srgb_encode", lambda: colour.srgb_encode(hdr))
    add("colour.srgb_decode", lambda: colour.srgb_decode(hdr / 10))
    add("dither.bayer16", lambda: dither.bayer(16))
    add("dither.clustered_dot7", lambda: dither.clustered_dot(7))
    add("dither.intensity_thresholds", lambda: dither.intensity_thresholds(dither.bayer(8)))
    add("dither.blue_noise_mask", lambda: dither.blue_noise_mask())
    add("dither.void_and_cluster", lambda: dither.void_and_cluster(16, sigma=1.2, seed=3))
    reference = rgb_f / 255.0
    test = np.clip(reference + rng.normal(0, 0.05, reference.shape).astype(np.float32), 0, 1)
    add("flip.ldr", lambda: flip.flip(test, reference, dynamic_range="ldr"))
    add("flip.hdr", lambda: flip.flip(test * 4, reference * 4, dynamic_range="hdr"))
    add("metrics.image_errors", lambda: metrics.image_errors(test, reference))
    add("spectrum.low_frequency_energy", lambda: spectrum.low_frequency_energy(noise))

    # post: every registered step through the command's workflow, on a PNG and an EXR
    from pointillist.post import post_process
    from pointillist.steps import steps

    inputs, outputs = tmp / "inputs", tmp / "outputs"
    inputs.mkdir()
    outputs.mkdir()
    png = inputs / "in.png"
    io.write_png(png, astronaut, srgb=False, max_value=255.0)
    exr = inputs / "in.exr"
    io.write_exr(exr, hdr)
    lut_file = inputs / "curve.txt"
    np.savetxt(lut_file, 255 - np.arange(256))
    chains = {
        "tonemap": "tonemap:reinhard,exposure=1", "gamma": "gamma:2.2", "stretch": "stretch:50,20,200,235",
        "equalize": "equalize", "quantize": "quantize:8", "hsv": "hsv:hue=30,saturation=1.2", "grey": "grey",
        "lut": f"lut:{lut_file}", "correlate": "correlate:gaussian,border=reflect,normalize=true",
        "sobel": "sobel;normalize", "prewitt": "prewitt", "laplacian": "laplacian;zero_crossings",
        "zero_crossings": "laplacian;zero_crossings:4", "normalize": "sobel;normalize", "threshold": "threshold:100",
        "median": "median:5", "resize": "resize:77,53,bicubic", "dither": "dither:jarvis_judice_ninke,levels=3",
    }
    for name in steps():
        chain = chains.get(name, name)
        for source in (png, exr):
            for suffix in (".png", ".exr"):
                def run(chain=chain, source=source, suffix=suffix, name=name):
                    out = outputs / f"{name}_{source.suffix[1:]}{suffix}"
                    post_process(source, out, steps=chain)
                    return io.read_image(out).image if suffix == ".png" else io.read_exr(out).image
                add(f"post.{name}/{source.suffix}{suffix}", run)
    for method in dither.DITHER_METHODS:
        add(f"post.dither.{method}", lambda method=method: (
            post_process(png, outputs / f"d_{method}.png", steps="grey", dither=method),
            io.read_image(outputs / f"d_{method}.png").image)[1])

    # volumes: readers on files written here and the packages' own test files
    phantom = volumes.shepp_logan_phantom((20, 24, 28))
    add("volumes.phantom", lambda: phantom)
    add("volumes.phantom_f", lambda: volumes.shepp_logan_phantom(17, dtype=np.float32, background=-500))
    np.save(tmp / "p.npy", phantom)
    volumes.write_vol(tmp / "p.vol", phantom, spacing=(0.5, 0.75, 1.0))

    def volume_digest(vol):
        return (vol.data, vol.spacing, vol.origin, vol.affine, repr(sorted(vol.metadata.items())), vol.axis_codes)

    add("volumes.npy", lambda: volume_digest(volumes.load_volume(tmp / "p.npy", spacing=(1, 2, 3))))
    add("volumes.vol", lambda: volume_digest(volumes.load_volume(tmp / "p.vol")))
    add("volumes.unknown", lambda: volumes.load_volume(lut_file))
    from nibabel.testing import data_path

    for name in ("anatomical.nii", "example4d.nii.gz", "standard.nii.gz"):
        add(f"volumes.nifti.{name}", lambda name=name: volume_digest(volumes.load_volume(
            f"{data_path}/{name}", frame=1 if "4d" in name else None)))
    import pydicom.data

    for name in ("CT_small.dcm", "MR_small.dcm"):
        folder = tmp / name.replace(".", "_")
        folder.mkdir()
        (folder / name).write_bytes(Path(pydicom.data.get_testdata_file(name)).read_bytes())
        add(f"volumes.dicom.{name}", lambda folder=folder: volume_digest(volumes.load_volume(folder)))
    for precision in ("auto", "half", "single"):
        add(f"volumes.texture.{precision}", lambda precision=precision: (
            lambda t: (t.texture.tensor().numpy(), t.offset, t.precision, t.minimum, t.maximum, t.exact))(
                volumes.volume_texture(phantom, precision=precision)))

    # mip: the plugin's paths (columns, bricks, march) through the workflow
    from pointillist.mip import project_volume as project

    def project_volume(*args, **kwargs):
        image, integrator = project(*args, **kwargs)
        return image, integrator.last_path

    vol = volumes.Volume(phantom, (0.8, 0.9, 1.1))
    for view in ("axial", "coronal", "sagittal"):
        for mode in ("mip", "minip", "average"):
            for interpolation in ("trilinear", "nearest"):
                add(f"mip.{view}.{mode}.{interpolation}", lambda view=view, mode=mode, interpolation=interpolation:
                    project_volume(vol, view=view, size=(40, 36), mode=mode, interpolation=interpolation))
        add(f"mip.{view}.native", lambda view=view: project_volume(vol, view=view, native=True))
    for mode in ("mip", "minip", "average"):
        add(f"mip.oblique.{mode}", lambda mode=mode: project_volume(vol, view=None, azimuth=30, elevation=20,
                                                                     size=(48, 40), mode=mode))
    add("mip.perspective", lambda: project_volume(vol, view="coronal", size=(40, 40), perspective=30))
    add("mip.single", lambda: project_volume(vol, view=None, azimuth=10, size=(32, 32), precision="single",
                                             interpolation="nearest"))
    return cases


def digests(root: Path | None) -> dict[str, object]:
    """Run every case; ``root``: the checkout to import (None: the installed one)."""
    if root is not None:
        sys.meta_path.insert(0, _TreeFinder(root.resolve()))
    import pointillist

    pointillist.setup()
    out = {}
    with tempfile.TemporaryDirectory() as folder:
        cases = _cases(Path(folder))
        for name, thunk in cases:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                try:
                    out[name] = _digest(thunk())
                except Exception as error:  # noqa: BLE001 - recorded: an error must stay the same error
                    out[name] = f"error {type(error).__name__}: {error}".replace(folder, "TMP")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, help="import pointillist from this checkout")
    parser.add_argument("-o", "--output", type=Path, help="write the digests here (JSON)")
    parser.add_argument("--compare", nargs=2, type=Path, metavar=("A", "B"), help="compare two digest files")
    args = parser.parse_args(argv)
    if args.compare:
        a, b = (json.loads(p.read_text()) for p in args.compare)
        differ = [k for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]
        for key in differ:
            print(f"{key}:\n  {a.get(key, '(missing)')}\n  {b.get(key, '(missing)')}")
        print(f"{len(a)} / {len(b)} outputs, {len(differ)} differ")
        return 1 if differ else 0
    result = digests(args.root)
    text = json.dumps(result, indent=1, sort_keys=True)
    if args.output:
        args.output.write_text(text)
    else:
        print(text)
    errors = sum(str(v).startswith("error") for v in result.values())
    print(f"{len(result)} outputs ({errors} errors recorded)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
