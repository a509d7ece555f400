"""Benchmark the ``mip`` integrator against numpy's axis max and scipy's affine_transform + max.

Run (under the shared lock, the machine has two cores):

    flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/mip.py [--size 512] [--ct]

Part A: a 512^3 int16 Shepp-Logan CT, 512x512 orthographic image.
  - axis-aligned (axial, one ray per voxel column) vs ``volume.max(axis=0)`` (goal: <= 3x);
  - oblique (azimuth 30, elevation 20) vs ``scipy.ndimage.affine_transform`` (rotate the
    volume, order 1 and the default order 3) followed by ``max(axis=0)`` (goal: >= 20x faster).
    scipy is timed on a 128^3 crop of the problem and scaled by the voxel count (x64): it is
    linear in the output voxels and too slow to run at 512^3 here (stated in the table).
Part B (``--ct``): a clinical-size CT, 512 x 512 x 1800 int16 (about 0.94 GB), oblique 512x512
  MIP in a subprocess that builds the volume and renders it; its peak RSS comes from
  ``resource.getrusage`` (goal: < 10 s and peak < 3x the volume's size).
Part C (``--axis``, the 8-bit pipelines' first goal): axis-aligned ``--native-size --interpolation nearest`` MIP
  of a 512^3 int16 CT-like volume with noise, for axial, coronal and sagittal, against numpy's
  single-threaded ``max(axis)``, in interleaved rounds (ours, the previous column kernels
  ``--before REV`` on the same integrator, numpy), medians and minima; every image checked equal to
  numpy's; peak RSS of the process (volume + texture + renders) over the volume's bytes
  (goal: ours at most 1.0x numpy per view, peak at most 2.5x). Runs in a subprocess.
Part D (``--vtk``, the 8-bit pipelines' second goal; needs the ``bench`` extra: ``pip install -e .[bench]``): oblique
  MIP (azimuth 30, elevation 20, 512x512, step 0.5 voxel, trilinear, brick skipping) against VTK's CPU
  ray caster ``vtkFixedPointVolumeRayCastMapper`` (maximum-intensity blend, 2 threads, sample distance
  0.5, auto-adjust off, off-screen window, parallel projection framing the volume's box as ours
  does), per image (interleaved rounds) and for the first image of a new volume (ours: texture +
  brick grid + render; VTK: mapper set-up + first render), on the noisy CT-like volume and on the
  phantom. Runs in a subprocess per volume.
Part E (``--bounds``): what bounds parts C and D, in one process on the noisy volume: a Dr.Jit pass
  reading the half storage as contiguous slice streams with one OR per word (the memory floor), the
  same streams reduced with the half keys, the packet-gather column kernel, numpy ``max(axis)`` on 1
  and on 2 threads (halves of a kept axis), interleaved rounds (kernel times from Dr.Jit's kernel
  history); then the oblique render with and without brick skipping on the noisy volume and the phantom.
JIT compile (first call) is reported apart from the steady state (median of repeats).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


def _median(fn, repeats):
    """Median wall seconds of ``repeats`` calls of ``fn`` (benchmarks/_timing.py; no warm-up call)."""
    from _timing import repeat

    return repeat(fn, repeats, warmup=False).median


def _ours(volume, integrator=None, **view):
    from pointillist.mip import project_volume

    return project_volume(volume, integrator=integrator, **view)


def part_a(n: int, repeats: int) -> dict:
    import drjit as dr
    import scipy
    from scipy.ndimage import affine_transform

    import pointillist
    from pointillist.mip import view_axes
    from pointillist.imaging.volumes import Volume, shepp_logan_phantom

    pointillist.setup()
    vol = shepp_logan_phantom(n)  # int16
    volume = Volume(vol)
    out: dict = {"n": n}
    out["numpy_axis_max"] = _median(lambda: vol.max(axis=0), repeats)
    for interp in ("nearest", "trilinear"):
        t = time.perf_counter()
        image, integrator = _ours(volume, view="axial", native=True, interpolation=interp)
        out[f"axial_{interp}_first"] = time.perf_counter() - t
        out[f"axial_{interp}"] = _median(lambda: _ours(volume, integrator, view="axial", native=True), repeats)
        out[f"axial_{interp}_path"] = integrator.last_path
        out[f"axial_{interp}_exact"] = bool(np.array_equal(image, vol.max(axis=0).astype(np.float32)))
        if interp == "trilinear":
            out["texture"] = integrator.texture_info()
    for name, axis in (("coronal", 1), ("sagittal", 2)):
        _, integrator = _ours(volume, view=name, native=True, interpolation="nearest")
        out[f"{name}_nearest"] = _median(lambda: _ours(volume, integrator, view=name, native=True), repeats)
        out[f"numpy_axis{axis}_max"] = _median(lambda: vol.max(axis=axis), repeats)
    view = dict(view=None, azimuth=30.0, elevation=20.0, size=(n, n))
    import pointillist as _p

    mi = _p.setup()
    for interp in ("trilinear", "nearest"):
        for step in (0.5, 1.0):
            for skip in (True, False):
                key = f"oblique_{interp}_step{step}_{'bricks' if skip else 'march'}"
                integrator = mi.load_dict({"type": "mip", "interpolation": interp, "step": step,
                                           "skip_bricks": skip})
                integrator.set_volume(volume)
                if skip:
                    t = time.perf_counter()
                    integrator.bricks.bounds()
                    out["bricks_build_s"] = time.perf_counter() - t
                t = time.perf_counter()
                image, _ = _ours(volume, integrator, **view)
                out[key + "_first"] = time.perf_counter() - t
                out[key] = _median(lambda: _ours(volume, integrator, **view), repeats)
                if skip:
                    reference = image
                else:
                    out[key + "_bits_equal"] = bool(np.array_equal(reference.view(np.uint32), image.view(np.uint32)))
    out["oblique"] = out["oblique_trilinear_step0.5_bricks"]
    out["oblique_first"] = out["oblique_trilinear_step0.5_bricks_first"]
    dr.sync_thread()

    # scipy: rotate the volume into the view frame, then max along the viewing axis
    small = 128
    sub = shepp_logan_phantom(small).astype(np.float32)
    right, up, forward = view_axes(None, 30.0, 20.0)
    rot = np.stack([forward, -up, right])[:, ::-1].T[::-1]  # output (depth, row, col) -> input (z, y, x)
    centre = (np.array(sub.shape) - 1) / 2
    offset = centre - rot @ centre
    for order in (1, 3):
        t = time.perf_counter()
        rotated = affine_transform(sub, rot, offset=offset, order=order, cval=-1000.0)
        rotated.max(axis=0)
        out[f"scipy_order{order}_{small}"] = time.perf_counter() - t
        out[f"scipy_order{order}_scaled"] = out[f"scipy_order{order}_{small}"] * (n / small) ** 3
    out["versions"] = {"numpy": np.__version__, "scipy": scipy.__version__, "drjit": dr.__version__}
    return out


def part_b_child(shape: tuple[int, int, int]) -> None:
    """Build the CT and render it; print a JSON line with timings and peak RSS."""
    t = time.perf_counter()
    import pointillist
    from pointillist.imaging.volumes import Volume, shepp_logan_phantom

    pointillist.setup()
    vol = shepp_logan_phantom(shape)
    volume = Volume(vol, (0.7, 0.7, 0.6))
    build = time.perf_counter() - t
    view = dict(view=None, azimuth=30.0, elevation=20.0, size=(512, 512))
    t = time.perf_counter()
    from pointillist.mip import project_volume

    mi = pointillist.setup()
    integrator = mi.load_dict({"type": "mip"})
    integrator.set_volume(volume)
    texture_s = time.perf_counter() - t
    t = time.perf_counter()
    peak_texture = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    integrator.bricks.bounds()  # needs the voxels: build the brick grid before dropping them
    bricks_s = time.perf_counter() - t
    peak_bricks = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    # the int16 source is no longer needed: keep only its shape (a zero-stride view)
    del vol
    volume = Volume(np.broadcast_to(np.zeros((), np.int16), shape), volume.spacing)
    integrator.volume = integrator.stored.volume = volume
    t = time.perf_counter()
    image, _ = project_volume(volume, integrator=integrator, **view)
    first = time.perf_counter() - t
    t = time.perf_counter()
    image, _ = project_volume(volume, integrator=integrator, **view)
    second = time.perf_counter() - t
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(json.dumps({"shape": shape, "build_s": build, "texture_s": texture_s, "bricks_s": bricks_s,
                      "peak_after_texture": peak_texture, "peak_after_bricks": peak_bricks,
                      "path": integrator.last_path, "first_s": first,
                      "steady_s": second, "peak_rss": peak, "volume_bytes": int(np.prod(shape)) * 2,
                      "texture": integrator.texture_info(), "image_max": float(image.max())}))


def noisy_ct(n: int, seed: int = 0) -> np.ndarray:
    """A CT-like int16 volume: the Shepp-Logan phantom plus Gaussian noise (sigma 20 HU) everywhere,
    air and soft tissue included (built in slabs: no full-size float temporary)."""
    from pointillist.imaging.volumes import shepp_logan_phantom

    vol = shepp_logan_phantom(n)
    rng = np.random.default_rng(seed)
    for z in range(0, n, 32):
        slab = vol[z:z + 32].astype(np.float32) + rng.normal(0.0, 20.0, vol[z:z + 32].shape).astype(np.float32)
        vol[z:z + 32] = np.clip(np.rint(slab), -32768, 32767).astype(np.int16)
    return vol


def part_c_child(n: int, rounds: int, before: str | None) -> None:
    """Axis-aligned MIP vs numpy, interleaved; prints one JSON line."""
    import importlib.util

    import pointillist

    pointillist.setup()
    import drjit as dr

    from pointillist.imaging.volumes import Volume
    from pointillist.mip import project_volume
    from pointillist.plugins.integrators import _mip_accel

    baseline = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # interpreter + Mitsuba + Dr.Jit
    vol = noisy_ct(n)
    volume = Volume(vol)
    old = None
    if before:
        source = subprocess.run(["git", "-C", str(ROOT), "show", f"{before}:plugins/integrators/_mip_accel.py"],
                                capture_output=True, text=True, check=True).stdout
        spec = importlib.util.spec_from_loader("_mip_accel_before", loader=None)
        old = importlib.util.module_from_spec(spec)
        exec(compile(source, f"{before}:_mip_accel.py", "exec"), old.__dict__)
    current = _mip_accel.reduce_half_words
    if old is not None:  # the revision's own column reduction, called as the integrator calls this one
        before_reduce = getattr(old, "reduce_half_words", None) or (
            lambda words, shape, axis, mode, **_: old.reduce_half_keys(words, shape, axis, mode))
    out = {"n": n, "rounds": rounds, "before": before, "views": {}}
    integrators = {}
    views = (("axial", 0), ("coronal", 1), ("sagittal", 2))
    for name, axis in views:
        t = time.perf_counter()
        image, integrators[name] = project_volume(volume, view=name, native=True, interpolation="nearest",
                                                  integrator=integrators.get("axial"))
        first = time.perf_counter() - t
        expected = vol.max(axis=axis).astype(np.float32)
        exact = any(np.array_equal(image, e) for e in (expected, expected[::-1], expected[:, ::-1],
                                                       expected[::-1, ::-1]))
        out["views"][name] = {"first_s": first, "path": integrators[name].last_path, "equals_numpy": exact,
                              "ours": [], "before": [], "numpy": [], "sitk": []}
    # ours' peak: volume + texture + the first image of each view (the steady renders allocate the
    # same), taken before SimpleITK is loaded and copies the volume into an ITK image
    out["peak_rss"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    try:  # the bench extra: SimpleITK's MaximumProjection (ITK image axes are x, y, z)
        import SimpleITK as sitk

        sitk.ProcessObject.SetGlobalDefaultNumberOfThreads(2)
        itk_image = sitk.GetImageFromArray(vol)
        out["sitk_version"] = sitk.Version.VersionString()
    except ImportError:
        sitk = None
    # the memory floor: one read of the stored volume on both cores (a Dr.Jit pass over the same slice
    # streams, one OR per word), and numpy's axial max split over two threads (halves of y)
    streams = integrators["axial"].stored.half_words()[1]
    from concurrent.futures import ThreadPoolExecutor

    pool = ThreadPoolExecutor(2)

    def or_fold(arrays):
        if len(arrays) <= _mip_accel.Z_GROUP:
            acc = arrays[0]
            for word in arrays[1:]:
                acc = acc | word
            return acc
        parts = []
        for first in range(0, len(arrays), _mip_accel.Z_GROUP):
            part = or_fold(arrays[first:first + _mip_accel.Z_GROUP])
            dr.eval(part)
            parts.append(part)
        return or_fold(parts)

    def floor_pass():  # the same streams as the axial fold, one OR per word
        planes = list(streams.rest)
        if streams.chunks:
            folded = or_fold(streams.chunks)
            dr.eval(folded)
            flat = np.asarray(folded)
            planes += [type(folded)(flat[i * streams.plane:(i + 1) * streams.plane]) for i in range(streams.stack)]
        dr.eval(or_fold(planes))
        dr.sync_thread()

    def numpy_two():
        return list(pool.map(lambda s: vol[:, s].max(axis=0), (slice(0, n // 2), slice(n // 2, n))))

    out["floor"], out["numpy_two"] = [], []
    for _ in range(rounds):
        t = time.perf_counter()
        floor_pass()
        out["floor"].append(time.perf_counter() - t)
        t = time.perf_counter()
        numpy_two()
        out["numpy_two"].append(time.perf_counter() - t)
        for name, axis in views:
            row = out["views"][name]
            t = time.perf_counter()
            project_volume(volume, view=name, native=True, integrator=integrators[name])
            row["ours"].append(time.perf_counter() - t)
            if old is not None:
                _mip_accel.reduce_half_words = before_reduce
                try:
                    t = time.perf_counter()
                    project_volume(volume, view=name, native=True, integrator=integrators[name])
                    row["before"].append(time.perf_counter() - t)
                finally:
                    _mip_accel.reduce_half_words = current
            t = time.perf_counter()
            vol.max(axis=axis)
            row["numpy"].append(time.perf_counter() - t)
            if sitk is not None:
                t = time.perf_counter()
                sitk.MaximumProjection(itk_image, 2 - axis)
                row["sitk"].append(time.perf_counter() - t)
    dr.sync_thread()
    out["peak_rss_with_peers"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    out["baseline_rss"] = baseline
    out["volume_bytes"] = vol.nbytes
    out["texture"] = integrators["axial"].texture_info()
    import os

    out["load_average"] = os.getloadavg()
    print(json.dumps(out))


def part_c(n: int, rounds: int, before: str | None) -> dict:
    cmd = [sys.executable, __file__, "--axis-child", f"{n},{rounds},{before or ''}"]
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=1500)
    if result.returncode != 0:
        raise RuntimeError(result.stderr[-2000:])
    return json.loads(result.stdout.strip().splitlines()[-1])


#: Goal of the speed round for the axis-aligned views: at most this times one read of the volume on both cores.
AXIS_GOAL = 1.25
#: Goals of the speed round for the oblique view against VTK: per image, and the first image of a new volume.
OBLIQUE_GOAL, FIRST_GOAL = 0.2, 0.5


def _machine() -> str:
    import drjit as dr

    return (f"{platform.machine()}, {os.cpu_count()} cores, {platform.platform()}; Python {platform.python_version()}, "
            f"numpy {np.__version__}, Dr.Jit {dr.__version__}")


def print_part_c(c: dict, command: str) -> str:
    """Part C as a Markdown section (returned, also printed)."""
    n = c["n"]
    floor = float(np.median(c["floor"])) * 1e3, float(np.min(c["floor"])) * 1e3
    two = float(np.median(c["numpy_two"])) * 1e3, float(np.min(c["numpy_two"])) * 1e3
    lines = ["## mip: axis-aligned views against one read of the volume (`benchmarks/mip.py --axis`)", "",
             f"Command: `{command}`. Machine: {_machine()}. Load average at the end: "
             f"{', '.join(f'{x:.1f}' for x in c['load_average'])} (2 cores: above ~1 the figures are loaded-machine "
             f"figures; rerun on a quiet machine). Volume: {n}^3 int16 CT-like (Shepp-Logan phantom plus Gaussian "
             f"noise of sigma 20 HU everywhere), stored as an exact half-precision texture; native size, nearest; "
             f"{c['rounds']} interleaved rounds (ours, numpy, the floor); ms, median (min); every image equal to "
             "numpy's.", "",
             f"Floor, one read of the stored volume on both cores (a Dr.Jit pass over the same slice streams, one "
             f"OR per word): {floor[0]:.1f} ({floor[1]:.1f}) ms; numpy's axial max split over two threads: "
             f"{two[0]:.1f} ({two[1]:.1f}) ms. Goal: each view at most {AXIS_GOAL}x the floor.", ""]
    sitk_on = bool(next(iter(c["views"].values()))["sitk"])
    head = "| view | ours | " + ("before (" + c["before"][:10] + ") | " if c["before"] else "") + \
        "numpy max(axis) 1 thread | " + ("SimpleITK MaximumProjection 2 threads | " if sitk_on else "") + \
        "ours / numpy (medians) | (minima) | ours / floor (medians) | (minima) | goal | met | first call (s) | " \
        "equal to numpy |"
    lines += [head, "|" + "---|" * (head.count("|") - 1)]
    for name, row in c["views"].items():
        med = {k: float(np.median(v)) * 1e3 for k, v in row.items() if isinstance(v, list) and v}
        low = {k: float(np.min(v)) * 1e3 for k, v in row.items() if isinstance(v, list) and v}
        ratio, ratio_min = med["ours"] / med["numpy"], low["ours"] / low["numpy"]
        to_floor, to_floor_min = med["ours"] / floor[0], low["ours"] / floor[1]
        before = f"{med['before']:.1f} ({low['before']:.1f}) | " if c["before"] else ""
        itk = f"{med['sitk']:.1f} ({low['sitk']:.1f}) | " if sitk_on else ""
        met = "yes" if to_floor <= AXIS_GOAL else "min only" if to_floor_min <= AXIS_GOAL else "NO"
        lines.append(f"| {name} | {med['ours']:.1f} ({low['ours']:.1f}) | {before}{med['numpy']:.1f} "
                     f"({low['numpy']:.1f}) | {itk}{ratio:.2f} | {ratio_min:.2f} | {to_floor:.2f} | {to_floor_min:.2f} "
                     f"| <= {AXIS_GOAL} | {met} | {row['first_s']:.2f} | {row['equals_numpy']} |")
    grown = c["peak_rss"] - c["baseline_rss"]
    lines += ["", f"Peak RSS (volume build + half texture + the three views): {c['peak_rss'] / 2**20:.0f} MiB = "
              f"{c['peak_rss'] / c['volume_bytes']:.2f}x the volume ({c['volume_bytes'] / 2**20:.0f} MiB); above the "
              f"process's RSS before the volume was built ({c['baseline_rss'] / 2**20:.0f} MiB: Python, Mitsuba, "
              f"Dr.Jit): {grown / 2**20:.0f} MiB = {grown / c['volume_bytes']:.2f}x; texture {c['texture']}.", "",
              AXIS_NOTES]
    text = "\n".join(lines)
    print(text)
    return text


AXIS_NOTES = """How (`plugins/integrators/_mip_accel.py`, `reduce_half_words`): the stored float16 voxels are read
two at a time as 32-bit words. Where the storage has no -0 and nothing below 2^-17 in magnitude (16-bit CT less
its integer offset, or checked once per volume), a word read as float32 orders like its high half and the word
shifted left by 16 like its low half: one shift and two float compares a word instead of integer keys (about 9
operations). Axial (z) columns fold zero-copy views of 8 slices each (folded like one slice 8 times as wide,
so Python traces 64 folds, not 512) as contiguous streams, 64 a kernel (a 512-slice volume in one kernel),
then the 8 planes; coronal (y) columns and sagittal (x) rows fold packets of 8 words a lane (one packet
gather: a vector load per lane and a transpose), one kernel each. What is left above the floor: for the axial
view the partials and the integrator's checks of the rays (`_columns`, a few small kernels); for y and x the
transposes of the packet loads (a row-major volume reduced along y or x needs data moved across SIMD lanes:
shuffles, or a hardware gather a word), which keep them at about 2.5x the floor. Lifting those needs 16-bit
SIMD lanes reading the voxels as numpy does (a native kernel), or a second copy of the volume in another axis
order (2x the memory)."""
def part_d_child(kind: str, n: int, rounds: int) -> None:
    """Oblique MIP, ours vs VTK's fixed-point CPU ray caster; prints one JSON line."""
    import vtk
    from vtk.util import numpy_support

    import pointillist

    mi = pointillist.setup()
    from pointillist.imaging.volumes import Volume, shepp_logan_phantom
    from pointillist.mip import project_volume, view_axes, view_frame

    vol = noisy_ct(n) if kind == "noisy" else shepp_logan_phantom(n)
    volume = Volume(vol)
    size = (512, 512)
    axes = view_axes(None, 30.0, 20.0)
    view = dict(view=None, azimuth=30.0, elevation=20.0, size=size)
    out = {"kind": kind, "n": n, "rounds": rounds}

    t = time.perf_counter()
    integrator = mi.load_dict({"type": "mip", "interpolation": "trilinear", "step": 0.5})
    integrator.set_volume(volume)
    integrator.bricks.bounds()
    ours_image, _ = project_volume(volume, integrator=integrator, **view)
    out["ours_first"] = time.perf_counter() - t

    def vtk_setup():
        nz, ny, nx = vol.shape
        data = vtk.vtkImageData()
        data.SetDimensions(nx, ny, nz)
        data.SetSpacing(1.0, 1.0, 1.0)
        data.SetOrigin(-(nx - 1) / 2, -(ny - 1) / 2, -(nz - 1) / 2)  # voxel centres as ours, box centred
        data.GetPointData().SetScalars(numpy_support.numpy_to_vtk(vol.ravel(), deep=False,
                                                                  array_type=vtk.VTK_SHORT))
        mapper = vtk.vtkFixedPointVolumeRayCastMapper()
        mapper.SetInputData(data)
        mapper.SetBlendModeToMaximumIntensity()
        mapper.SetAutoAdjustSampleDistances(0)
        mapper.SetSampleDistance(0.5)
        mapper.SetNumberOfThreads(2)
        lo, hi = float(vol.min()), float(vol.max())
        opacity, colour = vtk.vtkPiecewiseFunction(), vtk.vtkColorTransferFunction()
        opacity.AddPoint(lo, 1.0)
        opacity.AddPoint(hi, 1.0)
        colour.AddRGBPoint(lo, 0.0, 0.0, 0.0)
        colour.AddRGBPoint(hi, 1.0, 1.0, 1.0)
        prop = vtk.vtkVolumeProperty()
        prop.SetScalarOpacity(opacity)
        prop.SetColor(colour)
        prop.SetInterpolationTypeToLinear()
        actor = vtk.vtkVolume()
        actor.SetMapper(mapper)
        actor.SetProperty(prop)
        renderer = vtk.vtkRenderer()
        renderer.AddVolume(actor)
        window = vtk.vtkRenderWindow()
        window.SetOffScreenRendering(1)
        window.AddRenderer(renderer)
        window.SetSize(*size)
        right, up, forward = axes
        (_, _), half_w, half_h = view_frame(volume.extent, axes, size=size)
        camera = renderer.GetActiveCamera()
        camera.ParallelProjectionOn()
        distance = 2.0 * float(np.linalg.norm(volume.extent))
        camera.SetFocalPoint(0.0, 0.0, 0.0)
        camera.SetPosition(*(-forward * distance))
        camera.SetViewUp(*up)
        camera.SetParallelScale(half_h)
        camera.SetClippingRange(distance / 4, distance * 4)
        return window, camera, mapper

    t = time.perf_counter()
    window, camera, mapper = vtk_setup()
    window.Render()
    out["vtk_first"] = time.perf_counter() - t
    grab = vtk.vtkWindowToImageFilter()
    grab.SetInput(window)
    grab.Update()
    shot = numpy_support.vtk_to_numpy(grab.GetOutput().GetPointData().GetScalars())
    out["vtk_image_mean"] = float(shot.mean())
    out["ours"], out["vtk"] = [], []
    for _ in range(rounds):
        t = time.perf_counter()
        project_volume(volume, integrator=integrator, **view)
        out["ours"].append(time.perf_counter() - t)
        camera.Modified()  # a new frame: the mapper casts every ray again
        t = time.perf_counter()
        window.Render()
        out["vtk"].append(time.perf_counter() - t)
    out["vtk_time_to_draw"] = mapper.GetTimeToDraw()
    out["ours_image_max"] = float(np.max(ours_image))
    import os

    out["load_average"] = os.getloadavg()
    out["vtk_version"] = vtk.vtkVersion.GetVTKVersion()
    print(json.dumps(out))


def part_d(n: int, rounds: int) -> list[dict]:
    results = []
    for kind in ("noisy", "phantom"):
        cmd = [sys.executable, __file__, "--vtk-child", f"{kind},{n},{rounds}"]
        result = subprocess.run(cmd, capture_output=True, text=True, timeout=1500)
        if result.returncode != 0:
            raise RuntimeError(result.stderr[-2000:])
        results.append(json.loads(result.stdout.strip().splitlines()[-1]))
    return results


def print_part_d(rows: list[dict], command: str) -> str:
    """Part D as a Markdown section (returned, also printed)."""
    loads = ", ".join(f"{r['kind']} {r['load_average'][0]:.1f}" for r in rows)
    lines = ["## mip: oblique views against VTK's CPU ray caster (`benchmarks/mip.py --vtk`)", "",
             f"Command: `{command}`. Machine: {_machine()}, VTK {rows[0]['vtk_version']}. Load average (1 min) at "
             f"the end of each volume's run: {loads} (2 cores: above ~1 these are loaded-machine figures). Oblique "
             "MIP, azimuth 30, elevation 20, 512x512, step 0.5 voxel, trilinear, brick skipping, against "
             "vtkFixedPointVolumeRayCastMapper (maximum-intensity blend, 2 threads, sample distance 0.5, automatic "
             "sample distance off, linear interpolation, off-screen, parallel projection framing the volume's box as "
             f"ours does); {rows[0]['rounds']} interleaved rounds; s, median (min). First image: ours = half texture "
             "+ brick grid + render of a new volume; VTK = mapper set-up + first render. Goals: per "
             f"image at most {OBLIQUE_GOAL}x VTK, first image at most {FIRST_GOAL}x.", "",
             "| volume | ours per image | VTK per image | ours / VTK (medians) | (minima) | goal | met "
             "| ours first image | VTK first image | first: ours / VTK | goal | met |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        om, vm = float(np.median(r["ours"])), float(np.median(r["vtk"]))
        ratio, ratio_min = om / vm, min(r["ours"]) / min(r["vtk"])
        first = r["ours_first"] / r["vtk_first"]
        met = "yes" if ratio <= OBLIQUE_GOAL else "min only" if ratio_min <= OBLIQUE_GOAL else "NO"
        lines.append(f"| {r['n']}^3 {r['kind']} | {om:.3f} ({min(r['ours']):.3f}) | {vm:.3f} ({min(r['vtk']):.3f}) "
                     f"| {ratio:.2f} | {ratio_min:.2f} | <= {OBLIQUE_GOAL} | {met} | {r['ours_first']:.2f} "
                     f"| {r['vtk_first']:.2f} | {first:.2f} | <= {FIRST_GOAL} "
                     f"| {'yes' if first <= FIRST_GOAL else 'NO'} |")
    lines += ["", OBLIQUE_NOTES]
    text = "\n".join(lines)
    print(text)
    return text


OBLIQUE_NOTES = """How (`plugins/integrators/mip.py`): the marches read the half-precision texels through 32-bit
word gathers (`_mip_accel.HalfSampler`: the two texels of each of a trilinear lookup's 4 rows are one word,
or two for an odd x; the texture's own arithmetic, same bits), where Dr.Jit's texture gathers 16-bit values,
which LLVM splits into 16 scalar loads a packet, 8 times a lookup. The brick grid of a new volume is built by
one Dr.Jit kernel from the stored halves (`brick_grid_words`), not by numpy on one core. What bounds it: rays
that meet only air. In this framing most rays that hit the box miss the head, and the exact maximum of a noisy
(or, in the phantom, flat but rounded) air run needs every sample: a brick's bound is its largest voxel, which
a trilinear sample of noise rarely comes near, so nothing can be skipped there (`benchmarks/mip.py --bounds`:
samples taken against samples on the rays). Lifting it needs cheaper samples rather than fewer: the lookups
are latency-bound gathers (8 a lookup, 16 rays a packet); ordering each packet's rays in 4x4 pixel tiles
instead of rows of 16 brings their texels closer, and a brick-major traversal (all rays of a tile through a
brick's texels held in registers) would read each texel once per tile."""


def part_e_child(n: int, rounds: int) -> None:
    """Bounds of the axis-aligned and oblique paths; prints one JSON line."""
    from concurrent.futures import ThreadPoolExecutor

    import pointillist

    mi = pointillist.setup()
    import drjit as dr

    from pointillist.imaging.volumes import Volume, shepp_logan_phantom
    from pointillist.mip import project_volume
    from pointillist.plugins.integrators import _mip_accel as accel

    vol = noisy_ct(n)
    flat = vol.astype(np.float16).reshape(-1).view(np.uint32)  # the texture's bytes (offset aside)
    words = mi.UInt32(flat)
    plane = flat.size // n
    slices = [mi.UInt32(flat[z * plane:(z + 1) * plane]) for z in range(n)]  # zero-copy views
    dr.eval(words)

    def streams(combine, group=64):
        partial = []
        for g in range(0, n, group):
            acc = None
            for z in range(g, min(n, g + group)):
                acc = combine(acc, slices[z])
            dr.eval(acc)
            partial.append(acc)
        acc = None
        for p in partial:
            acc = combine(acc, p)
        return acc

    def or_pass(acc, w):
        return w if acc is None else acc | w

    def key_pass(acc, w):
        lo, hi = accel._half_key(w)
        packed = lo | (hi << 16)
        if acc is None:
            return packed
        return dr.maximum(acc & 0xFFFF, lo) | (dr.maximum(acc >> 16, hi) << 16)

    pool = ThreadPoolExecutor(2)

    def numpy_two(axis):
        keep = 1 if axis != 1 else 0
        cut = n // 2

        def part(lo_hi):
            index = [slice(None)] * 3
            index[keep] = slice(*lo_hi)
            return vol[tuple(index)].max(axis=axis)

        return list(pool.map(part, ((0, cut), (cut, n))))

    cases = {"Dr.Jit OR pass over slice streams (floor)": lambda: streams(or_pass),
             "Dr.Jit half-key max over slice streams": lambda: streams(key_pass),
             "reduce_half_words, axial (as shipped)": lambda: accel.reduce_half_words(words, vol.shape, 2, "mip",
                                                                                      floats=True)}
    numpy_cases = {f"numpy max(axis={a}), {t} thread{'s' if t > 1 else ''}": (
        (lambda a=a: vol.max(axis=a)) if t == 1 else (lambda a=a: numpy_two(a))) for a in (0, 1, 2) for t in (1, 2)}
    times = {name: [] for name in (*cases, *numpy_cases)}
    kernels = {name: [] for name in cases}
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    for round_ in range(rounds + 1):
        for name, call in cases.items():
            dr.kernel_history()
            t = time.perf_counter()
            dr.eval(call())
            dr.sync_thread()
            if round_:
                times[name].append(time.perf_counter() - t)
                kernels[name].append(sum(e["execution_time"] for e in dr.kernel_history()
                                         if e["type"] == dr.KernelType.JIT) / 1e3)
        for name, call in numpy_cases.items():
            t = time.perf_counter()
            call()
            if round_:
                times[name].append(time.perf_counter() - t)
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    out = {"n": n, "rounds": rounds, "times": times, "kernels": kernels}
    slices.clear()  # the zero-copy views: drop them before the renders
    view = dict(view=None, azimuth=30.0, elevation=20.0, size=(512, 512))
    for kind in ("noisy", "phantom"):
        volume = Volume(vol if kind == "noisy" else shepp_logan_phantom(n))
        for skip in (True, False):
            integrator = mi.load_dict({"type": "mip", "interpolation": "trilinear", "step": 0.5, "skip_bricks": skip})
            integrator.set_volume(volume)
            if skip:
                upper = np.asarray(integrator.bricks.bounds()[0])
                out[f"{kind}_brick_max_p90"] = float(np.quantile(upper[np.isfinite(upper)], 0.9))
            project_volume(volume, integrator=integrator, **view)
            runs = []
            for _ in range(2):
                t = time.perf_counter()
                project_volume(volume, integrator=integrator, **view)
                runs.append(time.perf_counter() - t)
            out[f"{kind}_{'bricks' if skip else 'march'}"] = min(runs)
    import os

    out["load_average"] = os.getloadavg()
    print(json.dumps(out))


def print_part_e(e: dict) -> None:
    print(f"\nBounds, {e['n']}^3 noisy int16, {e['rounds']} interleaved rounds (load average at the end "
          f"{e['load_average'][0]:.1f}); ms, median (min); Dr.Jit rows also give their kernel time")
    print("| pass | wall | kernels |")
    print("|---|---|---|")
    for name, t in e["times"].items():
        kern = e["kernels"].get(name)
        k = f"{np.median(kern) * 1e3:.1f} ({np.min(kern) * 1e3:.1f})" if kern else "-"
        print(f"| {name} | {np.median(t) * 1e3:.1f} ({np.min(t) * 1e3:.1f}) | {k} |")
    print("\n| oblique 30/20, 512x512, trilinear, step 0.5 (min of 2, s) | brick skipping | plain march | gain "
          "| 90th percentile of brick maxima |")
    print("|---|---|---|---|---|")
    for kind in ("noisy", "phantom"):
        b, m = e[f"{kind}_bricks"], e[f"{kind}_march"]
        print(f"| {kind} | {b:.2f} | {m:.2f} | {m / b:.1f}x | {e[f'{kind}_brick_max_p90']:.0f} |")


def part_b(shape) -> dict:
    cmd = [sys.executable, __file__, "--child", ",".join(map(str, shape))]
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    if result.returncode != 0:
        raise RuntimeError(result.stderr[-2000:])
    return json.loads(result.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--ct", action="store_true", help="also run part B (512x512x1800 CT)")
    parser.add_argument("--axis", action="store_true", help="only part C (axis-aligned views vs numpy)")
    parser.add_argument("--rounds", type=int, default=7, help="part C: interleaved rounds")
    parser.add_argument("--before", help="part C: also time the column kernels of git revision REV")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    parser.add_argument("--axis-child", help=argparse.SUPPRESS)
    parser.add_argument("--vtk", action="store_true", help="only part D (oblique MIP vs VTK's CPU ray caster)")
    parser.add_argument("--vtk-child", help=argparse.SUPPRESS)
    parser.add_argument("--bounds", action="store_true", help="only part E (what bounds parts C and D)")
    parser.add_argument("--bounds-child", help=argparse.SUPPRESS)
    parser.add_argument("--write", action="store_true",
                        help="parts C and D: write the section into benchmarks/RESULTS.md (mip_axis, mip_oblique)")
    args = parser.parse_args()
    if args.child:
        part_b_child(tuple(int(s) for s in args.child.split(",")))
        return
    if args.axis_child:
        n, rounds, before = args.axis_child.split(",")
        part_c_child(int(n), int(rounds), before or None)
        return
    if args.vtk_child:
        kind, n, rounds = args.vtk_child.split(",")
        part_d_child(kind, int(n), int(rounds))
        return
    if args.bounds_child:
        n, rounds = args.bounds_child.split(",")
        part_e_child(int(n), int(rounds))
        return
    if args.bounds:
        cmd = [sys.executable, __file__, "--bounds-child", f"{args.size},{args.rounds}"]
        result = subprocess.run(cmd, capture_output=True, text=True, timeout=1500)
        if result.returncode != 0:
            raise RuntimeError(result.stderr[-2000:])
        e = json.loads(result.stdout.strip().splitlines()[-1])
        print(json.dumps(e))
        print_part_e(e)
        return
    command = "flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/mip.py " + " ".join(sys.argv[1:])
    if args.vtk:
        d = part_d(args.size, args.rounds)
        print(json.dumps(d))
        text = print_part_d(d, command)
        if args.write:
            from _results import write_block

            write_block("mip_oblique", text)
        return
    if args.axis:
        c = part_c(args.size, args.rounds, args.before)
        print(json.dumps(c))
        text = print_part_c(c, command)
        if args.write:
            from _results import write_block

            write_block("mip_axis", text)
        return
    print(f"machine: {platform.processor() or platform.machine()}, python {platform.python_version()}")
    a = part_a(args.size, args.repeats)
    print(json.dumps(a, indent=1))
    n = a["n"]
    print(f"\n| {n}^3 int16, {n}x{n} image | ours (s) | first call (s) | peer (s) | ours / peer |")
    print("|---|---|---|---|---|")
    for interp in ("nearest", "trilinear"):
        print(f"| axial, {interp} ({a[f'axial_{interp}_path']}) vs numpy max(axis=0) | {a[f'axial_{interp}']:.4f} | "
              f"{a[f'axial_{interp}_first']:.3f} | {a['numpy_axis_max']:.4f} | "
              f"{a[f'axial_{interp}'] / a['numpy_axis_max']:.1f}x |")
    for name, axis in (("coronal", 1), ("sagittal", 2)):
        print(f"| {name}, nearest vs numpy max(axis={axis}) | {a[f'{name}_nearest']:.4f} | - | "
              f"{a[f'numpy_axis{axis}_max']:.4f} | {a[f'{name}_nearest'] / a[f'numpy_axis{axis}_max']:.1f}x |")
    for interp in ("trilinear", "nearest"):
        for step in (0.5, 1.0):
            for way in ("bricks", "march"):
                ours = a[f"oblique_{interp}_step{step}_{way}"]
                for order in (1, 3):
                    peer = a[f"scipy_order{order}_scaled"]
                    print(f"| oblique 30/20, {interp}, step {step}, {way} vs scipy order {order} + max "
                          f"(128^3 x64) | {ours:.3f} | {a[f'oblique_{interp}_step{step}_{way}_first']:.3f} | "
                          f"{peer:.2f} | {peer / ours:.1f}x faster |")
    if args.ct:
        b = part_b((1800, 512, 512))
        print(json.dumps(b, indent=1))
        gb = b["volume_bytes"] / 1e9
        print(f"\nCT 512x512x1800 int16 ({gb:.2f} GB, {b['path']}): build {b['build_s']:.1f} s, "
              f"bricks {b['bricks_s']:.1f} s, texture "
              f"{b['texture_s']:.1f} s, oblique 512x512 MIP first {b['first_s']:.2f} s, steady "
              f"{b['steady_s']:.2f} s, peak RSS {b['peak_rss'] / 1e9:.2f} GB = "
              f"{b['peak_rss'] / b['volume_bytes']:.2f}x the volume")


if __name__ == "__main__":
    main()
