"""Benchmark of the grid / jitter / poisson samplers and of `pointillist compare`.

Measures, side by side in one run:

1. sampler overhead: render time of ``jitter`` (and grid, poisson) against Mitsuba's
   ``stratified`` and ``independent`` at 64 spp, on scenes/edges.xml (direct) and on
   Mitsuba's Cornell box (path, many sampler dimensions); first call (JIT compile)
   apart from the steady state (median of repeats, image evaluated);
2. Poisson set generation (uncached) against one 64 spp render;
3. the default comparison sweep (`pointillist compare scenes/edges.xml`) wall time, and
   a 3-seed sweep with stratified added, for the slopes and the "within noise" check.

Run:  flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/samplers.py
Prints a Markdown block for benchmarks/RESULTS.md.
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
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "pointillist", "compare", str(ROOT / "scenes/edges.xml"),
                           "--out", str(out), "--no-progress", *args_list], capture_output=True, text=True,
                          cwd=ROOT)
    if done.returncode:
        raise SystemExit(done.stderr)
    return time.perf_counter() - start


def read_rows(out):
    with open(out / "results.csv") as handle:
        return list(csv.DictReader(handle))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--seeds", type=int, default=3)
    args = parser.parse_args()

    import drjit as dr
    import mitsuba as mi

    import pointillist
    from pointillist.compare_methods import METHODS, load_configured_scene
    from pointillist.compare_report import fit_slope

    pointillist.setup()
    from pointillist.plugins.samplers.poisson import poisson_disk_points
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
    from pointillist.plugins.samplers.poisson import (generate_poisson_disk_points, hexagonal_radius,
                                                      toroidal_min_distance)

    for n in (16, 64, 256, 1024):
        gen = []
        for _ in range(3):
            t = time.perf_counter()
            pts, r = generate_poisson_disk_points(n)
            gen.append(time.perf_counter() - t)
        g = float(np.median(gen))
        share = f"{g / render64:.1%}" if n == 64 else ""
        lines.append(f"| {n} | {g * 1000:.1f} | {toroidal_min_distance(pts) / hexagonal_radius(n):.3f} | {share} |")
    load = float(np.median([_timed(lambda: poisson_disk_points.__wrapped__(64)) for _ in range(5)]))
    generate = float(np.median([_timed(lambda: generate_poisson_disk_points(64)) for _ in range(3)]))
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
    print("\n".join(lines))


def _timed(fn):
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


if __name__ == "__main__":
    main()
