"""Adaptive super-sampling against uniform ``jitter`` on scenes/edges.xml, in one run.

Goal (issue 9): adaptive reaches the RMSE of uniform 16 spp ``jitter`` in at most 50%
of its time, and the scheduling overhead (render time not spent tracing rays) is below
20% of the adaptive render.

For every configuration: the first call (JIT compile reported apart, in-process kernel
cache cold; the ``~/.drjit`` disk cache may be warm), then the median wall time of
``--repeats`` further renders with other seeds, each evaluated (``timed_render``
forces ``dr.eval`` + ``dr.sync_thread``). Errors are RMSE against a high-spp
``stratified`` reference (Mitsuba's own sampler, ``pointillist.compare``'s definition).
The adaptive integrator's own split of each render (seconds spent tracing: ray
generation, the nested integrator and evaluating its kernel, vs everything else)
gives the overhead.

Run::

    flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/adaptive.py
"""

from __future__ import annotations

import argparse
import platform
import statistics
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

JITTER_SPP = (4, 8, 16, 32)
#: (threshold, max_depth, min_depth)
ADAPTIVE = [(t, d, m) for m, d in ((0, 3), (0, 4), (1, 2), (1, 3), (1, 4)) for t in (32.0, 16.0, 8.0, 4.0)]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default=str(ROOT / "scenes" / "edges.xml"))
    parser.add_argument("--res", type=int, default=None, help="override the scene's resolution")
    parser.add_argument("--reference-spp", type=int, default=1024)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--plot", default=str(ROOT / "benchmarks" / "adaptive.png"))
    args = parser.parse_args(argv)

    import pointillist

    mi = pointillist.setup()
    import drjit as dr
    from tqdm import tqdm

    from pointillist.compare import (METHODS, REFERENCE_SEED, REFERENCE_SAMPLER, image_errors,
                                     load_configured_scene)
    from pointillist.scene import timed_render

    params = {"res": str(args.res)} if args.res else {}
    reference_scene = load_configured_scene(args.scene, METHODS[REFERENCE_SAMPLER], args.reference_spp, params)
    reference = np.asarray(mi.render(reference_scene, seed=REFERENCE_SEED))
    del reference_scene

    def measure(scene, **kwargs):
        integrator = kwargs.get("integrator")
        _, first = timed_render(scene, seed=0, **kwargs)
        times, traced, errors, counts = [], [], [], []
        for seed in range(1, args.repeats + 1):
            image, timing = timed_render(scene, seed=seed, **kwargs)
            pixels = np.asarray(image)
            times.append(timing.total)
            errors.append(image_errors(pixels[..., :3], reference, flip=False)["rmse"])
            if integrator is not None:
                traced.append(integrator.stats["trace_seconds"] / integrator.stats["total_seconds"])
                counts.append(float(pixels[..., -1].mean()))
        return {"first": first.total, "compile": first.compile, "time": statistics.median(times),
                "rmse": float(np.mean(errors)),
                "traced": statistics.median(traced) if traced else 1.0,
                "spp": statistics.mean(counts) if counts else None,
                "image": pixels}

    rows = []
    jobs = [("jitter", spp) for spp in JITTER_SPP] + [("adaptive", config) for config in ADAPTIVE]
    for kind, config in tqdm(jobs, desc="adaptive benchmark", file=sys.stderr):
        if kind == "jitter":
            scene = load_configured_scene(args.scene, METHODS["jitter"], config, params)
            result = measure(scene, spp=config)
            result.update(name=f"jitter {config} spp", spp=float(config))
        else:
            threshold, max_depth, min_depth = config
            scene = load_configured_scene(args.scene, METHODS["jitter"], 16, params)
            nested = scene.integrator()
            integrator = mi.load_dict({"type": "adaptive", "threshold": threshold, "max_depth": max_depth,
                                       "min_depth": min_depth, "nested": nested})
            result = measure(scene, integrator=integrator)
            result.update(name=f"adaptive t={threshold:g} depth {min_depth}..{max_depth}")
        result["kind"] = kind
        rows.append(result)
        dr.flush_malloc_cache()

    goal = next(r for r in rows if r["name"] == "jitter 16 spp")
    reached = [r for r in rows if r["kind"] == "adaptive" and r["rmse"] <= goal["rmse"]]
    best = min(reached, key=lambda r: r["time"]) if reached else min(
        (r for r in rows if r["kind"] == "adaptive"), key=lambda r: r["rmse"])

    print(f"machine: {platform.machine()} {platform.processor() or ''}, Python {platform.python_version()}, "
          f"Mitsuba {mi.__version__}, Dr.Jit {dr.__version__}, scene {Path(args.scene).name} "
          f"{reference.shape[1]}x{reference.shape[0]}, reference {REFERENCE_SAMPLER} {args.reference_spp} spp")
    print()
    print("| method | mean spp | RMSE | RMSE / jitter-16 | time (median) s | time / jitter-16 | "
          "first call s (JIT compile s) | tracing share |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['name']} | {r['spp']:.2f} | {r['rmse']:.5f} | {r['rmse'] / goal['rmse']:.2f} | "
              f"{r['time']:.3f} | {r['time'] / goal['time']:.2f} | {r['first']:.2f} ({r['compile']:.2f}) | "
              f"{r['traced'] * 100:.0f}% |")
    print()
    if reached:
        print(f"goal RMSE <= jitter-16 ({goal['rmse']:.5f}) reached by {best['name']} in "
              f"{best['time']:.3f} s = {best['time'] / goal['time']:.2f} x jitter-16's {goal['time']:.3f} s "
              f"(goal <= 0.50: {'met' if best['time'] <= 0.5 * goal['time'] else 'NOT met'})")
    else:
        print(f"goal NOT met: no adaptive configuration reaches jitter-16's RMSE {goal['rmse']:.5f}; "
              f"the best, {best['name']}, has {best['rmse']:.5f} in {best['time']:.3f} s")
    print(f"scheduling overhead of {best['name']}: {(1 - best['traced']) * 100:.0f}% of the render "
          f"(goal < 20%: {'met' if best['traced'] > 0.8 else 'NOT met'})")
    _plot(rows, best, goal, args.plot)
    print(f"plot: {args.plot}")
    return 0


def _plot(rows, best, goal, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.5), dpi=100)
    jit = [r for r in rows if r["kind"] == "jitter"]
    left.loglog([r["time"] for r in jit], [r["rmse"] for r in jit], "o-", label="jitter (4, 8, 16, 32 spp)")
    for min_depth, marker in ((0, "s"), (1, "^")):
        for max_depth, colour in ((2, "tab:green"), (3, "tab:orange"), (4, "tab:red")):
            sel = [r for r in rows if r["kind"] == "adaptive" and f"depth {min_depth}..{max_depth}" in r["name"]]
            if not sel:
                continue
            left.loglog([r["time"] for r in sel], [r["rmse"] for r in sel], marker + "--", color=colour,
                        label=f"adaptive depth {min_depth}..{max_depth} (t = 32..4)")
    left.axhline(goal["rmse"], color="grey", lw=0.8)
    left.axvline(0.5 * goal["time"], color="grey", lw=0.8, ls=":")
    left.set_xlabel("render time (s, median)")
    left.set_ylabel("RMSE vs reference")
    left.legend(fontsize=7)
    left.set_title("error against time (lines: jitter-16 RMSE, half its time)", fontsize=9)
    counts = best["image"][..., -1]
    shown = right.imshow(counts, cmap="viridis", interpolation="nearest")
    fig.colorbar(shown, ax=right, label="samples per pixel")
    right.set_title(f"{best['name']}: sample count (mean {counts.mean():.1f})", fontsize=9)
    right.set_axis_off()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
