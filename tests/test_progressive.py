"""Progressive rendering (issue 19): passes, Welford accumulation, the relMSE estimate, budgets,
checkpoints, resume, interruption, and `pointillist render --time/--target-error`."""

from __future__ import annotations

import math
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from pointillist.cli import main
from pointillist.imaging.io import read_exr

ROOT = Path(__file__).resolve().parent.parent
SCENES = ROOT / "scenes"
EDGES, CORNELL, DEFAULT = SCENES / "edges.xml", SCENES / "cornell_phong.xml", SCENES / "default.xml"


def _load(path, **params):
    from pointillist.scene import load_scene

    return load_scene(path, {k: str(v) for k, v in params.items()})


def _render(scene, spp, seed):
    from pointillist.scene import timed_render

    return np.asarray(timed_render(scene, spp=spp, seed=seed)[0], dtype=np.float64)


def _relmse(image, reference):
    from pointillist.imaging.metrics import image_errors

    return image_errors(np.asarray(image), np.asarray(reference), flip=False)["relmse"]


def _stats(**kw):
    from pointillist.progressive import PassStats

    base = dict(passes=0, spp=0, pass_spp=0, seconds=0.0, pass_seconds=0.0, pass_compile_seconds=0.0,
                compile_seconds=0.0, estimated_relmse=math.nan, width=64, height=64)
    return PassStats(**dict(base, **kw))


# ------------------------------------------------------------------------------ seeds
def test_pass_seeds_are_mitsubas_tea_hash_and_distinct(mi):
    from pointillist.progressive import pass_seed, tea32

    for v0, v1 in [(0, 0), (1, 2), (123456, 7), (2**32 - 1, 5), (77, 2**32 - 1)]:
        expected = mi.sample_tea_32(mi.UInt32(v0), mi.UInt32(v1))
        assert tea32(v0, v1) == (int(expected[0][0]), int(expected[1][0]))
    seeds = [pass_seed(5, k) for k in range(10000)]
    assert len(set(seeds)) == len(seeds) and all(0 <= s < 2**32 for s in seeds)
    assert pass_seed(5, 0) != pass_seed(6, 0) and pass_seed(5, 1) == (pass_seed(5, 0) + 1) % 2**32


# ------------------------------------------------------------------------------ Welford
def test_weighted_welford_matches_the_two_pass_formulas(mi):
    """Mean and variance of the mean against numpy's two-pass formulas, passes of unequal spp."""
    from pointillist.progressive import Accumulator

    rng = np.random.default_rng(19)
    passes = [rng.gamma(2.0, 1.5, size=(5, 7, 3)).astype(np.float32) for _ in range(6)]
    weights = np.array([4, 4, 8, 1, 2, 4], np.float64)
    acc = Accumulator.empty()
    for image, n in zip(passes, weights):
        acc = acc.add(mi.TensorXf(image), int(n))
    x = np.stack(passes).astype(np.float64)
    mean = np.tensordot(weights, x, axes=1) / weights.sum()
    sigma2 = np.tensordot(weights, (x - mean) ** 2, axes=1) / (len(passes) - 1)
    assert acc.passes == 6 and acc.weight == 23
    np.testing.assert_allclose(acc.mean.numpy(), mean, rtol=1e-12)
    np.testing.assert_allclose(acc.variance_of_mean().numpy(), sigma2 / weights.sum(), rtol=1e-10)
    with pytest.raises(ValueError, match=r"image: expected shape \(5, 7, 3\)"):
        acc.add(mi.TensorXf(np.zeros((5, 6, 3), np.float32)), 1)


def test_estimate_formula_by_hand(mi):
    """One pixel, 8 passes alternating 1 and 3: mean 2, var of mean = (8 * 1 / 7) / 8 = 1/7."""
    from pointillist.progressive import MIN_PASSES, Accumulator

    acc = Accumulator.empty()
    for k in range(MIN_PASSES):
        acc = acc.add(mi.TensorXf(np.full((1, 1, 3), 1.0 + 2 * (k % 2), np.float32)), 1)
        if acc.passes < MIN_PASSES:
            assert math.isnan(acc.estimated_relmse())
    var = 1.0 / 7.0
    assert acc.estimated_relmse() == pytest.approx(var / (max(4.0 - var, 1.0) + 0.01), rel=1e-12)
    # A pixel whose noise exceeds its mean: the denominator stops at mean^2 / 4.
    acc = Accumulator.empty()
    for k in range(MIN_PASSES):
        acc = acc.add(mi.TensorXf(np.full((1, 1, 3), 8.0 if k == 0 else 0.0, np.float32)), 1)
    var = 1.0  # sum (x - 1)^2 = 49 + 7 * 1 = 56; / (K - 1) = 8; / 8 spp = 1
    assert acc.variance_of_mean().numpy()[0, 0, 0] == pytest.approx(var)
    assert acc.estimated_relmse() == pytest.approx(var / (0.25 * 1.0 + 0.01), rel=1e-12)


# ------------------------------------------------------------------------------ passes
def test_passes_are_the_mean_of_independent_renders_with_the_pass_seeds(mi):
    from pointillist.progressive import Budget, pass_seed, render_passes

    scene = _load(EDGES, res=16)
    for image, stats in render_passes(scene, pass_spp=Budget(spp=20, pass_spp=4), seed=2):
        pass
    assert (stats.passes, stats.spp, stats.seed) == (5, 20, pass_seed(2, 4))
    expected = np.mean([_render(scene, 4, pass_seed(2, k)) for k in range(5)], axis=0)
    np.testing.assert_allclose(np.asarray(image), expected, rtol=2e-6, atol=1e-7)


def test_deterministic_estimator_is_bit_for_bit_and_estimates_zero(mi):
    """`direct` + one point light + the seed-free `grid` sampler: every pass is the same image, so
    5 passes give exactly one render's pixels; no spread between passes: estimate 0 (the
    README's correlated-passes failure: the aliasing error of the grid is not seen)."""
    from pointillist.progressive import Budget, render_passes

    scene = _load(EDGES, res=24, sampler="grid")
    for image, stats in render_passes(scene, pass_spp=Budget(spp=40, pass_spp=4), seed=9):
        pass
    single = np.asarray(_render(scene, 4, 123), dtype=np.float32)
    assert stats.passes == 10 and np.array_equal(np.asarray(image), single)
    assert stats.estimated_relmse == 0.0


def test_passes_are_statistically_one_render_of_all_their_samples(mi):
    from pointillist.progressive import Budget, render_passes

    scene = _load(EDGES, res=48)
    reference = _render(scene, 1024, 1_000_003)
    for image, stats in render_passes(scene, pass_spp=Budget(spp=32, pass_spp=4), seed=4):
        pass
    ratio = _relmse(image, reference) / _relmse(_render(scene, 32, 77), reference)
    assert stats.spp == 32 and 0.75 < ratio < 1.33, ratio


@pytest.mark.parametrize("path, params, pass_spp", [
    (EDGES, {"res": 48}, 4),                                  # direct, pixel-area noise
    (CORNELL, {"res": 128}, 8),                               # whitted, area + point light
    (DEFAULT, {"res": 48, "integrator": "path"}, 4),          # path traced
], ids=["edges", "cornell", "default-path"])
def test_estimate_tracks_the_true_error_within_2x(mi, path, params, pass_spp):
    from pointillist.progressive import MIN_PASSES, Budget, render_passes

    scene = _load(path, **params)
    reference = _render(scene, 1024, 1_000_003)
    seen = {}
    for image, stats in render_passes(scene, pass_spp=Budget(spp=16 * pass_spp, pass_spp=pass_spp), seed=1):
        if stats.passes < MIN_PASSES:
            assert math.isnan(stats.estimated_relmse)
        elif stats.passes in (8, 16):
            seen[stats.passes] = _relmse(image, reference) / stats.estimated_relmse
    assert set(seen) == {8, 16} and all(0.5 <= r <= 2.0 for r in seen.values()), seen


def test_render_passes_with_an_injected_clock(mi):
    """Each pass reads the clock twice; 0.5 s per pass: a 2 s budget is 4 passes, 2.0 s."""
    from pointillist.progressive import Budget, render_passes

    ticks = iter(np.arange(0, 100, 0.5))
    budget = Budget(seconds=2.0, pass_spp=1)
    history = [stats for _, stats in render_passes(_load(EDGES, res=8), pass_spp=budget, clock=lambda: next(ticks))]
    assert [s.seconds for s in history] == [0.5, 1.0, 1.5, 2.0] and budget.stop_reason(history[-1]) == "time"


def test_render_passes_rejects_bad_arguments(mi):
    from pointillist.progressive import render_passes

    scene = _load(EDGES, res=8)
    for kwargs, message in [({"pass_spp": 0}, r"pass_spp: expected an integer in 1..2\^32-1 or a callable, got 0"),
                            ({"pass_spp": 2.5}, "pass_spp"), ({"pass_spp": 1, "seed": -1}, "seed: expected")]:
        with pytest.raises(ValueError, match=message):
            next(render_passes(scene, **kwargs))


# ------------------------------------------------------------------------------ budgets
def _simulate(budget, *, overhead, per_spp, compile_s=1.0, width=256, height=256, error=None):
    """Run the budget against a model of pass times (and an error ~ c / spp); returns the stats."""
    stats = _stats(width=width, height=height)
    history = []
    while (n := budget(stats)) > 0:
        # pass_spp, a power of two (one kernel), or the pass cut to land on the spp budget
        assert n == budget.pass_spp or n & (n - 1) == 0 or stats.spp + n == budget.spp, n
        seconds = overhead + n * per_spp + (compile_s if stats.passes == 0 else 0.0)
        spp, passes = stats.spp + n, stats.passes + 1
        stats = replace(stats, passes=passes, spp=spp, pass_spp=n, seconds=stats.seconds + seconds,
                        pass_seconds=seconds, pass_compile_seconds=compile_s if passes == 1 else 0.0,
                        estimated_relmse=error / spp if error and passes >= 8 else math.nan)
        history.append(stats)
        assert len(history) < 100000
    return history


@pytest.mark.parametrize("per_spp", [1e-4, 3e-3, 0.02, 0.09])
@pytest.mark.parametrize("seconds", [1.5, 4.0, 30.0])
def test_time_budget_ends_within_10_percent(per_spp, seconds):
    from pointillist.progressive import Budget

    history = _simulate(Budget(seconds=seconds), overhead=0.015, per_spp=per_spp)
    end = history[-1].seconds
    assert abs(end - seconds) <= 0.1 * seconds, (end, len(history))
    # granularity: half a spp (the rate includes the last pass's overhead share) + one pass overhead
    assert abs(end - seconds) <= (per_spp + 0.015) / 2 + 0.015 + 1e-9, (end, len(history))


def test_time_budget_passes_are_short_and_at_least_one_runs():
    from pointillist.progressive import TARGET_PASS_SECONDS, Budget

    history = _simulate(Budget(seconds=8.0), overhead=0.0, per_spp=1e-3, compile_s=0.0)
    # nearest power of two: within sqrt(2) of the target pass time
    assert max(s.pass_seconds for s in history) <= math.sqrt(2) * min(TARGET_PASS_SECONDS, 8.0 / 8) + 1e-9
    first = _simulate(Budget(seconds=0.1), overhead=0.0, per_spp=1e-3, compile_s=2.0)
    assert len(first) == 1 and first[0].seconds > 2.0   # the compiling first pass alone is over budget


def test_spp_budget_lands_exactly():
    from pointillist.progressive import Budget

    history = _simulate(Budget(spp=1000, pass_spp=64), overhead=0.01, per_spp=1e-3)
    assert history[-1].spp == 1000 and [s.pass_spp for s in history][:15] == [64] * 15
    assert sum(s.pass_spp for s in history) == 1000
    auto = _simulate(Budget(spp=77), overhead=0.01, per_spp=1e-3, width=8, height=8)
    assert auto[-1].spp == 77


def test_error_budget_stops_at_the_first_estimate_below_and_does_not_overshoot():
    from pointillist.progressive import MIN_PASSES, Budget

    history = _simulate(Budget(target_error=0.002, pass_spp=16), overhead=0.01, per_spp=1e-3, error=1.0)
    # error = 1 / spp: needs 500 spp; passes of 16 up to there, then shrunk to land on it.
    assert history[-1].estimated_relmse <= 0.002 < history[-2].estimated_relmse or len(history) == MIN_PASSES
    assert 500 <= history[-1].spp <= 512
    early = _simulate(Budget(target_error=0.5, pass_spp=16), overhead=0.01, per_spp=1e-3, error=1.0)
    assert len(early) == MIN_PASSES   # no estimate, so no stop, before MIN_PASSES passes


@pytest.mark.parametrize("kwargs, message", [
    ({"seconds": 0}, "seconds: expected a positive finite number, got 0"),
    ({"seconds": math.nan}, "seconds: expected a positive finite number, got nan"),
    ({"target_error": -1.0}, "target_error: expected a positive finite number, got -1.0"),
    ({"spp": 0}, "spp: expected an integer in 1..2^32-1, got 0"),
    ({"pass_spp": 1.5}, "pass_spp: expected an integer"),
    ({"min_passes": 2}, "min_passes: expected an integer >= 8"),
])
def test_budget_rejects_bad_values(kwargs, message):
    from pointillist.progressive import Budget

    with pytest.raises(ValueError, match=message.replace("^", r"\^")):
        Budget(**kwargs)


# ------------------------------------------------------------------------------ command line
def _bad(capsys, *argv):
    with pytest.raises(SystemExit) as info:
        raise SystemExit(main([str(a) for a in argv]))
    return info.value.code, capsys.readouterr().err.strip().splitlines()


@pytest.mark.parametrize("argv, message", [
    (["--time", "0"], "argument --time: expected a positive number, got '0'"),
    (["--time", "nan"], "argument --time: expected a positive number, got 'nan'"),
    (["--target-error", "-1"], "argument --target-error: expected a positive number, got '-1'"),
    (["--pass-spp", "0"], "argument --pass-spp: expected a positive integer"),
    (["--checkpoint", "inf"], "argument --checkpoint: expected a positive number"),
    (["--time", "1", "--tiles", "2x2"], "not with progressive rendering"),
    (["--resume"], "--resume: no checkpoint"),
])
def test_cli_bad_input_exit_2_one_line(capsys, tmp_path, mi, argv, message):
    code, err = _bad(capsys, "render", EDGES, "-o", tmp_path / "x.exr", "-D", "res=8", *argv)
    assert code == 2 and len(err) == 1 and message in err[0], err


def test_cli_time_budget_writes_exr_metadata_layers_and_progress(tmp_path, cli, mi):
    out = tmp_path / "t.exr"
    proc = cli("render", EDGES, "-o", out, "-D", "res=16", "--time", "1", "--png", "--variance-layer")
    assert proc.returncode == 0, proc.stderr
    image, meta, layers = read_exr(out)
    assert image.shape == (16, 16, 3) and np.isfinite(image).all()
    assert meta["interrupted"] == 0 and meta["stopped_by"] == "time" and meta["time_budget"] == 1.0
    assert meta["render_seconds"] > 0 and meta["passes"] >= 1 and meta["spp"] >= meta["passes"]
    assert f"{meta['spp']} spp in {meta['passes']} passes" in proc.stdout and "estimated relMSE" in proc.stdout
    rows = np.genfromtxt(out.with_suffix(".progress.csv"), delimiter=",", names=True)
    rows = np.atleast_1d(rows)
    assert len(rows) == meta["passes"] and rows["spp"][-1] == meta["spp"]
    assert np.all(np.diff(rows["seconds"]) > 0) and rows["seconds"][-1] == pytest.approx(meta["render_seconds"])
    assert np.all(np.diff(rows["spp"]) > 0)
    if meta["passes"] >= 8:
        assert rows["estimated_relmse"][-1] == pytest.approx(meta["estimated_relmse"], rel=1e-5)
    assert layers["variance"].shape == (16, 16) and (layers["variance"] >= 0).all()
    assert out.with_suffix(".progress.png").stat().st_size > 1000 and out.with_suffix(".png").exists()


def test_cli_spp_and_pass_spp_without_budget_and_plain_render_unchanged(tmp_path, cli, mi):
    out = tmp_path / "p.exr"
    proc = cli("render", EDGES, "-o", out, "-D", "res=16", "--spp", "40", "--pass-spp", "4", "--seed", "3",
               "--variance-layer")
    assert proc.returncode == 0, proc.stderr
    image, meta, layers = read_exr(out)
    assert (meta["spp"], meta["passes"], meta["stopped_by"]) == (40, 10, "spp") and meta["estimated_relmse"] > 0
    from pointillist.progressive import pass_seed

    scene = _load(EDGES, res=16)
    passes = np.stack([_render(scene, 4, pass_seed(3, k)) for k in range(10)])
    np.testing.assert_allclose(image, passes.mean(axis=0), rtol=2e-6, atol=1e-7)
    var_of_mean = passes.var(axis=0, ddof=1) / 10          # 10 equal passes: s^2 of the passes / K
    np.testing.assert_allclose(layers["variance"], var_of_mean.mean(axis=2), rtol=1e-4, atol=1e-9)
    m = passes.mean(axis=0)
    estimate = (var_of_mean / (np.maximum(m * m - var_of_mean, m * m / 4) + 0.01)).mean()
    assert meta["estimated_relmse"] == pytest.approx(estimate, rel=1e-5)
    plain = tmp_path / "plain.exr"
    assert cli("render", EDGES, "-o", plain, "-D", "res=16", "--spp", "4").returncode == 0
    assert not plain.with_suffix(".progress.csv").exists() and "passes" not in read_exr(plain).metadata


def test_cli_checkpoint_then_resume_equals_one_uninterrupted_render(tmp_path, cli, mi):
    scene = tmp_path / "edges.xml"
    shutil.copy(EDGES, scene)
    first, whole = tmp_path / "r.exr", tmp_path / "whole.exr"
    args = ["-D", "res=16", "--pass-spp", "4", "--seed", "5"]
    assert cli("render", scene, "-o", first, *args, "--spp", "32", "--checkpoint", "1000").returncode == 0
    assert first.with_suffix(".checkpoint.npz").exists()
    proc = cli("render", scene, "-o", first, *args, "--spp", "64", "--resume")
    assert proc.returncode == 0 and "resumed from 8 passes" in proc.stdout, proc.stderr
    assert cli("render", scene, "-o", whole, *args, "--spp", "64").returncode == 0
    resumed, meta, _ = read_exr(first)
    assert meta["passes"] == 16 and meta["spp"] == 64 and meta["resumed_from_passes"] == 8
    assert np.array_equal(resumed, read_exr(whole).image)
    rows = np.genfromtxt(first.with_suffix(".progress.csv"), delimiter=",", names=True)
    assert list(rows["pass"]) == list(range(1, 17))
    # another scene file (same name), another seed: exit 2, one line
    scene.write_text(scene.read_text().replace('value="40, 39, 36"', 'value="41, 39, 36"'))
    proc = cli("render", scene, "-o", first, *args, "--spp", "96", "--resume")
    assert proc.returncode == 2 and proc.stderr.strip().count("\n") == 0 and "another scene (" in proc.stderr
    shutil.copy(EDGES, scene)
    proc = cli("render", scene, "-o", first, "-D", "res=16", "--seed", "6", "--spp", "96", "--resume")
    assert proc.returncode == 2 and "other settings (seed 5, now 6)" in proc.stderr


@pytest.mark.parametrize("signum, status", [(signal.SIGINT, 130), (signal.SIGTERM, 143)], ids=["SIGINT", "SIGTERM"])
def test_interrupt_writes_the_passes_done(tmp_path, mi, signum, status):
    """Ctrl-C / SIGTERM during a --time 60 render: a valid EXR of what was rendered, interrupted=1;
    exit 130 for Ctrl-C and 143 for SIGTERM (issue 26: SIGTERM exited 130), with one line.

    Waits (event, not time) for the first checkpoint, i.e. for passes to exist, then signals.
    """
    out = tmp_path / "i.exr"
    proc = subprocess.Popen([sys.executable, "-m", "pointillist", "render", str(EDGES), "-o", str(out), "-D", "res=16",
                             "--time", "60", "--pass-spp", "1", "--checkpoint", "0.01"], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not out.with_suffix(".checkpoint.npz").exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    proc.send_signal(signum)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == status, stderr
    word = "interrupted" if status == 130 else "terminated (SIGTERM)"
    assert stderr.splitlines() == [f"pointillist render: {word}"]
    image, meta, _ = read_exr(out)
    assert meta["interrupted"] == 1 and meta["stopped_by"] == "interrupted" and meta["spp"] >= 1
    assert meta["render_seconds"] < 60 and image.shape == (16, 16, 3) and np.isfinite(image).all()
    assert "stopped by interrupted" in stdout


def test_cli_target_error_stops_below_it_and_tracks_the_true_error(tmp_path, cli, mi):
    out = tmp_path / "e.exr"
    proc = cli("render", EDGES, "-o", out, "-D", "res=32", "--target-error", "0.002", "--seed", "8")
    assert proc.returncode == 0, proc.stderr
    image, meta, _ = read_exr(out)
    assert meta["stopped_by"] == "error" and meta["estimated_relmse"] <= 0.002
    true = _relmse(image, _render(_load(EDGES, res=32), 1024, 1_000_003))
    assert 0.5 <= true / meta["estimated_relmse"] <= 2.0, (true, meta["estimated_relmse"])
