"""Benchmark imaging.dither on 2048 x 2048 beside Pillow (Floyd-Steinberg) and OpenCV (ordered).

Run (the machine is shared; always under the lock):

    flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/imaging_dither.py [--size 2048] [--repeats 15]

Goals (issue 7): Floyd-Steinberg at most 1.0x Pillow's ``Image.convert('1')``; ordered / Bayer /
blue-noise at most 0.5x OpenCV's ``cv2.compare`` against a pre-tiled threshold map (the map is
built outside the timed region: it is the equivalent threshold ceil(255 T / (n^2 + 1)) so that
``I >= map`` is exactly the SPEC rule p >= T for 8-bit input). Every other kernel is reported.

Timing: ours and the peer alternate inside one loop (same machine state); steady state is the
median of the repeats after warm-up, each ending with ``dr.eval`` + ``dr.sync_thread()``.
Input: a 2048 x 2048 8-bit image (a smooth gradient with noise), given to our functions as a
float32 Dr.Jit tensor ("tensor") and as a numpy uint8 array ("uint8", conversion included). JIT
compile time is the first call minus the steady-state time, measured in fresh processes with an
empty (cold) and then a populated (warm) Dr.Jit kernel cache (``$HOME/.drjit``).
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


def test_image(size: int) -> np.ndarray:
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:size, 0:size] / size
    image = 255 * (0.5 + 0.45 * np.sin(6 * x + 3 * y) * np.cos(5 * y)) + rng.normal(0, 12, (size, size))
    return np.clip(image, 0, 255).astype(np.uint8)


def first_call(size: int, home: str) -> dict[str, float]:
    """Run the first calls in a fresh process with HOME=home (so the kernel cache is home/.drjit)."""
    code = f"""
import json, time, numpy as np, drjit as dr, sys
sys.path.insert(0, {str(ROOT)!r})
from benchmarks.imaging_dither import test_image
import imaging.dither as d
from drjit.llvm import TensorXf
image = TensorXf(test_image({size}).astype(np.float32)); dr.eval(image)
result = {{}}
for name, fn in (("floyd_steinberg", lambda: d.floyd_steinberg(image)),
                 ("ordered", lambda: d.ordered(image))):
    times = []
    for _ in range(4):
        t0 = time.perf_counter(); out = fn(); dr.eval(out); dr.sync_thread(); times.append(time.perf_counter() - t0)
    result[name] = (times[0], float(np.median(times[1:])))
print(json.dumps(result))
"""
    env = dict(os.environ, HOME=home)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=2048)
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--json", type=Path, help="also write the numbers as JSON")
    args = parser.parse_args()

    import cv2
    import drjit as dr
    import PIL
    from drjit.llvm import TensorXf
    from PIL import Image
    from tqdm import tqdm

    import imaging.dither as d

    size, repeats = args.size, args.repeats
    u8 = test_image(size)
    tensor = TensorXf(u8.astype(np.float32))
    dr.eval(tensor)
    pil = Image.fromarray(u8)

    def ours(fn, *a, **k):
        def run():
            out = fn(*a, **k)
            dr.eval(out)
            dr.sync_thread()
            return out
        return run

    def tiled_map(template):
        n = template.shape[0]
        levels = np.ceil(255.0 * template / (n * n + 1)).astype(np.uint8)
        return np.tile(levels, (-(-size // n), -(-size // n)))[:size, :size].copy()

    pairs = {
        "floyd_steinberg (tensor)": (ours(d.floyd_steinberg, tensor), lambda: pil.convert("1"), "Pillow convert('1')"),
        "floyd_steinberg (uint8)": (ours(d.floyd_steinberg, u8), lambda: pil.convert("1"), "Pillow convert('1')"),
    }
    for name in d.KERNELS:
        if name != "floyd_steinberg":
            pairs[f"{name} (tensor)"] = (ours(d.diffuse, tensor, name), lambda: pil.convert("1"), "Pillow FS")
    pairs["floyd_steinberg serpentine"] = (ours(d.floyd_steinberg, tensor, serpentine=True),
                                           lambda: pil.convert("1"), "Pillow FS")
    pairs["error_diffusion (simple)"] = (ours(d.error_diffusion, tensor), lambda: pil.convert("1"), "Pillow FS")
    pairs["floyd_steinberg levels=4"] = (ours(d.floyd_steinberg, tensor, levels=4), lambda: pil.convert("1"),
                                         "Pillow FS")
    for label, template in (("ordered 4x4", d.TEMPLATE_4), ("bayer 8x8", d.bayer(8)),
                            ("blue_noise 64x64", d.blue_noise_mask())):
        threshold_map = tiled_map(template)
        pairs[f"{label} (tensor)"] = (ours(d.ordered, tensor, template),
                                      lambda m=threshold_map: cv2.compare(u8, m, cv2.CMP_GE), "cv2.compare")
        pairs[f"{label} (uint8)"] = (ours(d.ordered, u8, template),
                                     lambda m=threshold_map: cv2.compare(u8, m, cv2.CMP_GE), "cv2.compare")
    pairs["pattern 4x4"] = (ours(d.pattern, tensor), None, "")
    pairs["halftone n=3 (6144^2 out)"] = (ours(d.halftone, tensor, 3), None, "")

    # Check that the OpenCV map really is the SPEC rule before timing it.
    check = np.asarray(d.ordered(u8, d.TEMPLATE_4)) > 0
    assert np.array_equal(check, cv2.compare(u8, tiled_map(d.TEMPLATE_4), cv2.CMP_GE) > 0)

    rows = []
    for label, (mine, peer, peer_name) in tqdm(pairs.items(), desc="dither benchmarks"):
        mine()
        if peer:
            peer()
        t_mine, t_peer = [], []
        for _ in range(repeats):
            t0 = time.perf_counter(); mine(); t_mine.append(time.perf_counter() - t0)
            if peer:
                t0 = time.perf_counter(); peer(); t_peer.append(time.perf_counter() - t0)
        m = float(np.median(t_mine)) * 1e3
        p = float(np.median(t_peer)) * 1e3 if peer else float("nan")
        rows.append((label, m, peer_name, p, m / p if peer else float("nan")))

    with tempfile.TemporaryDirectory() as home:
        cold = first_call(size, home)
        warm = first_call(size, home)

    import drjit
    import mitsuba  # noqa: F401 - version only

    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores; Python "
          f"{platform.python_version()}, Dr.Jit {drjit.__version__}, Pillow {PIL.__version__}, OpenCV {cv2.__version__}, "
          f"numpy {np.__version__}; packet width {d._packet_width()}")
    print(f"\n| {size}x{size} | ours (ms) | peer | peer (ms) | ours / peer |")
    print("|---|---:|---|---:|---:|")
    for label, m, peer_name, p, ratio in rows:
        print(f"| {label} | {m:.2f} | {peer_name or '-'} | " + (f"{p:.2f} | {ratio:.2f} |" if peer_name else "- | - |"))
    print("\n| first call (ms) | cold cache | warm cache | steady |")
    print("|---|---:|---:|---:|")
    for name in cold:
        print(f"| {name} | {cold[name][0] * 1e3:.1f} | {warm[name][0] * 1e3:.1f} | {warm[name][1] * 1e3:.2f} |")
    if args.json:
        args.json.write_text(json.dumps({"rows": rows, "cold": cold, "warm": warm}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
