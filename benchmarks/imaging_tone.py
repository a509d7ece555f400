"""Benchmark imaging.tone / imaging.colour beside OpenCV, numpy, scikit-image and Pillow (one run).

2048x2048 float32 grey (0..255) and RGB, and uint8 for the table-based operations.
Steady state: median of repeats, each timed until the result is in memory
(Dr.Jit: ``dr.eval`` + ``dr.sync_thread``). OpenCV: the faster of 1 and 2
threads (``cv2.setNumThreads``). First-call JIT cost is measured apart in fresh
subprocesses, with the kernel cache (~/.drjit) cold (HOME pointed at an empty
folder) and warm.

Run:  flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/imaging_tone.py [--size 2048] [--repeats 15]
Prints a Markdown table; ``--write`` replaces the imaging_tone block of benchmarks/RESULTS.md.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import imaging  # noqa: E402,F401  (picks libLLVM)
import drjit as dr  # noqa: E402

from imaging import colour as ic  # noqa: E402
from imaging import tone  # noqa: E402


def images(size: int):
    rng = np.random.default_rng(0)
    grey = (rng.random((size, size), dtype=np.float32) * 255).astype(np.float32)
    rgb = rng.random((size, size, 3), dtype=np.float32)
    grey8 = (rng.random((size, size)) ** 2 * 255).astype(np.uint8)
    hdr = (rng.random((size, size, 3), dtype=np.float32) ** 4 * 16).astype(np.float32)
    return grey, rgb, grey8, hdr


def ours_cases(grey, rgb, grey8, hdr):
    """name -> zero-argument callable running our operation to completion."""
    table = (255 - np.arange(256)).astype(np.float32)
    import cv2

    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)  # not ours: keeps rgb_to_hsv's first call cold

    def done(function):
        def call():
            result = function()
            dr.eval(result)
            dr.sync_thread()
        return call

    return {
        "gamma (float grey)": done(lambda: tone.gamma(grey, 2.2)),
        "gamma (uint8 grey, table)": done(lambda: tone.gamma(grey8, 2.2)),
        "contrast_stretch (float grey)": done(lambda: tone.contrast_stretch(grey, 50, 20, 200, 235)),
        "quantize (float grey)": done(lambda: tone.quantize(grey, 8)),
        "rgb_to_hsv (float RGB)": done(lambda: ic.rgb_to_hsv(rgb)),
        "hsv_to_rgb (float RGB)": done(lambda: ic.hsv_to_rgb(hsv)),
        "tonemap aces (float RGB)": done(lambda: tone.tonemap(hdr, "aces")),
        "tonemap reinhard (float RGB)": done(lambda: tone.tonemap(hdr, "reinhard")),
        "lut (uint8 grey)": done(lambda: tone.lut(grey8, table)),
        "equalize_histogram (uint8 grey)": done(lambda: tone.equalize_histogram(grey8)),
        "equalize_histogram (float grey)": done(lambda: tone.equalize_histogram(grey)),
    }


def peer_cases(grey, rgb, grey8, hdr):
    """name -> (peer name, callable, goal ratio, kind: 'cv2' takes the faster of 1 and 2 threads)."""
    import cv2
    from PIL import Image, ImageOps

    gamma_table = np.round(255 * (np.arange(256) / 255) ** (1 / 2.2)).astype(np.uint8)
    table8 = (255 - np.arange(256)).astype(np.uint8)
    xp, fp = [0, 50, 200, 255], [0, 20, 235, 255]
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
    tm = cv2.createTonemapReinhard(gamma=2.2)

    def aces_numpy():
        x = hdr
        y = np.clip(x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14), 0, 1)
        return np.where(y <= 0.0031308, 12.92 * y, 1.055 * y ** (1 / 2.4) - 0.055) * 255

    return {
        "gamma (float grey)": ("OpenCV pow", lambda: cv2.multiply(cv2.pow(cv2.multiply(grey, 1 / 255.0), 1 / 2.2), 255.0), 0.5, "cv2"),
        "gamma (uint8 grey, table)": ("OpenCV LUT", lambda: cv2.LUT(grey8, gamma_table), 1.0, "cv2"),
        "contrast_stretch (float grey)": ("numpy interp", lambda: np.interp(grey, xp, fp), 0.5, "numpy"),
        "quantize (float grey)": ("numpy", lambda: np.minimum(np.floor(grey * (8 / 255.0)), 7) * (255 / 7), 0.5, "numpy"),
        "rgb_to_hsv (float RGB)": ("OpenCV cvtColor", lambda: cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV), 0.5, "cv2"),
        "hsv_to_rgb (float RGB)": ("OpenCV cvtColor", lambda: cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB), 0.5, "cv2"),
        "tonemap aces (float RGB)": ("numpy", aces_numpy, 0.5, "numpy"),
        "tonemap reinhard (float RGB)": ("OpenCV TonemapReinhard*", lambda: tm.process(hdr), 0.5, "cv2"),
        "lut (uint8 grey)": ("OpenCV LUT", lambda: cv2.LUT(grey8, table8), 1.0, "cv2"),
        "equalize_histogram (uint8 grey)": ("OpenCV equalizeHist", lambda: cv2.equalizeHist(grey8), 1.0, "cv2"),
        "equalize_histogram (float grey)": ("Pillow ImageOps.equalize",
                                            lambda: np.asarray(ImageOps.equalize(Image.fromarray(grey8))), 1.0, "other"),
    }


def median_time(function, repeats: int) -> float:
    function()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def cv2_best(function, repeats: int) -> tuple[float, int]:
    import cv2

    results = []
    for threads in (1, 2):
        cv2.setNumThreads(threads)
        results.append((median_time(function, repeats), threads))
    cv2.setNumThreads(-1)
    return min(results)


FIRST_CALL = r"""
import json, sys, time
sys.path.insert(0, {root!r})
import numpy as np
import benchmarks.imaging_tone as b
grey, rgb, grey8, hdr = b.images({size})
b.peer_cases(grey, rgb, grey8, hdr)
out = {{}}
for name, call in b.ours_cases(grey, rgb, grey8, hdr).items():
    start = time.perf_counter(); call(); first = time.perf_counter() - start
    start = time.perf_counter(); call(); second = time.perf_counter() - start
    out[name] = first - second
print(json.dumps(out))
"""


def first_call_costs(size: int, cold: bool) -> dict[str, float]:
    """First-call minus second-call time per op, in a fresh interpreter (cache cold or warm)."""
    env = dict(os.environ)
    scratch = None
    if cold:
        scratch = tempfile.mkdtemp(prefix="drjit-cold-")
        env["HOME"] = scratch
    code = FIRST_CALL.format(root=str(ROOT), size=size)
    result = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    return json.loads(result.stdout.strip().splitlines()[-1])


def main() -> int:
    from tqdm import tqdm

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=2048)
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--write", action="store_true", help="write the table into benchmarks/RESULTS.md")
    args = parser.parse_args()

    grey, rgb, grey8, hdr = images(args.size)
    peers = peer_cases(grey, rgb, grey8, hdr)
    ours = ours_cases(grey, rgb, grey8, hdr)
    rows = []
    for name in tqdm(ours, desc="steady state"):
        ours_s = median_time(ours[name], args.repeats)
        peer_name, peer, goal, kind = peers[name]
        if kind == "cv2":
            peer_s, threads = cv2_best(peer, args.repeats)
            peer_name += f" ({threads} thr)"
        else:
            peer_s = median_time(peer, max(5, args.repeats // 3))
        rows.append((name, ours_s, peer_name, peer_s, goal))
    cold = first_call_costs(args.size, cold=True)
    warm = first_call_costs(args.size, cold=False)

    import cv2
    import skimage

    lines = [
        f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores; Python "
        f"{platform.python_version()}, Dr.Jit {dr.__version__} (LLVM {'.'.join(map(str, dr.detail.llvm_version()))}), "
        f"OpenCV {cv2.__version__}, numpy {np.__version__}, scikit-image {skimage.__version__}.",
        f"Image {args.size}x{args.size} (float32 grey 0..255, float32 RGB 0..1, uint8 grey), "
        f"median of {args.repeats} repeats; ratio = ours / peer (goal: at most the number shown).",
        f"Command: `flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/imaging_tone.py --size {args.size} "
        f"--repeats {args.repeats} --write`",
        "",
        "| operation | ours (ms) | peer | peer (ms) | ratio | goal | met | first call, cold cache (ms) | first call, warm cache (ms) |",
        "|---|---:|---|---:|---:|---:|---|---:|---:|",
    ]
    for name, ours_s, peer_name, peer_s, goal in rows:
        ratio = ours_s / peer_s
        lines.append(f"| {name} | {ours_s * 1e3:.2f} | {peer_name} | {peer_s * 1e3:.2f} | {ratio:.2f} | "
                     f"{goal:g} | {'yes' if ratio <= goal else 'NO'} | {cold[name] * 1e3:.0f} | {warm[name] * 1e3:.0f} |")
    lines.append("")
    lines.append("*OpenCV's TonemapReinhard is Reinhard-Devlin 2005 with its own gamma, not the same curve: a cost "
                 "reference only. First call = first minus second call time in a fresh process (tracing + "
                 "compilation, or cache load).")
    table = "\n".join(lines)
    print(table)
    if args.write:
        results = ROOT / "benchmarks" / "RESULTS.md"
        text = results.read_text()
        block = re.compile(r"(<!-- BEGIN imaging_tone -->\n).*?(<!-- END imaging_tone -->)", re.S)
        if not block.search(text):
            raise SystemExit("RESULTS.md has no imaging_tone block")
        results.write_text(block.sub(lambda m: m.group(1) + "## Imaging: tone and colour\n\n" + table + "\n" + m.group(2), text))
    return 0


if __name__ == "__main__":
    sys.exit(main())
