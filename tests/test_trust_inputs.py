"""The second round of hostile but realistic inputs: each bounded and checked before the work, with
one line and exit status 2 (reconstruction filters, file names near the file system's limit, EXR
writes that fail, damaged start-up caches, scaled volumes beyond float32, error messages that would
echo a file, more workers than tasks)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import ROOT, SCENES

FILTER_SCENE = """<scene version="3.0.0"><integrator type="path"/>
<sensor type="perspective"><film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/>
{rfilter}</film></sensor><shape type="sphere"/></scene>"""


@pytest.mark.parametrize("rfilter, radius", [
    ('<rfilter type="lanczos"><integer name="lobes" value="5000"/></rfilter>', "5000"),
    ('<rfilter type="tent"><float name="radius" value="-1"/></rfilter>', "-1"),
    ('<rfilter type="gaussian"><float name="stddev" value="5"/></rfilter>', "20"),
])
def test_reconstruction_filters_are_bounded_before_the_render(cli, tmp_path, rfilter, radius):
    """They ran for minutes on an 8x8 film (still running after 180 s)."""
    (tmp_path / "f.xml").write_text(FILTER_SCENE.format(rfilter=rfilter))
    done = cli("render", tmp_path / "f.xml", "-o", tmp_path / "f.exr", timeout=120)
    assert done.returncode == 2, done.stderr
    assert "reconstruction filter" in done.stderr and f"has radius {radius} pixels; expected more than 0 and at " \
        "most 16" in done.stderr and len(done.stderr.splitlines()) == 1
    (tmp_path / "ok.xml").write_text(FILTER_SCENE.format(rfilter='<rfilter type="gaussian"><float name="stddev" '
                                                                  'value="4"/></rfilter>'))
    assert cli("render", tmp_path / "ok.xml", "-o", tmp_path / "ok.exr").returncode == 0


@pytest.mark.parametrize("command", ["render", "post", "mip"])
def test_output_names_too_long_for_the_temporary_file_are_refused_before_the_work(cli, tmp_path, command):
    name = "n" * (255 - len(".exr") - 3)      # fits the folder, not the temporary file beside it
    suffix = ".png" if command != "render" else ".exr"
    args = {"render": [SCENES / "default.xml", "-D", "res=8"], "post": [SCENES / "sun_sky.exr"],
            "mip": [SCENES / "phantom64.vol"]}[command]
    done = cli(command, *args, "-o", tmp_path / (name + suffix))
    assert done.returncode == 2, done.stderr
    assert "bytes long; at most 237 fit in" in done.stderr and len(done.stderr.splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


def test_an_exr_that_cannot_be_written_is_one_line_and_leaves_nothing(tmp_path):
    """``ulimit -f`` (a full disk behaves the same): it was "internal error: RuntimeError" with exit 1."""
    out = tmp_path / "big.exr"
    script = (f"ulimit -f 1; exec {sys.executable} -m pointillist render {SCENES / 'default.xml'} -D res=64 "
              f"-o {out}")
    done = subprocess.run(["bash", "-c", script], capture_output=True, text=True, cwd=ROOT, timeout=300)
    lines = [line for line in done.stderr.splitlines() if not line.startswith("jit_kernel_write")]
    assert done.returncode == 2, done.stderr
    assert lines == [f"pointillist render: error: cannot write {out}: File too large"]
    assert list(tmp_path.iterdir()) == []


def test_write_exr_raises_oserror_naming_the_file(tmp_path, monkeypatch):
    import OpenEXR

    from pointillist.imaging.io import write_exr

    class Full:
        def __init__(self, *args):
            pass

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def write(self, name):
            raise RuntimeError(f'Failed to write pixel data to image file "{name}". No space left on device')

    monkeypatch.setattr(OpenEXR, "File", Full)
    with pytest.raises(OSError) as raised:
        write_exr(tmp_path / "x.exr", np.zeros((2, 2, 3), np.float32))
    assert raised.value.strerror == f"cannot write {tmp_path / 'x.exr'}: No space left on device"
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("content", ["[true]", "[]", "null", '{"x": true}', "{", '{"k": [1, 2, 3]}'])
def test_a_damaged_libllvm_cache_is_probed_again(cli, tmp_path, content):
    """Every command failed with such a ~/.cache/pointillist/llvm.json."""
    (tmp_path / "pointillist").mkdir()
    (tmp_path / "pointillist" / "llvm.json").write_text(content)
    env = {"XDG_CACHE_HOME": str(tmp_path)}
    env.pop("DRJIT_LIBLLVM_PATH", None)
    done = cli("render", SCENES / "default.xml", "-D", "res=8", "-o", tmp_path / "d.exr",
               env=dict(env, DRJIT_LIBLLVM_PATH=""))
    assert done.returncode == 0, done.stderr
    assert isinstance(json.loads((tmp_path / "pointillist" / "llvm.json").read_text()), dict)


def test_an_unusable_drjit_libllvm_path_is_said_then_another_is_used(cli, tmp_path):
    """It was silently ignored."""
    missing = tmp_path / "libLLVM-19.so"
    done = cli("render", SCENES / "default.xml", "-D", "res=8", "-o", tmp_path / "d.exr",
               env={"DRJIT_LIBLLVM_PATH": str(missing)})
    assert done.returncode == 0, done.stderr
    assert f"pointillist render: warning: DRJIT_LIBLLVM_PATH: {missing} (no such file); using " in done.stderr


def test_a_nifti_scaled_beyond_float32_is_refused(cli, tmp_path):
    """scl_slope 1e38 gave an image of inf with exit 0 and numpy's "overflow encountered in cast"."""
    nibabel = pytest.importorskip("nibabel")
    image = nibabel.Nifti1Image(np.arange(27, dtype=np.int16).reshape(3, 3, 3), np.eye(4))
    image.header.set_slope_inter(1e38, 0)
    nibabel.save(image, tmp_path / "big.nii")
    done = cli("mip", tmp_path / "big.nii", "-o", tmp_path / "big.png")
    assert done.returncode == 2
    assert done.stderr == (f"pointillist mip: error: volume: {tmp_path / 'big.nii'}: scl_slope 1e+38 and scl_inter 0 "
                           "take its values beyond float32 (|x| <= 3.4e38)\n")
    image.header.set_slope_inter(2.0, 1.0)                       # an ordinary scaling still reads
    nibabel.save(image, tmp_path / "ok.nii")
    from pointillist.imaging.volumes import read_nifti

    assert float(np.asarray(read_nifti(tmp_path / "ok.nii").data).max()) == 2.0 * 26 + 1.0


def test_a_lut_file_that_is_not_numbers_is_named_not_shown(cli, tmp_path):
    """The message quoted the file's first line (``lut:file=/etc/shadow`` printed a password hash)."""
    secret = tmp_path / "secret"
    secret.write_text("0\n1\nroot:$6$hash:19000:0:99999:7:::\n")
    done = cli("post", SCENES / "sun_sky.exr", "-o", tmp_path / "p.png", "--steps", f"lut:file={secret}")
    assert done.returncode == 2 and "root:" not in done.stderr and "hash" not in done.stderr
    assert f"{secret} is not a table of numbers (row 3 is not a number)" in done.stderr


def test_no_more_local_workers_than_tasks(monkeypatch):
    """``--workers 12`` for 4 tiles started 14 processes."""
    from pointillist import distributed

    started = []

    class Client:
        cluster = None

        def close(self):
            pass

    monkeypatch.setattr(distributed, "start_cluster", lambda n, **_: started.append(n) or Client())
    with pytest.warns(UserWarning, match=r"--workers 12: only 4 task\(s\) to run; starting 4 worker\(s\)"):
        with distributed.open_client(12, None, tasks=4):
            pass
    with distributed.open_client(3, None, tasks=4):
        pass
    assert started == [4, 3]


def test_a_scene_file_naming_a_device_is_refused(cli, tmp_path):
    """A PLY named /dev/zero read until 4.3 GB."""
    (tmp_path / "dev.xml").write_text(FILTER_SCENE.format(rfilter="").replace(
        '<shape type="sphere"/>', '<shape type="ply"><string name="filename" value="/dev/zero"/></shape>'))
    done = cli("render", tmp_path / "dev.xml", "-o", tmp_path / "d.exr", timeout=60)
    assert done.returncode == 2 and "filename '/dev/zero' is /dev/zero, not a regular file" in done.stderr
    os.mkfifo(tmp_path / "pipe.ply")
    (tmp_path / "fifo.xml").write_text(FILTER_SCENE.format(rfilter="").replace(
        '<shape type="sphere"/>', '<shape type="ply"><string name="filename" value="pipe.ply"/></shape>'))
    done = cli("render", tmp_path / "fifo.xml", "-o", tmp_path / "f.exr", timeout=60)
    assert done.returncode == 2 and "not a regular file (a device, a pipe or a socket" in done.stderr


def test_films_beyond_one_tensor_or_the_memory_are_refused_before_the_render(cli, tmp_path):
    """A 30000 x 30000 film segfaulted (nothing printed); a 2147483647 x 1 film failed inside Mitsuba."""
    from pointillist.core.checks import available_memory

    scene = FILTER_SCENE.format(rfilter="").replace('value="8"/><integer name="height" value="8"',
                                                    'value="$w"/><integer name="height" value="$h"').replace(
        "</film>", '</film><sampler type="independent"><integer name="sample_count" value="1"/></sampler>')
    (tmp_path / "s.xml").write_text(scene)
    done = cli("render", tmp_path / "s.xml", "-D", "w=2147483647", "-D", "h=1", "-o", tmp_path / "a.exr")
    assert done.returncode == 2 and "more than one tensor holds (2^32 - 1)" in done.stderr, done.stderr
    side = int((available_memory() / 12 / 4) ** 0.5) + 1000   # film x 3 copies x 4 bytes x (3 colours + weight)
    done = cli("render", tmp_path / "s.xml", "-D", f"w={side}", "-D", f"h={side}", "-o", tmp_path / "b.exr")
    assert done.returncode == 2 and "GiB of memory available" in done.stderr, done.stderr
    assert list(p.name for p in tmp_path.iterdir()) == ["s.xml"]


def test_an_exr_whose_display_window_needs_more_memory_than_there_is(tmp_path, cli):
    """8x8 pixels in a 20000 x 20000 display window asked for gigabytes (MemoryError, or the kernel's
    out-of-memory killer) in post and compare --reference."""
    import OpenEXR

    from pointillist.core.checks import available_memory
    from pointillist.post import POST_COPIES

    side = int((available_memory() / 4 / POST_COPIES / 3) ** 0.5) + 1000
    if side * side * 3 > 2**31 - 1:
        pytest.skip("this machine has the memory for any EXR read can make (2^31 - 1 values)")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              "dataWindow": ((0, 0), (7, 7)), "displayWindow": ((0, 0), (side - 1, side - 1))}
    with OpenEXR.File(header, {"RGB": np.ones((8, 8, 3), np.float32)}) as exr:
        exr.write(str(tmp_path / "window.exr"))
    done = cli("post", tmp_path / "window.exr", "-o", tmp_path / "w.png")
    assert done.returncode == 2 and f"its display window {side} x {side}" in done.stderr, done.stderr
    assert "GiB of memory available" in done.stderr and len(done.stderr.splitlines()) == 1


def test_memory_check_says_what_needs_how_much():
    from pointillist.core.checks import available_memory, memory

    free = available_memory()
    assert 0 < free < 2**63 - 1
    memory(free // 2, "half")
    with pytest.raises(ValueError, match=r"^the film needs .* bytes \(.* GiB\), more than the .* GiB of memory"):
        memory(free * 2, "the film")


def test_an_nrrd_data_file_is_an_input_and_one_outside_its_folder_is_said(cli, tmp_path):
    """mip head.nhdr -o X where the header's data file is X overwrote it, exit 0."""
    pytest.importorskip("nrrd")
    raw = np.arange(64, dtype=np.uint8).tobytes()
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "out.png").write_bytes(raw)
    (tmp_path / "data" / "head.nhdr").write_text("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 4 4 4\n"
                                                 "encoding: raw\ndata file: out.png\n")
    done = cli("mip", tmp_path / "data" / "head.nhdr", "-o", tmp_path / "data" / "out.png")
    assert done.returncode == 2 and "refusing to overwrite the input file" in done.stderr
    assert (tmp_path / "data" / "out.png").read_bytes() == raw
    (tmp_path / "outside.raw").write_bytes(raw)
    (tmp_path / "data" / "up.nhdr").write_text("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 4 4 4\n"
                                               "encoding: raw\ndata file: ../outside.raw\n")
    done = cli("mip", tmp_path / "data" / "up.nhdr", "-o", tmp_path / "up.png")
    assert done.returncode == 0, done.stderr
    assert "outside.raw lies outside the header's folder" in done.stderr

    from pointillist.imaging.volumes import volume_files

    with pytest.warns(UserWarning, match="outside the header's folder"):
        assert volume_files(tmp_path / "data" / "up.nhdr") == [tmp_path / "data" / "up.nhdr",
                                                               tmp_path / "data" / ".." / "outside.raw"]
    assert volume_files(SCENES / "phantom64.vol") == [SCENES / "phantom64.vol"]


@pytest.mark.parametrize("command", ["render", "mip"])
def test_a_deleted_current_folder_is_said_in_one_line(tmp_path, command):
    """It was "internal error: ImportError" (and an abort with POINTILLIST_DEBUG=1): Mitsuba's file
    resolver starts from the current folder."""
    args = {"render": f"render {SCENES / 'default.xml'} -D res=8 -o {tmp_path / 'r.exr'}",
            "mip": f"mip {SCENES / 'phantom64.vol'} -o {tmp_path / 'm.png'}"}[command]
    gone = tmp_path / "gone"
    script = f"mkdir {gone} && cd {gone} && rmdir {gone} && exec {sys.executable} -m pointillist {args}"
    for debug in ("", "1"):
        done = subprocess.run(["bash", "-c", script], capture_output=True, text=True, timeout=300,
                              env=dict(os.environ, POINTILLIST_DEBUG=debug))
        assert done.returncode == 2, done.stderr
        assert done.stderr == (f"pointillist {command}: error: the current folder no longer exists (it was deleted "
                               "or moved); change to an existing folder first\n")


def test_the_result_cache_holds_data_and_never_unpickles(tmp_path, mi):
    """The tile cache and the Dask result cache were pickle files: a planted .pkl ran a shell command
    on the next render. Results are now numpy arrays and JSON with their SHA-256."""
    import pickle

    from pointillist.distributed import ResultCache
    from pointillist.tiles import RenderResult, RenderTask

    ran = tmp_path / "ran"

    class Planted:
        def __reduce__(self):
            return (os.system, (f"touch {ran}",))

    cache = ResultCache(tmp_path / "cache")
    result = RenderResult(image=np.arange(12, dtype=np.float32).reshape(2, 2, 3),
                          timing={"total": 0.5, "compile": float("nan")}, worker="host:1",
                          task=RenderTask("s.xml", (("res", "8"),), spp=4, seed=7, crop=(0, 0, 2, 2)))
    cache.put("k1", result)
    back = cache.get("k1")
    assert back.task == result.task and back.worker == "host:1" and back.timing["total"] == 0.5
    assert np.isnan(back.timing["compile"]) and np.array_equal(back.image, result.image)
    assert back.image.dtype == np.float32
    # a planted pickle under a key's name, and under the cache's own suffix
    (tmp_path / "cache" / "k2.pkl").write_bytes(pickle.dumps(Planted()))
    (tmp_path / "cache" / "k3.npz").write_bytes(pickle.dumps(Planted()))
    with pytest.warns(UserWarning, match=r"ignoring 1 file\(s\) that are not pointillist's results \(k2.pkl\)"):
        again = ResultCache(tmp_path / "cache")
    assert again.get("k2") is None and again.get("k3") is None and not ran.exists()
    # a result changed on disk (its digest no longer matches), or naming a class nobody registered
    with np.load(tmp_path / "cache" / "k1.npz", allow_pickle=False) as data:
        arrays = {name: data[name] for name in data.files}
    arrays["a0"] = arrays["a0"] + 1
    np.savez(tmp_path / "cache" / "k4.npz", **arrays)
    description = str(arrays["__result__"]).replace("pointillist.tiles:RenderResult", "os:system")
    np.savez(tmp_path / "cache" / "k5.npz", **dict(arrays, __result__=np.array(description)))
    assert again.get("k4") is None and again.get("k5") is None
    with pytest.raises(TypeError, match="cannot store a Planted as data"):
        cache.put("k6", Planted())


@pytest.mark.parametrize("channels, extra, message", [
    ({"Y": 1.0, "RY": 0.0, "BY": 0.0}, {}, "stores luminance and chroma (Y, RY, BY"),
    ({"A": 1.0}, {}, "has no Y or RGB channels (has ['A'])"),
    ({"R": 1.0, "G": 1.0, "B": 1.0}, {"dataWindow": ((100, 100), (103, 103)), "displayWindow": ((0, 0), (7, 7))},
     "its data window (100, 100, 103, 103) lies wholly outside its display window (0, 0, 7, 7)"),
])
def test_exrs_that_would_be_read_wrongly_are_refused(tmp_path, cli, channels, extra, message):
    """An EXR with Y/RY/BY channels was read as grey, one with only A was processed as the image, and a
    data window outside the display window gave an all-black image without a word."""
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, **extra}
    with OpenEXR.File(header, {name: np.full((4, 4), value, np.float32) for name, value in channels.items()}) as exr:
        exr.write(str(tmp_path / "in.exr"))
    done = cli("post", tmp_path / "in.exr", "-o", tmp_path / "out.png")
    assert done.returncode == 2 and message in done.stderr and len(done.stderr.splitlines()) == 1, done.stderr


def test_results_md_shows_a_scene_name_as_text(cli, tmp_path):
    """results.md's heading carried a scene name's raw HTML."""
    name = "<img src=x onerror=alert(1)>`*_.xml"
    (tmp_path / name).write_bytes((SCENES / "edges.xml").read_bytes())
    done = cli("compare", tmp_path / name, "--samplers", "jitter", "--spp", "1", "--reference-spp", "2",
               "-D", "res=8", "--out", tmp_path / "cmp")
    assert done.returncode == 0, done.stderr
    text = (tmp_path / "cmp" / "results.md").read_text()
    assert text.splitlines()[0] == r"# Sampler comparison: &lt;img src=x onerror=alert\(1\)&gt;\`\*\_.xml"
    assert f"Scene `` {tmp_path / name} ``" in text   # a code span: shown as text, whatever it holds


# ------------------------------------------------------------------ a signal during a long kernel
_LONG_KERNEL = textwrap.dedent("""
    import os, signal, sys, threading, time
    import drjit as dr
    from pointillist.console import main

    real = {"eval": dr.eval, "sync_thread": dr.sync_thread}
    hung = []

    def send():
        time.sleep(0.3)
        print("signal sent at", time.monotonic(), flush=True)  # the moment of the signal, on the system-wide clock
        os.kill(os.getpid(), signal.SIGTERM)

    def hang(name):
        def call(*args, **kwargs):
            if not hung and threading.current_thread() is threading.main_thread():
                hung.append(1)  # the first kernel the command waits for runs for ten minutes: a
                # native call that does not return (the signal lands in another thread)
                signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
                threading.Thread(target=send, daemon=True).start()
                time.sleep(600)
            return real[name](*args, **kwargs)
        return call

    dr.eval, dr.sync_thread = hang("eval"), hang("sync_thread")
    sys.argv = ["pointillist"] + sys.argv[1:]
    main()
""")


def _no_live_process_in_group(pgid: int) -> bool:
    """Whether the process group ``pgid`` has no process left but zombies (a container's first
    process may not reap the orphans it inherits)."""
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":
            return False
    return True


def _stopped_by_sigterm(argv: list, *, driver: str | None = None, wait: float | None = None) -> tuple:
    """Run ``pointillist *argv`` in a session of its own and SIGTERM it once (the driver sends it
    and prints when; else ``wait`` seconds after the start): (seconds to its end, stderr lines)."""
    command = [sys.executable, "-c", driver] if driver else [sys.executable, "-m", "pointillist"]
    proc = subprocess.Popen(command + [str(a) for a in argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, cwd=ROOT, start_new_session=True)
    try:
        if driver:
            sent = next(float(line.split()[-1]) for line in proc.stdout if line.startswith("signal sent at"))
        else:
            time.sleep(wait)
            assert proc.poll() is None, proc.communicate()
            sent = time.monotonic()
            proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=120)
        seconds = time.monotonic() - sent
        stderr = proc.stderr.read()
    finally:
        proc.kill()
        proc.communicate()
    assert proc.returncode == 143, stderr
    deadline = time.monotonic() + 5
    while not _no_live_process_in_group(proc.pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert _no_live_process_in_group(proc.pid)  # no worker, child render or helper left running
    return seconds, stderr.splitlines()


def _long_kernel_commands(folder: Path) -> dict[str, list]:
    from PIL import Image

    Image.fromarray(np.arange(256, dtype=np.uint8).reshape(16, 16)).save(folder / "img.png")
    np.save(folder / "vol.npy", np.arange(512, dtype=np.float32).reshape(8, 8, 8))
    scene = SCENES / "default.xml"
    return {
        "render": ["render", scene, "-D", "res=16", "--spp", "4", "-o", folder / "r.exr"],
        "progressive": ["render", scene, "-D", "res=16", "--spp", "64", "--pass-spp", "4", "--checkpoint", "0.01",
                        "-o", folder / "p.exr"],
        "compare": ["compare", scene, "-D", "res=8", "--samplers", "independent", "--spp", "1,4",
                    "--reference-spp", "16", "--no-progress", "--out", folder / "c"],
        "post": ["post", folder / "img.png", "-o", folder / "x.png", "--steps", "gamma:2;sobel"],
        "mip": ["mip", folder / "vol.npy", "-o", folder / "m.png", "--size", "16", "--turntable", "2"],
    }


@pytest.mark.parametrize("command", ["render", "progressive", "compare", "post", "mip"])
def test_one_sigterm_during_a_long_kernel_ends_every_command_within_two_seconds(tmp_path, command):
    """Defect 7: one SIGTERM to a command whose kernel runs for minutes was held until the kernel
    ended. Now, if the command has not stopped by itself a second after the signal, it is stopped
    at once: exit 143 within 2 s of the signal, one line, no temporary file."""
    from pointillist.core.signals import STOP_SECONDS

    argv = _long_kernel_commands(tmp_path)[command]
    before = set(tmp_path.rglob("*"))
    seconds, lines = _stopped_by_sigterm(argv, driver=_LONG_KERNEL)
    assert seconds <= 2.0 and STOP_SECONDS < 2.0, seconds
    assert lines == ["pointillist %s: terminated (SIGTERM); stopped at once (it did not stop within 1 s)"
                     % argv[0]], lines
    assert not [p for p in set(tmp_path.rglob("*")) - before if ".tmp" in p.name or p.suffix in (".exr", ".png")]


@pytest.mark.slow
@pytest.mark.parametrize("options", [["render", "--spp", "262144"],
                                     ["render", "--spp", "262144", "--tiles", "2x1", "--workers", "2"],
                                     ["verify", "--spp", "65536"]],
                         ids=["one-pass", "dask-workers", "verify-child-process"])
def test_one_sigterm_during_a_real_render_pass_ends_it_within_two_seconds(tmp_path, options):
    """The same with Dr.Jit's own kernel: a 64x64 pass of 2^18 spp runs for minutes here; SIGTERM
    once it runs (8 s after the start) ends the command within 2 s, its Dask workers and the
    process ``verify`` renders in too."""
    command, *options = options
    out = ["-o", tmp_path / "long.exr"] if command == "render" else []
    seconds, lines = _stopped_by_sigterm([command, SCENES / "default.xml", "-D", "res=64", *options, *out], wait=8.0)
    assert seconds <= 2.0, seconds
    assert len(lines) == 1 and lines[0].startswith(f"pointillist {command}: terminated (SIGTERM)"), lines
    assert list(tmp_path.iterdir()) == []


def test_pass_spp_under_a_time_budget_never_outlasts_it(cli, tmp_path):
    """Defect 7: ``--pass-spp 100000000 --time 1`` ran one pass of 323 s. Under ``--time`` the
    first pass (its cost unknown) takes no more than an auto first pass, the others what fits."""
    import math

    from pointillist.progressive import FIRST_PASS_SAMPLES, Budget, PassStats
    from pointillist.progressive.budget import _pow2_floor

    start = PassStats(0, 0, 0, 0.0, 0.0, 0.0, 0.0, math.nan, 64, 64)
    assert Budget(seconds=1, pass_spp=10**8)(start) == _pow2_floor(FIRST_PASS_SAMPLES // 64**2) == 64
    assert Budget(seconds=1, pass_spp=4)(start) == 4                   # a smaller pass is kept
    assert Budget(spp=10**9, pass_spp=10**8)(start) == 2**32 // 64**2 // 2  # no time budget: the largest pass
    out = tmp_path / "t.exr"
    done = cli("render", SCENES / "default.xml", "-D", "res=64", "--pass-spp", "100000000", "--time", "1", "-o", out)
    assert done.returncode == 0, done.stderr
    from pointillist.imaging.io import read_exr

    _, meta, _ = read_exr(out)
    assert meta["stopped_by"] == "time" and meta["passes"] >= 2


def test_turntable_and_seeds_are_bounded(cli, tmp_path):
    """Smaller ones: ``--turntable 100000`` wrote 4,237 frames in 150 s before it was stopped (and
    holds every frame for the GIF); ``--seeds 100000`` was accepted without a word."""
    from pointillist.mip import MAX_TURNTABLE_FRAMES, _plan_outputs

    done = cli("mip", SCENES / "phantom64.vol", "-o", tmp_path / "t.png", "--size", "16", "--turntable", "100000")
    assert done.returncode == 2 and done.stderr.splitlines() == [
        "pointillist mip: error: --turntable: expected at most 3600 frames (one every 0.1 degree), got 100000"]
    done = cli("compare", SCENES / "default.xml", "--seeds", "1001", "--out", tmp_path / "c")
    assert done.returncode == 2 and done.stderr.splitlines() == [
        "pointillist compare: error: --seeds: expected an integer in 1..1000, got 1001"]
    assert list(tmp_path.iterdir()) == []
    # frame names sort in frame order however many frames there are
    names, _, _ = _plan_outputs(SCENES / "phantom64.vol", tmp_path / "t.png", MAX_TURNTABLE_FRAMES)
    assert [n.name for n in (names[0], names[999], names[-1])] == ["t_0000.png", "t_0999.png", "t_3599.png"]
    assert sorted(names) == names
    names, _, _ = _plan_outputs(SCENES / "phantom64.vol", tmp_path / "t.png", 12)
    assert [n.name for n in (names[0], names[-1])] == ["t_000.png", "t_011.png"]


def test_grey_with_alpha_stays_grey_and_post_warns_as_every_command(cli, tmp_path):
    """New round: a grey+alpha PNG came out as RGB, and post's warnings read ``post: warning:``
    where every other command says ``pointillist CMD: warning:``. Grey+alpha reads as (H, W, 2), as
    scikit-image's ``imread`` reads it; post drops the alpha and keeps the grey."""
    import skimage.io
    from PIL import Image

    from pointillist.imaging.io import read_image

    grey = np.arange(64, dtype=np.uint8).reshape(8, 8) * 4
    Image.fromarray(np.dstack([grey, np.full_like(grey, 200)]), "LA").save(tmp_path / "la.png")
    image, _, _ = read_image(tmp_path / "la.png")
    assert image.shape == (8, 8, 2) == skimage.io.imread(tmp_path / "la.png").shape
    np.testing.assert_array_equal(image[..., 0], grey)
    done = cli("post", tmp_path / "la.png", "-o", tmp_path / "out.png", "--steps", "gamma:1")
    assert done.returncode == 0, done.stderr
    assert done.stderr.splitlines() == [
        "pointillist post: warning: the input's alpha channel is dropped (the steps run on grey)"]
    with Image.open(tmp_path / "out.png") as out:
        assert out.mode == "L"
        np.testing.assert_array_equal(np.asarray(out), grey)


def test_file_names_that_are_not_utf8(cli, tmp_path):
    """New round: an EXR named with bytes that are not UTF-8 (a Latin-1 name on a UTF-8 system) was
    refused by OpenEXR after the render ("use write(path: str)..."), and such a scene gave four lines
    of nanobind's signature. EXRs now go through Python files (any name the system takes); Mitsuba
    reads only UTF-8 names, so such a scene is refused in one line before the work."""
    import shutil

    from pointillist.imaging.io import read_exr

    folder = os.fsencode(tmp_path)
    exr = os.fsdecode(folder + b"/r\xff.exr")
    done = cli("render", SCENES / "default.xml", "-D", "res=8", "--spp", "4", "-o", exr)
    assert done.returncode == 0, done.stderr
    image, meta, _ = read_exr(exr)
    assert image.shape == (8, 8, 3) and meta["spp"] == 4
    png = os.fsdecode(folder + b"/p\xff.png")
    assert cli("post", exr, "-o", png).returncode == 0 and os.path.isfile(png)
    scene = os.fsdecode(folder + b"/s\xff.xml")
    shutil.copy(SCENES / "default.xml", scene)
    for command in (["render", scene, "-o", tmp_path / "x.exr"], ["verify", scene]):
        done = cli(*command)
        assert done.returncode == 2 and len(done.stderr.splitlines()) == 1, done.stderr
        assert "is not UTF-8 text, and Mitsuba reads only UTF-8 file names" in done.stderr


@pytest.mark.parametrize("encoding, compress", [("gzip", "gzip"), ("bzip2", "bz2")])
@pytest.mark.parametrize("detached", [False, True], ids=["attached", "detached"])
def test_a_compressed_nrrd_that_inflates_beyond_its_header_is_refused_while_streaming(tmp_path, encoding, compress,
                                                                                         detached):
    """New round: a 3 MB gzip NRRD whose header says 8x8x8 bytes inflated to 3 GB (6.4 GB of
    memory, 25 s) before pynrrd's size error. The data is now measured while it streams: 64 MB of
    zeros behind an 8x8x8 header is refused after a megabyte; the same header with its 512 bytes reads."""
    import bz2
    import gzip
    import tracemalloc

    from pointillist.imaging.volumes import load_volume

    codec = {"gzip": gzip, "bz2": bz2}[compress]
    header = f"NRRD0004\ntype: uchar\ndimension: 3\nsizes: 8 8 8\nencoding: {encoding}\n"
    good = np.arange(512, dtype=np.uint8)
    for name, payload in (("bomb", bytes(64 << 20)), ("good", good.tobytes())):
        data = codec.compress(payload)
        if detached:
            (tmp_path / f"{name}.raw.gz").write_bytes(data)
            (tmp_path / f"{name}.nhdr").write_text(header + f"data file: {name}.raw.gz\n\n")
        else:
            (tmp_path / f"{name}.nrrd").write_bytes(header.encode() + b"\n" + data)
    suffix = ".nhdr" if detached else ".nrrd"
    tracemalloc.start()
    with pytest.raises(ValueError, match=f"its {encoding} data inflates to more than the 512 bytes"):
        load_volume(tmp_path / f"bomb{suffix}")
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 16 << 20, peak
    with pytest.warns(UserWarning, match="without 'space directions'"):
        volume = load_volume(tmp_path / f"good{suffix}")
    np.testing.assert_array_equal(np.asarray(volume.data).ravel(), good)


@pytest.mark.parametrize("make, says", [
    (lambda tmp: "", "expected a file name, got an empty one"),
    (lambda tmp: tmp, "is a folder, expected a file"),
    (lambda tmp: "/dev/null", "is not a regular file (a device, a pipe or a socket: it may never end)"),
    (lambda tmp: (os.mkfifo(tmp / "fifo"), tmp / "fifo")[1], "is not a regular file"),
    (lambda tmp: tmp / "missing.png", "no such file"),
], ids=["empty", "folder", "device", "fifo", "missing"])
def test_an_input_that_is_not_a_file_says_what_it_is(cli, tmp_path, make, says):
    """New round: a folder, a FIFO, /dev/stdin and /dev/null given as post's input, a LUT file or
    compare's reference were all "no such file"; an empty name meant the current folder."""
    name = make(tmp_path)
    image = tmp_path / "in.png"
    from PIL import Image

    Image.fromarray(np.zeros((4, 4), np.uint8)).save(image)
    for argv, prefix in ((["post", name, "-o", tmp_path / "o.png"], "input"),
                         (["post", image, "-o", tmp_path / "o.png", "--steps", f"lut:file={name}"],
                          "--steps: lut: file"),
                         (["compare", SCENES / "default.xml", "--reference", name, "--out", tmp_path / "c"],
                          "--reference"),
                         (["render", name, "-o", tmp_path / "r.exr"], "scene")):
        done = cli(*argv, timeout=60)
        assert done.returncode == 2 and len(done.stderr.splitlines()) == 1, (argv, done.stderr)
        if name == "":  # the parser refuses an empty argument first: "argument --reference: expected a value, ..."
            assert "got an empty one" in done.stderr, (argv, done.stderr)
            continue
        assert f": error: {prefix}: " in done.stderr and says in done.stderr, (argv, done.stderr)


@pytest.mark.parametrize("argv", [
    ["render", SCENES / "default.xml", "-o", ""],
    ["mip", "", "-o", "{tmp}/m.png"],
    ["verify", ""],
    ["mip", SCENES / "phantom64.vol", "-o", "{tmp}/m.png", "--window", " "],
    ["post", SCENES / "sun_sky.exr", "-o", "{tmp}/p.png", "--steps", ""],
], ids=["output", "volume", "verify-scenes", "window", "steps"])
def test_an_empty_argument_is_refused(cli, tmp_path, argv):
    """New round: ``-o ''`` said "folder out does not exist", ``mip ''`` read the current folder as a
    DICOM series, ``verify ''`` checked every scene under the current folder, ``--window ''`` meant
    the default. An empty or blank value is now a usage error naming the argument."""
    done = cli(*[str(a).format(tmp=tmp_path) for a in argv], cwd=tmp_path)
    assert done.returncode == 2 and len(done.stderr.splitlines()) == 1, done.stderr
    assert "expected a value, got an empty one" in done.stderr
    assert list(tmp_path.iterdir()) == []


def test_non_finite_images_are_said(cli, tmp_path):
    """New round: a scene whose light is NaN rendered an image of NaN with exit 0 and no word (a
    progressive render warned); ``post`` turned NaN into black without a word when no step ran (the
    tone steps warn); an all-NaN volume projected to an image of zeros silently."""
    scene = tmp_path / "nan.xml"
    scene.write_text('<scene version="3.0.0"><integrator type="path"/><sensor type="perspective"><film type="hdrfilm">'
                     '<integer name="width" value="8"/><integer name="height" value="4"/></film></sensor>'
                     '<emitter type="constant"><rgb name="radiance" value="nan"/></emitter></scene>')
    for extra in ([], ["--tiles", "2x1"]):
        done = cli("render", scene, "-o", tmp_path / "nan.exr", *extra)
        assert done.returncode == 0, done.stderr
        assert done.stderr.splitlines() == ["pointillist render: warning: 32 of 32 pixels are NaN or inf (the scene "
                                            "or its integrator gives non-finite values); they stay so in the image"]
    done = cli("post", tmp_path / "nan.exr", "-o", tmp_path / "nan.png")
    assert done.returncode == 0 and done.stderr.splitlines() == [
        "pointillist post: warning: the preview replaced 96 non-finite value(s) (NaN -> 0, +inf -> white, -inf -> 0)"]
    np.save(tmp_path / "nan.npy", np.full((4, 4, 4), np.nan, np.float32))
    done = cli("mip", tmp_path / "nan.npy", "-o", tmp_path / "m.exr", "--size", "8")
    assert done.returncode == 0 and "no voxel is finite (all NaN or inf)" in done.stderr
    done = cli("render", SCENES / "default.xml", "-D", "res=8", "-o", tmp_path / "fine.exr")
    assert done.returncode == 0 and done.stderr == ""  # a finite image: no word


_REOPENING_WRITER = textwrap.dedent("""
    import os, signal, sys, time
    from PIL import Image
    from pointillist.console import main

    def save(self, fp, *args, **kwargs):  # a writer that opens its file by name again and again (as
        os.kill(os.getpid(), signal.SIGTERM)  # matplotlib and Pillow do), stopped at once meanwhile
        os.kill(os.getpid(), signal.SIGTERM)
        for _ in range(3000):
            with open(fp, "wb") as handle:
                handle.write(b"partial")
            time.sleep(0.001)

    Image.Image.save = save
    sys.argv = ["pointillist"] + sys.argv[1:]
    main()
""")


def test_a_writer_that_reopens_its_file_by_name_leaves_nothing(tmp_path):
    """Found by the twenty-moments test: a signal that stopped ``post --plot`` while matplotlib wrote
    the histogram left its temporary file: the file was removed, then the writer (which opens it by
    name) made it again before the exit. Removing the files and ending the process now happen
    without another thread running Python in between."""
    from PIL import Image

    Image.fromarray(np.zeros((8, 8), np.uint8)).save(tmp_path / "in.png")
    out = tmp_path / "out"
    out.mkdir()
    for _ in range(5):
        done = subprocess.run([sys.executable, "-c", _REOPENING_WRITER, "post", str(tmp_path / "in.png"), "-o",
                               str(out / "x.png"), "--steps", "gamma:2"], capture_output=True, text=True,
                              timeout=120, cwd=ROOT)
        assert done.returncode == 143, done.stderr
        assert done.stderr.splitlines() == ["pointillist post: terminated (SIGTERM); stopped at once (second signal)"]
        assert list(out.iterdir()) == []


def test_inside_a_notebook_one_signal_never_ends_the_process(tmp_path):
    """The deadline is the console script's (it owns the process): the command line run inside a
    notebook (``pointillist.cli.main``) keeps the first signal a request, stopped at the next safe
    point, however long that takes; the process lives on."""
    code = textwrap.dedent("""
        import os, signal, threading, time
        import pointillist.post as post
        from pointillist.cli import main

        real = post.apply_steps

        def slow(*args, **kwargs):  # a step that returns to Python only after 3 s
            threading.Timer(0.2, os.kill, (os.getpid(), signal.SIGINT)).start()
            time.sleep(3)
            return real(*args, **kwargs)

        post.apply_steps = slow
        print("status", main(["post", %r, "-o", %r, "--steps", "gamma:2"]), flush=True)
        print("still alive")
    """) % (str(SCENES / "sun_sky.exr"), str(tmp_path / "never.png"))
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert done.stdout.split() == ["status", "130", "still", "alive"], (done.stdout, done.stderr)
    assert done.stderr.splitlines() == ["pointillist post: interrupted"] and list(tmp_path.iterdir()) == []


_STOPPED_IN_A_NEW_FOLDER = textwrap.dedent("""
    import os, signal, sys, time
    from pathlib import Path
    from pointillist.core import signals
    from pointillist.console import main

    def run():  # a write into folders made for it, stopped at once in the middle
        out = Path(sys.argv[1]) / "a" / "b" / "x.txt"
        with signals.new_folders(out):
            os.kill(os.getpid(), signal.SIGTERM)
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(60)
        return 0

    import pointillist.cli as cli
    cli.main = lambda argv=None: run()
    main()
""")


def test_folders_made_for_a_write_cut_at_once_are_removed(tmp_path):
    """Found by the twenty-moments test on an empty kernel cache: compare's reference render was
    stopped at once while its EXR was written, and left its new folder empty. Folders made for a
    write (``signals.new_folders``) are part of the write in flight: removed when it is cut, kept
    once it succeeded."""
    from pointillist.core import signals

    done = subprocess.run([sys.executable, "-c", _STOPPED_IN_A_NEW_FOLDER, str(tmp_path)], capture_output=True,
                          text=True, timeout=60, cwd=ROOT)
    assert done.returncode == 143, done.stderr
    assert list(tmp_path.iterdir()) == []
    with signals.new_folders(tmp_path / "c" / "d" / "y.txt"):
        (tmp_path / "c" / "d" / "y.txt").write_text("kept")
    assert (tmp_path / "c" / "d" / "y.txt").read_text() == "kept"
    with pytest.raises(OSError), signals.new_folders(tmp_path / "e" / "f" / "z.txt"):
        raise OSError("the write failed")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c"]
