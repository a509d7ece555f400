"""Adaptive super-sampling against uniform ``jitter`` on scenes/edges.xml, in one run.

Goals: adaptive reaches the RMSE of uniform 16 spp ``jitter`` in at most 50%
of its time, and the scheduling overhead (render time not spent tracing rays) is below
20% of the adaptive render.

Two nested integrators: the scene's ``direct`` (cheap rays: ~25 ms for a whole 16 spp
render, so fixed per-level costs weigh most) and ``path`` with ``max_depth`` 8 (the
issue's "wrapping a nested integrator", where ray tracing dominates). For every
configuration: a first call (JIT compile reported apart; in-process kernel cache cold,
the ``~/.drjit`` disk cache may be warm), then ``--repeats`` rounds in which every
configuration renders once with a new seed, in rotating order, so that load from
other processes hits all of them alike; times are medians over the rounds, each render
evaluated (``timed_render``: ``dr.eval`` + ``dr.sync_thread``). As in ``pointillist
compare``, every render gets a freshly loaded scene, freed after it (one scene alive at a
time), and ``adaptive`` renders the scene as written (its ``independent`` sampler
drives the nested integrator's random numbers) while ``jitter`` gets its sampler. Errors are RMSE against
a high-spp ``stratified`` reference (``pointillist.compare``'s definition), averaged
over the rounds. The adaptive integrator's own split of each render (seconds tracing:
ray generation, the nested integrator and evaluating that kernel, vs everything else)
gives the scheduling overhead; "launches" counts JIT kernel launches per render.

Run::

    flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/adaptive.py
"""

from __future__ import annotations

import argparse
import gc
import platform
import statistics
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

JITTER_SPP = (4, 8, 16, 32)
#: (threshold, min_depth, max_depth) per nested integrator.
ADAPTIVE = {
    "direct": [(t, m, d) for m, d in ((0, 3), (1, 2), (1, 3), (1, 4)) for t in (128.0, 64.0, 32.0, 16.0)],
    "path8": [(t, m, d) for m, d in ((0, 3), (1, 2), (1, 3)) for t in (128.0, 64.0, 16.0)],
}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default=str(ROOT / "scenes" / "edges.xml"))
    parser.add_argument("--res", type=int, default=None, help="override the scene's resolution")
    parser.add_argument("--reference-spp", type=int, default=1024)
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--nested", default="direct,path8", help="direct, path8 or both")
    parser.add_argument("--plot", default=str(ROOT / "benchmarks" / "adaptive.png"))
    parser.add_argument("--write", action="store_true", help="write the section into benchmarks/RESULTS.md")
    args = parser.parse_args(argv)

    import pointillist

    mi = pointillist.setup()
    import drjit as dr
    from tqdm import tqdm

    from pointillist.compare import REFERENCE_SAMPLER, REFERENCE_SEED
    from pointillist.imaging.metrics import image_errors
    from pointillist.compare.methods import METHODS, load_configured_scene
    from pointillist.scene import load_scene, timed_render

    from _timing import load, load_note

    params = {"res": str(args.res)} if args.res else {}
    load_before = load()
    suites = {}
    for nested_name in [n.strip() for n in args.nested.split(",") if n.strip()]:
        nested_dict = None if nested_name == "direct" else {"type": "path", "max_depth": 8}
        suites[nested_name] = run_suite(mi, dr, tqdm, args, params, nested_name, nested_dict, METHODS,
                                        REFERENCE_SAMPLER, REFERENCE_SEED, image_errors, load_configured_scene,
                                        load_scene, timed_render)
    _plot(suites, args.plot)
    reproduce = " ".join(["flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/adaptive.py",
                          *(argv if argv is not None else sys.argv[1:])]).replace(" --write", "")
    lines = ["## Adaptive super-sampling", "",
             f"Machine: {platform.machine()}, Python {platform.python_version()}, Mitsuba {mi.__version__}, "
             f"Dr.Jit {dr.__version__}; {load_note(load_before, load())}. Scene {Path(args.scene).name}, reference "
             f"{REFERENCE_SAMPLER} {args.reference_spp} spp, medians of {args.repeats} interleaved rounds. "
             f"Reproduce: `{reproduce}`."]
    for suite in suites.values():
        lines += suite["lines"]
    lines += ["", f"![adaptive]({Path(args.plot).name})"]
    text = "\n".join(lines)
    print(text)
    if args.write:
        from _results import write_block

        write_block("adaptive", text)
    return 0


def run_suite(mi, dr, tqdm, args, params, nested_name, nested_dict, METHODS, REFERENCE_SAMPLER, REFERENCE_SEED,
              image_errors, load_configured_scene, load_scene, timed_render):
    reference_scene = load_configured_scene(args.scene, METHODS[REFERENCE_SAMPLER], args.reference_spp, params)
    nested = mi.load_dict(nested_dict) if nested_dict else reference_scene.integrator()
    reference = np.array(mi.render(reference_scene, integrator=nested, seed=REFERENCE_SEED))[..., :3]
    del reference_scene
    # The reference's wavefront (W H spp lanes) leaves GBs in Dr.Jit's allocation cache:
    # give them back, or every later render runs under memory pressure (2x slower here).
    dr.sync_thread()
    dr.flush_malloc_cache()

    # A fresh scene per render, freed after it, as `pointillist compare` does: Mitsuba
    # dispatches shape / BSDF / emitter calls over every instance alive in the process,
    # so each extra loaded scene slows every render (here 20 idle copies of edges.xml
    # made a jitter-16 render 2x slower, and adaptive, with more ray batches, up to 5x;
    # tables before 2026-11 were measured with 24 scenes alive). Loading takes ~1 ms,
    # outside the timed span. jitter's scene gets the jitter sampler; adaptive renders
    # the scene as written (its own sampler, as in compare).
    gc.collect()
    entries = []
    for spp in JITTER_SPP:
        entries.append({"name": f"jitter {spp} spp", "kind": "jitter", "spp": float(spp),
                        "load": lambda: load_configured_scene(args.scene, METHODS["jitter"], 16, params),
                        "kwargs": {"spp": spp, "integrator": nested}, "integrator": None})
    for threshold, min_depth, max_depth in ADAPTIVE[nested_name]:
        integrator = mi.load_dict({"type": "adaptive", "threshold": threshold, "max_depth": max_depth,
                                   "min_depth": min_depth, "nested": nested})
        entries.append({"name": f"adaptive t={threshold:g} depth {min_depth}..{max_depth}", "kind": "adaptive",
                        "load": lambda: load_scene(args.scene, params),
                        "kwargs": {"integrator": integrator}, "integrator": integrator,
                        "config": (threshold, min_depth, max_depth)})

    def render(e, seed):
        scene = e["load"]()
        try:
            return timed_render(scene, seed=seed, **e["kwargs"])
        finally:
            del scene
            gc.collect()

    for e in entries:
        image, first = render(e, 0)
        e.update(first=first.total, compile=first.compile, times=[], errors=[], traced=[], counts=[], launches=[])
        del image
    rounds = range(1, args.repeats + 1)
    for r in tqdm(rounds, desc=f"adaptive benchmark ({nested_name})", file=sys.stderr):
        order = entries[r % len(entries):] + entries[:r % len(entries)]
        for e in order:
            image, timing = render(e, r)
            pixels = np.asarray(image)
            e["times"].append(timing.total)
            e["launches"].append(timing.kernels)
            e["errors"].append(image_errors(pixels[..., :3], reference, flip=False)["rmse"])
            if e["integrator"] is not None:
                stats = e["integrator"].stats
                e["traced"].append(stats["trace_seconds"] / stats["total_seconds"])
                e["counts"].append(float(pixels[..., -1].mean()))
                e["stats"] = dict(stats)
    dr.flush_malloc_cache()
    rows = []
    for e in entries:
        rows.append({"name": e["name"], "kind": e["kind"], "time": statistics.median(e["times"]),
                     "rmse": float(np.mean(e["errors"])), "first": e["first"], "compile": e["compile"],
                     "traced": statistics.median(e["traced"]) if e["traced"] else 1.0,
                     "spp": statistics.mean(e["counts"]) if e["counts"] else e["spp"],
                     "launches": statistics.median(e["launches"]), "stats": e.get("stats"),
                     "config": e.get("config")})
    goal = next(r for r in rows if r["name"] == "jitter 16 spp")
    adaptive = [r for r in rows if r["kind"] == "adaptive"]
    reached = [r for r in adaptive if r["rmse"] <= goal["rmse"]]
    best = min(reached, key=lambda r: r["time"]) if reached else min(adaptive, key=lambda r: r["rmse"])
    nested_label = "direct" if nested_name == "direct" else "path (max_depth 8)"
    out = []
    out.append("")
    out.append(f"### nested `{nested_label}`")
    out.append("")
    out.append("| method | mean spp | rays / pixel | RMSE | RMSE / jitter-16 | time (median) s | time / jitter-16 | "
          "first call s (JIT compile s) | JIT launches | tracing share |")
    out.append("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        rays = sum(r["stats"]["rays"]) / (reference.shape[0] * reference.shape[1]) if r["stats"] else r["spp"]
        out.append(f"| {r['name']} | {r['spp']:.2f} | {rays:.2f} | {r['rmse']:.5f} | {r['rmse'] / goal['rmse']:.2f} | "
              f"{r['time']:.3f} | {r['time'] / goal['time']:.2f} | {r['first']:.2f} ({r['compile']:.2f}) | "
              f"{r['launches']:.0f} | {r['traced'] * 100:.0f}% |")
    out.append("")
    if reached:
        out.append(f"goal RMSE <= jitter-16 ({goal['rmse']:.5f}) reached fastest by {best['name']}: RMSE "
              f"{best['rmse'] / goal['rmse']:.2f} x, time {best['time']:.3f} s = {best['time'] / goal['time']:.2f} x "
              f"jitter-16's {goal['time']:.3f} s (goal <= 0.50: "
              f"{'met' if best['time'] <= 0.5 * goal['time'] else 'NOT met'})")
    else:
        out.append(f"goal NOT met: no adaptive configuration reaches jitter-16's RMSE {goal['rmse']:.5f}; "
              f"the best, {best['name']}, has {best['rmse']:.5f} in {best['time']:.3f} s")
    out.append(f"scheduling overhead of {best['name']}: {(1 - best['traced']) * 100:.0f}% of the render "
          f"(goal < 20%: {'met' if best['traced'] > 0.8 else 'NOT met'}); rays per batch "
          f"{best['stats']['rays']}, squares split per level {best['stats']['squares']}, host reads "
          f"{best['stats']['host_reads']}, JIT launches {best['launches']:.0f}")
    return {"rows": rows, "goal": goal, "best": best, "label": nested_label, "pixels": reference.shape[:2],
            "lines": out}


def _plot(suites, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(suites), figsize=(6 * len(suites), 4.6), dpi=100, squeeze=False)
    for ax, (name, suite) in zip(axes[0], suites.items()):
        rows, goal = suite["rows"], suite["goal"]
        jit = [r for r in rows if r["kind"] == "jitter"]
        ax.loglog([r["time"] for r in jit], [r["rmse"] for r in jit], "o-", color="black",
                  label="jitter (4, 8, 16, 32 spp)")
        depths = sorted({r["config"][1:] for r in rows if r["kind"] == "adaptive"})
        for (min_depth, max_depth), colour in zip(depths, ("tab:blue", "tab:green", "tab:orange", "tab:red")):
            sel = [r for r in rows if r["kind"] == "adaptive" and r["config"][1:] == (min_depth, max_depth)]
            ax.loglog([r["time"] for r in sel], [r["rmse"] for r in sel], "s--", color=colour,
                      label=f"adaptive depth {min_depth}..{max_depth} "
                            "(t = " + ", ".join(f"{r['config'][0]:g}" for r in sel) + ")")
        ax.axhline(goal["rmse"], color="grey", lw=0.8)
        ax.axvline(0.5 * goal["time"], color="grey", lw=0.8, ls=":")
        ax.set_xlabel("render time (s, median)")
        ax.set_ylabel("RMSE vs reference")
        ax.legend(fontsize=7)
        ax.set_title(f"edges.xml, nested {suite['label']}\n(lines: jitter-16 RMSE, half its time)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
