"""compare's report.html (pointillist/compare/html.py + pointillist/compare/page/), its tables' times,
and the page in a real browser: headless Chromium opens it from disk with the self-test
(tests/compare_page_selftest.js: scripted zoom, pan, exposure, hover and plot clicks, and the page's
time and sRGB formats; results written into the DOM, read back with ``--dump-dom``) injected into
the page's script (the page users get holds none of it), its console is read from Chromium's log,
and a screenshot is kept.

Chromium comes from the test set-up (``make test`` runs the Makefile's ``system-test``: Debian's
``chromium`` package). Without it the browser tests skip, except under CI (``CI`` set), where they fail.
"""

from __future__ import annotations

import base64
import csv
import html
import json
import math
import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from pointillist.compare import RenderRecord
from pointillist.compare.html import colormap_table, encode_half, page_script, subsample_stride, write_html_report
from pointillist.compare.report import write_report
from pointillist.compare.tables import TIMING_FLOOR, format_time, results_table, summarise
from pointillist.imaging.metrics import error_maps, image_errors

ROOT = Path(__file__).resolve().parent.parent
EDGES = ROOT / "scenes" / "edges.xml"
SELFTEST = Path(__file__).resolve().parent / "compare_page_selftest.js"
#: What the self-test formats in the page, to compare with Python: times from 1 ns to 28 h (with the
#: units' boundaries, values exactly halfway between two roundings, zero and negatives) and linear
#: values across the sRGB encoding's two pieces, below 0 and above 1.
SELFTEST_TIMES = sorted({0.0, 1e-9, 2.5e-7, 9.9949e-4, 9.9951e-4, 1e-3, 1.125, 0.001125, 0.0003125, 0.9995, 0.99949,
                         0.5, 12.345, 999.4, 999.5, 4321.0, 1e5, -0.0123, -1.125,
                         *np.round(10.0 ** np.random.default_rng(28).uniform(-9, 5, 200), 12).tolist()})
SELFTEST_LINEAR = np.float32([-1.0, 0.0, 1e-6, 0.0031308, 0.0031309, 0.04, 0.18, 0.5, 0.999, 1.0, 7.0,
                              *np.random.default_rng(29).uniform(0, 1, 300)]).astype(float).tolist()  # as in EXRs
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--enable-logging=stderr", "--v=0", "--virtual-time-budget=30000"]


# ------------------------------------------------------------------------- helpers
def page_data(path: Path) -> dict:
    """The JSON the page embeds (``<script type="application/json" id="report-data">``)."""
    text = path.read_text(encoding="utf-8")
    match = re.search(r'<script type="application/json" id="report-data">(.*?)</script>', text, re.S)
    return json.loads(match.group(1))


def half(b64: str) -> np.ndarray:
    return np.frombuffer(base64.b64decode(b64), "<f2").astype(np.float32)


def chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        if shutil.which(name):
            return shutil.which(name)
    message = "chromium not found: `make test` installs it (Makefile target system-test: apt-get install chromium)"
    if os.environ.get("CI"):
        pytest.fail(message)
    pytest.skip(message)


def run_chromium(page: Path, workdir: Path, *args: str, fragment: str = "") -> subprocess.CompletedProcess:
    """Headless Chromium on ``page`` (a file URL) with a fresh profile; ``args``: --dump-dom, --screenshot=..."""
    browser = chromium()
    profile = Path(workdir) / f"profile-{len(list(Path(workdir).glob('profile-*')))}"
    command = [browser, *FLAGS, f"--user-data-dir={profile}", *args, page.resolve().as_uri() + fragment]
    return subprocess.run(command, capture_output=True, text=True, timeout=180)


def console(stderr: str) -> list[str]:
    """The page's console messages in Chromium's log (``INFO:CONSOLE``): uncaught errors, policy violations."""
    return [line for line in stderr.splitlines() if ":CONSOLE" in line]


def _script_safe(text: str) -> str:
    """As the page inlines a script (no ``</`` that would end the element)."""
    return text.replace("</", "<\\/")


def with_selftest(page: Path, workdir: Path) -> Path:
    """A copy of ``page`` whose script runs the self-test after the page's own scripts, in their scope."""
    text = page.read_text(encoding="utf-8")
    shipped = _script_safe(page_script())
    assert text.count(shipped) == 1 and "selftest" not in text  # the page as shipped: its script alone
    values = f"var SELFTEST_VALUES = {json.dumps({'times': SELFTEST_TIMES, 'linear': SELFTEST_LINEAR})};"
    injected = _script_safe(page_script([values, SELFTEST.read_text(encoding="utf-8")]))
    target = Path(workdir) / f"selftest-{page.name}"
    target.write_text(text.replace(shipped, injected), encoding="utf-8")
    return target


def selftest(page: Path, workdir: Path) -> tuple[dict, list[str]]:
    """Open ``page`` with the self-test injected; the self-test's results and the console lines."""
    done = run_chromium(with_selftest(page, workdir), workdir, "--dump-dom")
    assert done.returncode == 0, done.stderr[-3000:]
    found = re.findall(r'<pre id="selftest-result">([^<]*)</pre>', done.stdout)
    assert found, "the page's self-test wrote no result (a script error?):\n" + "\n".join(console(done.stderr))
    return json.loads(html.unescape(found[-1])), console(done.stderr)


def check_page(result: dict, lines: list[str], data: dict) -> None:
    """What every report must pass in the browser."""
    assert result["errors"] == [] and lines == [], (result["errors"], lines)
    assert result["violations"] == [] and result["resources"] == []  # nothing fetched, nothing blocked
    # every render of the sweep drawn with its error maps (and its sample counts where it has some)
    assert [r["id"] for r in result["renders"]] == list(range(len(data["renders"])))
    for shown in result["renders"]:
        kinds = {p["kind"]: p for p in shown["panes"]}
        assert set(kinds) == {"rgb", "relmse", "flip"} | ({"count"} if shown["has_count"] else set())
        assert all(p["painted"] > 0.5 * p["width"] * p["height"] > 0 for p in kinds.values())
    assert {p["method"] for p in result["initial"]} == {"reference", *result["methods"]}
    # zooming one pane zoomed (and centred) every pane alike; so did panning another
    before = result["initial"][0]
    assert result["zoomed_pane"] != "reference:rgb"
    for key in ("after_zoom", "after_pan"):
        views = {(p["scale"], p["cx"], p["cy"]) for p in result[key]}
        assert len(views) == 1 and len(result[key]) == len(result["initial"]), key
    zoomed, panned = result["after_zoom"][0], result["after_pan"][0]
    assert zoomed["scale"] > 4 * before["scale"] and (zoomed["cx"], zoomed["cy"]) != (before["cx"], before["cy"])
    assert panned["scale"] == zoomed["scale"]
    assert panned["cx"] == pytest.approx(zoomed["cx"] - 20 / zoomed["scale"])  # dragged 20 px right, 10 down
    assert panned["cy"] == pytest.approx(zoomed["cy"] - 10 / zoomed["scale"])
    # nearest neighbour: the centre image pixel fills a uniform square of its own colour in every pane
    for check in result["pixel_checks"]:
        assert check["scale"] >= 16
        assert check["centre"] == check["expected"] and all(c == check["expected"] for c in check["corners"]), check
    # exposure +1 EV: the sRGB encoding of twice the value, computed here (IEC 61966-2-1)
    linear = 2 * np.array(result["exposure"]["value"])
    encoded = np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * np.maximum(linear, 0) ** (1 / 2.4) - 0.055)
    np.testing.assert_allclose(result["exposure"]["after"], np.round(255 * np.clip(encoded, 0, 1)), atol=1)
    # a click on a plot point shows that very render, and outlines the point in both plots
    assert result["click"]["mode"] == "time" and result["click"]["shown"]
    assert set(result["click"]["shown"]) == {result["click"]["point"]}
    assert result["click"]["selected"] == [result["click"]["index"]] * 2
    # the error spectrum beside the maps: one curve per render on show, every positive power of its spectrum drawn
    assert [c["render"] for c in result["spectrum"]] == result["spectrum_columns"]
    for curve in result["spectrum"]:
        powers = data["renders"][curve["render"]]["spectrum"]
        positive = [p for p, f in zip(powers, data["spectrum"]["frequency"]) if p is not None and p > 0 and f > 0]
        assert curve["points"] == len(positive) > 0
    assert result["click"]["point"] in result["click"]["spectrum"]  # the clicked render's spectrum is on show
    assert result["plots"] == [{"axis": "time", "points": len(data["points"])},
                               {"axis": "spp", "points": len(data["points"])}]
    # the page writes times as results.md does, and encodes sRGB as the PNG writer does
    assert result["formats"]["times"] == [format_time(t) for t in SELFTEST_TIMES]
    from pointillist.imaging.io import to_8bit

    expected = to_8bit(np.array(SELFTEST_LINEAR)[:, None]).ravel().tolist()
    assert result["formats"]["srgb"] == expected


def fake_record(method: str, value: float, time: float, rmse: float, exr: str = "", seed: int = 0,
                spp: float | None = None) -> RenderRecord:
    return RenderRecord(method=method, value=value, seed=seed, spp=value if spp is None else spp, exr=exr, width=4,
                        height=4, trace=0.0, compile=0.1, execute=time, total=time + 0.1, time=time, kernels=1,
                        cache_hits=0, scene_key="k", rmse=rmse, relmse=rmse, flip=rmse)


# ------------------------------------------------------------------- the tables' times
def test_format_time_three_significant_digits():
    assert format_time(0.001) == "1.00 ms"  # was "0.001" (three decimals of a second)
    assert format_time(0.00099949) == "999 µs" and format_time(0.00099951) == "1.00 ms"
    assert format_time(0.02) == "20.0 ms" and format_time(0.1234) == "123 ms" and format_time(12.345) == "12.3 s"
    assert format_time(2.5e-7) == "0.250 µs"
    assert format_time(0.5, 0.0123) == "500 ± 12.3 ms"
    assert format_time(math.nan) == "nan"


def test_results_table_marks_renders_too_short_to_time():
    records = [fake_record("a", 4, 0.005, 0.2, seed=0), fake_record("a", 4, 0.007, 0.2, seed=1),
               fake_record("a", 16, 0.050, 0.1)]
    header, cells = results_table(summarise(records))
    assert header[4] == "time" and cells[0][4] == "6.00 ± 1.41 ms *"  # mean and sample std of 5 and 7 ms
    assert cells[1][4] == "50.0 ms" and cells[1][6] == "0.10000"  # one seed: no spread


def test_report_leaves_short_renders_out_of_time_slopes_and_rankings(tmp_path):
    # "a": MSE = 0.1 / spp at times 5 ms (short), 40 ms, 160 ms; "b" only short renders
    records = [fake_record("jitter", s, t, math.sqrt(0.1 / s)) for s, t in ((1, 0.005), (4, 0.040), (16, 0.160))]
    records += [fake_record("random", s, t, math.sqrt(0.2 / s)) for s, t in ((1, 0.002), (4, 0.008))]
    write_report(records, tmp_path, scene="s.xml", reference="r.exr")
    text = (tmp_path / "results.md").read_text()
    assert "| jitter | 1 spp | 1 | 1 | 5.00 ms * |" in text and "| jitter | 4 spp | 4 | 1 | 40.0 ms |" in text
    assert f"3 of 5 points took under {format_time(TIMING_FLOOR)}" in text
    # jitter's time slope over 40 and 160 ms only: MSE 0.025 -> 0.00625 over 4x the time = -1.00
    assert "| jitter | -1.00 | -1.00 |" in text and "| random | -1.00 | – * |" in text
    ranking = text.split("## Equal-time ranking")[1].split("##")[0]
    assert "random" not in ranking and "| 40.0 ms | 1. jitter (2.50e-02) |" in ranking
    assert "| 160 ms | 1. jitter (6.25e-03) |" in ranking
    with open(tmp_path / "results.csv") as handle:
        assert [row["time"] for row in csv.DictReader(handle)] == ["0.005", "0.04", "0.16", "0.002", "0.008"]
    # every render too short: both rankings say so instead of ranking noise
    write_report(records[:1] + records[3:], tmp_path, scene="s.xml", reference="r.exr")
    text = (tmp_path / "results.md").read_text()
    assert text.count("Left out: every render took under 20.0 ms") == 2
    assert "which leaves nothing to rank" in text


def test_spectrum_plot_averages_seeds_and_places_other_sweeps_at_their_spp(tmp_path):
    """error_spectrum.png: per (method, value) the seeds' mean spectrum, a panel per spp; adaptive (a threshold
    sweep) joins the panel of its mean spp."""
    from pointillist.compare.report import mean_spectra
    from pointillist.imaging.spectrum import RadialSpectrum

    frequency, count = np.array([0.0, 0.25, 0.5]), np.array([1, 4, 3])
    records = [fake_record("jitter", 4, 0.03, 0.1, exr=f"j{seed}.exr", seed=seed) for seed in (0, 1)]
    records += [fake_record("adaptive", 32, 0.03, 0.1, exr="a.exr", spp=3.5)]
    for record, lowfreq in zip(records, (1e-3, 3e-3, 5e-3)):
        record.lowfreq = lowfreq
    spectra = {"j0.exr": RadialSpectrum(frequency, np.array([1.0, 2.0, 4.0]), count),
               "j1.exr": RadialSpectrum(frequency, np.array([3.0, 4.0, 8.0]), count),
               "a.exr": RadialSpectrum(frequency, np.array([1.0, 1.0, 1.0]), count),
               "other.exr": RadialSpectrum(frequency, np.zeros(3), count)}
    means = mean_spectra(records, spectra)
    assert set(means) == {("jitter", 4.0), ("adaptive", 32.0)}
    spectrum, spp, lowfreq = means[("jitter", 4.0)]
    assert spectrum.power.tolist() == [2.0, 3.0, 6.0] and spp == 4 and lowfreq == pytest.approx(2e-3)
    paths = write_report(records, tmp_path, scene="s.xml", reference="r.exr", spectra=spectra)
    assert paths["spectrum_plot"].stat().st_size > 10_000
    (tmp_path / "none").mkdir()
    assert "spectrum_plot" not in write_report(records, tmp_path / "none", scene="s.xml", reference="r.exr")
    # renders equal to the reference (a black scene): no power to put on log axes, and no error either
    # (matplotlib refused to log-scale the empty panels: compare exited 2 on tests/test_hostile.py's black scene)
    black = {key: RadialSpectrum(frequency, np.zeros(3), count) for key in spectra}
    assert write_report(records, tmp_path, scene="s.xml", reference="r.exr", spectra=black)["spectrum_plot"].is_file()


def test_run_sweep_logs_one_line_per_render_off_a_terminal(tmp_path, capsys):
    """Standard error is not a terminal under pytest: no bar redraws, one log line per finished render."""
    from pointillist.compare import Task, run_sweep
    from pointillist.imaging.io import write_exr

    reference = tmp_path / "ref.exr"
    write_exr(reference, np.full((4, 4, 3), 0.5, np.float32))

    def render(scene_path, method, value, seed, params, out_dir, key):
        stem = Task(method, value, seed).stem
        (tmp_path / "renders").mkdir(exist_ok=True)
        if not (tmp_path / "renders" / f"{stem}.exr").exists():
            write_exr(tmp_path / "renders" / f"{stem}.exr", np.full((4, 4, 3), 0.5 + 0.1 * seed, np.float32))
        record = fake_record(method, value, 0.0123, math.nan, exr=f"{stem}.exr", seed=seed)
        record.cached = seed == 1
        return record

    lines = []
    tasks = [Task("jitter", 4, 0), Task("jitter", 4, 1)]
    records = run_sweep(str(EDGES), tasks, params=None, out_dir=str(tmp_path), reference=reference,
                        log=lines.append, render=render, key="k")  # the key given: no scene to parse
    assert lines == ["compare 1/2: jitter_spp00004_seed0 12.3 ms", "compare 2/2: jitter_spp00004_seed1 (reused)"]
    assert capsys.readouterr().err == ""  # no progress bar drawn into a log
    assert records[0].rmse == 0 and records[1].rmse == pytest.approx(0.1)
    maps = {}
    again = run_sweep(str(EDGES), tasks, params=None, out_dir=str(tmp_path), reference=reference, progress=False,
                      log=lines.append, maps=maps, render=render, key="k")
    assert len(lines) == 2  # progress off: no lines either
    # the per-pixel maps of the seed-0 render, kept for the page (FLIP computed once); their means are the errors
    assert list(maps) == [records[0].exr] and set(maps[records[0].exr]) == {"relmse", "flip"}
    assert again[1].relmse == pytest.approx(0.01 / (0.25 + 0.01)) and maps[records[0].exr]["relmse"].max() == 0


# ------------------------------------------------------------------ the page's data
def test_error_maps_hand_worked_and_means_are_image_errors():
    ref = np.zeros((2, 3, 3), np.float32)
    ref[0, 0] = 1.0
    img = ref.copy()
    img[1, 2] = [0.3, 0.0, 0.0]
    maps = error_maps(img, ref)
    expected = np.zeros((2, 3), np.float32)
    expected[1, 2] = 0.09 / 0.01 / 3  # mean over RGB of (x - r)^2 / (r^2 + 0.01)
    np.testing.assert_allclose(maps["relmse"], expected, rtol=1e-6)
    assert maps["flip"].shape == (2, 3) and maps["flip"][1, 2] > 0
    rng = np.random.default_rng(3)
    ref = rng.random((16, 12, 3)).astype(np.float32)
    img = (ref + rng.normal(0, 0.05, ref.shape)).astype(np.float32)
    maps, errors = error_maps(img, ref), image_errors(img, ref)
    assert maps["relmse"].mean() == pytest.approx(errors["relmse"], rel=1e-5)
    assert maps["flip"].mean() == pytest.approx(errors["flip"], rel=1e-5)  # flip-evaluator's own mean
    with pytest.raises(ValueError, match="shape"):
        error_maps(img[:4], ref)


def test_encodings_and_stride():
    values = np.array([0.0, 1.0, -2.5, 65504.0, 1e-3, np.inf], np.float32)
    np.testing.assert_array_equal(half(encode_half(values)), values.astype(np.float16).astype(np.float32))
    assert base64.b64decode(encode_half([1.0])) == b"\x00\x3c"  # IEEE half 1.0 = 0x3C00, little-endian
    import matplotlib

    table = bytes.fromhex(colormap_table("viridis"))
    assert len(table) == 768 and tuple(table[:3]) == (68, 1, 84)  # viridis starts at #440154
    np.testing.assert_allclose(np.frombuffer(table, np.uint8).reshape(256, 3)[128],
                               np.round(np.array(matplotlib.colormaps["viridis"](128 / 255)[:3]) * 255), atol=1)
    # 100 bytes a pixel, 1 MB budget (less 200 kB reserved): 8000 pixels, so 100x100 needs stride 2
    assert subsample_stride(100, 100, 100.0, 1_000_000) == 2
    assert subsample_stride(89, 89, 100.0, 1_000_000) == 1  # 7921 pixels fit


def _synthetic_sweep(folder: Path) -> tuple[list[RenderRecord], Path, dict]:
    """A hand-made sweep on disk: a 9x7 reference, jitter at 1 and 4 spp, adaptive with a sample-count layer."""
    from pointillist.imaging.io import write_exr

    rng = np.random.default_rng(7)
    yy, xx = np.mgrid[0:7, 0:9]
    ref = np.stack([xx / 8, yy / 6, np.full_like(xx, 0.25, dtype=float)], axis=2).astype(np.float32)
    reference = folder / "reference.exr"
    write_exr(reference, ref, metadata={"sampler": "stratified", "spp": 4096})
    images, records = {}, []
    for method, value, noise, time in (("jitter", 1, 0.2, 0.030), ("jitter", 4, 0.1, 0.060),
                                       ("adaptive", 64, 0.05, 0.005)):
        image = np.clip(ref + rng.normal(0, noise, ref.shape), 0, None).astype(np.float32)
        name = f"{method}_{value}.exr"
        layers = {"sample_count": (1 + (xx + yy) % 5).astype(np.float32)} if method == "adaptive" else None
        (folder / "renders").mkdir(exist_ok=True)
        write_exr(folder / "renders" / name, image, layers=layers)
        record = fake_record(method, value, time, 0.0, exr=name, spp=3.0 if method == "adaptive" else None)
        record.__dict__.update(image_errors(image, ref))
        records.append(record)
        images[(method, value)] = image
    return records, reference, images


def test_html_report_holds_the_renders_maps_and_counts_subsampled(tmp_path):
    records, reference, images = _synthetic_sweep(tmp_path)
    full = write_html_report(records, tmp_path, scene="s.xml", reference=reference, title="T <&>")
    assert full.stride == 1 and full.shown_size == (9, 7) and full.bytes == full.path.stat().st_size
    text = full.path.read_text()
    assert "<title>T &lt;&amp;&gt;</title>" in text
    # self-contained: one policy forbidding any fetch; no external reference anywhere
    assert text.count('http-equiv="Content-Security-Policy"') == 1
    assert "default-src 'none'; img-src data: blob:; script-src 'unsafe-inline'; style-src 'unsafe-inline'" in text
    assert not re.search(r"<(link|img|iframe)\b|\ssrc=|\shref=|url\(|@import", text)
    assert "{{" not in text
    # a stride of 2 (budget below the full images): pixels 1, 3, 5, ... of the full-size data, not averages
    small = write_html_report(records, tmp_path, scene="s.xml", reference=reference, max_bytes=200_000 + 2000)
    assert small.stride == 2 and small.shown_size == (4, 3) and "every 2nd pixel of 9x7" in small.summary
    data = page_data(small.path)
    assert (data["width"], data["height"], data["stride"], data["offset"]) == (4, 3, 2, 1)
    ref = np.stack([np.mgrid[0:7, 0:9][1] / 8, np.mgrid[0:7, 0:9][0] / 6, np.full((7, 9), 0.25)], 2)
    np.testing.assert_allclose(half(data["reference"]["rgb"]).reshape(3, 4, 3), ref[1::2, 1::2], atol=1e-3)
    assert data["reference"]["label"] == "reference (stratified, 4096 spp)"
    by_key = {(r["method"], r["value"]): r for r in data["renders"]}
    assert set(by_key) == {("jitter", 1.0), ("jitter", 4.0), ("adaptive", 64.0)}
    for key, image in images.items():
        entry, maps = by_key[key], error_maps(image, ref.astype(np.float32))
        np.testing.assert_allclose(half(entry["rgb"]).reshape(3, 4, 3), image[1::2, 1::2], rtol=1e-3, atol=1e-4)
        np.testing.assert_allclose(half(entry["relmse_map"]).reshape(3, 4), maps["relmse"][1::2, 1::2], rtol=2e-3)
        np.testing.assert_allclose(half(entry["flip_map"]).reshape(3, 4), maps["flip"][1::2, 1::2], atol=1e-3)
    # the error spectrum of each render: the radial power spectrum of its full-size luminance error (4 digits)
    from pointillist.imaging.metrics import error_spectrum

    spectrum = error_spectrum(images[("jitter", 4.0)], ref.astype(np.float32))
    assert data["spectrum"]["frequency"] == spectrum.frequency.tolist() == [0, 1 / 9, 2 / 9, 3 / 9, 4 / 9]
    assert data["spectrum"]["cutoff"] == 0.125 and data["spectrum"]["nyquist"] == 0.5
    np.testing.assert_allclose(by_key[("jitter", 4.0)]["spectrum"], spectrum.power, rtol=1e-3)
    assert by_key[("jitter", 4.0)]["lowfreq"] == pytest.approx(records[1].lowfreq)
    assert [p["lowfreq"] for p in data["points"]] == pytest.approx([r.lowfreq for r in records])
    # maps passed in (the sweep's own, computed while scoring) are used as they are
    given = {records[0].exr: {"relmse": np.full((7, 9), 0.25, np.float32), "flip": np.full((7, 9), 0.5, np.float32)}}
    used = page_data(write_html_report(records, tmp_path, scene="s.xml", reference=reference, maps=given).path)
    assert set(half(used["renders"][0]["flip_map"])) == {0.5} and set(half(used["renders"][0]["relmse_map"])) == {0.25}
    assert set(half(used["renders"][1]["flip_map"])) != {0.5}
    counts = 1 + (np.mgrid[0:7, 0:9].sum(0)) % 5
    np.testing.assert_array_equal(half(by_key[("adaptive", 64.0)]["count_map"]).reshape(3, 4), counts[1::2, 1::2])
    assert by_key[("jitter", 1.0)]["count_map"] is None
    assert data["scales"]["count"]["lo"] == 1 and data["scales"]["count"]["hi"] == 5
    assert data["scales"]["relmse"]["hi"] == pytest.approx(1e4 * data["scales"]["relmse"]["lo"])
    adaptive = next(p for p in data["points"] if p["method"] == "adaptive")
    assert adaptive["short"] and adaptive["time_text"] == "5.00 ms" and adaptive["spp"] == 3.0
    # the table rows, in the order of the points (a click on row i shows point i's render)
    rows = re.findall(r'<tr data-render="(\d+)">', small.path.read_text())
    assert [int(r) for r in rows] == [p["render"] for p in data["points"]]


def test_html_report_bad_input(tmp_path):
    records, reference, _ = _synthetic_sweep(tmp_path)
    with pytest.raises(ValueError, match="records: expected at least one"):
        write_html_report([], tmp_path, scene="s", reference=reference)
    with pytest.raises(ValueError, match="max_bytes"):
        write_html_report(records, tmp_path, scene="s", reference=reference, max_bytes=0)
    from pointillist.imaging.io import write_exr

    other = tmp_path / "small.exr"
    write_exr(other, np.zeros((3, 3, 3), np.float32))
    with pytest.raises(ValueError, match="the reference 3x3"):
        write_html_report(records, tmp_path, scene="s", reference=other)


def test_set_up_installs_chromium_for_tests_only():
    """`make test` installs Chromium when missing (target system-test); `make demo` does not."""
    test = subprocess.run(["make", "-n", "test"], cwd=ROOT, capture_output=True, text=True)
    demo = subprocess.run(["make", "-n", "demo"], cwd=ROOT, capture_output=True, text=True)
    assert test.returncode == 0 and demo.returncode == 0, test.stderr + demo.stderr
    assert "apt-get install -y -qq chromium" in test.stdout
    assert "chromium" not in demo.stdout


# ------------------------------------------------------------------------ in a browser
@pytest.fixture(scope="module")
def sweep_report(tmp_path_factory):
    """`compare --samplers jitter,random --spp 1,4`, interrupted (a render missing, no report) and resumed."""
    from conftest import run_cli

    out = tmp_path_factory.mktemp("compare") / "cmp"
    args = ["compare", EDGES, "-D", "res=24", "--samplers", "jitter,random", "--spp", "1,4",
            "--reference-spp", "16", "--out", out]
    first = run_cli(*args, "--no-report")
    assert first.returncode == 0, first.stderr
    assert not (out / "report.html").exists() and "report:" not in first.stdout
    # no terminal: one line per finished render and no progress bar
    assert len(re.findall(r"^compare \d/4: \S+ ", first.stdout, re.M)) == 4 and "\r" not in first.stderr
    for path in (out / "renders").glob("*/random_spp00004_seed0.*"):
        path.unlink()  # as if the run had stopped before this render
    second = run_cli(*args)
    assert second.returncode == 0, second.stderr
    assert "4 renders (1 new, 3 reused)" in second.stdout
    assert f"report: {out / 'report.html'} (" in second.stdout
    return out / "report.html"


def test_compare_report_opens_in_chromium(sweep_report, tmp_path):
    """The issue's must-hold: the report of a small jitter/random sweep opens in headless Chromium with no
    script error and nothing fetched, shows both methods' renders and error maps, zooms all panes together."""
    data = page_data(sweep_report)
    assert {(r["method"], r["value"]) for r in data["renders"]} == {
        ("jitter", 1.0), ("jitter", 4.0), ("random", 1.0), ("random", 4.0)}  # the resumed sweep, complete
    result, lines = selftest(sweep_report, tmp_path)
    check_page(result, lines, data)
    assert set(result["methods"]) == {"jitter", "random"}
    # the readout names the hovered pixel's values: the reference's RGB as in its EXR (float16 precision)
    from pointillist.imaging.io import read_exr

    match = re.search(r"pixel x (\d+), y (\d+)\nreference +RGB ([\d.]+) ([\d.]+) ([\d.]+)", result["readout"])
    assert match, result["readout"]
    x, y = int(match.group(1)), int(match.group(2))
    reference = read_exr(next((sweep_report.parent / "reference" / "renders").glob("*/*.exr"))).image
    np.testing.assert_allclose([float(v) for v in match.groups()[2:]], reference[y, x, :3], atol=2e-3, rtol=2e-3)
    assert "relMSE" in result["readout"] and "FLIP" in result["readout"]
    # a screenshot as the test's artefact
    shot = tmp_path / "report.png"
    done = run_chromium(sweep_report, tmp_path, f"--screenshot={shot}", "--window-size=1400,1300")
    assert done.returncode == 0 and console(done.stderr) == [], done.stderr[-2000:]
    from PIL import Image

    image = np.asarray(Image.open(shot).convert("RGB"))
    assert image.shape == (1300, 1400, 3) and image.std() > 10
    print(f"screenshot of the report: {shot}")


def test_report_with_sample_counts_and_stride_in_chromium(tmp_path):
    """An adaptive method's sample-count pane and a subsampled page pass the same checks."""
    records, reference, _ = _synthetic_sweep(tmp_path)
    page = write_html_report(records, tmp_path, scene="s.xml", reference=reference, max_bytes=200_000 + 2000)
    data = page_data(page.path)
    result, lines = selftest(page.path, tmp_path)
    check_page(result, lines, data)
    assert [r["has_count"] for r in result["renders"]] == [r["count_map"] is not None for r in data["renders"]]
    assert any(r["has_count"] for r in result["renders"]) and "count" in result["scales"]
    assert "(1 in 2 pixels in x and y shown)" in result["readout"]


def test_browser_checks_can_fail(sweep_report, tmp_path):
    """A fetch and a script error slipped into the page are caught: blocked and reported, and logged."""
    text = sweep_report.read_text()
    bad = tmp_path / "bad.html"
    bad.write_text(text.replace("</body>", '<img src="https://example.invalid/x.png">'
                                "<script>window.setTimeout(function () {}, 0); noSuchFunction();</script></body>"))
    result, lines = selftest(bad, tmp_path)
    assert any("noSuchFunction" in e for e in result["errors"])
    assert any("img-src" in v and "example.invalid" in v for v in result["violations"])
    assert any("Uncaught ReferenceError" in line for line in lines)
    assert any("Content Security Policy" in line for line in lines)
