"""Benchmark: gradients through ``whitted`` against Mitsuba's ``prb`` on the same scene.

Measures, side by side in one run (ratio = ours / peer):

1. **Memory of one gradient**: growth of the process's resident memory during one
   ``render_backward`` at 64x64 and ``--spp`` samples (256 by default), after a warm-up gradient
   (kernels compiled) and ``dr.flush_malloc_cache()`` (else the gradient reuses the warm-up's
   cached buffers and nothing grows), sampled every millisecond by a thread; each integrator in
   its own fresh process. Goal: whitted at most ``prb`` + 20 MB.
2. **Time per optimisation step** (``mi.render`` with parameters, an L2 loss against a target,
   ``dr.backward``, an Adam step and ``params.update``), median of interleaved steps after a
   warm-up step of each. Goal: at most ``prb``'s.

The scene: a floor textured by a bitmap, a Phong ball, a mirror ball, a glass ball, an area light
and a point light (tests/test_whitted_ad.py's scene at 64x64); the parameter optimised is the
ball's diffuse reflectance. ``prb`` (Mitsuba's path replay integrator, max_depth 6) traces diffuse
bounces whitted does not; ``prb`` with max_depth 2 (direct light only, plus its BSDF-sampled
light hits) is the closer workload and is reported too. Mitsuba's C++ ``path`` is differentiated by
Mitsuba's generic fallback (the whole loop unrolled into one AD graph), as whitted was while it
was a plain sampling integrator: the row shows what the replay saves, and that the memory
measurement sees growth where there is some.

    flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/differentiable.py --write
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

INTEGRATORS = {"whitted": {"type": "whitted", "max_depth": 5},
               "prb": {"type": "prb", "max_depth": 6},
               "prb (max_depth 2)": {"type": "prb", "max_depth": 2},
               "path (Mitsuba's generic fallback)": {"type": "path", "max_depth": 6}}
KEY = "ball.bsdf.diffuse_reflectance.value"


def _setup():
    import pointillist

    return pointillist.setup("llvm_ad_rgb")


def _scene(mi, name, res):
    import test_whitted_ad

    test_whitted_ad.RES = res
    return test_whitted_ad._scene(mi, INTEGRATORS[name])


def _rss() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def memory_child(name: str, res: int, spp: int) -> None:
    """Print the resident-memory growth (bytes) of one gradient, after a warm-up gradient."""
    import drjit as dr
    import numpy as np

    mi = _setup()
    scene = _scene(mi, name, res)
    params = mi.traverse(scene)
    dr.enable_grad(params[KEY])
    params.update()
    grad_in = mi.TensorXf(np.ones((res, res, 3), np.float32))
    integrator = scene.integrator()

    def gradient(seed):
        integrator.render_backward(scene, params, grad_in, seed=seed, spp=spp)
        dr.eval(dr.grad(params[KEY]))
        dr.sync_thread()

    gradient(1)
    dr.flush_malloc_cache()       # hand the warm-up's buffers back, so the measured gradient allocates its own
    before = _rss()
    peak = [before]
    running = [True]

    def watch():
        while running[0]:
            peak[0] = max(peak[0], _rss())
            time.sleep(0.001)

    thread = threading.Thread(target=watch)
    thread.start()
    gradient(2)
    running[0] = False
    thread.join()
    print(json.dumps({"growth": peak[0] - before, "before": before}))


def _memory(name, res, spp):
    out = subprocess.run([sys.executable, __file__, "--memory-child", name, "--res", str(res), "--spp", str(spp)],
                         check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def _steps(mi, res, spp, rounds):
    """Median seconds per optimisation step of each integrator, in interleaved rounds."""
    import drjit as dr

    cases = {}
    for name in INTEGRATORS:
        scene = _scene(mi, name, res)
        params = mi.traverse(scene)
        target = mi.render(scene, seed=1000, spp=64)
        optimizer = mi.ad.Adam(lr=0.05)
        optimizer[KEY] = mi.Color3f(0.1, 0.8, 0.6)
        params.update(optimizer)
        seeds = iter(range(10**6))

        def step(scene=scene, params=params, target=target, optimizer=optimizer, seeds=seeds):
            image = mi.render(scene, params, seed=next(seeds), spp=spp)
            dr.backward(dr.mean(dr.square(image - target), axis=None))
            optimizer.step()
            params.update(optimizer)
            dr.eval(params[KEY])
            dr.sync_thread()

        cases[name] = step
    times = {name: [] for name in cases}
    for step in cases.values():
        step()                                       # warm-up: JIT compile
    for r in range(rounds):
        order = list(cases) if r % 2 == 0 else list(reversed(cases))
        for name in order:
            start = time.perf_counter()
            cases[name]()
            times[name].append(time.perf_counter() - start)
    return {name: statistics.median(t) for name, t in times.items()}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--res", type=int, default=64)
    parser.add_argument("--spp", type=int, default=256, help="samples per pixel of the memory measurement")
    parser.add_argument("--step-spp", type=int, default=16, help="samples per pixel of an optimisation step")
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--write", action="store_true", help="write the differentiable block of RESULTS.md")
    parser.add_argument("--memory-child", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.memory_child:
        memory_child(args.memory_child, args.res, args.spp)
        return 0
    import drjit as dr
    from startup import cpu_facts

    memory = {name: _memory(name, args.res, args.spp) for name in INTEGRATORS}
    mi = _setup()
    steps = _steps(mi, args.res, args.step_spp, args.rounds)
    mb = {name: m["growth"] / 2**20 for name, m in memory.items()}
    lines = [
        "## Gradients: whitted against Mitsuba's prb",
        "",
        f"Machine: {cpu_facts()}, {os.cpu_count()} cores, {platform.platform()}; "
        f"Python {platform.python_version()}, Mitsuba {mi.__version__}, "
        f"Dr.Jit {dr.__version__}. Load average after: {', '.join(f'{x:.1f}' for x in os.getloadavg())}. "
        f"Reproduce: `flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/differentiable.py "
        f"--res {args.res} --spp {args.spp} --step-spp {args.step_spp} --rounds {args.rounds} --write`.",
        "",
        f"Scene: tests/test_whitted_ad.py's (textured floor, Phong, mirror and glass balls, area and point "
        f"light) at {args.res}x{args.res}; parameter: the Phong ball's diffuse reflectance. Memory: growth of "
        "the resident set during one `render_backward` after a warm-up and `dr.flush_malloc_cache()`, each "
        "integrator in a fresh process (whitted and prb evaluate the primal and the replay in fused kernels "
        "without storing a graph; `path` goes through Mitsuba's generic fallback, as whitted did before it "
        "replayed its paths).",
        "",
        "| integrator | memory of one gradient (MB), {} spp | step (s), {} spp | step ratio whitted / this |".format(
            args.spp, args.step_spp),
        "|---|---|---|---|",
    ]
    for name in INTEGRATORS:
        ratio = steps["whitted"] / steps[name]
        lines.append(f"| {name} | {mb[name]:+.1f} | {steps[name]:.4f} | {ratio:.2f} |")
    lines += ["",
              f"Goals: memory whitted <= prb + 20 MB: {mb['whitted']:+.1f} against {mb['prb']:+.1f} MB, "
              f"{'met' if mb['whitted'] <= mb['prb'] + 20 else 'not met'}; "
              f"step time whitted <= prb: {steps['whitted'] / steps['prb']:.2f}x, "
              f"{'met' if steps['whitted'] <= steps['prb'] else 'not met'}."]
    text = "\n".join(lines)
    print(text)
    if args.write:
        from _results import write_block

        write_block("differentiable", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
