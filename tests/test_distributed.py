"""pointillist.distributed: tiles, the task runner and its cache, a 2-worker LocalCluster on loopback.

What "tiled equals untiled" means here: Mitsuba's samplers key their random
stream on the wavefront lane inside the crop window, and every tile has its own
seed, so a tiled render is another sample of the same estimator. We test
(1) exact agreement, to float rounding, for a deterministic estimator (the
``direct`` integrator with only a point light and emitter sampling, and the
``aov`` integrator, both with an unjittered ``stratified`` sampler, so no random
number changes a pixel) — this checks crop windows, tile placement and
assembly; and (2) statistical agreement for the path tracer: the tiled render
differs from an untiled one exactly as much as two untiled renders with
different seeds differ from each other.
"""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from pointillist.distributed import ResultCache, run_tasks, task_key
from pointillist.tiles import (RenderTask, Tile, assemble_tiles, parse_tiles, render_task, render_tiled, tile_grid,
                               tile_seed)

ROOT = Path(__file__).resolve().parent.parent
DEFAULT = str(ROOT / "scenes" / "default.xml")

#: A scene whose pixels use no random numbers: only a point light, emitter sampling only,
#: stratum centres (jitter off). ``$crop`` adds a crop window to the film.
DETERMINISTIC = """<scene version="3.0.0">
    <default name="integrator" value="direct"/>
    <default name="spp" value="4"/>
    <integrator type="direct">
        <integer name="emitter_samples" value="1"/>
        <integer name="bsdf_samples" value="0"/>
    </integrator>
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0, 2.2, 7" target="0, 0.6, 0" up="0, 1, 0"/></transform>
        <sampler type="stratified">
            <integer name="sample_count" value="$spp"/>
            <boolean name="jitter" value="false"/>
        </sampler>
        <film type="hdrfilm">
            <integer name="width" value="23"/>
            <integer name="height" value="17"/>
            <rfilter type="box"/>
            CROP
        </film>
    </sensor>
    <shape type="rectangle">
        <transform name="to_world"><scale value="6"/><rotate x="1" angle="-90"/></transform>
        <bsdf type="diffuse">
            <texture name="reflectance" type="checkerboard">
                <transform name="to_uv"><scale x="8" y="8"/></transform>
            </texture>
        </bsdf>
    </shape>
    <shape type="sphere">
        <point name="center" x="0.5" y="0.8" z="0"/>
        <float name="radius" value="0.8"/>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.25, 0.15"/></bsdf>
    </shape>
    <emitter type="point">
        <point name="position" x="3" y="5" z="4"/>
        <rgb name="intensity" value="60, 58, 52"/>
    </emitter>
</scene>
"""

CROP = """<integer name="crop_offset_x" value="3"/><integer name="crop_offset_y" value="2"/>
            <integer name="crop_width" value="15"/><integer name="crop_height" value="11"/>"""


@pytest.fixture(scope="module")
def det_scene(tmp_path_factory):
    folder = tmp_path_factory.mktemp("scenes")
    plain, cropped = folder / "det.xml", folder / "det_crop.xml"
    plain.write_text(DETERMINISTIC.replace("CROP", ""))
    cropped.write_text(DETERMINISTIC.replace("CROP", CROP))
    return plain, cropped


@pytest.fixture(scope="module")
def client():
    """A LocalCluster of 2 worker processes on loopback (one task thread, one Dr.Jit thread each)."""
    pytest.importorskip("distributed")
    from pointillist.distributed import start_cluster

    client = start_cluster(2, drjit_threads=1)
    yield client
    cluster = client.cluster
    client.close()
    cluster.close()


def _untiled(mi, scene, params=None, spp=None, seed=0):
    from pointillist.scene import load_scene, timed_render

    image, _ = timed_render(load_scene(scene, params or {}), spp=spp, seed=seed)
    return np.array(image)


# ----------------------------------------------------------------------------- tiles: pure functions
def test_parse_tiles():
    assert parse_tiles("4x4") == (4, 4) and parse_tiles(" 2X3 ") == (2, 3) and parse_tiles("1x1") == (1, 1)
    for bad in ("0x2", "2x0", "4", "x4", "2x2x2", "-1x2", "axb", ""):
        with pytest.raises(ValueError, match="tiles"):
            parse_tiles(bad)


def test_tile_grid_covers_every_pixel_once():
    for width, height, rows, cols in [(23, 17, 3, 2), (5, 5, 5, 5), (7, 1, 1, 7), (1, 1, 1, 1), (64, 48, 4, 4)]:
        tiles = tile_grid(width, height, rows, cols, x=3, y=2)
        assert len(tiles) == rows * cols and [t.index for t in tiles] == list(range(rows * cols))
        count = np.zeros((height + 2, width + 3), int)
        for t in tiles:
            count[t.y:t.y + t.height, t.x:t.x + t.width] += 1
        assert (count[2:, 3:] == 1).all() and count[:2].sum() == 0 and count[:, :3].sum() == 0
        widths = {t.width for t in tiles}
        heights = {t.height for t in tiles}
        assert max(widths) - min(widths) <= 1 and max(heights) - min(heights) <= 1
    # Row-major, hand-worked: 5 wide in 2 columns -> 2 + 3.
    assert [t.crop for t in tile_grid(5, 4, 2, 2)] == [(0, 0, 2, 2), (2, 0, 3, 2), (0, 2, 2, 2), (2, 2, 3, 2)]
    with pytest.raises(ValueError, match="do not fit"):
        tile_grid(4, 4, 5, 1)  # more tile rows than pixel rows
    with pytest.raises(ValueError, match="^width: expected an integer >= 1, got 0$"):
        tile_grid(0, 4, 1, 1)
    with pytest.raises(TypeError, match="^rows: expected an integer, got float 1.5$"):  # pointillist.core.checks
        tile_grid(4, 4, 1.5, 1)


def test_cluster_and_task_counts_are_checked_before_any_work():
    from pointillist.distributed import run_tasks, start_cluster

    with pytest.raises(ValueError, match="^n_workers: expected an integer >= 1, got 0$"):
        start_cluster(0)
    with pytest.raises(TypeError, match="^n_workers: expected an integer, got float 2.0$"):
        start_cluster(2.0)
    with pytest.raises(ValueError, match="^retries: expected an integer >= 0, got -1$"):
        run_tasks(abs, [1], retries=-1, progress=False)
    with pytest.raises(TypeError, match="^retries: expected an integer, got bool True$"):
        run_tasks(abs, [1], retries=True, progress=False)


def test_tile_seed_scheme():
    seeds = [tile_seed(s, i, 16) for s in range(5) for i in range(16)]
    assert len(set(seeds)) == len(seeds)  # distinct across tiles and base seeds
    assert [tile_seed(7, 0, 1), tile_seed(0, 3, 4), tile_seed(2, 1, 3)] == [7, 3, 7]
    assert tile_seed(2**32 - 1, 3, 4) == ((2**32 - 1) * 4 + 3) % 2**32  # wraps to 32 bits
    with pytest.raises(ValueError, match="index"):
        tile_seed(0, 4, 4)
    with pytest.raises(ValueError, match="seed"):
        tile_seed(-1, 0, 4)


def test_assemble_tiles_places_and_checks():
    tiles = tile_grid(5, 3, 1, 2, x=10, y=20)
    image = np.arange(15, dtype=np.float32).reshape(3, 5, 1)
    parts = [image[:, t.x - 10:t.x - 10 + t.width] for t in tiles]
    np.testing.assert_array_equal(assemble_tiles(tiles, parts, x=10, y=20), image)
    with pytest.raises(ValueError, match="shape"):
        assemble_tiles(tiles, [parts[0], parts[0]], x=10, y=20)
    with pytest.raises(ValueError, match="exactly once"):
        assemble_tiles([Tile(0, 0, 0, 2, 1), Tile(1, 1, 0, 2, 1)], [np.ones((1, 2))] * 2, width=3, height=1)
    with pytest.raises(ValueError, match="one image per tile"):
        assemble_tiles(tiles, parts[:1])


def test_render_task_validates():
    with pytest.raises(ValueError, match="^spp: expected an integer in 1..4294967295, got 0$"):
        RenderTask(DEFAULT, spp=0)
    with pytest.raises(TypeError, match="^spp: expected an integer, got float 2.5$"):  # pointillist.core.checks
        RenderTask(DEFAULT, spp=2.5)
    with pytest.raises(ValueError, match="^seed: expected an integer in 0..4294967295, got 4294967296$"):
        RenderTask(DEFAULT, seed=2**32)
    assert type(RenderTask(DEFAULT, spp=np.int64(4), seed=np.uint32(7)).seed) is int  # a plain int in cache keys
    with pytest.raises(ValueError, match="crop"):
        RenderTask(DEFAULT, crop=(0, 0, 0, 4))
    assert RenderTask(DEFAULT, {"b": 1, "a": "x"}).params == (("a", "x"), ("b", "1"))


# ----------------------------------------------------------------------------- tiled == untiled
def test_tiled_equals_untiled_for_deterministic_estimator(mi, det_scene):
    plain, _ = det_scene
    untiled = _untiled(mi, plain, seed=5)
    assert untiled.shape == (17, 23, 3) and untiled.std() > 0.05  # a real image, not a constant
    for tiles in [(1, 1), (3, 2), (17, 23)]:  # uneven tiles; one tile per pixel
        tiled = render_tiled(plain, tiles=tiles, seed=5, progress=False)
        assert tiled.image.shape == untiled.shape
        np.testing.assert_allclose(tiled.image, untiled, rtol=1e-5, atol=1e-6)
    # The comparison is sensitive to placement: swapping two same-size tiles breaks it.
    tiled = render_tiled(plain, tiles=(3, 2), seed=5, progress=False)
    images = [r.image for r in tiled.results]
    assert images[2].shape == images[4].shape
    images[2], images[4] = images[4], images[2]
    assert not np.allclose(assemble_tiles(tiled.tiles, images), untiled, rtol=1e-3, atol=1e-3)


def test_tiled_respects_the_scenes_own_crop_window(mi, det_scene):
    plain, cropped = det_scene
    full = _untiled(mi, plain)
    tiled = render_tiled(cropped, tiles=(2, 3), progress=False)
    assert tiled.image.shape == (11, 15, 3)
    assert min(t.x for t in tiled.tiles) == 3 and min(t.y for t in tiled.tiles) == 2
    np.testing.assert_allclose(tiled.image, full[2:13, 3:18], rtol=1e-5, atol=1e-6)


def test_aov_depth_tiles_exact(mi, tmp_path):
    scene = tmp_path / "aov.xml"
    scene.write_text(DETERMINISTIC.replace("CROP", "").replace(
        '<integrator type="direct">', '<integrator type="aov"><string name="aovs" value="d:depth,n:sh_normal"/>')
        .replace('<integer name="emitter_samples" value="1"/>\n        <integer name="bsdf_samples" value="0"/>', ""))
    untiled = _untiled(mi, scene, spp=1)
    tiled = render_tiled(scene, tiles=(4, 5), spp=1, seed=9, progress=False)
    np.testing.assert_allclose(tiled.image, untiled, rtol=1e-5, atol=1e-5)


def test_tiled_path_tracer_agrees_statistically(mi, tmp_path):
    # Mitsuba's path tracer, a constant sky and a point light: noisy everywhere.
    scene = tmp_path / "path.xml"
    scene.write_text(DETERMINISTIC.replace("CROP", "")
                     .replace('<integrator type="direct">', '<integrator type="path"><integer name="max_depth" '
                              'value="3"/>')
                     .replace('<integer name="emitter_samples" value="1"/>\n        '
                              '<integer name="bsdf_samples" value="0"/>', "")
                     .replace('<sampler type="stratified">', '<sampler type="independent">')
                     .replace('<boolean name="jitter" value="false"/>', "")
                     .replace("</scene>", '<emitter type="constant"><rgb name="radiance" value="0.5"/></emitter>'
                              "</scene>"))
    params, spp = {}, 32
    a = _untiled(mi, scene, params, spp, seed=11)
    b = _untiled(mi, scene, params, spp, seed=12)
    tiled = render_tiled(scene, params, tiles=(2, 2), spp=spp, seed=11, progress=False).image
    seeds = {r.task.seed for r in render_tiled(scene, params, tiles=(2, 2), spp=1, seed=11,
                                               progress=False).results}
    assert seeds == {44, 45, 46, 47}

    # Mean absolute per-channel difference (robust to the heavy tail of path-traced noise; the
    # median is not: many sky pixels have none). Across base seeds 3, 11, 77, 500 the ratios
    # below stayed within 0.92..1.08.
    def mae(x, y):
        return float(np.mean(np.abs(x - y)))

    noise = mae(a, b)  # two independent untiled renders
    assert noise > 0.01 * a.mean()
    # The tiled render is as far from each untiled one as they are from each other.
    assert 0.8 < mae(tiled, a) / noise < 1.25 and 0.8 < mae(tiled, b) / noise < 1.25
    # Not the same random numbers as the untiled render with the base seed.
    assert not np.allclose(tiled, a, atol=1e-3)
    # Same image brightness within 5 %.
    assert abs(tiled.mean() - a.mean()) < 0.05 * a.mean()


# ----------------------------------------------------------------------------- task runner and cache
def test_run_tasks_serial_cache_redoes_only_missing(mi, tmp_path):
    tasks = [RenderTask(DEFAULT, {"res": "8"}, spp=2, seed=s) for s in range(4)]
    keys = [task_key(render_task, t) for t in tasks]
    assert len(set(keys)) == 4 and keys[0] == task_key(render_task, RenderTask(DEFAULT, {"res": 8}, spp=2, seed=0))
    calls = []

    def counted(task):
        calls.append(task.seed)
        return render_task(task)

    cache = ResultCache(tmp_path / "cache")
    stats = {}
    first = run_tasks(counted, tasks, cache=cache, keys=keys, progress=False, stats=stats)
    assert calls == [0, 1, 2, 3] and stats == {"cached": 0, "computed": 4} and len(cache) == 4
    (tmp_path / "cache" / f"{keys[2]}.npz").unlink()  # lost one result
    (tmp_path / "cache" / f"{keys[0]}.npz").write_bytes(b"\x80\x05 truncated")  # a corrupt one
    calls.clear()
    again = run_tasks(counted, tasks, cache=cache, keys=keys, progress=False, stats=stats)
    assert sorted(calls) == [0, 2] and stats == {"cached": 2, "computed": 2}
    for x, y in zip(first, again):
        np.testing.assert_array_equal(x.image, y.image)
    assert not np.allclose(first[0].image, first[1].image)  # seeds matter
    with pytest.raises(ValueError, match="keys"):
        run_tasks(counted, tasks, keys=keys[:2], progress=False)
    with pytest.raises(TypeError, match="cache key"):
        run_tasks(counted, [object()], cache=cache, progress=False)


def test_task_key_changes_with_scene_file(tmp_path):
    scene = tmp_path / "s.xml"
    scene.write_text("<scene version='3.0.0'/>")
    key = task_key(render_task, RenderTask(str(scene)))
    scene.write_text("<scene version='3.0.0'><!-- edited --></scene>")
    assert task_key(render_task, RenderTask(str(scene))) != key


# ----------------------------------------------------------------------------- on the cluster
def test_distributed_equals_serial(mi, client):
    tasks = [RenderTask(DEFAULT, {"res": "16"}, spp=8, seed=s) for s in range(6)]
    remote = run_tasks(render_task, tasks, client=client, progress=False)
    serial = run_tasks(render_task, tasks, progress=False)
    for r, s in zip(remote, serial):
        assert int(r.worker.rsplit(":", 1)[1]) != os.getpid()  # rendered in a worker process
        assert r.timing["total"] > 0  # timed on the worker
        np.testing.assert_allclose(r.image, s.image, rtol=1e-5, atol=1e-6)
    # Tiled on the cluster equals tiled in process (same seeds).
    tiled_remote = render_tiled(DEFAULT, {"res": "16"}, tiles=(2, 2), spp=8, seed=3, client=client, progress=False)
    tiled_local = render_tiled(DEFAULT, {"res": "16"}, tiles=(2, 2), spp=8, seed=3, progress=False)
    np.testing.assert_allclose(tiled_remote.image, tiled_local.image, rtol=1e-5, atol=1e-6)


def test_task_error_reaches_the_client(client):
    from pointillist.core.errors import UsageError

    with pytest.raises(UsageError, match="no such file"):
        run_tasks(render_task, [RenderTask("/nonexistent/scene.xml")], client=client, retries=1, progress=False)


def test_connect_to_missing_scheduler_is_a_usage_error():
    pytest.importorskip("distributed")
    from pointillist.distributed import connect
    from pointillist.core.errors import UsageError

    with pytest.raises(UsageError, match="--scheduler: cannot connect"):
        connect("tcp://127.0.0.1:9", timeout=1)


def test_killed_worker_loses_no_results(mi, client, tmp_path):
    """SIGKILL a worker just after it starts a task: that task is re-run elsewhere, nothing is lost."""
    tasks = [RenderTask(DEFAULT, {"res": "24"}, spp=4096, seed=s) for s in range(6)]  # ~0.35 s each
    keys = [task_key(render_task, t) for t in tasks]
    killed: dict = {}

    def executing(dask_worker):
        return os.getpid(), [str(ts.key) if hasattr(ts, "key") else str(ts) for ts in dask_worker.state.executing]

    def killer():
        seen, first, deadline = set(), True, time.monotonic() + 60
        while time.monotonic() < deadline:
            try:
                states = client.run(executing)
            except Exception:  # noqa: BLE001 - a worker may be restarting
                states = {}
            running = {(pid, key) for pid, keys_ in states.values() for key in keys_
                       if key.startswith("pointillist-render_task-")}
            fresh = running - seen
            if fresh and not first:
                # A task this poll sees for the first time started at most ~10 ms ago: kill now.
                pid, key = next(iter(fresh))
                os.kill(pid, signal.SIGKILL)
                killed.update(pid=pid, key=key)
                return
            seen |= running
            first = False
            time.sleep(0.01)

    thread = threading.Thread(target=killer, daemon=True)
    thread.start()
    remote = run_tasks(render_task, tasks, client=client, cache=tmp_path / "cache", keys=keys, progress=False)
    thread.join(5)
    assert killed, "the test never saw a running task to kill"
    index = keys.index(killed["key"].rsplit("-", 1)[1])
    # The killed task's result came from another (or the restarted) worker process.
    assert int(remote[index].worker.rsplit(":", 1)[1]) != killed["pid"]
    assert len(ResultCache(tmp_path / "cache")) == len(tasks)
    serial = run_tasks(render_task, tasks, progress=False)
    for r, s in zip(remote, serial):
        np.testing.assert_allclose(r.image, s.image, rtol=1e-5, atol=1e-6)
    # The cluster recovered its two workers.
    client.wait_for_workers(2, timeout=30)


# ----------------------------------------------------------------------------- command line
def test_render_cli_tiles_workers_and_cache(cli, tmp_path, mi):
    from pointillist.imaging.io import read_exr

    serial, remote = tmp_path / "serial.exr", tmp_path / "remote.exr"
    common = [DEFAULT, "--spp", "4", "--seed", "2", "-D", "res=20", "--tiles", "2x3"]
    proc = cli("render", *common, "-o", serial, "--cache", tmp_path / "cache")
    assert proc.returncode == 0, proc.stderr
    proc = cli("render", *common, "-o", remote, "--workers", "2")
    assert proc.returncode == 0, proc.stderr
    assert "2x3 tiles on 2 worker(s)" in proc.stdout
    a, b = read_exr(serial), read_exr(remote)
    assert a.image.shape == (20, 20, 3) and a.metadata["tile_grid"] == "2x3" and a.metadata["seed"] == 2
    np.testing.assert_allclose(a.image, b.image, rtol=1e-5, atol=1e-6)
    expected = render_tiled(DEFAULT, {"res": "20"}, tiles=(2, 3), spp=4, seed=2, progress=False).image
    np.testing.assert_allclose(a.image, expected, rtol=1e-5, atol=1e-6)
    # A rerun with the cache renders nothing; a deleted tile is rendered again.
    next((tmp_path / "cache").glob("*.npz")).unlink()
    proc = cli("render", *common, "-o", serial, "--cache", tmp_path / "cache")
    assert proc.returncode == 0 and "5 of 6 tiles from the cache" in proc.stdout, proc.stdout + proc.stderr
    np.testing.assert_array_equal(read_exr(serial).image, a.image)


@pytest.mark.parametrize("argv, message", [
    (["--tiles", "0x2"], "--tiles"),
    (["--tiles", "30x1"], "do not fit"),
    (["--workers", "0"], "--workers"),
])
def test_render_cli_bad_distributed_options(cli, tmp_path, argv, message):
    proc = cli("render", DEFAULT, "-o", tmp_path / "x.exr", "--spp", "1", "-D", "res=20", *argv)
    assert proc.returncode == 2 and message in proc.stderr, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and "Traceback" not in proc.stderr


@pytest.mark.parametrize("command", [["render", DEFAULT], ["compare", DEFAULT], ["mip", "phantom"]])
def test_every_distributed_command_takes_workers_or_a_scheduler_not_both(cli, tmp_path, command):
    """The Dask options are declared once for the three commands: the same names, the same refusal."""
    proc = cli(*command, "--workers", "2", "--scheduler", "tcp://127.0.0.1:9")
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip() == (f"pointillist {command[0]}: error: argument --scheduler: not allowed with "
                                   "argument --workers")


@pytest.mark.slow  # ~25 s: a compare sweep twice, serial and on a cluster
def test_compare_sweep_distributed_equals_serial(cli, tmp_path):
    """`compare --workers 2` renders each (sampler, spp, seed) as a task: same renders and errors as serial."""
    import csv

    from pointillist.imaging.io import read_exr

    common = ["compare", DEFAULT, "-D", "res=12", "--spp", "1,4", "--samplers", "independent,stratified",
              "--seeds", "2", "--reference-spp", "32", "--no-progress"]
    serial = cli(*common, "--out", tmp_path / "serial")
    assert serial.returncode == 0, serial.stderr
    remote = cli(*common, "--out", tmp_path / "remote", "--workers", "2")
    assert remote.returncode == 0, remote.stderr
    # what the cluster rendered for this run is new, not reused (it read them back from the folder)
    assert "8 renders (8 new, 0 reused)" in serial.stdout and "8 renders (8 new, 0 reused)" in remote.stdout, \
        remote.stdout
    again = cli(*common, "--out", tmp_path / "remote", "--workers", "2")
    assert again.returncode == 0 and "8 renders (0 new, 8 reused)" in again.stdout, again.stdout
    assert "9 renders done on the cluster" in remote.stdout  # 8 sweep renders + the reference

    def rows(folder):
        with open(folder / "results.csv") as handle:
            return {(r["method"], r["value"], r["seed"]): r for r in csv.DictReader(handle)}

    a, b = rows(tmp_path / "serial"), rows(tmp_path / "remote")
    assert a.keys() == b.keys() and len(a) == 8
    for key in a:
        for column in ("rmse", "relmse", "flip"):
            assert float(a[key][column]) == pytest.approx(float(b[key][column]), rel=1e-4, abs=1e-6)
        assert float(b[key]["total"]) > 0  # timed (on the worker)
        np.testing.assert_allclose(read_exr(tmp_path / "serial" / a[key]["exr"]).image,
                                   read_exr(tmp_path / "remote" / b[key]["exr"]).image, rtol=1e-5, atol=1e-6)
    # Run again: everything is cached, nothing is sent to the cluster.
    again = cli(*common, "--out", tmp_path / "remote", "--workers", "2")
    assert again.returncode == 0 and "0 renders done on the cluster" in again.stdout, again.stderr


def test_mip_turntable_frames_on_workers_equal_serial(cli, tmp_path):
    """`mip --turntable N --workers 2`: each frame a task; the EXR frames equal the serial ones."""
    from pointillist.imaging.io import read_exr

    z, y, x = np.mgrid[0:10, 0:9, 0:8]
    volume = np.exp(-((x - 3.0) ** 2 + (y - 5.0) ** 2 + (z - 4.0) ** 2) / 6.0).astype(np.float32)
    volume[2, 2, 6] = 2.0  # an off-centre bright voxel: frames differ as the view turns
    np.save(tmp_path / "v.npy", volume)
    common = ["mip", tmp_path / "v.npy", "--turntable", "4", "--size", "20", "--elevation", "15"]
    serial = cli(*common, "-o", tmp_path / "s.exr")
    assert serial.returncode == 0, serial.stderr
    remote = cli(*common, "-o", tmp_path / "r.exr", "--workers", "2")
    assert remote.returncode == 0, remote.stderr
    frames = []
    for k in range(4):
        a, b = read_exr(tmp_path / f"s_{k:03d}.exr").image, read_exr(tmp_path / f"r_{k:03d}.exr").image
        np.testing.assert_allclose(b, a, rtol=1e-6, atol=1e-6)
        frames.append(a)
    assert frames[0].max() > 0.9 and not np.allclose(frames[0], frames[1])  # real, turning frames
