"""Start-up: `pointillist render` of a plain Mitsuba scene against a five-line Mitsuba script, whole processes.

A user rendering previews, or a script calling the command once per frame, pays the start-up each
time. Both sides render the same scene (Mitsuba's tutorial layout: ``direct``, a PLY mesh, two point
lights, ``independent`` sampler, box filter; 256x256 at 16 spp) and write an EXR:

- **Mitsuba**: ``import mitsuba as mi; mi.set_variant("llvm_ad_rgb"); scene = mi.load_file(...);
  image = mi.render(scene); mi.Bitmap(image).write(...)``;
- **pointillist**: ``pointillist render SCENE -D spp=16 -o OUT.exr``;

and, alone, ``pointillist --help`` and ``pointillist render -h``. Each case is a fresh process,
timed from outside, in interleaved rounds (after one warm-up run of each: the kernel cache
``~/.drjit`` is warm for both). Goals: render at most 1.1x the script; each help under 0.3 s.

Python's bytecode caches are on, as on users' machines: the warm-up run writes ``__pycache__``
(``PYTHONDONTWRITEBYTECODE`` and ``PYTHONPYCACHEPREFIX`` are removed from the processes'
environment). Where they cannot be written, every start compiles pointillist's modules (Mitsuba's
were compiled when pip installed it): about 40 ms more on a 2-core AMD EPYC.

Run::

    flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/startup.py [--rounds 9]
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(Path(__file__).resolve().parent))

SCENE = """<scene version="3.0.0">
    <default name="spp" value="256"/>
    <default name="res" value="256"/>
    <integrator type="direct"/>
    <sensor type="perspective">
        <transform name="to_world"><lookat target="0, 0, 0.2" origin="0, -4, 2" up="0, 0, 1"/></transform>
        <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
        <film type="hdrfilm"><rfilter type="box"/>
            <integer name="width" value="$res"/><integer name="height" value="$res"/></film>
    </sensor>
    <shape type="ply"><string name="filename" value="{mesh}"/>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.9 0.9 0.0"/></bsdf></shape>
    <emitter type="point"><point name="position" x="3" y="-10" z="6"/><rgb name="intensity" value="100"/></emitter>
    <emitter type="point"><point name="position" x="-3" y="-10" z="-2"/><rgb name="intensity" value="100"/></emitter>
</scene>
"""

MITSUBA_SCRIPT = ("import mitsuba as mi; mi.set_variant('llvm_ad_rgb'); "
                  "scene = mi.load_file({scene!r}, spp=16); image = mi.render(scene); "
                  "mi.Bitmap(image).write({out!r})")


def cpu_facts() -> str:
    """The CPU's model name and its widest vector instruction set (from /proc/cpuinfo)."""
    model, flags = platform.processor() or platform.machine(), set()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name":
                model = value.strip()
            elif key.strip() == "flags":
                flags = set(value.split())
    except OSError:
        pass
    widest = "AVX-512" if "avx512f" in flags else "AVX2" if "avx2" in flags else "SSE/other"
    return f"{model} ({widest})"


def _process(argv: list[str], env: dict[str, str]):
    def run() -> None:
        subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT, env=env)
    return run


def main(argv: list[str] | None = None) -> int:
    from _results import write_block
    from _timing import interleaved, load, load_note, ratio

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=9)
    parser.add_argument("--no-write", action="store_true", help="print the table only")
    args = parser.parse_args(argv)
    python = sys.executable
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        scene = folder / "plain.xml"
        scene.write_text(SCENE.format(mesh=ROOT / "scenes" / "corpus" / "assets" / "meshes" / "pyramid.ply"))
        cached = {k: v for k, v in os.environ.items() if k not in ("PYTHONDONTWRITEBYTECODE", "PYTHONPYCACHEPREFIX")}
        mitsuba = [python, "-c", MITSUBA_SCRIPT.format(scene=str(scene), out=str(folder / "m.exr"))]
        ours = [python, "-m", "pointillist", "render", str(scene), "-D", "spp=16", "-o", str(folder / "p.exr")]
        cases = {
            "mitsuba": _process(mitsuba, cached),
            "pointillist": _process(ours, cached),
            "help": _process([python, "-m", "pointillist", "--help"], cached),
            "render-help": _process([python, "-m", "pointillist", "render", "-h"], cached),
        }
        before = load()
        times = interleaved(cases, args.rounds)
        after = load()
    import drjit as dr
    import mitsuba as mi

    median_ratio, minima_ratio = ratio(times["pointillist"], times["mitsuba"])
    rows = [("`pointillist render` / five-line Mitsuba script", f"{times['pointillist'].median:.3f} / "
             f"{times['mitsuba'].median:.3f}", f"{median_ratio:.2f}x (minima {minima_ratio:.2f}x)", "<= 1.1x",
             median_ratio <= 1.1),

            ("`pointillist --help`", f"{times['help'].median:.3f}", "-", "< 0.3 s", times["help"].median < 0.3),
            ("`pointillist render -h`", f"{times['render-help'].median:.3f}", "-", "< 0.3 s",
             times["render-help"].median < 0.3)]
    lines = ["## Start-up: whole processes (`benchmarks/startup.py`)", "",
             f"CPU: {cpu_facts()}, {os.cpu_count()} cores; Python {platform.python_version()}, Mitsuba "
             f"{mi.__version__}, Dr.Jit {dr.__version__}; {load_note(before, after)}. Reproduce: "
             f"`flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/startup.py --rounds {args.rounds}`. "
             "A plain Mitsuba scene (`direct`, a PLY mesh, two point lights) at 256x256, 16 spp, written as EXR; "
             f"medians of {args.rounds} interleaved rounds of fresh processes (warm kernel cache; Python's bytecode "
             "caches on, as on users' machines), seconds.", "",
             "| case | seconds | ratio | goal | met |", "|---|---|---|---|---|"]
    lines += [f"| {name} | {secs} | {r} | {goal} | {'-' if met is None else 'yes' if met else '**no**'} |"
              for name, secs, r, goal, met in rows]
    text = "\n".join(lines)
    print(text)
    if not args.no_write:
        write_block("startup", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
