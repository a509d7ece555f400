"""Benchmark imaging.dither on 2048 x 2048 beside Pillow (Floyd-Steinberg) and OpenCV (ordered).

Run (the machine is shared; always under the lock):

    flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/imaging_dither.py [--size 2048] [--repeats 21]

Goals: Floyd-Steinberg at most 1.0x Pillow's ``Image.convert('1')``; ordered / Bayer /
blue-noise at most 0.5x OpenCV's ``cv2.compare`` against a pre-tiled threshold map (built outside
the timed region). The 8-bit pipelines (8-bit in, 8-bit out: uint8 input gives uint8 output): Floyd-Steinberg
of uint8 at most 0.6x Pillow; ordered / Bayer / blue noise of uint8 at most 1.5x ``cv2.compare``
against a pre-tiled uint8 map. Every other kernel is reported.

Like with like: ordered dithering is timed twice against OpenCV,
(a) float32 in both: our float32 tensor vs ``cv2.compare(float32 image, float32 tiled map)``; the
    map holds :func:`imaging.dither.intensity_thresholds` (I >= map is exactly the conventions' rule);
(b) uint8 in both: our uint8 path (bytes read in the kernel) vs ``cv2.compare(uint8 image,
    uint8 tiled map ceil(255 T / (n^2 + 1)))``.
Both results are checked equal to ours before timing. Bytes moved are printed: OpenCV writes a
uint8 mask (1 B/pixel); we write float32 levels for float input (4 B/pixel) and uint8 levels for
uint8 input (1 B/pixel; 1-bit uint8 ordered dithering reads a cached pre-tiled byte map, as OpenCV).
OpenCV runs with 1 and with 2 threads (``cv2.setNumThreads``) and the faster median counts.

Timing: ours and the peers alternate inside one loop (same machine state); steady state is the
median of the repeats after warm-up, each of ours ending with ``dr.eval`` + ``dr.sync_thread()``.
Our kernel time (Dr.Jit kernel history: launches per call, summed execution time) is reported
beside the wall time. JIT compile time is the first call minus the steady-state time, measured in
fresh processes with an empty (cold) and then a populated (warm) Dr.Jit kernel cache
(``$HOME/.drjit``).
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
sys.path.insert(0, str(ROOT / "benchmarks"))


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
import pointillist.imaging.dither as d
from drjit.llvm import TensorXf
image = TensorXf(test_image({size}).astype(np.float32)); dr.eval(image)
result = {{}}
u8 = test_image({size})
for name, fn in (("floyd_steinberg", lambda: d.floyd_steinberg(image)),
                 ("ordered (float32)", lambda: d.ordered(image)),
                 ("ordered (uint8)", lambda: d.ordered(u8))):
    times, compile_ms = [], 0.0
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()
    for k in range(7):
        t0 = time.perf_counter(); out = fn(); dr.eval(out); dr.sync_thread(); times.append(time.perf_counter() - t0)
        if k == 0:  # LLVM code generation + compilation (0 on a cache hit) of the first call's kernels
            compile_ms = sum((e.get("codegen_time") or 0) + (e.get("backend_time") or 0)
                             for e in dr.kernel_history() if e["type"] == dr.KernelType.JIT)
    result[name] = (times[0], float(np.median(times[1:])), compile_ms)
print(json.dumps(result))
"""
    env = dict(os.environ, HOME=home)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def load_revision(rev: str):
    """imaging/dither.py as of git revision ``rev``, imported as a separate module."""
    import importlib.util

    source = subprocess.run(["git", "-C", str(ROOT), "show", f"{rev}:imaging/dither.py"], capture_output=True,
                            text=True, check=True).stdout
    spec = importlib.util.spec_from_loader("imaging._dither_before", loader=None)
    module = importlib.util.module_from_spec(spec)
    module.__file__ = str(ROOT / "imaging" / "dither.py")  # its data directory
    sys.modules[spec.name] = module
    exec(compile(source, f"{rev}:imaging/dither.py", "exec"), module.__dict__)
    return module


def plot(results: list[dict], path: Path, size: int) -> None:
    """Horizontal bars of ours / peer (log scale) with the goals marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in results if r["best"]]
    fig, ax = plt.subplots(figsize=(8, 0.32 * len(rows) + 1.2))
    ratios = [r["ratio"] for r in rows]
    def colour(r: dict) -> str:
        if r["label"].startswith("floor"):
            return "tab:grey"  # a read-and-write pass, no dithering: the floor
        if "before" in r["best"]:
            return "tab:blue"  # this tree over the older revision
        goal = (1.5 if "u8" in r["best"] else 0.5) if "compare" in r["best"] else (
            0.6 if "uint8" in r["label"] else 1.0)
        return "tab:green" if r["ratio"] <= goal else "tab:red"

    colours = [colour(r) for r in rows]
    ax.barh(range(len(rows)), ratios, color=colours)
    ax.set_yticks(range(len(rows)), [f"{r['label']}  [{r['best']}]" for r in rows], fontsize=7)
    ax.invert_yaxis()
    ax.set_xscale("log")
    for x, style, label in ((1.0, "-", "1.0x (error diffusion, float)"), (0.6, ":", "0.6x (FS, uint8)"),
                            (0.5, "--", "0.5x (ordered, float32)"), (1.5, "-.", "1.5x (ordered, uint8)")):
        ax.axvline(x, color="k", linestyle=style, linewidth=0.8, label=label)
    ax.set_xlabel("ours / peer time (median; lower is better)\ngreen/red: goal met/missed; "
                  "grey: copy floor; blue: vs older revision", fontsize=7)
    ax.set_title(f"imaging.dither, {size}x{size}")
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


NOTES = """Floyd-Steinberg: a grey image whose width is a whole number of 8-column blocks, scanned left to
right, is diffused by the blocked schedule of `imaging/wavefront.py`: one SIMD packet of 16 rows per band, each
loop iteration diffusing 8 columns of every row with the steps unrolled; the block's inputs (8-bit input read as
bytes), the next 8 errors of the row above and the block's 8 errors and 8 output levels move as packet gathers and
scatters (a vector load or store per lane and a transpose) instead of one hardware gather or scatter per value
and step. The row "one-column schedule" is the same diffusion by the previous schedule (same bits, checked before
timing; tests/test_dither.py compares both with a sequential float64 scan and with each other on scikit-image's
camera and noise). What bounds it: the scan is sequential between bands and each band is one packet, so the
kernel runs on one core against Pillow's one core, at the latency of the float64 arithmetic of a step (the
error of the pixel to the left feeds the next pixel: about 16 cycles of multiply, add, compare, select and
subtract), 16 rows at a time; sharing bands between the two cores needs a per-row progress counter between
packets, which Dr.Jit's lockstep packets cannot express (a hand-written kernel). Serpentine scans and colour
images keep the one-column schedule.

Ordered dithering: uint8 input is compared with a cached pre-tiled byte map (three contiguous
byte streams, as `cv2.compare`); the floor rows are a bare Dr.Jit copy. Sub-millisecond kernels on Dr.Jit's two
worker threads lose to preemption on a loaded machine, where single-threaded OpenCV on the calling thread does
not: read the minima there."""


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=2048)
    parser.add_argument("--repeats", type=int, default=21)
    parser.add_argument("--only", choices=("all", "ordered", "diffusion"), default="all")
    parser.add_argument("--before", metavar="REV", help="also time imaging/dither.py as of git revision REV "
                        "(rows 'vs before': this tree's time over REV's, interleaved)")
    parser.add_argument("--json", type=Path, help="also write the numbers as JSON")
    parser.add_argument("--plot", type=Path, help="also draw ours / peer per row (PNG)")
    parser.add_argument("--write", action="store_true", help="write the section into benchmarks/RESULTS.md")
    args = parser.parse_args()

    import cv2
    import drjit as dr
    import PIL
    from drjit.llvm import TensorXf
    from PIL import Image
    from tqdm import tqdm

    import pointillist.imaging.dither as d
    from pointillist.imaging.wavefront import packet_width

    size, repeats = args.size, args.repeats
    odd = size - 1  # a width that is not a power of two: the template index needs a division
    u8 = test_image(size)
    u8_odd = np.ascontiguousarray(test_image(size)[:odd, :odd])
    f32, f32_odd = u8.astype(np.float32), u8_odd.astype(np.float32)
    tensor, tensor_odd = TensorXf(f32), TensorXf(f32_odd)
    dr.eval(tensor, tensor_odd)
    pil = Image.fromarray(u8)

    def ours(fn, *a, **k):
        def run():
            out = fn(*a, **k)
            dr.eval(out)
            dr.sync_thread()
            return out
        return run

    def opencv(threads, a, b):
        # setNumThreads outside the timed call; returns (setup, timed call)
        return (lambda: cv2.setNumThreads(threads)), (lambda: cv2.compare(a, b, cv2.CMP_GE))

    def tiled(table, shape):
        n = table.shape[0]
        return np.ascontiguousarray(np.tile(table, (-(-shape[0] // n), -(-shape[1] // n)))[:shape[0], :shape[1]])

    pillow = {"Pillow convert('1')": (None, lambda: pil.convert("1"))}
    rows = []  # (label, ours, {peer: (setup, fn)}, bytes ours, bytes peer)
    pixels = size * size
    if args.only in ("all", "diffusion"):
        rows.append(("floyd_steinberg (float32 tensor)", ours(d.floyd_steinberg, tensor), pillow, None, None))
        rows.append(("floyd_steinberg (uint8 numpy)", ours(d.floyd_steinberg, u8), pillow, None, None))
        # the same diffusion by the one-column schedule (the speed round's blocked schedule off): same bits
        from drjit.llvm import UInt8 as Bytes

        from pointillist.imaging.dither._shared import _quantiser
        from pointillist.imaging.wavefront import diffuse_wavefront

        fs_kernel = tuple((dy, dx, k / 16) for dy, dx, k in d.KERNELS["floyd_steinberg"].weights)
        fs_tables = _quantiser(2, 128.0, False)
        u8_flat = Bytes(u8.reshape(-1))
        assert np.array_equal(diffuse_wavefront(u8_flat, size, size, 1, fs_kernel, False, fs_tables, eight_bit=True,
                                                blocks=False).numpy(), np.asarray(d.floyd_steinberg(u8)).ravel())
        rows.append(("floyd_steinberg (uint8, one-column schedule)",
                     ours(diffuse_wavefront, u8_flat, size, size, 1, fs_kernel, False, fs_tables, eight_bit=True,
                          blocks=False), pillow, None, None))
    if args.only in ("all", "ordered"):
        cases = (("ordered 4x4", d.TEMPLATE_4), ("bayer 8x8", d.bayer(8)), ("blue_noise 64x64", d.blue_noise_mask()))
        for label, template in cases:
            n = template.shape[0]
            map_f32 = tiled(d.intensity_thresholds(template), (size, size))
            map_u8 = tiled((-(-255 * template // (n * n + 1))).astype(np.uint8), (size, size))
            mine = np.asarray(d.ordered(tensor, template)) > 0
            assert np.array_equal(mine, cv2.compare(f32, map_f32, cv2.CMP_GE) > 0), label
            assert np.array_equal(mine, cv2.compare(u8, map_u8, cv2.CMP_GE) > 0), label
            assert np.array_equal(mine, np.asarray(d.ordered(u8, template)) > 0), label
            rows.append((f"{label}, float32 in both", ours(d.ordered, tensor, template),
                         {f"cv2.compare f32, {t} thr": opencv(t, f32, map_f32) for t in (1, 2)},
                         8 * pixels, 9 * pixels))
            assert np.array_equal(np.asarray(d.ordered(u8, template)), cv2.compare(u8, map_u8, cv2.CMP_GE)), label
            rows.append((f"{label}, uint8 in both", ours(d.ordered, u8, template),
                         {f"cv2.compare u8, {t} thr": opencv(t, u8, map_u8) for t in (1, 2)},
                         3 * pixels, 3 * pixels))
        # Floors: what one pass that only reads and writes costs under the same convention.
        from drjit.llvm import Float, UInt8

        zero = dr.opaque(Float, 0.0)
        map_f32 = tiled(d.intensity_thresholds(d.TEMPLATE_4), (size, size))
        map_u8 = tiled((-(-255 * d.TEMPLATE_4 // 17)).astype(np.uint8), (size, size))
        rows.append(("floor: Dr.Jit copy float32 -> float32", ours(lambda: tensor.array + zero),
                     {f"cv2.compare f32, {t} thr": opencv(t, f32, map_f32) for t in (1, 2)}, 8 * pixels, 9 * pixels))
        bytes_u8 = UInt8(u8.reshape(-1))
        zero8 = dr.opaque(UInt8, 0)
        rows.append(("floor: Dr.Jit copy uint8 -> uint8", ours(lambda: bytes_u8 + zero8),
                     {f"cv2.compare u8, {t} thr": opencv(t, u8, map_u8) for t in (1, 2)}, 2 * pixels, 3 * pixels))
        map_odd = tiled(d.intensity_thresholds(d.TEMPLATE_4), (odd, odd))
        assert np.array_equal(np.asarray(d.ordered(tensor_odd)) > 0, cv2.compare(f32_odd, map_odd, cv2.CMP_GE) > 0)
        rows.append((f"ordered 4x4, float32, {odd}x{odd}", ours(d.ordered, tensor_odd),
                     {f"cv2.compare f32, {t} thr": opencv(t, f32_odd, map_odd) for t in (1, 2)},
                     8 * odd * odd, 9 * odd * odd))
        rows.append(("ordered 4x4 levels=4 (float32)", ours(d.ordered, tensor, levels=4), {}, None, None))
        rows.append(("pattern 4x4 (float32)", ours(d.pattern, tensor), {}, None, None))
        rows.append(("halftone n=3 (float32; 6144^2 out)", ours(d.halftone, tensor, 3), {}, None, None))
    if args.only in ("all", "diffusion"):
        for name in d.KERNELS:
            if name != "floyd_steinberg":
                rows.append((f"{name} (float32)", ours(d.diffuse, tensor, name), pillow, None, None))
        rows.append(("floyd_steinberg serpentine (sequential)", ours(d.floyd_steinberg, tensor, serpentine=True),
                     pillow, None, None))
        rows.append(("error_diffusion, simple serpentine (sequential)", ours(d.error_diffusion, tensor), pillow,
                     None, None))
        rows.append(("floyd_steinberg levels=4", ours(d.floyd_steinberg, tensor, levels=4), pillow, None, None))

    if args.before:
        old = load_revision(args.before)
        tag = f"{args.before[:10]}"
        for label, mine, theirs in (
                ("ordered 4x4 (float32)", ours(d.ordered, tensor), ours(old.ordered, tensor)),
                ("ordered 4x4 (uint8)", ours(d.ordered, u8), ours(old.ordered, u8)),
                ("blue_noise (float32)", ours(d.blue_noise, tensor), ours(old.blue_noise, tensor)),
                ("ordered 4x4 levels=4 (float32)", ours(d.ordered, tensor, levels=4),
                 ours(old.ordered, tensor, levels=4)),
                ("pattern 4x4 (float32)", ours(d.pattern, tensor), ours(old.pattern, tensor)),
                ("halftone n=3 (float32)", ours(d.halftone, tensor, 3), ours(old.halftone, tensor, 3)),
                ("floyd_steinberg (float32)", ours(d.floyd_steinberg, tensor), ours(old.floyd_steinberg, tensor)),
                ("floyd_steinberg (uint8)", ours(d.floyd_steinberg, u8), ours(old.floyd_steinberg, u8))):
            assert np.array_equal(np.asarray(mine()), np.asarray(theirs())), label
            rows.append((f"{label} vs before", mine, {f"before ({tag})": (None, theirs)}, None, None))

    dr.set_flag(dr.JitFlag.KernelHistory, True)
    results = []
    threads_before = cv2.getNumThreads()
    for label, mine, peers, bytes_mine, bytes_peer in tqdm(rows, desc="dither benchmarks"):
        mine()
        for setup, fn in peers.values():
            if setup:
                setup()
            fn()
        t_mine, t_kernel, launches = [], [], []
        t_peer = {name: [] for name in peers}
        def run_mine():
            dr.kernel_history()  # drop the peers' launches (the 'before' peer is Dr.Jit too)
            t0 = time.perf_counter()
            mine()
            t_mine.append(time.perf_counter() - t0)
            history = [e for e in dr.kernel_history() if e["type"] == dr.KernelType.JIT]
            launches.append(len(history))
            t_kernel.append(sum(e["execution_time"] for e in history) * 1e-3)

        def run_peers():
            for name, (setup, fn) in peers.items():
                if setup:
                    setup()
                t0 = time.perf_counter()
                fn()
                t_peer[name].append(time.perf_counter() - t0)

        for k in range(repeats):
            # alternate who goes first: whoever follows OpenCV's 2-thread call shares the cores
            # with its worker pool's spin-wait
            for run in ((run_mine, run_peers) if k % 2 else (run_peers, run_mine)):
                run()
        m = float(np.median(t_mine)) * 1e3
        medians = {name: float(np.median(t)) * 1e3 for name, t in t_peer.items()}
        minima = {name: float(np.min(t)) * 1e3 for name, t in t_peer.items()}
        best = min(medians, key=medians.get) if medians else ""
        results.append(dict(label=label, ours=m, ours_min=float(np.min(t_mine)) * 1e3,
                            kernel=float(np.median(t_kernel)) * 1e3,
                            launches=int(np.median(launches)), peers=medians, peers_min=minima, best=best,
                            ratio=m / medians[best] if best else float("nan"),
                            ratio_min=float(np.min(t_mine)) * 1e3 / minima[best] if best else float("nan"),
                            bytes_ours=bytes_mine, bytes_peer=bytes_peer))
    cv2.setNumThreads(threads_before)
    dr.set_flag(dr.JitFlag.KernelHistory, False)

    with tempfile.TemporaryDirectory() as home:
        cold = first_call(size, home)
        warm = first_call(size, home)

    import drjit

    lines = ["## Dithering (imaging.dither), 2048 x 2048", "",
             "`flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/imaging_dither.py "
             f"{' '.join(sys.argv[1:])}`",
             "",
             f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, load average "
             f"{', '.join(f'{x:.2f}' for x in os.getloadavg())} (2 cores: above ~1 these are loaded-machine figures; "
             f"rerun on a quiet machine); Python {platform.python_version()}, Dr.Jit {drjit.__version__}, "
             f"Pillow {PIL.__version__}, OpenCV {cv2.__version__}, numpy {np.__version__}; Dr.Jit threads "
             f"{dr.thread_count()}, packet width {packet_width()}; median (and minimum) of {repeats} interleaved "
             "repeats. Input: 8-bit gradient + noise. Goals of the speed round: Floyd-Steinberg of uint8 at most 0.6x "
             "Pillow's `convert('1')`; of the 8-bit pipelines: ordered / Bayer / blue noise of uint8 at most 1.5x "
             "`cv2.compare` against a pre-tiled uint8 map; of the dithering speed goals: float32 ordered at most "
             "0.5x `cv2.compare` f32.",
             "", f"| {size}x{size} | ours median (min) ms | our kernel (ms) | launches | peer (faster setting) "
             f"| peer median (min) ms | ours / peer, medians | (minima) | MB moved ours / peer |",
             "|---|---:|---:|---:|---|---:|---:|---:|---:|"]
    for r in results:
        peer = (f"{r['best']} | {r['peers'][r['best']]:.2f} ({r['peers_min'][r['best']]:.2f}) | {r['ratio']:.2f} "
                f"| {r['ratio_min']:.2f}") if r["best"] else "- | - | - | -"
        moved = f"{r['bytes_ours'] / 1e6:.0f} / {r['bytes_peer'] / 1e6:.0f}" if r["bytes_ours"] else "-"
        lines.append(f"| {r['label']} | {r['ours']:.2f} ({r['ours_min']:.2f}) | {r['kernel']:.2f} | {r['launches']} "
                     f"| {peer} | {moved} |")
    lines += ["", "all peer medians (ms): " + "; ".join(
        f"{r['label']}: " + ", ".join(f"{k} {v:.2f}" for k, v in r["peers"].items()) for r in results if r["peers"])]
    lines += ["", "| first call in a fresh process (ms) | cold cache | of which LLVM codegen + compile | warm cache "
              "| of which codegen + compile | steady (median of 6) |", "|---|---:|---:|---:|---:|---:|"]
    for name in cold:
        lines.append(f"| {name} | {cold[name][0] * 1e3:.1f} | {cold[name][2]:.1f} | {warm[name][0] * 1e3:.1f} "
                     f"| {warm[name][2]:.1f} | {warm[name][1] * 1e3:.2f} |")
    lines += ["", NOTES]
    print("\n".join(lines))
    if args.write:
        from _results import write_block

        write_block("imaging_dither", "\n".join(lines))
    if args.json:
        args.json.write_text(json.dumps({"rows": results, "cold": cold, "warm": warm}, indent=1))
    if args.plot:
        plot(results, args.plot, size)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
