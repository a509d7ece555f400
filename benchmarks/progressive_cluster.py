"""Benchmark: progressive rendering in tiles on a Dask cluster, the work going to the noise.

Measures, in one run, on a local cluster of ``--workers`` worker processes (one Dr.Jit thread each):

1. **Work to the noise against uniform passes.** ``scenes/corner_caustic.xml`` (noise in one
   corner: a glass sphere's caustic and the small light seen through it) at ``--res``, in 4x4 tiles,
   with ``Budget(target_error=E)``: the tile-driven render (passes to the tiles whose error is
   largest) and uniform passes (every tile the same passes), alternating which goes first, after one
   warm-up of each (the JIT compilation apart). Wall seconds to the target (goal: tile-driven <= 0.6x
   uniform), mean spp, each render's estimate and its true relMSE against a reference of 2^30 samples
   (``benchmarks/_references.py``; goal: true / estimate within 0.5-2); and at **equal wall time**:
   uniform passes with a time budget of the tile-driven render's seconds, and their true relMSE.
2. **Time budgets on the cluster**: ``Budget(seconds=T)``, the render seconds against T (goal: within 2 %).
3. **The rare-path rule** (an error budget stops only on an estimate settled over a doubling of the
   spp, :func:`pointillist.progressive.stats.settled`), on one machine, automatic passes: where the
   render stopped with the rule and where it would have stopped without it (the first trusted estimate
   at or below the target), the spp and the true relMSE at both: its cost on easy scenes, what it
   buys on hard ones.

Run it under the shared benchmark lock (the first run renders the references, minutes each)::

    flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/progressive_cluster.py --write

``--write`` puts the tables into the ``progressive_cluster`` block of benchmarks/RESULTS.md.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))
SCENES = ROOT / "scenes"

CORNER = SCENES / "corner_caustic.xml"

#: (label, scene, -D params, reference spp per half, targets) of the rare-path rule's runs
RULE_CASES = [
    ("edges, direct", "edges.xml", {"res": "64"}, 8192, (0.01, 0.002)),
    ("default, whitted", "default.xml", {"res": "64"}, 8192, (0.01, 0.002)),
    ("Cornell, whitted", "cornell_phong.xml", {"res": "64"}, 8192, (0.01, 0.002)),
    ("tiny light", "tiny_light.xml", {}, 16384, (0.05, 0.01)),
    ("glass caustic", "glass_caustic.xml", {}, 16384, (0.05, 0.01)),
]


def noise_to_work(client, scene, params, targets, seeds, ref):
    """Section 1: rows (target, seed, mode, seconds, spp, tile spp, estimate, true relMSE)."""
    from _references import true_relmse

    from pointillist.progressive import Budget
    from pointillist.progressive.tiled import render_progressive_tiled

    def run(budget, adaptive, seed):
        result = render_progressive_tiled(scene, CORNER, budget, tiles=(4, 4), params=params, seed=seed, client=client,
                                          progress=False, adaptive=adaptive)
        return result, true_relmse(result.image, ref)

    run(Budget(target_error=targets[0]), True, 99)   # warm-up: every kernel compiled
    run(Budget(target_error=targets[0]), False, 99)
    rows, shown = [], None
    for target in targets:
        for i, seed in enumerate(seeds):
            done = {}
            for adaptive in ((True, False) if i % 2 == 0 else (False, True)):
                result, true = run(Budget(target_error=target), adaptive, seed)
                done[adaptive] = result
                rows.append((target, seed, "tiles to the noise" if adaptive else "uniform", result.stats.seconds,
                             result.stats.spp, result.metadata["tile_spp"], result.stats.estimated_relmse, true,
                             result.stop))
            result, true = run(Budget(seconds=done[True].stats.seconds), False, seed)
            if shown is None:
                shown = (target, done[True], result)
            rows.append((target, seed, "uniform, same seconds", result.stats.seconds, result.stats.spp,
                         result.metadata["tile_spp"], result.stats.estimated_relmse, true, result.stop))
    return rows, shown


def picture(shown, ref, path: Path) -> None:
    """The tile-driven render, the spp of its tiles, and uniform passes in the same seconds, with
    their true relMSE per pixel."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from pointillist.imaging.metrics import RELMSE_EPSILON

    target, tiled, uniform = shown
    r = ref["R"][..., :3]

    def error(image):
        return ((np.asarray(image[..., :3], np.float64) - r) ** 2 / (r * r + RELMSE_EPSILON)).mean(axis=2)

    fig, axes = plt.subplots(1, 4, figsize=(16, 4.4), dpi=90)
    axes[0].imshow(np.clip(tiled.image[..., :3], 0, 1) ** (1 / 2.2))
    axes[0].set_title(f"tiles to the noise: target {target:g}, {tiled.stats.seconds:.1f} s")
    low, high = (int(v) for v in tiled.metadata["tile_spp"].split(".."))
    image = axes[1].imshow(tiled.spp_map, cmap="viridis")
    axes[1].set_title(f"spp per tile ({low}..{high})")
    fig.colorbar(image, ax=axes[1], fraction=0.046)
    vmax = float(np.percentile(error(uniform.image), 99.5))
    for ax, result, name in ((axes[2], tiled, "tiles to the noise"), (axes[3], uniform, "uniform, same seconds")):
        e = error(result.image)
        ax.imshow(e, cmap="magma", vmin=0, vmax=vmax)
        ax.set_title(f"{name}: relMSE per pixel (mean {e.mean():.4f})", fontsize=9)
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def time_budgets(client, scene, params, budgets):
    from pointillist.progressive import Budget
    from pointillist.progressive.tiled import render_progressive_tiled

    rows = []
    for seconds in budgets:
        result = render_progressive_tiled(scene, CORNER, Budget(seconds=seconds), tiles=(4, 4), params=params,
                                          client=client, progress=False)
        rows.append((seconds, result.stats.seconds, result.stats.passes, result.stats.spp))
    return rows


def rare_path_rule(seeds):
    """Section 3: per case, target and seed: the stop without the rule and with it."""
    from _references import reference, true_relmse

    from pointillist.progressive import Budget, render_passes
    from pointillist.scene import load_scene

    rows = []
    for label, name, params, ref_spp, targets in RULE_CASES:
        ref = reference(SCENES / name, params, ref_spp)
        scene = load_scene(SCENES / name, params)
        for target in targets:
            for seed in seeds:
                budget, before = Budget(target_error=target, seconds=120), None
                for image, stats in render_passes(scene, pass_spp=budget, seed=seed):
                    if before is None and stats.trusted and stats.estimated_relmse <= target:
                        before = (stats.spp, stats.estimated_relmse, true_relmse(image.numpy(), ref))
                    last = (stats, image)
                stats, image = last
                after = (stats.spp, stats.estimated_relmse, true_relmse(image.numpy(), ref))
                rows.append((label, target, seed, before, after, budget.stop_reason(stats)))
    return rows


def _ratio(true, estimate):
    return true / estimate if estimate and math.isfinite(estimate) and estimate > 0 else math.nan


def report(work_rows, budget_rows, rule_rows, args, machine) -> str:
    lines = [f"Machine: {machine}. Command: `flock /tmp/pointillist-bench.lock .venv/bin/python "
             f"benchmarks/progressive_cluster.py --workers {args.workers} --res {args.res} --write`.", "",
             f"**1. Work to the noise** (`corner_caustic.xml` at {args.res}x{args.res}, 4x4 tiles, local cluster of "
             f"{args.workers} workers, one Dr.Jit thread each; automatic passes; warm kernels):", "",
             "| target | seed | passes | seconds | mean spp | tile spp | estimate | true relMSE | true / est. | stop |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for target, seed, mode, seconds, spp, tile_spp, est, true, stop in work_rows:
        lines.append(f"| {target:g} | {seed} | {mode} | {seconds:.2f} | {spp} | {tile_spp} | {est:.4g} | {true:.4g} | "
                     f"{_ratio(true, est):.2f} | {stop} |")
    ratios = []
    for target in sorted({r[0] for r in work_rows}):
        for seed in sorted({r[1] for r in work_rows}):
            pick = {r[2]: r for r in work_rows if r[0] == target and r[1] == seed}
            ratios.append(pick["tiles to the noise"][3] / pick["uniform"][3])
    lines += ["", f"Wall time to the target, tiles to the noise / uniform: "
              f"{', '.join(f'{r:.2f}' for r in ratios)} (median {statistics.median(ratios):.2f}; goal <= 0.6).", ""]
    lines += ["**2. Time budgets on the cluster** (same scene and cluster):", "",
              "| budget s | render s | off by | rounds | mean spp |", "|---|---|---|---|---|"]
    for budget, seconds, passes, spp in budget_rows:
        lines.append(f"| {budget:g} | {seconds:.2f} | {100 * (seconds - budget) / budget:+.1f} % | {passes} | {spp} |")
    lines += ["", "**3. The rare-path rule** (one machine, automatic passes, bounded at 120 s): the first trusted "
              "estimate at or below the target (where a render stopped without the rule) against where it stops "
              "with it; true relMSE against a reference.", "",
              "| scene | target | seed | without: spp | est. | true | with: spp | est. | true | stop | spp cost |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for label, target, seed, before, after, stop in rule_rows:
        b = ("| - | - | -" if before is None else f"| {before[0]} | {before[1]:.3g} | {before[2]:.3g}")
        cost = f"{after[0] / before[0]:.2f}x" if before else "-"
        lines.append(f"| {label} | {target:g} | {seed} {b} | {after[0]} | {after[1]:.3g} | {after[2]:.3g} | {stop} | "
                     f"{cost} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--res", type=int, default=256)
    parser.add_argument("--targets", type=float, nargs="+", default=[1e-4, 5e-5])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--budgets", type=float, nargs="+", default=[5.0, 15.0])
    parser.add_argument("--skip-rule", action="store_true", help="leave out section 3")
    parser.add_argument("--write", action="store_true", help="write the progressive_cluster block of RESULTS.md")
    args = parser.parse_args(argv)

    import pointillist

    mi = pointillist.setup()
    import drjit as dr
    from _references import reference
    from _results import write_block
    from startup import cpu_facts

    from pointillist.distributed import start_cluster
    from pointillist.scene import load_scene

    params = {"res": str(args.res)}
    ref = reference(CORNER, params, max(16384 * 128 ** 2 // args.res ** 2, 1024))   # 2^29 samples a half
    scene = load_scene(CORNER, params)
    client = start_cluster(args.workers, drjit_threads=1)
    try:
        start = time.perf_counter()
        work_rows, shown = noise_to_work(client, scene, params, args.targets, args.seeds, ref)
        picture(shown, ref, Path(__file__).resolve().parent / "progressive_cluster.png")
        budget_rows = time_budgets(client, scene, params, args.budgets)
        print(f"cluster sections: {time.perf_counter() - start:.0f} s", file=sys.stderr)
    finally:
        cluster = client.cluster
        client.close()
        cluster.close()
    rule_rows = [] if args.skip_rule else rare_path_rule(args.seeds[:1])
    machine = (f"{cpu_facts()}, {os.cpu_count()} cores, {platform.platform()}; Mitsuba {mi.__version__}, "
               f"Dr.Jit {dr.__version__}")
    text = report(work_rows, budget_rows, rule_rows, args, machine)
    print(text)
    if args.write:
        print(f"wrote {write_block('progressive_cluster', text)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
