"""Benchmark of the grid / jitter / poisson samplers and of `pointillist compare`, and of sobol / zsobol.

Measures, side by side in one run (``--part patterns``, the default):

1. sampler overhead: render time of ``jitter`` (and grid, poisson) against Mitsuba's
   ``stratified`` and ``independent`` at 64 spp, on scenes/edges.xml (direct) and on
   Mitsuba's Cornell box (path, many sampler dimensions); first call (JIT compile)
   apart from the steady state (median of repeats, image evaluated);
2. Poisson set generation (uncached) against one 64 spp render;
3. the default comparison sweep (`pointillist compare scenes/edges.xml`) wall time, and
   a 3-seed sweep with stratified added, for the slopes and the "within noise" check.

Run:  flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/samplers.py
Prints a Markdown block for benchmarks/RESULTS.md.

``--part sobol`` (``--write`` puts it into the ``samplers_sobol`` block of RESULTS.md) measures the
Sobol' samplers against random and jitter:

1. render time at 16 spp of ``zsobol`` and ``sobol`` against ``independent`` (and ``jitter``),
   interleaved rounds, medians, on edges.xml 256x256 (direct) and the Cornell box 128x128 (path,
   many dimensions), first call (JIT compile) apart; goal: zsobol at most 1.2x independent;
2. a `pointillist compare scenes/edges.xml --samplers random,jitter,sobol,zsobol --spp 1,4,16,64
   --seeds S` sweep: MSE slopes (goal: sobol and zsobol at least as steep as jitter), and at 1 and 4
   spp the error's energy below a quarter of Nyquist (goal: zsobol at most half of random's) and
   zsobol's MSE against sobol's (goal: within 10 %); its spectrum plot is kept as
   benchmarks/samplers_sobol_spectrum.png.

Run:  flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/samplers.py --part sobol --write
"""

from __future__ import annotations

import argparse
import csv
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def render_times(mi, scene, spp, repeats):
    """First call and median steady-state total render time of ``scene``."""
    from pointillist.scene import timed_render

    _, first = timed_render(scene, spp=spp, seed=0)
    steady = []
    for i in range(repeats):
        _, t = timed_render(scene, spp=spp, seed=i + 1)
        steady.append(t.total)
    return first, float(np.median(steady))


def cornell(mi, sampler, spp, res=128):
    d = mi.cornell_box()
    d["sensor"]["sampler"] = {"type": sampler, "sample_count": spp}
    d["sensor"]["film"]["width"] = d["sensor"]["film"]["height"] = res
    return mi.load_dict(d)


def sweep(args_list, out):
    """Wall seconds of one ``pointillist compare`` process (benchmarks/_timing.py)."""
    from _timing import timed

    done, wall, _ = timed(subprocess.run, [sys.executable, "-m", "pointillist", "compare",
                                           str(ROOT / "scenes/edges.xml"), "--out", str(out), "--no-progress",
                                           *args_list], capture_output=True, text=True, cwd=ROOT)
    if done.returncode:
        raise SystemExit(done.stderr)
    return wall


def read_rows(out):
    with open(out / "results.csv") as handle:
        return list(csv.DictReader(handle))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--part", choices=("patterns", "sobol"), default="patterns")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--write", action="store_true",
                        help="write the part's block into RESULTS.md (samplers, or samplers_sobol)")
    args = parser.parse_args()
    if args.part == "sobol":
        sobol_part(args)
        return

    import drjit as dr
    import mitsuba as mi

    import pointillist
    from pointillist.compare.methods import METHODS, load_configured_scene
    from pointillist.compare.tables import fit_slope

    pointillist.setup()
    from pointillist.plugins.samplers.poisson import poisson_disk_points
    from _timing import load as load_average
    from _timing import load_note

    load_before = load_average()
    lines = [f"Machine: {platform.machine()}, {os.cpu_count()} cores; Python {platform.python_version()}, "
             f"Mitsuba {mi.__version__}, Dr.Jit {dr.__version__}, libLLVM {dr.detail.llvm_version()}.",
             "Command: `flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/samplers.py`", ""]

    # 1. sampler overhead at 64 spp
    lines += ["**Sampler overhead at 64 spp** (render wall time, image evaluated; first call includes "
              "JIT compile or ~/.drjit cache load; steady = median of "
              f"{args.repeats}, samplers interleaved round robin; ratio = steady / stratified's steady)", "",
              "| scene | sampler | first call (s) | steady (s) | ratio vs stratified |", "|---|---|---:|---:|---:|"]
    overhead = {}
    for label, make in (("edges.xml 256², direct", lambda s: load_configured_scene(
            ROOT / "scenes/edges.xml", METHODS[s], 64)),
                        ("Cornell box 128², path", lambda s: cornell(mi, s, 64))):
        from pointillist.scene import timed_render

        names = ("stratified", "independent", "jitter", "grid", "poisson")
        scenes = {name: make(name) for name in names}
        first = {name: timed_render(scenes[name], spp=64, seed=0)[1] for name in names}
        steady = {name: [] for name in names}
        for i in range(args.repeats):  # round robin, so that load changes hit every sampler alike
            for name in names:
                steady[name].append(timed_render(scenes[name], spp=64, seed=i + 1)[1].total)
        results = {name: (first[name], float(np.median(steady[name]))) for name in names}
        base = results["stratified"][1]
        for sampler, (first, steady) in results.items():
            lines.append(f"| {label} | {sampler} | {first.total:.3f} | {steady:.3f} | {steady / base:.3f} |")
        overhead[label] = results["jitter"][1] / base

    # 2. Poisson generation
    render64 = render_times(mi, load_configured_scene(ROOT / "scenes/edges.xml", METHODS["poisson"], 64),
                            64, 3)[1]
    lines += ["", "**Poisson set generation** (Bridson on the torus, NumPy, not the shipped sets) against one 64 spp "
              "render of edges.xml", "", "| points | generation (ms) | r / r_hex | share of 64 spp render |",
              "|---:|---:|---:|---:|"]
    from _timing import repeat

    from pointillist.plugins.samplers.poisson import (generate_poisson_disk_points, hexagonal_radius,
                                                      toroidal_min_distance)

    for n in (16, 64, 256, 1024):
        g = repeat(lambda n=n: generate_poisson_disk_points(n), 3, warmup=False).median
        pts, r = generate_poisson_disk_points(n)
        share = f"{g / render64:.1%}" if n == 64 else ""
        lines.append(f"| {n} | {g * 1000:.1f} | {toroidal_min_distance(pts) / hexagonal_radius(n):.3f} | {share} |")
    load = repeat(lambda: poisson_disk_points.__wrapped__(64), 5, warmup=False).median
    generate = repeat(lambda: generate_poisson_disk_points(64), 3, warmup=False).median
    poisson_share = load / render64
    lines += ["", f"64 points: shipped set read {load * 1000:.1f} ms = {load / render64:.1%} of a 64 spp render "
              f"({render64 * 1000:.0f} ms); generated instead {generate * 1000:.1f} ms = {generate / render64:.1%}."]

    # 3. sweeps
    tmp = Path(tempfile.mkdtemp(prefix="pointillist-bench-"))
    try:
        default_s = sweep([], tmp / "default")
        drjit_note = "warm ~/.drjit cache"
        seeds_s = sweep(["--samplers", "grid,jitter,random,poisson,stratified", "--seeds", str(args.seeds),
                         "--reference", str(next((tmp / "default" / "reference" / "renders").rglob("*.exr")))],
                        tmp / "seeds")
        rows = read_rows(tmp / "seeds")
    finally:
        pass
    methods = ["grid", "jitter", "random", "poisson", "stratified"]
    spps = sorted({float(r["spp"]) for r in rows})
    mse = {(m, s): [float(r["rmse"]) ** 2 for r in rows if r["method"] == m and float(r["spp"]) == s]
           for m in methods for s in spps}
    lines += ["", f"**Default sweep** `pointillist compare scenes/edges.xml` (4 samplers x 1,4,16,64,256 spp, "
              f"reference 4096 spp stratified, 256²): **{default_s:.1f} s** wall ({drjit_note}).", "",
              f"**Error (MSE, mean ± std over {args.seeds} seeds) on edges.xml** ({seeds_s:.1f} s)", "",
              "| spp | " + " | ".join(methods) + " |", "|---:|" + "---:|" * len(methods)]
    for s in spps:
        lines.append(f"| {s:g} | " + " | ".join(f"{np.mean(mse[m, s]):.2e} ± {np.std(mse[m, s], ddof=1):.1e}"
                                                for m in methods) + " |")
    slopes = {m: fit_slope([s for s in spps for _ in mse[m, s]], [v for s in spps for v in mse[m, s]])
              for m in methods}
    lines += ["", "| fitted MSE-vs-spp slope | " + " | ".join(f"{m} {slopes[m]:.2f}" for m in methods) + " |",
              "|---|" + "---|" * len(methods)]
    poisson_better = all(np.mean(mse["poisson", s]) < np.mean(mse["random", s]) for s in spps if s >= 16)
    within = []
    for s in spps:
        a, b = np.array(mse["jitter", s]), np.array(mse["stratified", s])
        noise = np.sqrt(a.var(ddof=1) / len(a) + b.var(ddof=1) / len(b))
        within.append(abs(a.mean() - b.mean()) <= 3 * noise)
    lines += ["", "**Goals**", "",
              f"- random slope about -1: {slopes['random']:.2f}; jitter slope <= -1.3: {slopes['jitter']:.2f} "
              f"({'met' if slopes['jitter'] <= -1.3 and abs(slopes['random'] + 1) < 0.15 else 'NOT met'})",
              f"- poisson MSE below random at every spp >= 16: {'met' if poisson_better else 'NOT met'}",
              f"- jitter within noise (3 standard errors) of stratified at every spp: "
              f"{'met' if all(within) else 'NOT met'} ({sum(within)}/{len(within)})",
              "- jitter render time <= 1.1x stratified at 64 spp: " + ", ".join(
                  f"{k}: {v:.3f}x" for k, v in overhead.items()) + (
                  " (met)" if max(overhead.values()) <= 1.1 else " (NOT met)"),
              f"- Poisson generation <= 10% of a 64 spp render: {poisson_share:.1%} "
              f"({'met' if poisson_share <= 0.1 else 'NOT met'})",
              f"- default sweep under 5 minutes: {default_s:.1f} s ({'met' if default_s < 300 else 'NOT met'})"]
    shutil.copy(tmp / "seeds" / "error_vs_spp.png", ROOT / "benchmarks" / "samplers_error_vs_spp.png")
    shutil.copy(tmp / "seeds" / "error_vs_time.png", ROOT / "benchmarks" / "samplers_error_vs_time.png")
    shutil.rmtree(tmp, ignore_errors=True)
    lines.insert(1, f"Load: {load_note(load_before, load_average())}.")
    text = "## Samplers (grid, jitter, poisson) and `pointillist compare`\n\n" + "\n".join(lines)
    print(text)
    if args.write:
        from _results import write_block

        print(f"wrote {write_block('samplers', text)}")


SOBOL_METHODS = ("random", "jitter", "sobol", "zsobol")


def sobol_part(args) -> None:
    """sobol / zsobol against random and jitter: render cost at 16 spp, then a compare sweep's errors."""
    import drjit as dr
    import mitsuba as mi

    import pointillist
    from pointillist.compare.methods import METHODS, load_configured_scene
    from pointillist.compare.tables import fit_slope
    from pointillist.scene import timed_render

    pointillist.setup()
    load_before = os.getloadavg()
    repeats = max(args.repeats, 15)
    lines = ["## sobol and zsobol", "",
             f"Machine: {platform.machine()}, {os.cpu_count()} cores; Python {platform.python_version()}, "
             f"Mitsuba {mi.__version__}, Dr.Jit {dr.__version__}, libLLVM {dr.detail.llvm_version()}.",
             "Command: `flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/samplers.py --part sobol "
             f"--repeats {args.repeats} --seeds {args.seeds} --write`", ""]

    # 1. cost at 16 spp, interleaved
    lines += [f"**Render time at 16 spp** (image evaluated; first call = JIT compile or ~/.drjit cache load; steady = "
              f"median of {repeats} interleaved rounds, wall clock and this process's CPU time (all its threads: "
              "the work, without the waiting for other processes); the four scenes of a row group are loaded "
              "together, so each pays alike for the others' instances; kernel operations: the render kernel's "
              "size in Dr.Jit IR operations)", "",
              "| scene | sampler | first call (s) | of which compile (s) | steady wall (s) | wall ratio vs independent "
              "| steady CPU (s) | CPU ratio | kernel operations |",
              "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    names = ("independent", "jitter", "sobol", "zsobol")
    ratios = {}
    for label, make in (("edges.xml 256², direct", lambda n: load_configured_scene(
            ROOT / "scenes/edges.xml", METHODS[n], 16)), ("Cornell box 128², path", lambda n: cornell(mi, n, 16))):
        scenes = {name: make(name) for name in names}
        if label.startswith("Cornell"):
            from pointillist.scene import attach_films

            for scene in scenes.values():
                attach_films(scene)
        first = {name: timed_render(scenes[name], spp=16, seed=0)[1] for name in names}
        operations = {name: _kernel_operations(mi, scenes[name]) for name in names}
        steady = {name: [] for name in names}
        cpu = {name: [] for name in names}
        for i in range(repeats):
            order = names if i % 2 == 0 else names[::-1]  # alternate, so that who runs first varies
            for name in order:
                start = time.process_time()
                steady[name].append(timed_render(scenes[name], spp=16, seed=i + 1)[1].total)
                cpu[name].append(time.process_time() - start)
        base, base_cpu = float(np.median(steady["independent"])), float(np.median(cpu["independent"]))
        for name in names:
            median, median_cpu = float(np.median(steady[name])), float(np.median(cpu[name]))
            ratios[label, name] = median / base
            lines.append(f"| {label} | {name} | {first[name].total:.3f} | {first[name].compile:.3f} | {median:.4f} | "
                         f"{median / base:.3f} | {median_cpu:.4f} | {median_cpu / base_cpu:.3f} | "
                         f"{operations[name]} |")
        del scenes
    load_mid = os.getloadavg()

    # 2. the compare sweep
    tmp = Path(tempfile.mkdtemp(prefix="pointillist-bench-sobol-"))
    try:
        seconds = sweep(["--samplers", ",".join(SOBOL_METHODS), "--spp", "1,4,16,64", "--seeds", str(args.seeds),
                         "--no-report"], tmp)
        rows = read_rows(tmp)
        shutil.copy(tmp / "error_spectrum.png", ROOT / "benchmarks" / "samplers_sobol_spectrum.png")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    load_after = os.getloadavg()
    spps = (1.0, 4.0, 16.0, 64.0)

    def mean(method, spp, field):
        values = [float(r[field]) ** (2 if field == "rmse" else 1) for r in rows
                  if r["method"] == method and float(r["value"]) == spp]
        return float(np.mean(values)), float(np.std(values, ddof=1)) if len(values) > 1 else 0.0

    lines += ["", f"**Error on edges.xml** (`pointillist compare scenes/edges.xml --samplers {','.join(SOBOL_METHODS)} "
              f"--spp 1,4,16,64 --seeds {args.seeds}`, 256², reference 4096 spp stratified; {seconds:.0f} s): MSE "
              "(RGB) and low-freq MSE (the part of the luminance error's mean square at frequencies up to a quarter "
              "of Nyquist), mean ± std over seeds", "",
              "| spp | " + " | ".join(f"{m} MSE | {m} low-freq" for m in SOBOL_METHODS) + " |",
              "|---:|" + "---:|---:|" * len(SOBOL_METHODS)]
    for spp in spps:
        cells = []
        for m in SOBOL_METHODS:
            mse, mse_sd = mean(m, spp, "rmse")
            low, low_sd = mean(m, spp, "lowfreq")
            cells += [f"{mse:.3e} ± {mse_sd:.1e}", f"{low:.2e} ± {low_sd:.1e}"]
        lines.append(f"| {spp:g} | " + " | ".join(cells) + " |")
    slopes = {m: fit_slope([float(r["spp"]) for r in rows if r["method"] == m],
                           [float(r["rmse"]) ** 2 for r in rows if r["method"] == m]) for m in SOBOL_METHODS}
    low_ratio = {spp: mean("zsobol", spp, "lowfreq")[0] / mean("random", spp, "lowfreq")[0] for spp in (1.0, 4.0)}
    mse_ratio = {spp: mean("zsobol", spp, "rmse")[0] / mean("sobol", spp, "rmse")[0] for spp in (1.0, 4.0)}
    cost = {label: ratios[label, "zsobol"] for label in dict.fromkeys(k[0] for k in ratios)}
    analytic = blue_noise_shares(mi)
    lines += ["", "| fitted MSE-vs-spp slope (1..64 spp) | " + " | ".join(f"{m} {slopes[m]:.2f}" for m in SOBOL_METHODS)
              + " |", "|---|" + "---|" * len(SOBOL_METHODS), "",
              "**Goals**", "",
              f"- sobol and zsobol converge at least as fast as jitter: slopes {slopes['sobol']:.2f}, "
              f"{slopes['zsobol']:.2f} vs {slopes['jitter']:.2f} "
              f"({'met' if max(slopes['sobol'], slopes['zsobol']) <= slopes['jitter'] else 'NOT met'})",
              "- zsobol's low-freq error at most half of random's: " + ", ".join(
                  f"{spp:g} spp {r:.2f}x ({'met' if r <= 0.5 else 'NOT met'})" for spp, r in low_ratio.items()),
              "- zsobol's MSE within 10 % of sobol's: " + ", ".join(
                  f"{spp:g} spp {r:.3f}x ({'met' if abs(r - 1) <= 0.1 else 'NOT met'})"
                  for spp, r in mse_ratio.items()),
              "- a zsobol render at most 1.2x independent's at 16 spp: " + ", ".join(
                  f"{label} {r:.2f}x ({'met' if r <= 1.2 else 'NOT met'})" for label, r in cost.items()),
              "",
              "Why not at 1 spp on edges.xml: its error lies in one-pixel-wide lines (checker edges, wires, "
              "silhouettes), and each pixel of such a line integrates another edge than its neighbours, so the "
              "complementary samples zsobol gives neighbouring pixels cancel little. At 4 spp it holds because "
              "zsobol's error is lower at every frequency. Where neighbouring pixels "
              "integrate alike, zsobol's 1-spp error is blue noise: the same integrand in every pixel of a 256² "
              "film, the share of the error's mean square below a quarter of Nyquist (mean of 4 seeds; white "
              "noise: pi/64 = 0.049):", "",
              "| integrand over the pixel | " + " | ".join(analytic["names"]) + " | zsobol / random |",
              "|---|" + "---:|" * (len(analytic["names"]) + 1)]
    for label, shares in analytic["rows"].items():
        lines.append(f"| {label} | " + " | ".join(f"{v:.4f}" for v in shares) + f" | {shares[-1] / shares[0]:.2f} |")
    lines += ["",
              f"Load average (1, 5, 15 min): {load_before[0]:.1f} / {load_before[1]:.1f} / {load_before[2]:.1f} "
              "before, "
              f"{load_mid[0]:.1f} after the timings, {load_after[0]:.1f} after the sweep, on 2 cores with other "
              "processes running: the interleaved rounds make the ratios fair, not the absolute times, which want a "
              "rerun on a quiet machine. Spectra: `benchmarks/samplers_sobol_spectrum.png` (compare's "
              "error_spectrum.png of this sweep)."]
    text = "\n".join(lines)
    print(text)
    if args.write:
        from _results import write_block

        print(f"wrote {write_block('samplers_sobol', text)}")


def _kernel_operations(mi, scene) -> int:
    """IR operations of the largest kernel of a 16-spp render of ``scene`` (its render kernel)."""
    import drjit as dr

    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()
        dr.eval(mi.render(scene, spp=16, seed=99))
        dr.sync_thread()
        return max(k["operation_count"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT)
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)


def blue_noise_shares(mi, side: int = 256, seeds: int = 4) -> dict:
    """Share of the 1-spp error's mean square below a quarter of Nyquist, for integrands that are the same
    in every pixel (a step, a smooth product, a disk), per sampler (film positions drawn by the sampler)."""
    from pointillist.imaging.spectrum import low_frequency_energy

    integrands = {"step x < 0.3": (lambda p: (p[..., 0] < 0.3).astype(float), 0.3),
                  "x y": (lambda p: p[..., 0] * p[..., 1], 0.25),
                  "disk of radius 0.4": (lambda p: (np.hypot(p[..., 0] - 0.5, p[..., 1] - 0.5) < 0.4).astype(float),
                                         np.pi * 0.16)}
    names = ("independent", "sobol", "zsobol")
    film = mi.load_dict({"type": "hdrfilm", "width": side, "height": side, "rfilter": {"type": "box"}})
    rows = {label: [] for label in integrands}
    for name in names:
        sampler = mi.load_dict({"type": name, "sample_count": 1})
        if hasattr(sampler, "attach_film"):
            sampler.attach_film(film)
        points = []
        for seed in range(seeds):
            sampler.seed(seed, side * side)
            points.append(np.asarray(sampler.next_2d()).T.reshape(side, side, 2))
        for label, (f, integral) in integrands.items():
            shares = [low_frequency_energy(f(p) - integral) / float(((f(p) - integral) ** 2).mean()) for p in points]
            rows[label].append(float(np.mean(shares)))
    return {"names": names, "rows": rows}


if __name__ == "__main__":
    main()
