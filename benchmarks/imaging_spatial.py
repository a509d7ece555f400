"""Benchmark imaging.filters / imaging.resample against OpenCV (best of 1 and 2 threads) and scipy.

Run: flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/imaging_spatial.py [--size 2048] [--repeat 9]

Prints a Markdown table: steady-state median time (after dr.eval + dr.sync_thread), the first
call (JIT compile + run, with whatever ~/.drjit cache there is), the peers, and ours / OpenCV best.
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

import imaging  # noqa: F401
import cv2
import drjit as dr
import scipy
import scipy.ndimage as ndi
from tqdm import tqdm

from imaging import filters as F
from imaging.resample import resize


def timed(function, repeat):
    start = time.perf_counter()
    function()
    first = time.perf_counter() - start
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return first, float(np.median(times))


def ours(function):
    def run():
        result = function()
        for r in (result if isinstance(result, tuple) else (result,)):
            dr.eval(r)
        dr.sync_thread()
    return run


def opencv_best(function, repeat):
    best = None
    for threads in (1, 2):
        cv2.setNumThreads(threads)
        _, t = timed(function, repeat)
        best = t if best is None or t < best[0] else best
        best = best if isinstance(best, tuple) else (best, threads)
    cv2.setNumThreads(2)
    return best


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--size", type=int, default=2048)
    parser.add_argument("--repeat", type=int, default=9)
    args = parser.parse_args()
    n = args.size
    img = (np.random.default_rng(0).random((n, n)) * 255).astype(np.float32)
    up, down = (n * 5 // 4, n * 5 // 4), (n * 3 // 4, n * 3 // 4)

    def cv_norm():
        d = cv2.filter2D(img, -1, F.GAUSSIAN_3, borderType=cv2.BORDER_CONSTANT)
        roi = np.abs(d[1:-1, 1:-1])
        return cv2.normalize(roi, roi, 0, 255, cv2.NORM_MINMAX)

    def cv_grad(kx, ky):
        return lambda: cv2.magnitude(cv2.filter2D(img, -1, kx), cv2.filter2D(img, -1, ky))

    cases = [
        ("correlate 3x3 + normalize", ours(lambda: F.correlate(img, F.GAUSSIAN_3, normalize=True)), cv_norm,
         lambda: ndi.correlate(img, F.GAUSSIAN_3, mode="constant"), 0.7),
        ("correlate 3x3", ours(lambda: F.correlate(img, F.GAUSSIAN_3)),
         lambda: cv2.filter2D(img, -1, F.GAUSSIAN_3), lambda: ndi.correlate(img, F.GAUSSIAN_3), None),
        ("correlate 7x7", ours(lambda: F.correlate(img, np.ones((7, 7), np.float32))),
         lambda: cv2.filter2D(img, -1, np.ones((7, 7), np.float32)), None, None),
        ("Sobel magnitude", ours(lambda: F.sobel(img)),
         lambda: cv2.magnitude(cv2.Sobel(img, cv2.CV_32F, 1, 0), cv2.Sobel(img, cv2.CV_32F, 0, 1)),
         lambda: np.hypot(ndi.sobel(img, 1), ndi.sobel(img, 0)), 0.7),
        ("Prewitt magnitude", ours(lambda: F.prewitt(img)), cv_grad(F.PREWITT_X, F.PREWITT_Y),
         lambda: np.hypot(ndi.prewitt(img, 1), ndi.prewitt(img, 0)), 0.7),
        ("Laplacian", ours(lambda: F.laplacian(img)), lambda: cv2.Laplacian(img, cv2.CV_32F, ksize=1),
         lambda: ndi.correlate(img, F.LAPLACIAN), 0.7),
        ("median 3x3", ours(lambda: F.median(img, 3)), lambda: cv2.medianBlur(img, 3),
         lambda: ndi.median_filter(img, 3, mode="nearest"), 1.0),
        ("median 5x5", ours(lambda: F.median(img, 5)), lambda: cv2.medianBlur(img, 5),
         lambda: ndi.median_filter(img, 5, mode="nearest"), 1.0),
        ("median 7x7 (peer: scipy)", ours(lambda: F.median(img, 7)), None,
         lambda: ndi.median_filter(img, 7, mode="nearest"), None),
        (f"bilinear resize -> {up[0]}", ours(lambda: resize(img, up, "bilinear")),
         lambda: cv2.resize(img, up, interpolation=cv2.INTER_LINEAR), None, 1.0),
        (f"bilinear resize -> {down[0]}", ours(lambda: resize(img, down, "bilinear")),
         lambda: cv2.resize(img, down, interpolation=cv2.INTER_LINEAR), None, 1.0),
        (f"bicubic resize -> {up[0]}", ours(lambda: resize(img, up, "bicubic", a=-0.75)),
         lambda: cv2.resize(img, up, interpolation=cv2.INTER_CUBIC), None, 1.0),
        (f"bicubic resize -> {down[0]}", ours(lambda: resize(img, down, "bicubic", a=-0.75)),
         lambda: cv2.resize(img, down, interpolation=cv2.INTER_CUBIC), None, 1.0),
    ]
    print(f"machine: {platform.processor() or platform.machine()}, {dr.detail.llvm_version() if hasattr(dr.detail, 'llvm_version') else ''} "
          f"Dr.Jit {dr.__version__}, OpenCV {cv2.__version__}, scipy {scipy.__version__}, image {n}x{n} float32, "
          f"median of {args.repeat}")
    rows = []
    for name, our, cv, sp, goal in tqdm(cases, desc="benchmarks"):
        first, steady = timed(our, args.repeat)
        cv_t, threads = opencv_best(cv, args.repeat) if cv else (None, None)
        sp_t = timed(sp, max(3, args.repeat // 3))[1] if sp else None
        peer = cv_t if cv_t is not None else sp_t
        ratio = steady / peer
        met = "" if goal is None else ("yes" if ratio <= goal else "NO")
        rows.append(f"| {name} | {steady * 1e3:.2f} | {first * 1e3:.0f} | "
                    f"{'' if cv_t is None else f'{cv_t * 1e3:.2f} ({threads} thr)'} | "
                    f"{'' if sp_t is None else f'{sp_t * 1e3:.1f}'} | {ratio:.2f}x | "
                    f"{'' if goal is None else f'<= {goal}x'} {met} |")
    print("| operation | ours ms | ours first call ms | OpenCV best ms | scipy ms | ours / peer | goal |")
    print("|---|---|---|---|---|---|---|")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
