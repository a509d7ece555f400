"""Does forcing hardware gathers help? The gather-bound imaging operations under three LLVM targets.

Dr.Jit compiles for the host CPU (here ``znver4``, AMD Zen 4), for which LLVM 19 emits
every ``dr.gather`` as scalar loads. This script re-runs itself in fresh processes
with Dr.Jit's LLVM target changed *before the first kernel* (``jit_llvm_set_target``
from ``libdrjit-core``, called through ctypes: Dr.Jit 1.5 has no Python binding for
it) and an empty kernel cache, then times the operations whose goals are missed:

- ``default``: the host CPU and features Dr.Jit picked;
- ``+fast-gather``: the same, with LLVM's tuning flag that makes it emit ``vgather``;
- ``skylake-avx512``: an Intel target, whose cost model also prefers hardware gathers.

Run::

    flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/llvm_target.py [--repeats 15] [--rounds 5]

Prints a Markdown table: per operation the median over ``--rounds`` processes of each
process's median ms, 2048x2048 float32 (uint8 for LUT and equalisation).
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TARGETS = ("default", ":+fast-gather", "skylake-avx512:")


def _set_target(mode: str) -> str:
    import drjit as dr

    lib = ctypes.CDLL(os.path.join(os.path.dirname(dr.__file__), "libdrjit-core.so"))
    cpu = lib._Z19jit_llvm_target_cpuv
    cpu.restype = ctypes.c_char_p
    features = lib._Z24jit_llvm_target_featuresv
    features.restype = ctypes.c_char_p
    if mode != "default":
        set_target = lib._Z19jit_llvm_set_targetPKcS0_j
        set_target.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_uint32]
        name, extra = mode.split(":")
        flags = features().decode() + ("," + extra if extra else "")
        set_target((name or cpu().decode()).encode(), flags.encode(), 16)
    return cpu().decode() + (" +fast-gather" if "fast-gather" in features().decode() else "")


def child(mode: str, repeats: int) -> dict:
    sys.path.insert(0, str(ROOT))
    import pointillist

    pointillist.setup()
    import drjit as dr
    import numpy as np

    target = _set_target(mode)
    from pointillist.imaging import colour, tone
    from pointillist.imaging import filters as F
    from pointillist.imaging.resample import resize

    rng = np.random.default_rng(0)
    g8 = (rng.random((2048, 2048)) * 255).astype(np.uint8)
    gf = dr.llvm.TensorXf((rng.random((2048, 2048)) * 255).astype(np.float32))
    rgb = dr.llvm.TensorXf(rng.random((2048, 2048, 3)).astype(np.float32))
    table = np.arange(256, dtype=np.float32)[::-1].copy()
    cases = {
        "lut (uint8)": lambda: tone.lut(g8, table),
        "equalize_histogram (uint8)": lambda: tone.equalize_histogram(g8),
        "rgb_to_hsv": lambda: colour.rgb_to_hsv(rgb),
        "hsv_to_rgb": lambda: colour.hsv_to_rgb(rgb),
        "laplacian (no gathers)": lambda: F.laplacian(gf),
        "median 3x3 (no gathers)": lambda: F.median(gf, 3),
        "bilinear resize -> 2560": lambda: resize(gf, (2560, 2560), "bilinear"),
        "bilinear resize -> 1536": lambda: resize(gf, (1536, 1536), "bilinear"),
        "bicubic resize -> 2560": lambda: resize(gf, (2560, 2560), "bicubic"),
        "bicubic resize -> 1536": lambda: resize(gf, (1536, 1536), "bicubic"),
    }
    from _timing import repeat

    out = {"target": target}
    for name, f in cases.items():
        out[name] = repeat(f, repeats).median * 1e3   # after a warm-up call (compilation)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15, help="timed calls per operation and process")
    parser.add_argument("--rounds", type=int, default=5, help="processes per target (median over them)")
    parser.add_argument("--write", action="store_true", help="write the table into benchmarks/RESULTS.md")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps(child(args.child, args.repeats)))
        return 0
    from _timing import load, load_note
    from tqdm import tqdm

    load_before = load()
    # Rounds of one fresh process per target, in rotating order (a process's place in the
    # sequence moved its times by up to 1.5x, for kernels without any gather too).
    runs: dict[str, list[dict]] = {mode: [] for mode in TARGETS}
    plan = [TARGETS[r % len(TARGETS):] + TARGETS[:r % len(TARGETS)] for r in range(args.rounds)]
    for mode in tqdm([m for order in plan for m in order], desc="LLVM targets", file=sys.stderr):
        with tempfile.TemporaryDirectory() as home:  # empty ~/.drjit: no kernel from another target
            env = dict(os.environ, HOME=home)
            done = subprocess.run([sys.executable, __file__, "--child", mode, "--repeats", str(args.repeats)],
                                  env=env, capture_output=True, text=True, check=True)
        runs[mode].append(json.loads(done.stdout.strip().splitlines()[-1]))
    results = []
    for mode in TARGETS:
        merged = {"target": runs[mode][0]["target"]}
        for name in runs[mode][0]:
            if name != "target":
                merged[name] = float(sorted(r[name] for r in runs[mode])[len(runs[mode]) // 2])
        results.append(merged)
    names = [k for k in results[0] if k != "target"]
    lines = ["## LLVM target: would hardware gathers help the missed imaging goals?", "",
             f"Command: `flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/llvm_target.py --rounds "
             f"{args.rounds} --repeats {args.repeats}` (each column a fresh process with an empty `~/.drjit`; "
             f"median over the rounds of each process's median, ms); {load_note(load_before, load())}.", "",
             "| operation | " + " | ".join(r["target"] for r in results) + " |", "|---|" + "---:|" * len(results)]
    for name in names:
        base = results[0][name]
        cells = [f"{results[0][name]:.2f}"] + [f"{r[name]:.2f} ({r[name] / base:.2f}x)" for r in results[1:]]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    text = "\n".join(lines)
    print(text)
    if args.write:
        from _results import write_block

        write_block("llvm_target", text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
