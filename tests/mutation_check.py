"""Plant known bugs one at a time and check that the tests notice.

Each mutant is a list of exact textual substitutions in the library sources (each ``old`` must
occur exactly once in the files it is looked for in, so a moved helper is reported as
"not applicable" rather than silently skipped). The file is patched in place, the mutant's
targeted test selection runs in a subprocess (with ``PYTHONPYCACHEPREFIX`` pointing to a fresh
folder, so no stale bytecode of either version is ever imported), and the original text is put
back in a ``finally`` block. A backup of every patched file lies in ``$TMPDIR/pointillist-mutation``
while it is patched; a later run restores any backup left by a killed run before it starts.

Usage (from the repository root)::

    .venv/bin/python tests/mutation_check.py            # all mutants, a markdown table at the end
    .venv/bin/python tests/mutation_check.py --list     # names only
    .venv/bin/python tests/mutation_check.py jjn_7_5 exr_rb   # some of them

Exit status 1 when a mutant survives (no test failed) or a baseline selection fails.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BACKUP = Path(tempfile.gettempdir()) / "pointillist-mutation" / ROOT.name
#: Where substitutions are looked for (library code only).
SOURCES = ("imaging", "plugins", "pointillist")

DITHER = ["tests/test_dither.py"]
IO = ["tests/test_io.py"]
VARIANCE = ["tests/test_adaptive.py", "-k", "variance"]
RANGE = ["tests/test_adaptive.py", "-k", "not variance and not compare and not cli"]
FLIP = ["tests/test_compare.py", "-k", "flip or image_errors"]
THRESHOLD = ["tests/test_dither.py", "tests/test_filters.py", "-k", "threshold or levels or level"]


@dataclass
class Mutant:
    name: str
    description: str
    substitutions: list[tuple[str, str]]
    tests: list[str]
    in_issue: bool = False
    files: list[Path] = field(default_factory=list)


def _swap(text: str, a: str, b: str) -> str:
    """``text`` with the whole numbers ``a`` and ``b`` exchanged (only as the third member of a
    ``(dy, dx, n)`` weight)."""
    return re.sub(r"(\(-?\d+, -?\d+, )(\d+)\)", lambda m: m.group(1) + {a: b, b: a}.get(m.group(2), m.group(2)) + ")",
                  text)


JJN = ("((0, 1, 7), (0, 2, 5), (1, -2, 3), (1, -1, 5), (1, 0, 7), (1, 1, 5), (1, 2, 3),\n"
       "                     (2, -2, 1), (2, -1, 3), (2, 0, 5), (2, 1, 3), (2, 2, 1)), 48")
STUCKI = ("((0, 1, 8), (0, 2, 4), (1, -2, 2), (1, -1, 4), (1, 0, 8), (1, 1, 4), (1, 2, 2),\n"
          "                     (2, -2, 1), (2, -1, 2), (2, 0, 4), (2, 1, 2), (2, 2, 1)), 42")
FS = '((0, 1, 7), (1, -1, 3), (1, 0, 5), (1, 1, 1)), 16'
BURKES = "((0, 1, 8), (0, 2, 4), (1, -2, 2), (1, -1, 4), (1, 0, 8), (1, 1, 4), (1, 2, 2)),\n                    32"
SIERRA = ("((0, 1, 5), (0, 2, 3), (1, -2, 2), (1, -1, 4), (1, 0, 5), (1, 1, 4), (1, 2, 2),\n"
          "                     (2, -1, 2), (2, 0, 3), (2, 1, 2)), 32")
SIERRA_LITE = "((0, 1, 2), (1, -1, 1), (1, 0, 1)), 4"
ATKINSON = "((0, 1, 1), (0, 2, 1), (1, -1, 1), (1, 0, 1), (1, 1, 1), (2, 0, 1)), 8"

EXR_WRITE = "channels: dict[str, np.ndarray] = {names: np.ascontiguousarray(pixels)}"
EXR_READ = 'image = take("R", "G", "B", "A") if "A" in channels else take("R", "G", "B")'


def _exr_write(order: str) -> tuple[str, str]:
    index = ["RGBA".index(c) for c in order]
    return EXR_WRITE, ("channels: dict[str, np.ndarray] = {names: np.ascontiguousarray("
                       f"pixels[..., {index}[:pixels.shape[2]]] if pixels.ndim == 3 else pixels)}}")


def _exr_read(order: str) -> tuple[str, str]:
    names = ", ".join(f'"{c}"' for c in order)
    return EXR_READ, f'image = take({names}) if "A" in channels else take({names[:-5]})'


QUANTILE = "self.quantile = NormalDist().inv_cdf(1.0 - self.p_value / 2.0)"
HALF_WIDTH = "half_width = dr.opaque(mi.Float, self.quantile) * dr.sqrt(var / nv)"
VAR = "var = dr.maximum(s2 - s1 * s1 / nv, 0.0) / dr.maximum(valid_n - 1.0, 1.0)"
MORE = "more = ~converged & (count + spp <= limit)"
CONVERGED = "(half_width <= dr.opaque(mi.Float, self.max_error) * dr.abs(mean))"
FLIP_REFERENCE = "reference, test = clean(r), clean(x)"
FLIP_CALL = 'result = _flip_drjit(test, reference, dynamic_range="hdr",'
QUANTISER = "thresholds = work[:-1] + (work[1:] - work[:-1]) * (level / 255.0)"
THRESHOLD_RULE = "values = dr.select(tensor.array >= dr.opaque(Float, float(level))"
RANGE_SPLIT = "flags = dr.select(spread([shown(values) for values in quad]) > threshold, mi.UInt32(1), 0)"

MUTANTS = [
    # -- error-diffusion tables (the issue's two, then the others)
    Mutant("jjn_7_5", "Jarvis-Judice-Ninke: every 7 and 5 swapped", [(JJN, _swap(JJN, "7", "5"))], DITHER, True),
    Mutant("stucki_8_4", "Stucki: every 8 and 4 swapped", [(STUCKI, _swap(STUCKI, "8", "4"))], DITHER, True),
    Mutant("jjn_7_5_first_row", "Jarvis-Judice-Ninke: the 7 and 5 right of the pixel swapped (sum kept)",
           [(JJN, JJN.replace("(0, 1, 7), (0, 2, 5)", "(0, 1, 5), (0, 2, 7)"))], DITHER, True),
    Mutant("stucki_8_4_first_row", "Stucki: the 8 and 4 right of the pixel swapped (sum kept)",
           [(STUCKI, STUCKI.replace("(0, 1, 8), (0, 2, 4)", "(0, 1, 4), (0, 2, 8)"))], DITHER, True),
    Mutant("stucki_8_4_below", "Stucki: the 8 below and a 4 below-right swapped (sum kept)",
           [(STUCKI, STUCKI.replace("(1, 0, 8), (1, 1, 4)", "(1, 0, 4), (1, 1, 8)"))], DITHER),
    Mutant("fs_7_5", "Floyd-Steinberg 7 and 5 swapped", [(FS, _swap(FS, "7", "5"))], DITHER),
    Mutant("fs_3_1", "Floyd-Steinberg 3 and 1 swapped", [(FS, _swap(FS, "3", "1"))], DITHER),
    Mutant("jjn_divisor", "Jarvis-Judice-Ninke divisor 48 -> 42", [(JJN, JJN[:-2] + "42")], DITHER),
    Mutant("burkes_8_4", "Burkes weights 8 and 4 swapped", [(BURKES, _swap(BURKES, "8", "4"))], DITHER),
    Mutant("sierra_5_3", "Sierra weights 5 and 3 swapped", [(SIERRA, _swap(SIERRA, "5", "3"))], DITHER),
    Mutant("sierra_lite_2_1", "Sierra lite: 2 below-left, 1 right",
           [(SIERRA_LITE, "((0, 1, 1), (1, -1, 2), (1, 0, 1)), 4")], DITHER),
    Mutant("atkinson_shape", "Atkinson: the pixel two rows down moved one column right",
           [(ATKINSON, ATKINSON.replace("(2, 0, 1)", "(2, 1, 1)"))], DITHER),
    Mutant("atkinson_full", "Atkinson divisor 8 -> 6 (diffuses the whole error)",
           [(ATKINSON, ATKINSON[:-1] + "6")], DITHER),
    # -- multi-level quantisation and the threshold rule
    Mutant("levels_midpoint", "multi-level thresholds at the middle of each gap (not level/255)",
           [(QUANTISER, "thresholds = work[:-1] + (work[1:] - work[:-1]) * 0.5")], THRESHOLD),
    Mutant("threshold_gt", "threshold: > instead of >=",
           [(THRESHOLD_RULE, THRESHOLD_RULE.replace(">=", ">"))], THRESHOLD),
    # -- EXR channel order
    Mutant("exr_rb", "R and B swapped in both write_exr and read_exr",
           [_exr_write("BGRA"), _exr_read("BGRA")], IO, True),
    Mutant("exr_gb", "G and B swapped in both write_exr and read_exr",
           [_exr_write("RBGA"), _exr_read("RBGA")], IO),
    Mutant("exr_rg", "R and G swapped in both write_exr and read_exr",
           [_exr_write("GRBA"), _exr_read("GRBA")], IO),
    Mutant("exr_ra", "R and A swapped in both write_exr and read_exr (RGBA only)",
           [(EXR_WRITE, ("channels: dict[str, np.ndarray] = {names: np.ascontiguousarray(pixels[..., [3, 1, 2, 0]] "
                         "if pixels.ndim == 3 and pixels.shape[2] == 4 else pixels)}")),
            (EXR_READ, 'image = take("A", "G", "B", "R") if "A" in channels else take("R", "G", "B")')], IO),
    Mutant("exr_rb_write", "R and B swapped in write_exr only", [_exr_write("BGRA")], IO),
    Mutant("exr_rb_read", "R and B swapped in read_exr only", [_exr_read("BGRA")], IO),
    # -- the variance stopping rule
    Mutant("quantile_p20", "variance rule: quantile of 1 - p/20 instead of 1 - p/2",
           [(QUANTILE, QUANTILE.replace("/ 2.0", "/ 20.0"))], VARIANCE, True),
    Mutant("quantile_one_sided", "variance rule: one-sided quantile 1 - p",
           [(QUANTILE, QUANTILE.replace(" / 2.0", ""))], VARIANCE),
    Mutant("stderr_sqrt_var_over_n", "variance rule: sqrt(var)/n instead of sqrt(var/n)",
           [(HALF_WIDTH, HALF_WIDTH.replace("dr.sqrt(var / nv)", "dr.sqrt(var) / nv"))], VARIANCE, True),
    Mutant("variance_divides_by_n", "variance rule: sample variance divided by n, not n - 1",
           [(VAR, VAR.replace("valid_n - 1.0", "valid_n"))], VARIANCE),
    Mutant("cap_off_by_one_round", "variance rule: the cap allows one more round",
           [(MORE, "more = ~converged & (count <= limit)")], VARIANCE),
    Mutant("max_error_squared", "variance rule: max_error squared",
           [(CONVERGED, CONVERGED.replace("self.max_error)", "self.max_error ** 2)"))], VARIANCE),
    # -- the range criterion
    Mutant("range_split_ge", "range rule: split when the spread >= threshold (not >)",
           [(RANGE_SPLIT, RANGE_SPLIT.replace("> threshold", ">= threshold"))], RANGE),
    # -- FLIP
    Mutant("flip_swapped", "FLIP: reference and test arguments swapped",
           [(FLIP_REFERENCE, "reference, test = clean(x), clean(r)")], FLIP, True),
    Mutant("flip_swapped_call",
           "FLIP: reference and test swapped in the call only (exposures still from the reference)",
           [(FLIP_CALL, FLIP_CALL.replace("(test, reference", "(reference, test"))], FLIP),
    Mutant("flip_ldr", "FLIP: LDR instead of HDR", [(FLIP_CALL, FLIP_CALL.replace('"hdr"', '"ldr"'))], FLIP, True),
]


def _locate(old: str) -> Path:
    hits = [path for folder in SOURCES for path in sorted((ROOT / folder).rglob("*.py"))
            if old in path.read_text()]
    if len(hits) != 1 or hits[0].read_text().count(old) != 1:
        raise LookupError(f"expected exactly one occurrence, found it in {[str(h) for h in hits]}")
    return hits[0]


def _restore_leftovers() -> None:
    if not BACKUP.is_dir():
        return
    for saved in BACKUP.rglob("*.orig"):
        target = ROOT / saved.relative_to(BACKUP).with_suffix("")
        print(f"restoring {target} from a killed run's backup", file=sys.stderr)
        target.write_text(saved.read_text())
        saved.unlink()


def _run_pytest(selection: list[str], timeout: float) -> tuple[str, list[str], float]:
    """('pass' | 'fail' | 'timeout' | 'error', failed test ids, seconds)."""
    with tempfile.TemporaryDirectory(prefix="mutation-pyc-") as pyc:
        env = dict(os.environ, PYTHONPYCACHEPREFIX=pyc, PYTHONDONTWRITEBYTECODE="1")
        command = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-rfE",
                   "--timeout", str(int(timeout)), *selection]
        start = time.perf_counter()
        try:
            result = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True,
                                    timeout=timeout + 60, check=False)
        except subprocess.TimeoutExpired:
            return "timeout", [], time.perf_counter() - start
    seconds = time.perf_counter() - start
    failed = [line.split()[1] for line in result.stdout.splitlines() if line.startswith(("FAILED ", "ERROR "))]
    if result.returncode == 0:
        return "pass", [], seconds
    if result.returncode == 1 and failed:
        return "fail", failed, seconds
    return "error", failed or [result.stdout.strip().splitlines()[-1] if result.stdout.strip() else "?"], seconds


def run_mutant(mutant: Mutant, timeout: float) -> tuple[str, list[str], float]:
    try:
        paths = [_locate(old) for old, _ in mutant.substitutions]
    except LookupError as error:
        return "n/a", [str(error)], 0.0
    originals = {path: path.read_text() for path in set(paths)}
    try:
        for path, text in originals.items():
            backup = BACKUP / (str(path.relative_to(ROOT)) + ".orig")
            backup.parent.mkdir(parents=True, exist_ok=True)
            backup.write_text(text)
        for (old, new), path in zip(mutant.substitutions, paths):
            path.write_text(path.read_text().replace(old, new, 1))
        status, failed, seconds = _run_pytest(mutant.tests, timeout)
    finally:
        for path, text in originals.items():
            path.write_text(text)
            (BACKUP / (str(path.relative_to(ROOT)) + ".orig")).unlink(missing_ok=True)
    return {"pass": "SURVIVED", "fail": "caught"}.get(status, status), failed, seconds


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("names", nargs="*", help="mutants to run (default: all)")
    parser.add_argument("--list", action="store_true", help="list the mutants and exit")
    parser.add_argument("--timeout", type=float, default=300, help="seconds per pytest run (default 300)")
    parser.add_argument("--no-baseline", action="store_true", help="skip the unmutated runs of the selections")
    args = parser.parse_args(argv)
    if args.list:
        for m in MUTANTS:
            print(f"{m.name:24s} {'(issue) ' if m.in_issue else ''}{m.description}")
        return 0
    unknown = set(args.names) - {m.name for m in MUTANTS}
    if unknown:
        parser.error(f"unknown mutants: {', '.join(sorted(unknown))}")
    chosen = [m for m in MUTANTS if not args.names or m.name in args.names]
    signal.signal(signal.SIGTERM, lambda *_: (_ for _ in ()).throw(KeyboardInterrupt()))
    _restore_leftovers()
    bad = 0
    if not args.no_baseline:
        for selection in {tuple(m.tests) for m in chosen}:
            status, failed, seconds = _run_pytest(list(selection), args.timeout)
            print(f"baseline {' '.join(selection)}: {status} ({seconds:.0f} s) {' '.join(failed)}", flush=True)
            bad += status != "pass"
    rows = []
    for mutant in chosen:
        status, failed, seconds = run_mutant(mutant, args.timeout)
        print(f"{mutant.name}: {status} ({seconds:.0f} s) {' '.join(failed)}", flush=True)
        rows.append((mutant, status, failed))
        bad += status != "caught"
    print("\n| mutant | in issue | result | tests that noticed |")
    print("|---|---|---|---|")
    for mutant, status, failed in rows:
        shown = ", ".join(f"`{f.removeprefix('tests/')}`" for f in failed[:4])
        more = f" and {len(failed) - 4} more" if len(failed) > 4 else ""
        print(f"| {mutant.name}: {mutant.description} | {'yes' if mutant.in_issue else ''} | {status} "
              f"| {shown or '-'}{more} |")
    survivors = [m.name for m, status, _ in rows if status != "caught"]
    print(f"\n{len(rows) - len(survivors)} of {len(rows)} caught; not caught: {', '.join(survivors) or 'none'}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
