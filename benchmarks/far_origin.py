"""Benchmark: scenes far from the origin, loaded as written and camera-relative.

Measures, in one run:

1. Pixels: the far-origin scene (tests/far_scenes.py: Phong, mirror and glass spheres on a diffuse
   floor, one point light, 80x80, 4 spp, seed 1) written into the XML 1e3 .. 1e7 from the origin
   along x, y, z and (1, 1, 1), rendered with ``whitted``, Mitsuba's ``path`` (max_depth 6) and
   ``direct``, loaded as written (``instantiate_scene(parse_scene(...))``, "before") and camera-
   relative (``load_scene``, "after"), against the same integrator on the scene at the origin: the
   fraction of pixels more than 1 % off (tests/test_stiff.py's ``fraction_off``). Goal: at most
   0.5 % at 1e4, 1e5, 1e6 for whitted and path.
2. Mesh files: the same scene with the floor and spheres as meshes (a UV sphere of 64 x 32
   quads), their vertices stored near the origin with the offset in the XML's ``to_world``
   (float64 text: camera-relative loading removes it exactly), or stored in world coordinates in
   a PLY (float32: the file already rounded them; loading can only move them exactly) or an OBJ
   (17-digit text that Mitsuba's reader rounds to float32 before any transform).
3. Cost: the main kernel's operation count before and after (the far scenes, every integrator),
   and load time of every scene of ``scenes/`` and of the far scene: ``load_scene`` against
   parse + instantiate, interleaved round by round (median of the per-round ratios; goal within
   10 %), for the first load in a fresh process and for repeated loads in one process, with the
   camera-relative step's own time.

It writes benchmarks/far_origin.png (the scene at 1e6 before and after, and the pixels off) and
prints a Markdown section (``--write`` puts it into the ``far_origin`` block of
benchmarks/RESULTS.md). Run it under the shared benchmark lock::

    flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/far_origin.py --write
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

OFFSETS = (1e3, 1e4, 1e5, 1e6, 1e7)
AXES = ("x", "y", "z", "xyz")
INTEGRATORS = ("whitted", "path", "direct")


def _setup():
    import pointillist

    return pointillist.setup("llvm_ad_rgb")


def _load(path, camera_relative: bool):
    """The scene at ``path`` camera-relative (``load_scene``) or as written (parse + instantiate)."""
    from pointillist.scene import instantiate_scene, load_scene, parse_scene

    return load_scene(path) if camera_relative else instantiate_scene(parse_scene(path))


def _render(mi, scene) -> np.ndarray:
    from tests.far_scenes import SEED

    return np.asarray(mi.render(scene, seed=SEED))[..., :3].astype(np.float64)


# ------------------------------------------------------------------ pixels
def pixel_table(mi, folder: Path, bar):
    """{(integrator, axis, offset, after): fraction off} and the images shown in the picture."""
    from tests.far_scenes import write_far_scene
    from tests.test_stiff import fraction_off

    cells, images = {}, {}
    for integrator in INTEGRATORS:
        ref = _render(mi, _load(write_far_scene(folder, 0.0, integrator=integrator), True))
        images[(integrator, "origin")] = ref
        for axis in AXES:
            for offset in OFFSETS:
                path = write_far_scene(folder, offset, axis, integrator)
                for after in (False, True):
                    img = _render(mi, _load(path, after))
                    cells[(integrator, axis, offset, after)] = fraction_off(img, ref)
                    if axis == "xyz" and offset == 1e6:
                        images[(integrator, after)] = img
                bar.update(1)
    return cells, images


# ------------------------------------------------------------------ mesh files
def _uv_sphere(n_theta: int = 32, n_phi: int = 64):
    """Unit UV sphere: vertex positions (V, 3) float64 (also its normals) and faces (F, 3)."""
    theta = np.linspace(0.0, np.pi, n_theta + 1)
    phi = np.linspace(0.0, 2 * np.pi, n_phi + 1)[:-1]
    t, p = np.meshgrid(theta, phi, indexing="ij")
    unit = np.stack([np.sin(t) * np.cos(p), np.cos(t), np.sin(t) * np.sin(p)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n_theta), np.arange(n_phi), indexing="ij")
    a, b = i * n_phi + j, i * n_phi + (j + 1) % n_phi
    c, d = a + n_phi, b + n_phi
    faces = np.stack([np.stack([a, c, b], -1), np.stack([b, c, d], -1)], 2).reshape(-1, 3)
    return unit, faces.astype(np.uint32)


def _write_ply(mi, path: Path, positions: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None):
    """A PLY mesh written by Mitsuba (float32 vertices: what a mesh file holds)."""
    import drjit as dr

    mesh = mi.Mesh(path.stem, len(positions), len(faces), has_vertex_normals=normals is not None)
    params = mi.traverse(mesh)
    params["vertex_positions"] = dr.ravel(mi.Point3f(*positions.T.astype(np.float32)))
    params["faces"] = dr.ravel(mi.Vector3u(*faces.T))
    if normals is not None:
        params["vertex_normals"] = dr.ravel(mi.Normal3f(*normals.T.astype(np.float32)))
    params.update()
    mesh.write_ply(str(path))


def _write_obj(path: Path, positions: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None):
    """An OBJ mesh with every coordinate written to 17 significant digits (float64 text)."""
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in positions.tolist()]
    if normals is not None:
        lines += [f"vn {x!r} {y!r} {z!r}" for x, y, z in normals.tolist()]
        lines += [f"f {a}//{a} {b}//{b} {c}//{c}" for a, b, c in (faces + 1).tolist()]
    else:
        lines += [f"f {a} {b} {c}" for a, b, c in (faces + 1).tolist()]
    path.write_text("\n".join(lines) + "\n")


#: Where a mesh's offset is stored: in the XML's ``to_world`` (vertices near the origin), or in
#: the vertices of a PLY (float32) or an OBJ (float64 text) in world coordinates.
STORAGE = {"to_world": "near the origin, offset in `to_world`", "ply": "PLY in world coordinates (float32)",
           "obj": "OBJ in world coordinates (17-digit text)"}


def mesh_scene(mi, folder: Path, offset: float, integrator: str, storage: str) -> Path:
    """The far-origin scene with its floor and spheres as meshes, offset along (1, 1, 1) as ``storage`` says."""
    from tests.far_scenes import FLOOR_BSDF, FLOOR_HALF_SIZE, SPHERES, far_scene_xml

    shift = np.full(3, float(offset))
    unit, faces = _uv_sphere()
    h = FLOOR_HALF_SIZE
    parts = {"floor": (np.array([[-h, 0, -h], [h, 0, -h], [h, 0, h], [-h, 0, h]]), None,
                       np.array([[0, 2, 1], [0, 3, 2]], np.uint32), np.zeros(3), FLOOR_BSDF)}
    for name, (centre, radius, bsdf) in SPHERES.items():
        parts[name] = (unit * radius, unit, faces, np.array(centre), bsdf)
    tag = f"{storage}{offset:g}"
    shapes = ""
    for name, (vertices, normals, part_faces, position, bsdf) in parts.items():
        where = position + shift
        kind = "obj" if storage == "obj" else "ply"
        file = folder / f"{name}_{tag}.{kind}"
        transform = ""
        if storage == "to_world":
            _write_ply(mi, file, vertices, part_faces, normals)
            transform = ('<transform name="to_world"><translate ' + " ".join(
                f'{a}="{float(v)!r}"' for a, v in zip("xyz", where)) + '/></transform>')
        elif storage == "ply":
            _write_ply(mi, file, vertices + where, part_faces, normals)
        else:
            _write_obj(file, vertices + where, part_faces, normals)
        shapes += f'    <shape type="{kind}"><string name="filename" value="{file.name}"/>{transform}{bsdf}</shape>\n'
    path = folder / f"mesh_{integrator}_{tag}.xml"
    path.write_text(far_scene_xml(offset, "xyz", integrator, shapes=shapes))
    return path


def mesh_table(mi, folder: Path, bar):
    """{(integrator, storage, offset, after): fraction off} against the same meshes at the origin."""
    from tests.test_stiff import fraction_off

    cells = {}
    for integrator in INTEGRATORS:
        ref = _render(mi, _load(mesh_scene(mi, folder, 0.0, integrator, "to_world"), True))
        for storage in STORAGE:
            for offset in OFFSETS:
                path = mesh_scene(mi, folder, offset, integrator, storage)
                for after in (False, True):
                    cells[(integrator, storage, offset, after)] = fraction_off(_render(mi, _load(path, after)), ref)
                bar.update(1)
    return cells


# ------------------------------------------------------------------ cost
def kernel_ops(mi, folder: Path):
    """{integrator: (main kernel operations as written, camera-relative)} at 1e5 from the origin."""
    import drjit as dr

    from tests.far_scenes import write_far_scene

    def ops(scene):
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.kernel_history()
        try:
            dr.eval(mi.render(scene, seed=3))
            dr.sync_thread()
            return max(k.get("operation_count", 0) for k in dr.kernel_history())
        finally:
            dr.set_flag(dr.JitFlag.KernelHistory, False)

    out = {}
    for integrator in INTEGRATORS:
        path = write_far_scene(folder, 1e5, integrator=integrator)
        out[integrator] = (ops(_load(path, False)), ops(_load(path, True)))
    return out


_FIRST_LOAD = """
import sys, time
sys.path.insert(0, {root!r})
import pointillist
pointillist.setup("llvm_ad_rgb")
from pointillist.scene import instantiate_scene, load_scene, parse_scene
start = time.perf_counter()
scene = load_scene({path!r}) if {after} else instantiate_scene(parse_scene({path!r}))
print(time.perf_counter() - start)
"""


def _first_load(path: Path, after: bool) -> float:
    """Seconds of the first scene load in a fresh process (what ``pointillist render`` reports)."""
    code = _FIRST_LOAD.format(root=str(ROOT), path=str(path), after=after)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return float(done.stdout.strip().splitlines()[-1])


def load_times(folder: Path, rounds: int, first_rounds: int, bar):
    """Per scene: the first load in a fresh process and repeated loads in one process (median
    seconds as written / camera-relative, median per-round ratio, interleaved), and the camera-
    relative step's own median time (on copies of the parsed scene)."""
    import mitsuba as mi
    from _timing import interleaved, seconds

    from pointillist.camera_relative import make_camera_relative
    from pointillist.scene import ParsedScene, parse_scene
    from tests.far_scenes import write_far_scene

    def summary(times):
        """Medians (before, after), median per-round ratio, ratio of the minima, minima (before, after)."""
        return (statistics.median(times[False]), statistics.median(times[True]),
                statistics.median(a / b for a, b in zip(times[True], times[False])),
                min(times[True]) / min(times[False]), min(times[False]), min(times[True]))

    scenes = sorted((ROOT / "scenes").glob("*.xml")) + [write_far_scene(folder, 1e6, integrator="path")]
    rows = []
    for scene in scenes:
        first = {False: [], True: []}
        for r in range(first_rounds):
            for after in ((False, True) if r % 2 == 0 else (True, False)):
                first[after].append(_first_load(scene, after))
        # interleaved (benchmarks/_timing.py), after a warm-up load of each (plugins, files)
        timings = interleaved({after: (lambda after=after: _load(scene, after)) for after in (False, True)}, rounds)
        times = {after: timings[after].wall for after in (False, True)}
        parsed = parse_scene(scene)
        step = []
        for _ in range(rounds):
            copy = ParsedScene(parsed.path, parsed.params, mi.parser.ParserState(parsed.state), parsed.config)
            step.append(seconds(make_camera_relative, copy))
        rows.append({"scene": scene.name if scene.parent == ROOT / "scenes" else "the far-origin scene at 1e6 (path)",
                     "first": summary(first), "repeat": summary(times), "step": statistics.median(step),
                     "moved": copy.recentring.moved})
        bar.update(1)
    return rows


# ------------------------------------------------------------------ picture
def picture(images, path: Path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 4, figsize=(11, 8.6))
    for row, integrator in enumerate(INTEGRATORS):
        ref = images[(integrator, "origin")]
        top = np.percentile(ref, 99.5) or 1.0
        tol = 0.01 * np.abs(ref) + 1e-3 * ref.mean()
        panels = [(images[(integrator, False)], f"{integrator}: 1e6 from the origin, as written"),
                  (np.any(np.abs(images[(integrator, False)] - ref) > tol, -1), "pixels > 1 % off"),
                  (images[(integrator, True)], "camera-relative"),
                  (np.any(np.abs(images[(integrator, True)] - ref) > tol, -1), "pixels > 1 % off")]
        for k, (img, title) in enumerate(panels):
            ax = axes[row, k]
            if img.ndim == 3:
                ax.imshow(np.clip(img / top, 0, 1) ** (1 / 2.2))
            else:
                ax.imshow(img, cmap="magma", vmin=0, vmax=1)
            ax.set_title(title, fontsize=9)
            ax.set_axis_off()
    fig.tight_layout()
    from pointillist.core.files import save_figure

    save_figure(fig, path)


# ------------------------------------------------------------------ report
def _pct(x: float) -> str:
    return f"{100 * x:.2f} %"


def _offset_table(cells: dict, rows: list[tuple[str, str, tuple]], columns: tuple[str, str]) -> list[str]:
    """A Markdown table of before / after fractions: one row per (label, label, key), one column
    per offset; ``cells[key + (offset, after)]``."""
    out = [f"| {columns[0]} | {columns[1]} | " + " | ".join(f"{o:g} before / after" for o in OFFSETS) + " |",
           "|---|---|" + "---|" * len(OFFSETS)]
    for first, second, key in rows:
        out.append(f"| {first} | {second} | " + " | ".join(
            f"{_pct(cells[key + (o, False)])} / **{_pct(cells[key + (o, True)])}**" for o in OFFSETS) + " |")
    return out


def report(args, pixels, meshes, ops, loads, seconds, load_avg) -> str:
    import drjit as dr
    import mitsuba as mi

    out = ["## Far from the origin: camera-relative loading", "",
           f"Machine: {platform.machine()}, {os.cpu_count()} cores with other processes running (load average "
           f"{load_avg[0]:.1f} before, {load_avg[1]:.1f} after), {platform.platform()}; Python "
           f"{platform.python_version()}, Mitsuba {mi.__version__}, Dr.Jit {dr.__version__}. Run time {seconds:.0f} s. "
           f"Reproduce: `flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/far_origin.py --rounds "
           f"{args.rounds} --first-rounds {args.first_rounds}`.", "",
           "Pixels more than 1 % off (relative; absolute floor 1e-3 of the image mean) against the same integrator "
           "on the scene at the origin, same seed: the far-origin scene (tests/far_scenes.py, 80x80, 4 spp, seed 1) "
           "with every position written into the XML moved by the offset along the axis; *before*: loaded as "
           "written, *after*: camera-relative (`load_scene`, what `pointillist render` does). Goal: at most 0.5 % at "
           "1e4, 1e5, 1e6 for whitted and `path`.", ""]
    names = {"whitted": "whitted", "path": "`path` (max_depth 6)", "direct": "`direct`"}
    out += _offset_table(pixels, [(names[i], axis, (i, axis)) for i in INTEGRATORS for axis in AXES],
                         ("integrator", "axis"))
    out += ["", "![far origin](far_origin.png)", "",
            "Mesh files (the floor and the spheres as meshes, a UV sphere of 64 x 32 quads; offset along "
            "(1, 1, 1)): the offset written in the XML's `to_world` (float64 text, removed exactly), or the "
            "vertices stored in world coordinates, in a PLY (float32: the file already rounded them to the "
            "spacing there, 6.1e-5 at 1e3 .. 1 at 1e7; loading moves them exactly but cannot restore the lost "
            "digits) or in an OBJ (17-digit text: the digits are in the file, but Mitsuba's OBJ reader parses "
            "them into float32 before any transform). Against the same meshes at the origin:", ""]
    out += _offset_table(meshes, [(i, label, (i, storage)) for i in INTEGRATORS for storage, label in STORAGE.items()],
                         ("integrator", "vertices"))
    out += ["", "Render cost: the main kernel's operation count, the far-origin scene at 1e5, as written / camera-"
            "relative (the same kernels; only the data they read changes): " + ", ".join(
                f"{k} {a} / {b}" for k, (a, b) in ops.items()) + ".", "",
            "Load time: `load_scene` against parse + instantiate, interleaved: the first load in a fresh process "
            f"({args.first_rounds} rounds; what `pointillist render` reports as load; seconds, medians, with the "
            "median per-round ratio and the ratio of the minima) and repeated loads in one process (plugins and "
            f"files warm, so the step weighs most; the fastest of {args.rounds}, milliseconds: medians here swing "
            "by 10x with the other jobs); the step alone (median, on copies of the parsed scene) and its share of "
            "the first load. Goal: within 10 %:", "",
            "| scene | moved | first load (s) | ratio: median, minima | repeated load, fastest (ms) | ratio "
            "| the step alone (ms) | step / first load |", "|---|---|---|---|---|---|---|---|"]
    for row in loads:
        f, r = row["first"], row["repeat"]
        out.append(f"| {row['scene']} | {'yes' if row['moved'] else 'no'} | {f[0]:.3f} / {f[1]:.3f} | "
                   f"{f[2]:.3f}, {f[3]:.3f} | {1000 * r[4]:.2f} / {1000 * r[5]:.2f} | {r[3]:.3f} | "
                   f"{1000 * row['step']:.2f} | {100 * row['step'] / f[0]:.1f} % |")
    out += ["", "On this shared machine a load of these small scenes takes 1 ms, or 15-25 ms when another job "
            "takes the core; the step's own time is the figure that bounds the cost. Rerun on a quiet machine "
            "for the ratios."]
    return "\n".join(out)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=30, help="interleaved repeated-load rounds (default 30)")
    parser.add_argument("--first-rounds", type=int, default=5,
                        help="interleaved first-load rounds, two fresh processes each (default 5)")
    parser.add_argument("--write", action="store_true", help="write the section into benchmarks/RESULTS.md")
    args = parser.parse_args(argv)
    for name in ("rounds", "first_rounds"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')}: expected a positive integer")

    from tqdm import tqdm

    load_before = os.getloadavg()[0]
    start = time.perf_counter()
    mi = _setup()
    folder = Path(tempfile.mkdtemp(prefix="far_origin_"))
    with tqdm(total=len(INTEGRATORS) * len(AXES) * len(OFFSETS), desc="pixels") as bar:
        pixels, images = pixel_table(mi, folder, bar)
    picture(images, ROOT / "benchmarks" / "far_origin.png")
    with tqdm(total=len(INTEGRATORS) * len(STORAGE) * len(OFFSETS), desc="mesh files") as bar:
        meshes = mesh_table(mi, folder, bar)
    ops = kernel_ops(mi, folder)
    with tqdm(total=len(list((ROOT / "scenes").glob("*.xml"))) + 1, desc="load time") as bar:
        loads = load_times(folder, args.rounds, args.first_rounds, bar)
    text = report(args, pixels, meshes, ops, loads, time.perf_counter() - start, (load_before, os.getloadavg()[0]))
    print(text)
    if args.write:
        from _results import write_block

        write_block("far_origin", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
