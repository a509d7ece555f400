"""Benchmark: stiff scenes, whitted's error-bound ray offsets against Mitsuba's.

Measures, in one run:

1. Pixel statistics: the scene of tests/test_stiff.py (Phong, mirror and glass spheres on a
   diffuse floor, one point light, 80x80, 4 spp; variants with a thin sphere and a grazing
   light) scaled by 1e-6 .. 1e6 and moved 1e3 from the origin, compared pixel by pixel with the
   same integrator at scale 1 (same seed): the fraction of pixels off by more than 1 %. For
   ``whitted`` (this tree), ``whitted`` before the stiff-scenes round (Mitsuba's ``spawn_ray`` offsets; the file
   from ``--before``), and Mitsuba's ``path`` (max_depth 6) and ``direct``. Goals: whitted at most
   0.5 % at every scale, 2 % moved 1e3.
2. The camera side: the scene moved 1e3, 1e4, 1e5 from the origin (float32 spacing there:
   6.1e-5, 9.8e-4, 7.8e-3), whitted against itself at the origin.
3. Render time: whitted now against whitted before, interleaved round by round on
   scenes/whitted.xml and scenes/cornell_phong.xml: wall time and CPU time (the steadier on a
   loaded machine), the median of the per-round ratios and the ratio of the minima; goal:
   within 2 %.
4. Instanced geometry at scales 1e-6 .. 1e4, camera rays only (Mitsuba's ``aov`` depth).
5. ``--offsets``: for spheres, rectangles, disks, cubes (triangle meshes) and cylinders of
   radius 1e-5 .. 1e4 centred 0 .. 3e4 radii from the origin, rays leaving hits at grazing to
   normal angles, offset by ``gamma(n) M_S``: the fraction that meet their own surface again,
   for n = 0 .. 32 (what ``ERROR_ULPS`` in plugins/integrators/_offsets.py is chosen from).

It writes benchmarks/stiff.png (renders at scale 1e-4 and their differences from scale 1) and
prints a Markdown section (``--write`` puts it into the ``stiff`` block of
benchmarks/RESULTS.md). Run it under the shared benchmark lock::

    flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/stiff.py --offsets --write
"""

from __future__ import annotations

import argparse
import importlib.util
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

#: The commit whose whitted.py is "before" (the branch point of the stiff-scenes round).
BEFORE = "4245953"
SCALES = (1e-6, 1e-4, 1e4, 1e6)
SHIFTS = (1e3, 1e4, 1e5)
VARIANTS = {"main": {}, "thin sphere (close-up)": {"thin": True},
            "thin sphere, grazing light (close-up)": {"thin": True, "grazing": True}}


def _setup():
    import pointillist

    return pointillist.setup("llvm_ad_rgb")


#: Where the helpers an older whitted.py imports live now: ``{old module: new module}`` (the
#: property readers left ``plugins/bsdfs/_common.py`` for ``plugins/properties.py``).
MOVED = {"pointillist.plugins.bsdfs._common": "pointillist.plugins.properties"}


def resolve_imports(source: str) -> str:
    """``source`` with every ``from OLD import names`` of :data:`MOVED` whose names ``OLD`` no longer
    has importing them from the new module (which must have them all)."""
    import importlib
    import re

    def fix(match):
        module, names = match.group(1), [n.strip() for n in match.group(2).split(",")]
        if module not in MOVED or all(hasattr(importlib.import_module(module), n) for n in names):
            return match.group(0)
        new = importlib.import_module(MOVED[module])
        missing = [n for n in names if not hasattr(new, n)]
        if missing:
            raise ImportError(f"{MOVED[module]} lacks {', '.join(missing)} (imported from {module})")
        return f"from {MOVED[module]} import {match.group(2)}"

    return re.sub(r"^from ([\w.]+) import ([\w, ]+)$", fix, source, flags=re.M)


def register_before(mi, rev: str) -> str:
    """Register whitted.py as of ``rev`` under the name ``whitted_before``; returns the name."""
    source = subprocess.run(["git", "show", f"{rev}:plugins/integrators/whitted.py"], cwd=ROOT,
                            capture_output=True, text=True, check=True).stdout
    path = Path(tempfile.mkdtemp()) / "whitted_before.py"
    path.write_text(resolve_imports(source))
    spec = importlib.util.spec_from_file_location("pointillist_whitted_before", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    mi.register_integrator("whitted_before", lambda props: module.PLUGIN_CLASS(props))
    return "whitted_before"


# ------------------------------------------------------------------ pixels
INTEGRATORS = {"whitted": {"type": "whitted"}, "whitted before": {"type": "whitted_before"},
               "`path` (max_depth 6)": {"type": "path", "max_depth": 6}, "`direct`": {"type": "direct"}}


def pixel_table(mi, bar):
    from tests.test_stiff import fraction_off, render, stiff_scene

    rows, images = [], {}
    for variant, kw in VARIANTS.items():
        for name, integrator in INTEGRATORS.items():
            ref = render(mi, stiff_scene(mi, integrator, **kw))
            cells = []
            for case in [{"scale": s} for s in SCALES] + [{"shift": SHIFTS[0]}]:
                img = render(mi, stiff_scene(mi, integrator, **case, **kw))
                cells.append(fraction_off(img, ref))
                if variant == "main" and case.get("scale") == 1e-4:
                    images[name] = (ref, img)
                bar.update(1)
            rows.append((variant, name, cells))
    return rows, images


def camera_table(mi, bar):
    from tests.test_stiff import fraction_off, render, stiff_scene

    rows = []
    for variant, kw in VARIANTS.items():
        ref = render(mi, stiff_scene(mi, {"type": "whitted"}, **kw))
        cells = []
        for shift in SHIFTS:
            cells.append(fraction_off(render(mi, stiff_scene(mi, {"type": "whitted"}, shift=shift, **kw)), ref))
            bar.update(1)
        rows.append((variant, cells))
    return rows


def picture(images, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(images)
    fig, axes = plt.subplots(2, len(names), figsize=(3 * len(names), 6.2))
    for k, name in enumerate(names):
        ref, img = images[name]
        top = np.percentile(ref, 99.5) or 1.0
        axes[0, k].imshow(np.clip(img / top, 0, 1) ** (1 / 2.2))
        axes[0, k].set_title(f"{name}\nscale 1e-4", fontsize=9)
        tol = 0.01 * np.abs(ref) + 1e-3 * ref.mean()
        axes[1, k].imshow(np.any(np.abs(img - ref) > tol, axis=-1), cmap="magma", vmin=0, vmax=1)
        axes[1, k].set_title("pixels off by > 1 % vs scale 1", fontsize=9)
        for ax in axes[:, k]:
            ax.set_axis_off()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


INSTANCE_SCALES = (1e-6, 1e-4, 1e-2, 1e2, 1e4)


def _instanced_scene(mi, scale, instanced):
    """A sphere over a floor, as plain shapes or inside a shapegroup instanced with ``scale``."""
    T = mi.ScalarTransform4f().scale(scale)
    shapes = {"ball": {"type": "sphere"},
              "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, -1, 0])
                        .rotate([1, 0, 0], -90).scale(3)}}
    scene = {"type": "scene",
             "sensor": {"type": "perspective", "near_clip": 1e-2 * scale, "far_clip": 1e3 * scale,
                        "to_world": mi.ScalarTransform4f().look_at(origin=T @ mi.ScalarPoint3f(0, 1, 5),
                                                                   target=T @ mi.ScalarPoint3f(0, 0, 0), up=[0, 1, 0]),
                        "film": {"type": "hdrfilm", "width": 32, "height": 32, "rfilter": {"type": "box"}}}}
    if instanced:
        scene["group"] = {"type": "shapegroup", **shapes}
        scene["inst"] = {"type": "instance", "shapegroup": {"type": "ref", "id": "group"}, "to_world": T}
    else:
        shapes["ball"]["to_world"] = T
        shapes["floor"]["to_world"] = T @ shapes["floor"]["to_world"]
        scene.update(shapes)
    return mi.load_dict(scene)


def instance_table(mi, bar):
    """Camera rays only: Mitsuba's own ``aov`` depth integrator, depth / scale against scale 1
    (fraction of pixels off by more than 0.1 %), plain shapes and the same shapes instanced."""
    aov = mi.load_dict({"type": "aov", "aovs": "dd:depth"})
    rows = []
    for instanced in (False, True):
        ref = np.asarray(mi.render(_instanced_scene(mi, 1.0, instanced), integrator=aov, spp=1, seed=1))[..., 0]
        cells = []
        for scale in INSTANCE_SCALES:
            img = np.asarray(mi.render(_instanced_scene(mi, scale, instanced), integrator=aov, spp=1, seed=1))
            cells.append(float(np.mean(np.abs(img[..., 0] / scale - ref) > 1e-3 * (ref + 1e-3))))
            bar.update(1)
        rows.append(("instance of a shapegroup" if instanced else "plain shapes", cells))
    return rows


# ------------------------------------------------------------------ timing
def _main_kernel_ops(mi, scene, spp):
    """Operation count of the largest kernel of one render (Dr.Jit's kernel history)."""
    import drjit as dr

    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()
    try:
        dr.eval(mi.render(scene, spp=spp, seed=99))
        dr.sync_thread()
        return max(k.get("operation_count", 0) for k in dr.kernel_history())
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)


def timing_table(mi, res, spp, rounds, bar):
    """Per scene: medians of wall and CPU time, the median of the per-round ratios and the
    ratio of the minima (now / before), and the first render's wall time (warm-up)."""
    from _timing import interleaved, ratio

    from pointillist.scene import load_scene

    rows = []
    for name in ("whitted.xml", "cornell_phong.xml"):
        scenes = {which: load_scene(ROOT / "scenes" / name, {"res": str(res), "integrator": which})
                  for which in ("whitted", "whitted_before")}
        seeds = {which: iter(range(1, 10**6)) for which in scenes}   # a new seed each render
        times = interleaved({which: (lambda s=s, which=which: mi.render(s, spp=spp, seed=next(seeds[which])))
                             for which, s in scenes.items()}, rounds, bar=bar)
        now, before = times["whitted"], times["whitted_before"]
        row = {"scene": name, "first": (now.first, before.first),
               "ops": tuple(_main_kernel_ops(mi, scenes[which], spp) for which in ("whitted", "whitted_before"))}
        row["wall"] = (now.median, before.median, *ratio(now, before))
        row["cpu"] = (now.cpu_median, before.cpu_median, *ratio(now, before, "cpu"))
        rows.append(row)
    return rows


# ----------------------------------------------------------------- offsets
KINDS = ("sphere", "rectangle", "disk", "cube", "cylinder")
OFFSET_NS = (0, 1, 2, 3, 4, 6, 8, 12, 16, 24, 32)


def offsets_table(mi, n_rays, bar):
    """Self-intersection fractions per kind and n (worst over radii and centre distances)."""
    from pointillist.plugins.integrators._offsets import ErrorBounds, gamma, magnitude
    from tests.test_stiff import _leaving_rays, _vec

    rng = np.random.default_rng(1)
    worst = {kind: np.zeros(len(OFFSET_NS)) for kind in KINDS}
    for kind in KINDS:
        for r in (1e-5, 1.0, 1e4):
            for ratio in (0.0, 1.0, 30.0, 1e3, 3e4):
                scene, si, valid, out, into, cos = _leaving_rays(mi, kind, r, ratio, n_rays, rng)
                if kind == "cylinder":        # open: only hits on the outside (convex there) count
                    normal = np.asarray(si.n)
                    valid = valid & ((out * (normal.T if normal.shape[0] == 3 else normal)).sum(1) > 0)
                bounds = ErrorBounds(scene)
                mag = magnitude(scene.shapes()[0].bbox())
                for k, n in enumerate(OFFSET_NS):
                    bounds.shape_table = mi.Float(np.full(4096, gamma(n) * mag, np.float32))
                    bounds._last_shape = 4095
                    length = bounds.hit_offset(si)
                    leaving = bounds.spawn_ray(si, _vec(mi, out, mi.Vector3f), length)
                    fail = np.asarray(scene.ray_test(leaving)) & valid
                    entering = bounds.spawn_ray(si, _vec(mi, into, mi.Vector3f), length)
                    if kind in ("rectangle", "disk"):
                        fail |= np.asarray(scene.ray_test(entering)) & valid
                    elif kind == "sphere":
                        fail |= valid & ~(np.asarray(scene.ray_intersect(entering).t) > 0.5 * 2 * r * cos)
                    worst[kind][k] = max(worst[kind][k], fail.sum() / max(valid.sum(), 1))
                bar.update(1)
    return worst


# ------------------------------------------------------------------ report
def _pct(x):
    return f"{100 * x:.2f} %"


def report(args, pixels, camera, instances, timing, offsets, seconds, loads):
    import drjit as dr
    import mitsuba as mi
    from _timing import load_note

    out = ["## Stiff scenes: scale and distance from the origin", "",
           f"Machine: {platform.machine()}, 2 cores with other processes running (loaded: timings are "
           f"interleaved ratios), {platform.platform()}; Python {platform.python_version()}, "
           f"Mitsuba {mi.__version__}, Dr.Jit {dr.__version__}; {load_note(*loads)}. Run time {seconds:.0f} s. "
           "Reproduce: "
           f"`flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/stiff.py --res {args.res} "
           f"--spp {args.spp} --rounds {args.rounds}{f' --offsets --rays {args.rays}' if offsets else ''}`.", ""]
    out += ["Pixels off by more than 1 % (relative; absolute floor 1e-3 of the image mean) against the same "
            "integrator at scale 1, same seed (tests/test_stiff.py's scene, 80x80, 4 spp). Goals for whitted: "
            "<= 0.5 % at every scale, <= 2 % moved 1e3. \"whitted before\" is whitted.py of commit "
            f"`{args.before}` (Mitsuba's `spawn_ray` offsets).", "",
            "| scene | integrator | x 1e-6 | x 1e-4 | x 1e4 | x 1e6 | moved 1e3 |", "|---|---|---|---|---|---|---|"]
    for variant, name, cells in pixels:
        out.append(f"| {variant} | {name} | " + " | ".join(_pct(c) for c in cells) + " |")
    out += ["", "![stiff](stiff.png)", "",
            "Camera side: whitted moved away from the origin, against itself at the origin (float32 spacing "
            "of the coordinates there: 6.1e-5 at 1e3, 9.8e-4 at 1e4, 7.8e-3 at 1e5; the thin sphere's "
            "radius is 8e-3, a pixel of its close-up 4.5e-4):", "",
            "| scene | moved 1e3 | moved 1e4 | moved 1e5 |", "|---|---|---|---|"]
    for variant, cells in camera:
        out.append(f"| {variant} | " + " | ".join(_pct(c) for c in cells) + " |")
    out += ["", "Instanced geometry (Mitsuba 3.9.1, camera rays only, its own `aov` depth integrator; a sphere over "
            "a floor, 32x32): pixels whose depth / scale is off by more than 0.1 % against scale 1. Below unit "
            "scale Mitsuba's instance intersection itself changes the image, whatever the integrator:", "",
            "| shapes | " + " | ".join(f"x {s:g}" for s in INSTANCE_SCALES) + " |",
            "|---|" + "---|" * len(INSTANCE_SCALES)]
    for label, cells in instances:
        out.append(f"| {label} | " + " | ".join(_pct(c) for c in cells) + " |")
    out += ["", f"Render time, whitted now / before, {args.rounds} interleaved rounds (order alternating), "
            f"{args.res}x{args.res}, {args.spp} spp, image evaluated. Wall time swings with the other jobs on "
            "the machine; CPU time (this process's threads) is the steadier measure here. Seconds are medians; "
            "goal: within 2 %:", "",
            "| scene | wall now / before (s) | median ratio | ratio of minima | CPU now / before (s) "
            "| median ratio | ratio of minima | first render now / before (s) | main kernel operations now / before |",
            "|---|---|---|---|---|---|---|---|---|"]
    for row in timing:
        w, c = row["wall"], row["cpu"]
        out.append(f"| scenes/{row['scene']} | {w[0]:.3f} / {w[1]:.3f} | {w[2]:.3f} | {w[3]:.3f} "
                   f"| {c[0]:.3f} / {c[1]:.3f} | {c[2]:.3f} | {c[3]:.3f} | {row['first'][0]:.2f} / "
                   f"{row['first'][1]:.2f} | {row['ops'][0]} / {row['ops'][1]} |")
    out += ["", "On this machine, loaded by other processes, the timing ratios vary by about 3-5 % from run to "
            "run; the median per-round CPU ratio is the figure to read."]
    if offsets:
        out += ["", "Rays that meet their own surface again, offset by gamma(n) M_S (worst fraction over radii "
                "1e-5, 1, 1e4 and centres 0 .. 3e4 radii from the origin; rays leave at cos 1e-4 .. 1 to the "
                "normal, both sides):", "", "| shape | " + " | ".join(f"n = {n}" for n in OFFSET_NS) + " |",
                "|---|" + "---|" * len(OFFSET_NS)]
        for kind, fractions in offsets.items():
            out.append(f"| {kind} | " + " | ".join(f"{100 * f:.3g} %" for f in fractions) + " |")
    return "\n".join(out)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--res", type=int, default=256, help="resolution of the timed scenes (default 256)")
    parser.add_argument("--spp", type=int, default=16, help="samples per pixel of the timed scenes (default 16)")
    parser.add_argument("--rounds", type=int, default=15, help="interleaved timing rounds (default 15)")
    parser.add_argument("--before", default=BEFORE, help=f"commit of the 'before' whitted.py (default {BEFORE})")
    parser.add_argument("--offsets", action="store_true", help="also measure self-intersection against n")
    parser.add_argument("--rays", type=int, default=4000, help="rays per case for --offsets (default 4000)")
    parser.add_argument("--write", action="store_true", help="write the section into benchmarks/RESULTS.md")
    args = parser.parse_args(argv)
    for name in ("res", "spp", "rounds", "rays"):
        if getattr(args, name) < 1:
            parser.error(f"--{name}: expected a positive integer")

    from tqdm import tqdm

    from _timing import load

    start, load_before = time.perf_counter(), load()
    mi = _setup()
    register_before(mi, args.before)
    n_pix = len(VARIANTS) * len(INTEGRATORS) * (len(SCALES) + 1)
    with tqdm(total=n_pix, desc="pixel statistics") as bar:
        pixels, images = pixel_table(mi, bar)
    picture(images, ROOT / "benchmarks" / "stiff.png")
    with tqdm(total=len(VARIANTS) * len(SHIFTS), desc="camera side") as bar:
        camera = camera_table(mi, bar)
    with tqdm(total=2 * len(INSTANCE_SCALES), desc="instances") as bar:
        instances = instance_table(mi, bar)
    with tqdm(total=2 * args.rounds, desc="render time") as bar:
        timing = timing_table(mi, args.res, args.spp, args.rounds, bar)
    offsets = None
    if args.offsets:
        with tqdm(total=len(KINDS) * 15, desc="offsets") as bar:
            offsets = offsets_table(mi, args.rays, bar)
    text = report(args, pixels, camera, instances, timing, offsets, time.perf_counter() - start, (load_before, load()))
    print(text)
    if args.write:
        from _results import write_block

        write_block("stiff", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
