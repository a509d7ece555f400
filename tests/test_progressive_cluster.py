"""Progressive rendering in tiles (pointillist.progressive.tiled): in this process and on a real local
Dask cluster (``dask scheduler`` and ``dask worker`` processes, as a user starts them).

What must hold: the same EXR bit for bit in this process and on 1, 2 and 4 workers; a checkpoint
made on one cluster resumed on another continues the render exactly; a worker killed in a pass
changes nothing; a scheduler that goes away ends the command with one line and a usable checkpoint;
the work goes to the noisy tiles; time budgets end within 2 % (a model of the rounds' times).
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pointillist.imaging.io import read_exr

ROOT = Path(__file__).resolve().parent.parent
SCENES = ROOT / "scenes"
EDGES, CORNER = SCENES / "edges.xml", SCENES / "corner_caustic.xml"

pytest.importorskip("distributed")


# ----------------------------------------------------------------------------- a real cluster
class Cluster:
    """A ``dask scheduler`` and ``dask worker`` processes on loopback, started as a user would."""

    def __init__(self, folder: Path):
        self.folder, self.workers = folder, []
        self.file = folder / "scheduler.json"
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        self.env = env
        self.scheduler = subprocess.Popen(
            [sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
             "--scheduler-file", str(self.file)], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            cwd=folder)
        deadline = time.monotonic() + 60
        while not self.file.is_file() or not self.file.read_text().strip():
            assert time.monotonic() < deadline and self.scheduler.poll() is None, "the scheduler did not start"
            time.sleep(0.1)
        import json

        self.address = json.loads(self.file.read_text())["address"]

    def add_workers(self, count: int) -> None:
        for _ in range(count):
            self.workers.append(subprocess.Popen(
                [sys.executable, "-m", "dask", "worker", "--scheduler-file", str(self.file), "--nworkers", "1",
                 "--nthreads", "1", "--no-dashboard", "--local-directory", str(self.folder)],
                env=self.env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=self.folder))
        self.wait(len(self.workers))

    def wait(self, count: int) -> None:
        from distributed import Client

        with Client(self.address, timeout=30) as client:
            client.wait_for_workers(count, timeout=90)

    def close(self) -> None:
        for process in [*self.workers, self.scheduler]:
            if process.poll() is None:
                process.terminate()
        for process in [*self.workers, self.scheduler]:
            try:
                process.wait(20)
            except subprocess.TimeoutExpired:
                process.kill()


@pytest.fixture
def cluster(tmp_path):
    made = Cluster(tmp_path)
    yield made
    made.close()


def _render(cli, out: Path, *argv) -> subprocess.CompletedProcess:
    proc = cli("render", *argv, "-o", out)
    assert proc.returncode == 0, proc.stderr
    return proc


def _same(a: Path, b: Path) -> None:
    """Two EXRs with the same pixels, bit for bit, and the same estimate."""
    x, y = read_exr(a), read_exr(b)
    assert x.image.tobytes() == y.image.tobytes(), f"{a.name} and {b.name} differ"
    for key in ("spp", "estimated_relmse", "estimate_state", "tile_spp", "stopped_by"):
        assert x.metadata.get(key) == y.metadata.get(key), key


# An adaptive render whose decisions read no clock: --pass-spp with an error target and an spp cap.
ADAPTIVE = [str(CORNER), "-D", "res=48", "--tiles", "3x3", "--target-error", "0.0003", "--pass-spp", "8",
            "--spp", "512", "--seed", "3"]


def test_the_same_exr_in_process_and_on_1_2_and_4_workers(cli, cluster, tmp_path):
    here = tmp_path / "here.exr"
    proc = _render(cli, here, *ADAPTIVE)
    assert "as 3x3 tiles in process" in proc.stdout
    meta = read_exr(here).metadata
    low, high = (int(v) for v in meta["tile_spp"].split(".."))
    assert low < high < 512, meta["tile_spp"]     # the passes went where the noise is, and the target was met
    assert meta["stopped_by"] == "error"
    for count, more in ((1, 1), (2, 1), (4, 2)):
        cluster.add_workers(more)
        there = tmp_path / f"on{count}.exr"
        proc = _render(cli, there, *ADAPTIVE, "--scheduler", cluster.address)
        assert f"on {count} worker(s)" in proc.stdout, proc.stdout
        _same(here, there)
    # a local cluster (--workers) too, and the progress logs agree round by round but for the seconds
    local = tmp_path / "local.exr"
    _render(cli, local, *ADAPTIVE, "--workers", "2")
    _same(here, local)
    rows = [[line.split(",")[:1] + line.split(",")[2:]
             for line in p.with_suffix(".progress.csv").read_text().splitlines()] for p in (here, local)]
    assert rows[0] == rows[1] and len(rows[0]) > 9


def test_a_checkpoint_made_on_one_cluster_continues_exactly_on_another(cli, cluster, tmp_path):
    common = [str(EDGES), "-D", "res=24", "--tiles", "2x3", "--pass-spp", "2", "--seed", "5"]
    straight = tmp_path / "straight.exr"
    _render(cli, straight, *common, "--spp", "24")
    cluster.add_workers(2)
    split = tmp_path / "split.exr"
    _render(cli, split, *common, "--spp", "12", "--checkpoint", "1000", "--scheduler", cluster.address)
    proc = _render(cli, split, *common, "--spp", "24", "--resume", "--workers", "1")
    assert "resumed from 6 passes" in proc.stdout
    _same(straight, split)
    # a checkpoint of other tiles is refused, with one line
    proc = cli("render", *common[:4], "--tiles", "3x2", *common[6:], "--spp", "30", "--resume", "-o", split)
    assert proc.returncode == 2 and "tiles" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1


def _worker_pids(address: str) -> dict:
    from distributed import Client

    with Client(address, timeout=30) as client:
        return client.run(os.getpid)


def test_a_worker_killed_in_a_pass_changes_nothing(cli, cluster, tmp_path):
    common = [str(CORNER), "-D", "res=64", "--tiles", "3x3", "--pass-spp", "64", "--spp", "512", "--seed", "1"]
    quiet = tmp_path / "quiet.exr"
    _render(cli, quiet, *common)
    cluster.add_workers(2)
    out = tmp_path / "killed.exr"
    proc = subprocess.Popen([sys.executable, "-m", "pointillist", "render", *common, "--scheduler", cluster.address,
                             "-o", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    killed = {}

    def executing(dask_worker):
        return os.getpid(), [str(key) for key in dask_worker.state.executing]

    def killer():
        from distributed import Client

        with Client(cluster.address, timeout=30) as client:
            first_seen, deadline = None, time.monotonic() + 300
            while time.monotonic() < deadline and proc.poll() is None:
                try:
                    states = client.run(executing)
                except Exception:  # noqa: BLE001 - a worker may be restarting
                    states = {}
                running = [pid for pid, keys in states.values() if any("render_tile_pass" in k for k in keys)]
                if running and first_seen is None:
                    first_seen = time.monotonic()
                # a second after the first pass: the scene is loaded, the render is under way
                if running and time.monotonic() - first_seen > 1.0:
                    os.kill(running[0], signal.SIGKILL)
                    killed["pid"] = running[0]
                    return
                time.sleep(0.01)

    thread = threading.Thread(target=killer, daemon=True)
    thread.start()
    stdout, stderr = proc.communicate(timeout=600)
    thread.join(10)
    assert proc.returncode == 0, stderr
    assert killed, "the test never saw a pass running to kill"
    _same(quiet, out)


def test_a_scheduler_that_goes_away_ends_with_one_line_and_a_checkpoint(cli, cluster, tmp_path):
    common = [str(EDGES), "-D", "res=32", "--tiles", "2x2", "--pass-spp", "4", "--seed", "2"]
    cluster.add_workers(1)
    out = tmp_path / "lost.exr"
    proc = subprocess.Popen([sys.executable, "-m", "pointillist", "render", *common, "--spp", "4000000",
                             "--checkpoint", "0.5", "--scheduler", cluster.address, "-o", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    checkpoint = out.with_suffix(".checkpoint.npz")
    deadline = time.monotonic() + 120
    while not checkpoint.is_file() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.1)
    assert checkpoint.is_file(), proc.communicate()[1]
    cluster.scheduler.kill()
    stdout, stderr = proc.communicate(timeout=180)
    assert proc.returncode == 1, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and "lost the Dask cluster" in lines[0] and "--resume continues" in lines[0], stderr
    assert "Traceback" not in stderr
    # the checkpoint is usable: resumed in this process, it goes on to a larger budget
    import json

    with np.load(checkpoint) as data:
        stats = json.loads(str(data["stats"]))
    assert stats["passes"] >= 1
    proc = _render(cli, out, *common, "--spp", str(stats["spp"] + 8), "--resume")
    assert f"resumed from {stats['passes']} passes" in proc.stdout
    assert read_exr(out).metadata["spp"] == stats["spp"] + 8


# ----------------------------------------------------------------------------- in this process
def test_the_frame_has_one_estimate_the_one_machine_formula_on_its_tiles(mi, rng):
    """Passes split into 2x3 tiles, each tile its own accumulator: the frame's estimate is the one an
    accumulator of the whole passes makes (the neighbours of a tile's border pixels lie in the next tile)."""
    from pointillist.progressive import Accumulator, Budget
    from pointillist.progressive.tiled import _Engine
    from pointillist.tiles import tile_grid

    height, width, passes = 12, 17, 12
    grid = tile_grid(width, height, 2, 3)
    images = [rng.gamma(0.5, 1.0, (height, width, 3)).astype(np.float32) for _ in range(passes)]
    images[5][4, 7] += 40.0   # a firefly on a tile's border
    whole, tiles = Accumulator.empty(), [Accumulator.empty() for _ in grid]
    for k, image in enumerate(images):
        spp = 1 << (k % 3)
        whole = whole.add(mi.TensorXf(image), spp)
        tiles = [acc.add(mi.TensorXf(np.ascontiguousarray(image[t.y:t.y + t.height, t.x:t.x + t.width])), spp)
                 for acc, t in zip(tiles, grid)]
    engine = _Engine(EDGES, {}, Budget(spp=64), grid, window=(0, 0, width, height), seed=0, sensor=0, client=None,
                     inputs_sha256="x", channels=3, clock=time.perf_counter)
    frame, alone = engine.measure(tiles), whole.estimate(3)
    assert math.isclose(frame.relmse, alone.relmse, rel_tol=1e-12)
    assert frame.halves == pytest.approx(alone.halves, rel=1e-12) and frame.trusted == alone.trusted
    assert engine.shares.sum() == pytest.approx(frame.relmse, rel=1e-12)
    assert int(np.argmax(engine.shares)) == next(t.index for t in grid if t.x <= 7 < t.x + t.width and t.y <= 4 < t.y
                                                  + t.height)
    image, variance = engine.image(tiles)
    np.testing.assert_array_equal(image, whole.mean.numpy().astype(np.float32))


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(1e-4, 1.0), st.integers(8, 4096), st.integers(1, 4096)), min_size=1, max_size=12),
       st.floats(1e-4, 1e-1))
def test_tile_targets_reach_the_target_at_the_least_cost(tiles, target):
    from pointillist.progressive.tiled import MIN_TILE_SHARE, tile_targets

    c, w, p = (np.array(column, np.float64) for column in zip(*tiles))
    wanted = tile_targets(c, w, p, target)
    assert (wanted >= w).all() and (wanted >= wanted.max() / MIN_TILE_SHARE * (1 - 1e-12)).all()
    reached = float((c * w / wanted).sum())
    assert reached <= target * (1 + 1e-9)      # raised spp only lower the error
    free = np.sqrt(c * w / p) * np.sqrt(c * w * p).sum() / target
    if np.allclose(free, wanted):               # nothing raised: the target exactly, at the least cost
        assert reached == pytest.approx(target, rel=1e-9)
        cost = float((p * wanted).sum())
        for k in range(len(c)):                 # moving spp between tiles at the same error costs more
            for j in range(len(c)):
                if j != k:
                    moved = wanted.copy()
                    moved[k] *= 1.1
                    # tile j gives back what keeps the error at the target
                    rest = target - float((c * w / moved).sum()) + c[j] * w[j] / moved[j]
                    if rest > 0:
                        moved[j] = c[j] * w[j] / rest
                        assert float((p * moved).sum()) >= cost * (1 - 1e-9)


def _model_cluster(monkeypatch, workers: int, per_sample: float, overhead: float):
    """``run_tasks`` replaced by a model of a cluster: a round takes ``overhead`` plus its samples'
    seconds shared by ``workers``, read from a clock it advances (no rendering, no real time)."""
    import pointillist.distributed as distributed
    from pointillist.tiles import RenderResult

    now = [0.0]

    def run_tasks(function, tasks, **_):
        samples = [t.spp * t.crop[2] * t.crop[3] for t in tasks]
        loads = sorted(samples, reverse=True)
        lanes = [0.0] * workers
        for s in loads:                      # the scheduler gives each task to the first free worker
            lanes[lanes.index(min(lanes))] += s * per_sample
        now[0] += overhead + max(lanes)
        return [RenderResult(image=np.full((t.crop[3], t.crop[2], 3), 0.5, np.float32),
                             timing={"trace": 0.0, "compile": 0.0, "execute": s * per_sample, "kernels": 1,
                                     "cache_hits": 1}, worker="model:1", task=t) for t, s in zip(tasks, samples)]

    monkeypatch.setattr(distributed, "run_tasks", run_tasks)
    return lambda: now[0]


@pytest.mark.parametrize("workers", [1, 2, 4])
@pytest.mark.parametrize("per_sample, seconds", [(2e-7, 3.0), (2e-6, 20.0), (5e-8, 60.0)])
def test_time_budgets_end_within_2_percent_on_a_cluster(mi, monkeypatch, workers, per_sample, seconds):
    from pointillist.progressive import Budget
    from pointillist.progressive.tiled import render_progressive_tiled
    from pointillist.scene import load_scene

    clock = _model_cluster(monkeypatch, workers, per_sample, overhead=0.02)
    scene = load_scene(EDGES, {"res": "256"})
    result = render_progressive_tiled(scene, EDGES, Budget(seconds=seconds), tiles=(4, 4), params={"res": "256"},
                                      progress=False, clock=clock)
    assert result.stop == "time"
    assert abs(result.stats.seconds - seconds) <= 0.02 * seconds, (result.stats.seconds, result.stats.passes)
    assert result.stats.passes >= 8      # room for the passes of an estimate


def test_progressive_cache_is_refused_in_one_line(cli, tmp_path):
    proc = cli("render", EDGES, "--time", "1", "--cache", tmp_path / "cache", "-o", tmp_path / "x.exr")
    assert proc.returncode == 2 and "--cache: not with progressive rendering" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


@settings(max_examples=50, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 64), st.integers(1, 40), st.integers(1, 40)), min_size=1, max_size=40),
       st.integers(1, 8))
def test_a_rounds_passes_go_out_in_bundles_of_about_equal_samples(passes, count):
    """Every pass in exactly one bundle, in task order within it; no bundle heavier than the lightest
    by more than the largest pass (the longest-first rule)."""
    from pointillist.progressive.tiled import _bundles
    from pointillist.tiles import RenderTask

    tasks = [RenderTask(str(EDGES), spp=spp, crop=(0, 0, w, h)) for spp, w, h in passes]
    bundles = _bundles(tasks, count)
    assert sorted(i for b in bundles for i in b) == list(range(len(tasks)))
    assert all(b == sorted(b) for b in bundles) and len(bundles) == min(count, len(tasks))
    loads = [sum(tasks[i].spp * tasks[i].crop[2] * tasks[i].crop[3] for i in b) for b in bundles]
    largest = max(t.spp * t.crop[2] * t.crop[3] for t in tasks)
    assert max(loads) - min(loads) <= largest


def test_a_second_signal_keeps_the_rounds_done(tmp_path):
    """Two SIGINTs during a tiled render: the process ends at once, the EXR and the checkpoint of the
    rounds done are written (interrupted = 1), nothing the render had is lost."""
    out = tmp_path / "cut.exr"
    proc = subprocess.Popen([sys.executable, "-m", "pointillist", "render", str(EDGES), "-D", "res=64",
                             "--tiles", "2x2", "--time", "120", "--checkpoint", "0.2", "-o", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    checkpoint = out.with_suffix(".checkpoint.npz")
    deadline = time.monotonic() + 120
    while not checkpoint.is_file() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.1)
    assert checkpoint.is_file(), proc.communicate()[1]
    proc.send_signal(signal.SIGINT)
    time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    meta = read_exr(out).metadata
    assert meta["interrupted"] == 1 and meta["stopped_by"] == "interrupted" and meta["rounds"] >= 1
    import json

    with np.load(checkpoint) as data:
        assert json.loads(str(data["stats"]))["passes"] == meta["rounds"]
