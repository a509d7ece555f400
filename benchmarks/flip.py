"""Benchmark FLIP on Dr.Jit (pointillist.imaging.flip) beside flip-evaluator (NVIDIA's C++ with OpenMP), one run.

The inputs are what ``pointillist compare`` scores: renders of the project's scenes (4 spp, seed 1)
against a 64-spp reference (another seed), at 256x256 and 512x512, HDR-FLIP with the exposure range
each reference gives (edges.xml: 7 exposures, cornell_phong.xml: 9), and LDR-FLIP of the same pair
tone-mapped (ACES, sRGB-encoded). Steady state: interleaved rounds, each timing ours and then
flip-evaluator on every case (the order flips every round, so load from other processes hits both);
the first round is a warm-up and is dropped. Ours is timed until the map is in numpy memory (the call
returns it evaluated); flip-evaluator's call returns its map. Reported: medians (and minima) and their
ratio, the agreement of the two maps, and ours' kernel launches and summed kernel time (Dr.Jit's
kernel history). JIT compilation is measured apart: first minus second call in a fresh process, with
the kernel cache (~/.drjit) cold (HOME pointed at an empty folder) and warm.

Run:  flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/flip.py [--repeats 5] [--write]
``--write`` replaces the flip block of benchmarks/RESULTS.md (through benchmarks/_results.py) and
writes benchmarks/flip.png.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import pointillist  # noqa: E402
import drjit as dr  # noqa: E402

SCENES = ("edges", "cornell_phong")
SIZES = (256, 512)


def renders(scene: str, size: int) -> tuple[np.ndarray, np.ndarray]:
    """(test, reference): 4 spp seed 1 and 64 spp seed 1000 of ``scenes/<scene>.xml`` at ``size``."""
    mi = pointillist.setup()
    loaded = mi.load_file(str(ROOT / "scenes" / f"{scene}.xml"), res=str(size))
    rgb = [np.ascontiguousarray(np.clip(np.asarray(mi.render(loaded, spp=spp, seed=seed))[..., :3], 0, None),
                                dtype=np.float32) for spp, seed in ((4, 1), (64, 1000))]
    del loaded
    return rgb[0], rgb[1]


def cases() -> dict[str, tuple[np.ndarray, np.ndarray, str]]:
    """name -> (test, reference, mode)."""
    from pointillist.imaging.tone import tonemap

    out = {}
    for size in SIZES:
        for scene in SCENES:
            test, reference = renders(scene, size)
            out[f"{scene} {size}x{size} HDR"] = (test, reference, "HDR")
            if scene == "cornell_phong":
                ldr = [np.ascontiguousarray(np.asarray(tonemap(a, "aces")) / 255.0, dtype=np.float32)
                       for a in (test, reference)]
                out[f"{scene} {size}x{size} LDR (ACES, sRGB)"] = (ldr[0], ldr[1], "LDR")
    return out


def ours(test, reference, mode):
    from pointillist.imaging.flip import flip

    return flip(test, reference, dynamic_range=mode.lower())


def peer(test, reference, mode):
    import flip_evaluator

    return flip_evaluator.evaluate(reference, test, mode, applyMagma=False)


def openmp():
    """flip-evaluator's own OpenMP runtime (the libgomp its wheel bundles), to set its thread count."""
    import ctypes
    import glob

    import flip_evaluator

    return ctypes.CDLL(glob.glob(os.path.join(os.path.dirname(flip_evaluator.__file__) + ".libs", "libgomp*"))[0])


def interleaved(work: dict, repeats: int) -> tuple[dict, dict, dict]:
    """Every round times ours and flip-evaluator at 1 and at 2 OpenMP threads on every case; the first
    round is a warm-up. On a loaded machine OpenMP's threads wait for each other at every barrier (one of
    them descheduled), so one thread can be the faster: the table reports the faster median."""
    from tqdm import tqdm

    gomp = openmp()
    ours_t = {name: [] for name in work}
    peer_t = {name: {1: [], 2: []} for name in work}
    last = {}
    for round_ in tqdm(range(repeats + 1), desc="rounds (all cases, interleaved)"):
        for name, (test, reference, mode) in work.items():
            def run_ours():
                start = time.perf_counter()
                result = ours(test, reference, mode)
                np.asarray(result.map)
                if round_:
                    ours_t[name].append(time.perf_counter() - start)
                return result

            def run_peer():
                for threads, times in peer_t[name].items():
                    gomp.omp_set_num_threads(threads)
                    start = time.perf_counter()
                    result = peer(test, reference, mode)
                    if round_:
                        times.append(time.perf_counter() - start)
                return result

            if round_ % 2:
                a, b = run_ours(), run_peer()
            else:
                b, a = run_peer(), run_ours()
            last[name] = (a, b)
    gomp.omp_set_num_threads(os.cpu_count())
    return ours_t, peer_t, last


def kernel_profile(test, reference, mode) -> tuple[int, float, bool]:
    """(JIT kernel launches per call, least summed execution time in s, all from the in-memory cache)."""
    from imaging_tone import kernel_profile as profile   # the one kernel-history profiler of the benchmarks

    return profile(lambda: ours(test, reference, mode), calls=3)


FIRST_CALL = r"""
import json, sys, time
sys.path.insert(0, {root!r})
import numpy as np
from pointillist.imaging.flip import flip
rng = np.random.default_rng(0)
reference = (rng.random((256, 256, 3), dtype=np.float32) ** 3 * 4).astype(np.float32)
test = np.clip(reference + rng.normal(0, 0.1, reference.shape), 0, None).astype(np.float32)
out = {{}}
for mode in ("hdr", "ldr"):
    a, b = (np.clip(x, 0, 1) for x in (test, reference)) if mode == "ldr" else (test, reference)
    start = time.perf_counter(); flip(a, b, dynamic_range=mode); first = time.perf_counter() - start
    start = time.perf_counter(); flip(a, b, dynamic_range=mode); second = time.perf_counter() - start
    out[mode] = first - second
print(json.dumps(out))
"""


def first_call_costs(cold: bool) -> dict[str, float]:
    """First-call minus second-call time (HDR, LDR) in a fresh interpreter, kernel cache cold or warm."""
    env = dict(os.environ)
    if cold:
        env["HOME"] = tempfile.mkdtemp(prefix="drjit-cold-")
    result = subprocess.run([sys.executable, "-c", FIRST_CALL.format(root=str(ROOT))], env=env,
                            capture_output=True, text=True, check=True)
    return json.loads(result.stdout.strip().splitlines()[-1])


def plot(rows, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [r["name"] for r in rows]
    y = np.arange(len(rows))[::-1]
    fig, ax = plt.subplots(figsize=(8, 0.55 * len(rows) + 1.4))
    ax.barh(y + 0.2, [r["ours"] * 1e3 for r in rows], height=0.4, color="tab:green", label="FLIP on Dr.Jit (ours)")
    ax.barh(y - 0.2, [r["peer"] * 1e3 for r in rows], height=0.4, color="tab:grey", label="flip-evaluator")
    for yy, r in zip(y, rows):
        ax.text(r["peer"] * 1e3 * 1.05, yy - 0.2, f"{r['ours'] / r['peer']:.3f}x", va="center", fontsize=7)
    ax.set_xscale("log")
    ax.set_yticks(y, names, fontsize=8)
    ax.set_xlabel("time per call, median (ms, log)")
    ax.set_title("FLIP: ours vs flip-evaluator (ratio = ours / flip-evaluator)", fontsize=9)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    from pointillist.core.files import save_figure

    save_figure(fig, path)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--write", action="store_true", help="write the table into benchmarks/RESULTS.md")
    args = parser.parse_args()

    work = cases()
    load_before = os.getloadavg()[0]
    ours_t, peer_t, last = interleaved(work, args.repeats)
    load_after = os.getloadavg()[0]
    rows = []
    for name, (test, reference, mode) in work.items():
        result, (peer_map, peer_mean, used) = last[name]
        difference = np.abs(np.asarray(result.map, np.float64) - np.asarray(peer_map)[..., 0])
        launches, execute, cached = kernel_profile(test, reference, mode)
        threads = min(peer_t[name], key=lambda n: np.median(peer_t[name][n]))
        peer_times = peer_t[name][threads]
        rows.append(dict(name=name, ours=float(np.median(ours_t[name])), ours_min=min(ours_t[name]),
                         peer=float(np.median(peer_times)), peer_min=min(peer_times), threads=threads,
                         exposures=used["numExposures"] if mode == "HDR" else "-",
                         mean_diff=abs(result.mean - float(peer_mean)), p99=float(np.percentile(difference, 99)),
                         max=float(difference.max()), launches=launches, execute=execute, cached=cached))
    cold, warm = first_call_costs(cold=True), first_call_costs(cold=False)

    import flip_evaluator  # noqa: F401
    from importlib.metadata import version

    lines = [
        f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores; Python "
        f"{platform.python_version()}, Dr.Jit {dr.__version__} (LLVM {'.'.join(map(str, dr.detail.llvm_version()))}), "
        f"flip-evaluator {version('flip-evaluator')} (C++ with OpenMP: 1 and 2 threads timed, the faster shown), "
        f"numpy {np.__version__}.",
        f"Load average {load_before:.1f} before and {load_after:.1f} after the timed rounds on {os.cpu_count()} cores "
        "(other processes were running): loaded-machine figures; rerun on a quiet machine for absolute times. "
        "The ratios hold better than the times: both sides ran in every round.",
        f"{args.repeats} interleaved rounds after a warm-up; ours = `pointillist.imaging.flip.flip` (the map returned "
        "evaluated, as `imaging.metrics` uses it); peer = `flip_evaluator.evaluate(reference, test, mode, "
        "applyMagma=False)`.",
        f"Command: `flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/flip.py --repeats {args.repeats} "
        "--write`",
        "",
        "| case | exposures | ours median (min) ms | flip-evaluator median (min) ms | ratio of medians "
        "| ratio of minima | kernels (exec ms) | mean diff | map diff p99 / max |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['name']} | {r['exposures']} | {r['ours'] * 1e3:.1f} ({r['ours_min'] * 1e3:.1f}) | "
            f"{r['peer'] * 1e3:.0f} ({r['peer_min'] * 1e3:.0f}), {r['threads']} thr | {r['ours'] / r['peer']:.3f} | "
            f"{r['ours_min'] / r['peer_min']:.3f} | {r['launches']}{'' if r['cached'] else ' RECOMPILED'} "
            f"({r['execute'] * 1e3:.1f}) | {r['mean_diff']:.1e} | {r['p99']:.1e} / {r['max']:.1e} |")
    lines += [
        "",
        f"JIT compilation apart (first minus second call on 256x256, fresh process): HDR {cold['hdr'] * 1e3:.0f} ms "
        f"with an empty kernel cache, {warm['hdr'] * 1e3:.0f} ms with a warm one; LDR (another pass-1 kernel) "
        f"{cold['ldr'] * 1e3:.0f} / {warm['ldr'] * 1e3:.0f} ms. The kernels do not depend on the image size or the "
        "exposures (tests/test_flip.py checks that another size launches only cached kernels): one compilation per "
        "process and tone mapper, and per pixels-per-degree value (the filter weights are kernel constants).",
        "",
        "Kernels: three per batch of exposures (colour transform of the padded frames, horizontal pass, vertical "
        "pass and error), the exposures of a render in one batch or a few (at most 2^21 lanes each: 26 exposures "
        "of a 256^2 image, 7 of a 512^2 one); LDR adds the sRGB decoding of the two images (2 kernels). exec = "
        "their summed execution time, the least over 3 calls. The rest of a call is host work (the exposure "
        "range: a median by partition; the largest error over the exposures) and Python tracing (about 3-5 ms "
        "of one thread's time per batch). mean diff is against flip-evaluator's own mean, which it sums in "
        "float32 (its map's float64 mean is within 1e-8 of ours, tests/test_flip.py); the map differences are "
        "per pixel. flip-evaluator's time is the faster of 1 and 2 OpenMP threads: on this loaded machine its "
        "two threads often wait for each other at the barriers, and one thread was sometimes faster.",
    ]
    table = "\n".join(lines)
    print(table)
    if args.write:
        plot(rows, ROOT / "benchmarks" / "flip.png")
        table = table.replace("\n\nJIT compilation apart", "\n\n![times](flip.png)\n\nJIT compilation apart", 1)
        from _results import write_block

        write_block("flip", "## FLIP on Dr.Jit (imaging.flip) beside flip-evaluator\n\n" + table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
