"""Benchmark imaging.filters / imaging.resample beside OpenCV (best of 1 and 2 threads), scipy, scikit-image.

Run:  flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/imaging_spatial.py [--size 2048] [--repeat 9]

One run, 2048x2048 float32 grey (0..255) by default. Steady state: median (and min) of
``--repeat`` calls, each timed until the result is in memory (Dr.Jit: ``dr.eval`` +
``dr.sync_thread``), with ours, OpenCV 1 thread and OpenCV 2 threads *interleaved* in every
repeat so that load from other processes hits all of them alike. The ratio is ours / the faster
OpenCV median. scipy.ndimage and scikit-image run a few times each (they are 10-200x slower).

Per operation the Dr.Jit kernel history gives the kernels launched per call, their summed
execution time, and whether any steady-state call compiled a kernel again (a recompile
would mean a per-call value was baked in as a constant). The first call (JIT compile +
run) is measured apart in fresh subprocesses, with the kernel cache ``~/.drjit`` cold
(HOME pointed at an empty folder) and warm.

Prints Markdown tables; ``--write`` puts them into the ``imaging_spatial`` block of RESULTS.md.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import pointillist.imaging  # noqa: E402,F401  (picks libLLVM first)
import cv2  # noqa: E402
import drjit as dr  # noqa: E402
import scipy  # noqa: E402
import scipy.ndimage as ndi  # noqa: E402
import skimage  # noqa: E402
import skimage.filters  # noqa: E402
import skimage.transform  # noqa: E402
from tqdm import tqdm  # noqa: E402

from pointillist.imaging import filters as F  # noqa: E402
from pointillist.imaging.resample import resize  # noqa: E402

from _timing import finish, load, load_note, seconds  # noqa: E402


def cases(n: int):
    """(name, ours, OpenCV, scipy, scikit-image, goal) for an n x n float32 image."""
    img = (np.random.default_rng(0).random((n, n)) * 255).astype(np.float32)
    up, down = (n * 5 // 4, n * 5 // 4), (n * 3 // 4, n * 3 // 4)
    box7 = np.ones((7, 7), np.float32)

    def cv_norm():     # filter2D, |.| and min-max stretch over the interior (the ring is not computed)
        d = cv2.filter2D(img, -1, F.GAUSSIAN_3, borderType=cv2.BORDER_CONSTANT)
        roi = np.abs(d[1:-1, 1:-1])
        return cv2.normalize(roi, roi, 0, 255, cv2.NORM_MINMAX)

    def cv_grad(kx, ky):
        return lambda: cv2.magnitude(cv2.filter2D(img, -1, kx), cv2.filter2D(img, -1, ky))

    def sk_resize(size, order):
        return lambda: skimage.transform.resize(img, (size[1], size[0]), order=order, mode="edge",
                                                anti_aliasing=False, preserve_range=True)

    return [
        ("correlate 3x3 + normalize", lambda: F.correlate(img, F.GAUSSIAN_3, normalize=True), cv_norm,
         None, None, 0.7),
        ("correlate 3x3", lambda: F.correlate(img, F.GAUSSIAN_3),
         lambda: cv2.filter2D(img, -1, F.GAUSSIAN_3), lambda: ndi.correlate(img, F.GAUSSIAN_3), None, None),
        ("correlate 7x7", lambda: F.correlate(img, box7), lambda: cv2.filter2D(img, -1, box7),
         lambda: ndi.correlate(img, box7), None, None),
        ("Sobel magnitude", lambda: F.sobel(img),
         lambda: cv2.magnitude(cv2.Sobel(img, cv2.CV_32F, 1, 0), cv2.Sobel(img, cv2.CV_32F, 0, 1)),
         lambda: np.hypot(ndi.sobel(img, 1), ndi.sobel(img, 0)), lambda: skimage.filters.sobel(img), 0.7),
        ("Prewitt magnitude", lambda: F.prewitt(img), cv_grad(F.PREWITT_X, F.PREWITT_Y),
         lambda: np.hypot(ndi.prewitt(img, 1), ndi.prewitt(img, 0)), lambda: skimage.filters.prewitt(img), 0.7),
        ("Laplacian", lambda: F.laplacian(img), lambda: cv2.Laplacian(img, cv2.CV_32F, ksize=1),
         lambda: ndi.correlate(img, F.LAPLACIAN), None, 0.7),
        ("median 3x3", lambda: F.median(img, 3), lambda: cv2.medianBlur(img, 3),
         lambda: ndi.median_filter(img, 3, mode="nearest"), None, 1.0),
        ("median 5x5", lambda: F.median(img, 5), lambda: cv2.medianBlur(img, 5),
         lambda: ndi.median_filter(img, 5, mode="nearest"), None, 1.0),
        ("median 7x7 (peer: scipy)", lambda: F.median(img, 7), None,
         lambda: ndi.median_filter(img, 7, mode="nearest"), None, None),
        (f"bilinear resize -> {up[0]}", lambda: resize(img, up, "bilinear"),
         lambda: cv2.resize(img, up, interpolation=cv2.INTER_LINEAR), None, sk_resize(up, 1), 1.0),
        (f"bilinear resize -> {down[0]}", lambda: resize(img, down, "bilinear"),
         lambda: cv2.resize(img, down, interpolation=cv2.INTER_LINEAR), None, sk_resize(down, 1), 1.0),
        (f"bicubic resize -> {up[0]}", lambda: resize(img, up, "bicubic", a=-0.75),
         lambda: cv2.resize(img, up, interpolation=cv2.INTER_CUBIC), None, sk_resize(up, 3), 1.0),
        (f"bicubic resize -> {down[0]}", lambda: resize(img, down, "bicubic", a=-0.75),
         lambda: cv2.resize(img, down, interpolation=cv2.INTER_CUBIC), None, sk_resize(down, 3), 1.0),
    ]


def run_ours(function):
    """``function()`` with its Dr.Jit results evaluated (benchmarks/_timing.py)."""
    finish(function())


def clock(function) -> float:
    """Wall seconds of ``function()``, its Dr.Jit work finished (benchmarks/_timing.py)."""
    return seconds(function)


def cv_threads(function, threads):
    def run():
        cv2.setNumThreads(threads)
        return seconds(function)
    return run


def first_calls(n: int) -> dict:
    """First call of every case in this (fresh) process: wall time and JIT codegen+backend time."""
    dr.eval(dr.llvm.Float(np.arange(4, dtype=np.float32)) * 3.0)   # Dr.Jit/LLVM start-up, not per op
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    out = {}
    for name, ours, *_ in cases(n):
        dr.kernel_history()
        wall = clock(lambda: run_ours(ours))
        history = [k for k in dr.kernel_history() if k.get("type") == dr.KernelType.JIT]
        compile_ms = sum(k.get("codegen_time", 0.0) + k.get("backend_time", 0.0) for k in history)
        out[name] = {"wall_ms": wall * 1e3, "compile_ms": compile_ms,
                     "from_cache": sum(1 for k in history if k.get("cache_hit") or k.get("cache_disk"))}
    return out


def first_calls_subprocess(n: int, cold: bool) -> dict:
    env = dict(os.environ)
    with tempfile.TemporaryDirectory() as home:
        if cold:
            env["HOME"] = home
        proc = subprocess.run([sys.executable, __file__, "--size", str(n), "--first-call-json"],
                              env=env, capture_output=True, text=True, check=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def plot(rows, path, n):
    """Horizontal bars of ours / peer per operation, the goal as a tick, below 1 = faster."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [r["name"] for r in rows]
    ratios = [r["ours"] / (r["cv"][0] if r["cv"] else r["scipy"]) for r in rows]
    colours = ["tab:gray" if r["goal"] is None else ("tab:green" if q <= r["goal"] else "tab:red")
               for r, q in zip(rows, ratios)]
    fig, ax = plt.subplots(figsize=(8, 0.42 * len(rows) + 1.2))
    y = np.arange(len(rows))[::-1]
    ax.barh(y, ratios, color=colours)
    for yi, r in zip(y, rows):
        if r["goal"] is not None:
            ax.plot([r["goal"]] * 2, [yi - 0.4, yi + 0.4], color="black", lw=2)
    ax.axvline(1.0, color="gray", ls=":")
    ax.set_yticks(y, names)
    ax.set_xscale("log")
    ax.set_xlabel("time ours / OpenCV best of 1-2 threads (median 7x7: / scipy); black tick = goal")
    ax.set_title(f"imaging_spatial, {n}x{n} float32 (green: goal met, red: not met)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--size", type=int, default=2048)
    parser.add_argument("--repeat", type=int, default=9)
    parser.add_argument("--peer-repeat", type=int, default=2, help="repeats of scipy / scikit-image")
    parser.add_argument("--only", default="", help="run only cases whose name contains this")
    parser.add_argument("--plot", default="", help="save a bar chart of ours / OpenCV with the goals here")
    parser.add_argument("--write", action="store_true", help="write the tables into benchmarks/RESULTS.md")
    parser.add_argument("--first-call-json", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    n = args.size
    if args.first_call_json:
        print(json.dumps(first_calls(n)))
        return

    load_before = load()
    selected = [c for c in cases(n) if args.only in c[0]]
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    rows = []
    for name, ours, cv, sp, sk, goal in tqdm(selected, desc="steady state"):
        run_ours(ours)                                  # compile (kept apart) and warm up
        if cv:
            cv(); cv()
        mine, cv1, cv2t, kernels, exec_ms, recompiles = [], [], [], [], [], 0
        for _ in range(args.repeat):                    # interleaved: load hits all alike
            dr.kernel_history()
            mine.append(clock(lambda: run_ours(ours)))
            history = [k for k in dr.kernel_history() if k.get("type") == dr.KernelType.JIT]
            kernels.append(len(history))
            exec_ms.append(sum(k["execution_time"] for k in history))
            recompiles += sum(1 for k in history if not k.get("cache_hit"))
            if cv:
                cv1.append(cv_threads(cv, 1)())
                cv2t.append(cv_threads(cv, 2)())
        cv2.setNumThreads(2)
        sp_t = float(np.median([clock(sp) for _ in range(args.peer_repeat)])) if sp else None
        sk_t = float(np.median([clock(sk) for _ in range(args.peer_repeat)])) if sk else None
        cv_best = min((float(np.median(cv1)), 1), (float(np.median(cv2t)), 2)) if cv else None
        cv_min = min(cv1 + cv2t) if cv else None
        rows.append(dict(name=name, ours=float(np.median(mine)), ours_min=min(mine), cv=cv_best, cv_min=cv_min,
                         scipy=sp_t, skimage=sk_t, goal=goal, kernels=int(np.median(kernels)),
                         exec_ms=float(np.median(exec_ms)), recompiles=recompiles))

    cold = first_calls_subprocess(n, cold=True)
    warm = first_calls_subprocess(n, cold=False)
    lines = ["## imaging_spatial: correlation, edges, median, resize", ""]
    lines.append(f"Machine: {platform.machine()}, {os.cpu_count()} cores, {platform.platform()}; Python "
          f"{platform.python_version()}, Dr.Jit {dr.__version__}, LLVM {'.'.join(map(str, dr.detail.llvm_version()))}, "
          f"OpenCV {cv2.__version__}, scipy {scipy.__version__}, scikit-image {skimage.__version__}; image {n}x{n} "
          f"float32; median of {args.repeat} interleaved repeats; {load_note(load_before, load())}.")
    lines.append("")
    lines.append("| operation | ours ms (min) | OpenCV best ms (min) | scipy ms | skimage ms | ours / OpenCV | goal | "
          "ratio of mins | kernels/call (exec ms) | first call cold / warm ms (JIT compile ms) |")
    lines.append("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        peer = r["cv"][0] if r["cv"] else r["scipy"]
        ratio = r["ours"] / peer
        goal = "" if r["goal"] is None else f"<= {r['goal']}x {'yes' if ratio <= r['goal'] else 'NO'}"
        c, w = cold.get(r["name"], {}), warm.get(r["name"], {})
        cv_text = f"{r['cv'][0] * 1e3:.2f} ({r['cv'][1]} thr) ({r['cv_min'] * 1e3:.2f})" if r["cv"] else ""
        min_ratio = f"{r['ours_min'] / r['cv_min']:.2f}x" if r["cv"] else ""
        sp_text = "" if r["scipy"] is None else f"{r['scipy'] * 1e3:.1f}"
        sk_text = "" if r["skimage"] is None else f"{r['skimage'] * 1e3:.1f}"
        first = (f"{c.get('wall_ms', float('nan')):.0f} ({c.get('compile_ms', float('nan')):.0f}) / "
                 f"{w.get('wall_ms', float('nan')):.0f} ({w.get('compile_ms', float('nan')):.0f})")
        lines.append(f"| {r['name']} | {r['ours'] * 1e3:.2f} ({r['ours_min'] * 1e3:.2f}) | {cv_text} | {sp_text} | "
              f"{sk_text} | {ratio:.2f}x{'' if r['cv'] else ' (scipy)'} | {goal} | {min_ratio} | "
              f"{r['kernels']} ({r['exec_ms']:.2f}) | {first} |")
    if args.plot:
        plot(rows, args.plot, n)
    total = sum(r["recompiles"] for r in rows)
    lines += ["", f"Kernels compiled again during steady-state calls: {total} (0 = no per-call recompiles)."]
    text = "\n".join(lines)
    print(text)
    if args.write:
        from _results import write_block

        write_block("imaging_spatial", text)


if __name__ == "__main__":
    main()
