"""Benchmark: the progressive error estimate on hard scenes, candidates side by side.

Measures, in one run, against long references whose own noise is measured from two halves and
subtracted (``benchmarks/_references.py``, cached in ``benchmarks/.cache/``):

1. **Candidates along a render.** Each scene is rendered in a fixed schedule of passes (8 of 1 spp,
   then 4 each of 2, 4, ..., 128 spp: 1024 spp in 36 passes) with two seeds; after 8, 16, 32, ...,
   1024 spp every candidate estimates the relMSE from the same passes, and the table gives
   true relMSE / estimate (goal 0.5-2; above 1: the estimate is too low). Candidates (``v``: a
   variance of the pixel mean; ``m``: the mean; ``eps`` = 0.01):

   - ``previous``: the estimate before its rework for hard scenes, Welford's
     ``v / (max(m^2 - v, m^2 / 4) + eps)``;
   - ``dual buffer``: ``v`` from two half buffers, ``(m_A - m_B)^2 W_A W_B / W^2`` (Rousselle, Knaus
     and Zwicker 2012; Cycles' adaptive sampling compares the image with a half buffer, the same
     information), with the previous denominator;
   - ``independent half``: ``v / (max(m_A m_B, 0) + eps)``, the product of two independent halves
     being unbiased for ``r^2``;
   - ``cross halves``: each half's variance over the other half's mean (a firefly and the
     denominator never in the same half);
   - ``median of passes``: ``v / (median of the pass images^2 + eps)``, a robust per-pixel reference
     (needs every pass kept);
   - ``Welford, median 3x3`` / ``loo 3x3`` / ``loo 5x5``: where the pixel is unreliable (``v > m^2 /
     4``), ``min(m^2 - v, n^2)``, ``n`` the median of its 3x3 neighbourhood or the mean of its 8 / 24
     neighbours (leave one out); ``, MoM``: the median of the means of the per-pixel terms over 16
     hashed groups of pixels (robust to a few extreme pixels);
   - ``dual buffer, loo 3x3`` / ``quarters, loo 3x3``: the same with ``v`` from two halves or from
     four quarters (``sum_q W_q (m_q - m)^2 / (3 W)``); ``, floor``: the denominator at least
     ``(m / 64)^2``; ``, 1/9``: reliable where ``v <= m^2 / 9``;
   - ``pointillist``: :meth:`pointillist.progressive.Accumulator.estimate` (Dr.Jit) on the same passes
     (= ``quarters, loo 3x3, floor``).

   The last column of the halves row is the ratio of the two halves' errors per spp
   (``halves_ratio``; the estimate is trusted at 3 or less).
2. **Stops.** ``render_progressive`` with ``Budget(target_error=E, seconds=120)`` at three targets
   per scene (``c / 128``, ``c / 512`` and ``c / 2048``, ``c`` = relMSE x spp measured at 1024 spp,
   one significant digit; the 120 s bound the runs whose rare paths, found later, put the target out
   of reach) and ``Budget(seconds=T)`` at two budgets, two seeds each: where it stopped, the
   estimate, its state, the true relMSE and their ratio (goal 0.5-2).
3. **Cost of estimating** per pass at 64x64, 256x256 and 512x512 (synthetic passes; ``estimate``
   alone, evaluated), against the ~2 s of an automatic pass.

Run it under the shared benchmark lock (the first run renders the references: about 10 minutes
each for the hard scenes on 2 loaded cores)::

    flock /tmp/pointillist-bench.lock .venv/bin/python benchmarks/estimator.py --write

``--write`` puts the tables into the ``estimator`` block of benchmarks/RESULTS.md.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))
SCENES = ROOT / "scenes"

#: (label, scene file, -D values, reference spp per half)
HARD = [
    ("glass caustic", "glass_caustic.xml", {}, 32768),
    ("tiny light", "tiny_light.xml", {}, 32768),
    ("Phong 200-1000", "phong_glossy.xml", {}, 32768),
    ("sun + envmap", "sun_sky.xml", {}, 32768),
]
#: The scenes the previous estimate was tuned on, at 64x64.
TUNED = [
    ("edges, direct", "edges.xml", {"res": "64"}, 16384),
    ("Cornell, whitted", "cornell_phong.xml", {"res": "64"}, 16384),
    ("default, path", "default.xml", {"res": "64", "integrator": "path"}, 16384),
]
SCHEDULE = [1] * 8 + [n for n in (2, 4, 8, 16, 32, 64, 128) for _ in range(4)]
POINTS = (8, 16, 32, 64, 128, 256, 512, 1024)
TIME_BUDGETS = (3.0, 12.0)
#: Error budgets run with this time budget too: a target that the rare paths of a scene put out of
#: reach (they show up as the render goes on) then ends as a time budget, and is reported as one.
TARGET_CAP = 120.0
SEEDS = (1, 2)
EPS = 0.01


# ------------------------------------------------------------------------------ candidates (numpy)
def _welford(passes, weights):
    x, w = np.stack(passes), np.asarray(weights, np.float64)
    total = w.sum()
    mean = np.tensordot(w, x, 1) / total
    return mean, np.tensordot(w, (x - mean) ** 2, 1) / ((len(passes) - 1) * total), total


def _halves(weights):
    """Pass k's half: the one with fewer samples so far (ties: the first), as the accumulator does."""
    a = b = 0
    out = []
    for n in weights:
        out.append(0 if a <= b else 1)
        a, b = (a + n, b) if out[-1] == 0 else (a, b + n)
    return np.array(out)


def _quarters(weights):
    """Pass k's quarter: the lighter half (ties: the first), then the lighter quarter of that half."""
    w = [0, 0, 0, 0]
    out = []
    for n in weights:
        h = 0 if w[0] + w[1] <= w[2] + w[3] else 2
        q = h if w[h] <= w[h + 1] else h + 1
        out.append(q)
        w[q] += n
    return np.array(out)


def _bucket_means(passes, weights, buckets):
    x, w = np.stack(passes).astype(np.float64), np.asarray(weights, np.float64)
    return [(np.tensordot(w[buckets == q], x[buckets == q], 1) / w[buckets == q].sum(), w[buckets == q].sum())
            for q in range(int(buckets.max()) + 1)]


def _loo(image, r):
    from scipy.ndimage import uniform_filter

    n = (2 * r + 1) ** 2
    return (uniform_filter(image, size=(2 * r + 1, 2 * r + 1, 1), mode="nearest") * n - image) / (n - 1)


def _median3(image):
    from scipy.ndimage import median_filter

    return median_filter(image, size=(3, 3, 1), mode="nearest")


def _fallback(m, v, n, floor=0.0, c=0.25):
    square = m * m
    own = np.maximum(square - v, 0.0)
    d = np.where(v <= c * square, own, np.minimum(own, n * n))
    return v / (np.maximum(d, floor * square) + EPS)


def _median_of_means(terms, groups=16):
    flat = terms.reshape(terms.shape[0] * terms.shape[1], -1)
    key = (np.arange(flat.shape[0], dtype=np.uint64) * np.uint64(2654435761)) % np.uint64(2**32) % np.uint64(groups)
    return float(np.median([flat[key == g].mean() for g in range(groups)]))


def _quarter_variance(passes, weights):
    quarters = _bucket_means(passes, weights, _quarters(weights))
    total = sum(w for _, w in quarters)
    mean = sum(w * m for m, w in quarters) / total
    return sum(w * (m - mean) ** 2 for m, w in quarters) / (3 * total)


def candidates(passes, weights) -> dict[str, float]:
    """Every candidate's estimated relMSE of the mean of ``passes`` (colour channels)."""
    passes = [p[..., :3] for p in passes]
    m, v, total = _welford(passes, weights)
    half = _halves(weights)
    (m_a, v_a, w_a), (m_b, v_b, w_b) = [_welford([p for p, h in zip(passes, half) if h == k],
                                                 [n for n, h in zip(weights, half) if h == k]) for k in (0, 1)]
    square = m * m
    dual = (m_a - m_b) ** 2 * w_a * w_b / total ** 2
    cross_a = v_a / (np.maximum(m_b * m_b - v_b, m_b * m_b / 4) + EPS)
    cross_b = v_b / (np.maximum(m_a * m_a - v_a, m_a * m_a / 4) + EPS)
    loo3, vq = _loo(m, 1), _quarter_variance(passes, weights)
    return {
        "previous": float((v / (np.maximum(square - v, square / 4) + EPS)).mean()),
        "dual buffer": float((dual / (np.maximum(square - dual, square / 4) + EPS)).mean()),
        "independent half": float((v / (np.maximum(m_a * m_b, 0.0) + EPS)).mean()),
        "cross halves": float(((w_a ** 2 * cross_a + w_b ** 2 * cross_b) / total ** 2).mean()),
        "median of passes": float((v / (np.median(np.stack(passes), 0) ** 2 + EPS)).mean()),
        "Welford, median 3x3": float(_fallback(m, v, _median3(m)).mean()),
        "Welford, loo 3x3": float(_fallback(m, v, loo3).mean()),
        "Welford, loo 5x5": float(_fallback(m, v, _loo(m, 2)).mean()),
        "Welford, loo 3x3, MoM": _median_of_means(_fallback(m, v, loo3)),
        "dual buffer, loo 3x3": float(_fallback(m, dual, loo3).mean()),
        "quarters, loo 3x3": float(_fallback(m, vq, loo3).mean()),
        "quarters, loo 3x3, floor": float(_fallback(m, vq, loo3, floor=1 / 4096).mean()),
        "quarters, loo 3x3, floor, 1/9": float(_fallback(m, vq, loo3, floor=1 / 4096, c=1 / 9).mean()),
    }


def production(passes, weights):
    """pointillist's own estimate (Dr.Jit) of the same passes: an ErrorEstimate."""
    import mitsuba as mi

    from pointillist.progressive import Accumulator

    acc = Accumulator.empty()
    for p, n in zip(passes, weights):
        acc = acc.add(mi.TensorXf(np.ascontiguousarray(p, np.float32)), int(n))
    return acc.estimate(3)


# ------------------------------------------------------------------------------ runs
def _passes(name, params, seed):
    """The schedule's pass images of ``seed`` (cached beside the references)."""
    from _references import CACHE, _key

    from pointillist.progressive import pass_seed
    from pointillist.scene import load_scene, timed_render

    path = CACHE / f"passes-{_key(SCENES / name, params, sum(SCHEDULE))}-{seed}.npz"
    if path.exists():
        with np.load(path) as data:
            return list(data["p"])
    scene = load_scene(SCENES / name, params)
    images = [np.asarray(timed_render(scene, spp=n, seed=pass_seed(seed, k))[0], np.float32)
              for k, n in enumerate(SCHEDULE)]
    CACHE.mkdir(exist_ok=True)
    np.savez(path.with_suffix(".tmp.npz"), p=np.stack(images))
    path.with_suffix(".tmp.npz").replace(path)
    return images


def along(cases, seeds):
    from _references import reference, true_relmse

    rows = []
    for label, name, params, ref_spp in cases:
        ref = reference(SCENES / name, params, ref_spp)
        for seed in seeds:
            images = _passes(name, params, seed)
            for k in range(MIN_K, len(SCHEDULE) + 1):
                spp = sum(SCHEDULE[:k])
                if spp not in POINTS:
                    continue
                weights = SCHEDULE[:k]
                mean = np.tensordot(np.asarray(weights, np.float64), np.stack(images[:k]).astype(np.float64), 1) / spp
                true = true_relmse(mean, ref)
                est = candidates(images[:k], weights)
                prod = production(images[:k], weights)
                est["pointillist"] = prod.relmse
                rows.append(dict(label=label, seed=seed, spp=spp, passes=k, true=true, est=est,
                                 halves_ratio=prod.halves_ratio, trusted=prod.trusted))
                print(label, seed, spp, f"true {true:.4g}", {k2: round(true / v, 2) for k2, v in est.items()},
                      f"q {prod.halves_ratio:.3g}", file=sys.stderr)
    return rows


MIN_K = 8


def targets_for(rows, label):
    """Three error targets for ``label``: c / 128, c / 512, c / 2048 (c = relMSE x spp at 1024 spp)."""
    c = statistics.median(r["true"] * r["spp"] for r in rows if r["label"] == label and r["spp"] == 1024)
    return [float(f"{c / n:.1g}") for n in (128, 512, 2048)]


def stops(cases, seeds, along_rows):
    from _references import reference, true_relmse

    from pointillist.progressive import Budget, render_progressive
    from pointillist.scene import load_scene

    rows = []
    for label, name, params, ref_spp in cases:
        ref = reference(SCENES / name, params, ref_spp)
        scene = load_scene(SCENES / name, params)
        budgets = [Budget(target_error=e, seconds=TARGET_CAP) for e in targets_for(along_rows, label)] + \
                  [Budget(seconds=t) for t in TIME_BUDGETS]
        for budget in budgets:
            for seed in seeds:
                load = os.getloadavg()[0]
                result = render_progressive(scene, SCENES / name, budget, params=params, seed=seed, progress=False)
                s = result.stats
                true = true_relmse(result.image, ref)
                rows.append(dict(label=label, budget=(f"--target-error {budget.target_error:g} --time {TARGET_CAP:g}"
                                                      if budget.target_error else f"--time {budget.seconds:g}"),
                                 seed=seed,
                                 stop=result.stop, spp=s.spp, passes=s.passes, seconds=s.seconds,
                                 est=s.estimated_relmse, state=s.estimate_state, q=s.halves_ratio, true=true,
                                 load=load))
                print(rows[-1], file=sys.stderr)
        del scene
    return rows


def cost(repeats):
    """Seconds per estimate (median of ``repeats``) at three sizes, against one accumulation."""
    import drjit as dr
    import mitsuba as mi

    from _timing import seconds, timed

    from pointillist.progressive import MIN_PASSES, Accumulator

    rows = []
    rng = np.random.default_rng(27)
    for size in (64, 256, 512):
        acc = Accumulator.empty()
        for _ in range(MIN_PASSES):
            acc = acc.add(mi.TensorXf(rng.gamma(0.5, 1.0, (size, size, 3)).astype(np.float32)), 4)
        acc.estimate(3)      # compile
        image = mi.TensorXf(rng.gamma(0.5, 1.0, (size, size, 3)).astype(np.float32))
        dr.eval(image)
        est, add = [], []
        for _ in range(repeats):   # each timed with its arrays evaluated (benchmarks/_timing.py)
            nxt, seconds_add, _ = timed(acc.add, image, 4)
            add.append(seconds_add)
            est.append(seconds(nxt.estimate, 3))
        rows.append(dict(size=size, estimate=statistics.median(est), add=statistics.median(add)))
        print(rows[-1], file=sys.stderr)
    return rows


# ------------------------------------------------------------------------------ report
def _ratio(true, est):
    if not (math.isfinite(est) and est > 0):
        return "-"
    r = true / est
    return f"{r:.2f}" if 0.01 <= r < 100 else f"{r:.0e}"


READING = [
    "Reading it. Welford's variance over passes (`previous`, `Welford, ...`) counts a firefly found in a pass "
    "of n spp W / ((K - 1) n) times the error it adds: with the 1-spp passes an error budget starts with, "
    "the sun scene's `Welford, loo 3x3` stays 30-170x high; the quarters (`quarters, ...`, `pointillist`) "
    "count it by its error. The reference of a firefly's pixel from its own mean (`previous`, `dual buffer`) "
    "makes the estimate 40-200x low on the glass caustic at 8-32 spp; from its neighbours (`loo`, "
    "`median`) it follows the truth, and the floor (m / 64)^2 bounds what one hit of a glint (the tiny "
    "light's reflection in the mirror sphere, seed 2 from 256 spp) can claim. The other references: "
    "`independent half` (the product of two halves) stays 2-12x low on the glass caustic up to 512 spp, "
    "`cross halves` and `median of passes` (every pass kept) are 3-100x high on the sun scene (a half, or "
    "the median of skewed passes, lies far below the mean); the median of means over pixel groups (`MoM`) "
    "drops the few pixels that hold a caustic's error at low spp (100-200x low). `dual buffer, loo 3x3` "
    "(one degree of freedom per pixel) is close to the quarters (three). The rows `halves` say where the "
    "estimate is trusted "
    "(3 or less, and at most half of it from floored pixels). Stops outside 0.5-2 are the tiny "
    "light's `--time` runs, whose estimates were untrusted: single samples of its radiance of 4e5 "
    "carried most of the true error there.", ""]


def report(along_rows, stop_rows, cost_rows, args, load_before, load_after, mi, dr) -> str:
    names = list(along_rows[0]["est"]) if along_rows else []
    lines = ["## The progressive error estimate on hard scenes", "",
             f"Machine: {os.cpu_count()} cores ({platform.machine()}), Python {platform.python_version()}, "
             f"Mitsuba {mi.__version__}, Dr.Jit {dr.__version__}. Load average (1 min) {load_before:.1f} before, "
             f"{load_after:.1f} after (other processes running: the seconds and the spp a time budget reaches "
             "depend on it, the ratios do not). Command: `flock /tmp/pointillist-bench.lock .venv/bin/python "
             "benchmarks/estimator.py --write`. References: two independent halves of 2x32768 spp (hard scenes) or "
             "2x16384 spp, their variance `(A - B)^2 / 4` subtracted from the squared error: true relMSE = "
             "`mean(((x - R)^2 - (A - B)^2 / 4) / (R^2 + 0.01))`.", ""]
    if along_rows:
        lines += ["### Candidates along a render: true relMSE / estimate (goal 0.5-2), seeds 1 / 2", "",
                  "Passes: 8 of 1 spp, then 4 each of 2, 4, ..., 128 spp. A cell is `seed 1 / seed 2`; "
                  "above 1 the estimate is too low. `halves` is the ratio of the two halves' errors per spp "
                  "(trusted at 3 or less).", ""]
        header = "| scene | candidate | " + " | ".join(f"{p} spp" for p in POINTS) + " |"
        lines += [header, "|---|---|" + "---:|" * len(POINTS)]
        labels = list(dict.fromkeys(r["label"] for r in along_rows))
        for label in labels:
            rows = [r for r in along_rows if r["label"] == label]
            cell = {(r["seed"], r["spp"]): r for r in rows}
            truth = " / ".join(f"{cell[(s, POINTS[-1])]['true']:.3g}" for s in SEEDS if (s, POINTS[-1]) in cell)
            for name in names:
                values = []
                for p in POINTS:
                    values.append(" / ".join(_ratio(cell[(s, p)]["true"], cell[(s, p)]["est"][name])
                                             for s in SEEDS if (s, p) in cell))
                lines.append(f"| {label} | {name} | " + " | ".join(values) + " |")
            values = [" / ".join(f"{cell[(s, p)]['halves_ratio']:.3g}" for s in SEEDS if (s, p) in cell)
                      for p in POINTS]
            lines.append(f"| {label} | halves (true at 1024: {truth}) | " + " | ".join(values) + " |")
        lines.append("")
    if stop_rows:
        lines += ["### Stops: true relMSE / estimate where the render stopped (goal 0.5-2)", "",
                  "Targets per scene: `c / 128`, `c / 512`, `c / 2048` with `c` = relMSE x spp at 1024 spp "
                  "(above). Each row: seed 1, then seed 2.", "",
                  "| scene | budget | stopped by | spp (passes, s) | estimate (state, halves) | true | true / estimate "
                  "| load |", "|---|---|---|---|---|---|---:|---:|"]
        for r in stop_rows:
            lines.append(f"| {r['label']} | `{r['budget']}` (seed {r['seed']}) | {r['stop']} | {r['spp']} "
                         f"({r['passes']}, {r['seconds']:.1f}) | {r['est']:.4g} ({r['state']}, {r['q']:.2f}) | "
                         f"{r['true']:.4g} | {_ratio(r['true'], r['est'])} | {r['load']:.1f} |")
        def inside(rows):
            return sum(r["est"] > 0 and 0.5 <= r["true"] / r["est"] <= 2 for r in rows)

        trusted = [r for r in stop_rows if r["state"] == "trusted"]
        ratios = [r["true"] / r["est"] for r in stop_rows if r["est"] > 0]
        lines += ["", f"{inside(stop_rows)} of {len(stop_rows)} stops within 0.5-2 (ratios {min(ratios):.2f} to "
                  f"{max(ratios):.2f}); {inside(trusted)} of the {len(trusted)} with a trusted estimate; "
                  f"{sum(r['state'] == 'none' for r in stop_rows)} without an estimate.", ""]
    if along_rows or stop_rows:
        lines += READING
    if cost_rows:
        lines += ["### Cost of estimating (per pass; median of rounds)", "",
                  "| image | estimate ms | accumulate one pass ms | estimate / 2-s auto pass |", "|---|---:|---:|---:|"]
        for r in cost_rows:
            lines.append(f"| {r['size']}x{r['size']} RGB | {1e3 * r['estimate']:.1f} | {1e3 * r['add']:.1f} | "
                         f"{100 * r['estimate'] / 2.0:.2f} % |")
        lines.append("")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skip", default="", help="comma list of parts to skip: along,stops,cost,tuned")
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--write", action="store_true", help="write the tables into benchmarks/RESULTS.md")
    args = parser.parse_args(argv)
    import pointillist

    mi = pointillist.setup("llvm_ad_rgb")
    import drjit as dr

    skip = set(filter(None, args.skip.split(",")))
    load_before = os.getloadavg()[0]
    cases = HARD + ([] if "tuned" in skip else TUNED)
    along_rows = along(cases, SEEDS) if "along" not in skip or "stops" not in skip else []
    stop_rows = [] if "stops" in skip else stops(HARD, SEEDS, along_rows)
    cost_rows = [] if "cost" in skip else cost(args.repeats)
    load_after = os.getloadavg()[0]
    text = report([] if "along" in skip else along_rows, stop_rows, cost_rows, args, load_before, load_after, mi, dr)
    print(text)
    if args.write:
        from _results import write_block

        write_block("estimator", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
