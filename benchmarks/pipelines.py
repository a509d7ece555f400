"""Benchmark: whole ``post`` pipelines, where Dr.Jit's lazy evaluation can fuse steps, against the
same chains in OpenCV / numpy / Pillow.

Chains, from the loaded image to the result array (file I/O apart):

A. ``grey;gamma:2.2;sobel;normalize;threshold:level=128`` on a 2048x2048 RGB image; the peer:
   ``cv2.cvtColor`` (RGB->grey), ``cv2.LUT`` (gamma on uint8), two ``cv2.Sobel`` + ``cv2.magnitude``,
   ``cv2.normalize`` (min-max to 0..255), ``cv2.threshold``.
B. ``tonemap:reinhard;gamma:1.2;median:3;dither:floyd_steinberg`` on a 2048x2048 grey HDR image;
   the peer: numpy Reinhard (the same formula, white = the largest value) and sRGB encoding to
   uint8, ``cv2.LUT`` (gamma), ``cv2.medianBlur`` (3x3), Pillow ``convert("1")`` (Floyd-Steinberg).

OpenCV runs with 1 and 2 threads (``cv2.setNumThreads``); the better is the peer's time. Rounds
are interleaved (ours, peer 1 thread, peer 2 threads, ...); each result is forced (``dr.eval`` +
``dr.sync_thread``; OpenCV and numpy are eager). The first call of ours in the process (JIT compile,
or kernel-cache load) is reported apart. For ours, Dr.Jit's kernel history counts the kernels
launched and their passes over memory. Run::

    flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/pipelines.py [--size 2048] [--rounds 9]

It prints a Markdown section (``--write`` puts it into the ``pipelines`` block of RESULTS.md).
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

GOAL = 0.5
CHAIN_A = "grey;gamma:2.2;sobel;normalize;threshold:level=128"
CHAIN_B = "tonemap:reinhard;gamma:1.2;median:3;dither:floyd_steinberg"


def _images(size: int, seed: int = 7):
    """A smooth RGB test image with texture (uint8) and a grey HDR image (float32, 0..~50)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size] / size
    base = 0.5 + 0.25 * np.sin(12 * x) * np.cos(9 * y)
    rgb = np.stack([base, np.roll(base, size // 7, 0), np.roll(base, size // 5, 1)], -1)
    rgb = np.clip(rgb * 255 + rng.normal(0, 12, rgb.shape), 0, 255).astype(np.uint8)
    hdr = (np.exp(4 * base - 1) + rng.exponential(0.3, base.shape)).astype(np.float32)
    return rgb, hdr


def ours(image, chain: str):
    import drjit as dr

    from pointillist.post import apply_steps

    result = apply_steps(image, chain, linear=image.dtype == np.float32).image  # the HDR image is linear
    dr.eval(result)
    dr.sync_thread()
    return result


def peer_a(rgb: np.ndarray) -> np.ndarray:
    import cv2

    table = np.clip(np.round((np.arange(256) / 255.0) ** (1 / 2.2) * 255), 0, 255).astype(np.uint8)
    grey = cv2.LUT(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), table)
    gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3)
    norm = cv2.normalize(cv2.magnitude(gx, gy), None, 0, 255, cv2.NORM_MINMAX)
    return cv2.threshold(norm, 127.999, 255, cv2.THRESH_BINARY)[1]


def peer_b(hdr: np.ndarray) -> np.ndarray:
    import cv2
    from PIL import Image

    w = float(hdr.max())
    mapped = np.clip((hdr + (hdr / w) ** 2) / (1.0 + hdr), 0.0, 1.0)
    encoded = np.where(mapped <= 0.0031308, 12.92 * mapped, 1.055 * np.power(mapped, 1 / 2.4) - 0.055)
    display = np.round(encoded * 255).astype(np.uint8)
    table = np.clip(np.round((np.arange(256) / 255.0) ** (1 / 1.2) * 255), 0, 255).astype(np.uint8)
    smooth = cv2.medianBlur(cv2.LUT(display, table), 3)
    return np.asarray(Image.fromarray(smooth).convert("1"))


def _kernels(image, chain: str, repeats: int = 5) -> tuple[int, int, list[float]]:
    """(kernels launched, operations, least execution time of each kernel in ms over ``repeats``
    runs) for ``chain`` (after its first run)."""
    import drjit as dr

    ours(image, chain)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    times = []
    for _ in range(repeats):
        dr.kernel_history()
        ours(image, chain)
        history = [k for k in dr.kernel_history() if k.get("type") == dr.KernelType.JIT]
        times.append([float(k.get("execution_time", 0.0)) for k in history])
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    least = [min(run[i] for run in times) for i in range(len(times[0]))] if all(
        len(run) == len(times[0]) for run in times) else times[-1]
    return len(history), sum(int(k.get("operation_count", 0)) for k in history), least


def measure(size: int, rounds: int):
    import cv2
    from _timing import seconds as _timed

    import pointillist.imaging  # noqa: F401  (libLLVM first)

    rgb, hdr = _images(size)
    cases = {"A": (CHAIN_A, rgb, peer_a), "B": (CHAIN_B, hdr, peer_b)}
    first = {name: _timed(ours, image, chain) for name, (chain, image, _) in cases.items()}
    for _, image, peer in cases.values():
        peer(image)  # warm OpenCV's and numpy's first calls too
    times = {(name, who): [] for name in cases for who in ("ours", "cv1", "cv2")}
    from tqdm import tqdm

    for _ in tqdm(range(rounds), desc="interleaved rounds"):
        for name, (chain, image, peer) in cases.items():
            times[name, "ours"].append(_timed(ours, image, chain))
            cv2.setNumThreads(1)
            times[name, "cv1"].append(_timed(peer, image))
            cv2.setNumThreads(2)
            times[name, "cv2"].append(_timed(peer, image))
    kernels = {name: _kernels(image, chain) for name, (chain, image, _) in cases.items()}
    return cases, first, times, kernels


def markdown(args, cases, first, times, kernels) -> str:
    import cv2
    import drjit as dr
    import PIL

    lines = ["## Whole pipelines (`post` chains) against OpenCV / numpy / Pillow", "",
             f"Machine: {platform.machine()}, {os.cpu_count()} cores, {platform.platform()}; Python "
             f"{platform.python_version()}, Dr.Jit {dr.__version__}, OpenCV {cv2.__version__}, numpy "
             f"{np.__version__}, Pillow {PIL.__version__}. Reproduce: `flock /tmp/pointillist-bench.lock "
             f".venv/bin/python benchmarks/pipelines.py --size {args.size} --rounds {args.rounds}`. "
             f"{args.size}x{args.size}; {args.rounds} interleaved rounds; median (min) in ms; the peer is the "
             "better of OpenCV with 1 and 2 threads. Load average (1, 5, 15 min) at the end: "
             f"{', '.join(f'{x:.1f}' for x in os.getloadavg())} (2 cores: above ~1 these are loaded-machine "
             "figures; rerun on a quiet machine).", "",
             "| chain | ours | peer 1 thread | peer 2 threads | ratio (median) | ratio (min) | goal | met | "
             "first call (JIT) | kernels / operations | kernel times, least of 5 (ms) |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, (chain, _, _) in cases.items():
        o, c1, c2 = (times[name, w] for w in ("ours", "cv1", "cv2"))
        peer_med = min(statistics.median(c1), statistics.median(c2))
        peer_min = min(min(c1), min(c2))
        ratio, ratio_min = statistics.median(o) / peer_med, min(o) / peer_min
        lines.append(f"| {name}: `{chain}` | {statistics.median(o) * 1e3:.1f} ({min(o) * 1e3:.1f}) "
                     f"| {statistics.median(c1) * 1e3:.1f} ({min(c1) * 1e3:.1f}) "
                     f"| {statistics.median(c2) * 1e3:.1f} ({min(c2) * 1e3:.1f}) | {ratio:.2f} | {ratio_min:.2f} "
                     f"| <= {GOAL}x | {'yes' if ratio <= GOAL else '**no**'} | {first[name] * 1e3:.0f} ms "
                     f"| {kernels[name][0]} / {kernels[name][1]} "
                     f"| {' + '.join(f'{t:.2f}' for t in kernels[name][2])} |")
    return "\n".join(lines + ["", NOTES])


NOTES = """Chain A on 8-bit RGB: the image stays bytes until `grey` (`Step.takes_bytes`), which reads
R, G, B as 32-bit word gathers inside the kernel of the next step; `gamma` is fused with it (one pass: bytes in,
float32 grey out); `sobel` runs the padded-window engine over that grey (numpy's padded copy, then one kernel);
`normalize` finds min and max in one pass over the magnitude with |.| and the uncomputed ring left out in the
kernel; `normalize` and `threshold` are fused into the last kernel. Before: a numpy float32 copy of the 48 MB RGB
image, 7 kernels (a separate absolute-value pass and a masked copy for the min/max). Outputs are bit-identical
(tests/test_post.py compares the 8-bit chains with the chains of the float32 conversion). What bounds it: the
grey stays float32 (the luma of 8-bit RGB is not 8-bit, and gamma of it is a float curve), so the window reads
4 bytes a pixel; the min/max needs its own pass before any output can be written; and on a loaded machine the
four 2-thread kernels lose more to preemption than single-threaded OpenCV. Fusing the min/max into the window
kernel (a block-wise reduction it writes beside the magnitude) would save one 16 MB read."""


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=2048)
    parser.add_argument("--rounds", type=int, default=9)
    parser.add_argument("--write", action="store_true", help="write the section into benchmarks/RESULTS.md")
    args = parser.parse_args(argv)
    text = markdown(args, *measure(args.size, args.rounds))
    print(text)
    if args.write:
        from _results import write_block

        write_block("pipelines", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
