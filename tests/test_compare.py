"""Tests of the sampler comparison workflow (pointillist/compare.py) and `pointillist compare`."""

from __future__ import annotations

import csv
import dataclasses
import math
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from pointillist.compare import RenderRecord, Task
from pointillist.imaging.metrics import image_errors
from pointillist.compare.methods import METHODS, Method, configure_scene, resolve_methods, setting_label
from pointillist.compare.tables import equal_error_ranking, equal_time_ranking, fit_slope
from pointillist.core.errors import UsageError

ROOT = Path(__file__).resolve().parent.parent
EDGES = ROOT / "scenes" / "edges.xml"


# ------------------------------------------------------------------ scene configuration
def test_swap_samplers_swaps_every_sensor_sampler(mi, tmp_path):
    """Every top-level sensor gets the method's sampler holding only sample_count (stratified's jitter
    dropped; one added where a sensor has none), also a sensor stated in an <include>."""
    from pointillist.compare.methods import swap_samplers
    from pointillist.scene import parse_scene

    (tmp_path / "cam.xml").write_text('<scene version="3.0.0"><sensor type="thinlens"><float name="aperture_radius" '
                                      'value="0.1"/><film type="hdrfilm"/></sensor></scene>')
    (tmp_path / "s.xml").write_text("""<scene version="3.0.0">
      <default name="spp" value="8"/>
      <sensor type="perspective"><sampler type="stratified"><integer name="sample_count" value="$spp"/>
        <boolean name="jitter" value="false"/></sampler><film type="hdrfilm"/></sensor>
      <sensor type="orthographic"><film type="hdrfilm"/></sensor>
      <include filename="cam.xml"/>
    </scene>""")
    parsed = parse_scene(tmp_path / "s.xml")
    swap_samplers(parsed, "poisson", 64)
    scene = mi.parser.instantiate(parsed.config, parsed.state)
    samplers = [sensor.sampler() for sensor in scene.sensors()]
    assert len(samplers) == 3 and all(s.sample_count() == 64 for s in samplers)
    assert {type(s).__name__ for s in samplers} == {"PoissonSampler"}, [type(s).__name__ for s in samplers]
    with pytest.raises(UsageError, match="has no <sensor>"):
        (tmp_path / "empty.xml").write_text('<scene version="3.0.0"/>')
        swap_samplers(parse_scene(tmp_path / "empty.xml"), "grid", 4)


def test_configure_scene_integrator_method_and_errors():
    method = Method("thresh", "path", kind="integrator", parameter="max_depth", values=(3,))
    root = ET.fromstring(configure_scene('<scene version="3.0.0"><integrator type="direct"/>'
                                         '<sensor type="perspective"/></scene>', method, 3))
    integrators = root.findall("integrator")
    assert len(integrators) == 1 and integrators[0].get("type") == "path"
    assert integrators[0][0].get("name") == "max_depth" and float(integrators[0][0].get("value")) == 3
    with pytest.raises(ValueError, match="grid is a sampler method"):
        configure_scene('<scene version="3.0.0"/>', METHODS["grid"], 4)
    with pytest.raises(UsageError, match="not valid XML"):
        configure_scene("<scene", method, 4)
    # the file's bytes: the encoding its declaration names
    text = ('<?xml version="1.0" encoding="UTF-16"?>\n'
            '<scene version="3.0.0"><!-- Größe --><sensor type="perspective"/></scene>')
    root = ET.fromstring(configure_scene(text.encode("utf-16"), method, 2))
    assert root.find("integrator").get("type") == "path" and root.find("sensor") is not None


def test_resolve_methods():
    assert [m.name for m in resolve_methods("grid, jitter,random,poisson,stratified,grid")] == [
        "grid", "jitter", "random", "poisson", "stratified"]
    assert [(m.name, m.plugin, m.kind) for m in resolve_methods("sobol,zsobol")] == [
        ("sobol", "sobol", "sampler"), ("zsobol", "zsobol", "sampler")]
    with pytest.raises(UsageError, match="unknown sampler 'nope'"):
        resolve_methods("grid,nope")
    with pytest.raises(UsageError):
        resolve_methods(" , ")


def test_user_scene_elsewhere_resolves_relative_paths(mi, tmp_path):
    """Any scene works: its sampler is replaced and its relative files still resolve."""
    from pointillist.compare.methods import load_configured_scene

    folder = tmp_path / "user"
    folder.mkdir()
    (folder / "part.xml").write_text('<scene version="3.0.0"><emitter type="constant">'
                                     '<rgb name="radiance" value="0.25"/></emitter></scene>')
    (folder / "scene.xml").write_text(
        '<scene version="3.0.0"><integrator type="direct"/>'
        '<sensor type="perspective"><sampler type="multijitter"><integer name="sample_count" value="9"/>'
        '</sampler><film type="hdrfilm"><integer name="width" value="4"/><integer name="height" value="4"/>'
        '</film></sensor><include filename="part.xml"/></scene>')
    scene = load_configured_scene(folder / "scene.xml", METHODS["jitter"], 16)
    sampler = scene.sensors()[0].sampler()
    assert "JitterSampler" in str(sampler) and sampler.sample_count() == 16
    np.testing.assert_allclose(np.asarray(mi.render(scene)), 0.25, rtol=1e-3)


def test_configured_scene_loads_serially_like_load_scene(mi, monkeypatch):
    """Mitsuba's parallel loader failed about one compare run in ten here ("failed to instantiate
    film plugin of type hdrfilm: std::bad_alloc" / "basic_string::_M_create", exit 2 on a valid
    scene; 0 failures in 40 runs after the fix) and instantiates plugins in a random order (new
    kernels each run): compare loads serially, as :func:`pointillist.scene.load_scene` does."""
    from pointillist.compare.methods import load_configured_scene

    calls = []
    original = mi.parser.instantiate

    def spy(config, state):
        calls.append(config.parallel)
        return original(config, state)

    monkeypatch.setattr(mi.parser, "instantiate", spy)
    scene = load_configured_scene(ROOT / "scenes" / "default.xml", METHODS["random"], 2, {"res": "4"})
    assert list(scene.sensors()[0].film().size()) == [4, 4]
    assert calls == [False]


# ------------------------------------------------------------------------------ errors
def test_image_errors_hand_worked():
    ref = np.zeros((2, 2, 3), np.float32)
    ref[0, 0] = 1.0
    img = ref.copy()
    img[1, 1] = 0.3  # one pixel off by 0.3 in 3 of 12 values
    e = image_errors(img, ref)
    assert math.isclose(e["rmse"], math.sqrt(3 * 0.09 / 12), rel_tol=1e-6)
    assert math.isclose(e["relmse"], 3 * 0.09 / 0.01 / 12, rel_tol=1e-5)
    assert e["flip"] > 0
    same = image_errors(ref, ref)
    assert same["rmse"] == 0 and same["relmse"] == 0 and same["flip"] == 0
    # relative MSE divides by ref^2 + 0.01
    e = image_errors(np.full((1, 1, 3), 3.0), np.full((1, 1, 3), 2.0), flip=False)
    assert math.isclose(e["relmse"], 1 / 4.01, rel_tol=1e-9)
    # grey images compare as RGB; NaN is reported, not hidden
    assert image_errors(np.ones((3, 3)), np.ones((3, 3)))["rmse"] == 0
    assert math.isnan(image_errors(np.full((3, 3, 3), np.nan), np.ones((3, 3, 3)))["rmse"])
    with pytest.raises(ValueError, match="shape"):
        image_errors(np.ones((3, 3, 3)), np.ones((4, 3, 3)))


def test_flip_is_flip_evaluators_hdr_flip_of_the_reference_and_the_test(rng):
    """``image_errors(image, reference)["flip"]`` is flip-evaluator's mean HDR-FLIP with the
    reference first; on this HDR pair swapping the arguments or using LDR-FLIP changes the value."""
    import flip_evaluator

    reference = np.ones((24, 32, 3), np.float32) * 0.2
    reference[4:12, 6:20] = [4.0, 2.0, 0.5]  # a bright HDR patch (sets HDR-FLIP's exposure range)
    image = np.clip(reference + rng.normal(0, 0.05, reference.shape), 0, None).astype(np.float32)
    image[16:20, 2:30] = [40.0, 10.0, 1.0]  # a brighter feature only the test image has
    expected = float(flip_evaluator.evaluate(reference, image, "HDR", applyMagma=False)[1])
    swapped = float(flip_evaluator.evaluate(image, reference, "HDR", applyMagma=False)[1])
    ldr = float(flip_evaluator.evaluate(np.clip(reference, 0, 1), np.clip(image, 0, 1), "LDR", applyMagma=False)[1])
    assert min(abs(expected - swapped), abs(expected - ldr)) > 0.01 * expected  # the pair tells them apart
    assert image_errors(image, reference, flip_backend="flip-evaluator")["flip"] == pytest.approx(expected, rel=1e-6)
    # the default, FLIP on Dr.Jit (pointillist.imaging.flip), agrees to float32 rounding (tests/test_flip.py)
    assert image_errors(image, reference)["flip"] == pytest.approx(expected, abs=1e-5)
    with pytest.raises(ValueError, match="^flip_backend: expected one of 'drjit', 'flip-evaluator', got 'nvidia'$"):
        image_errors(image, reference, flip_backend="nvidia")


def test_flip_of_a_black_or_constant_reference_does_not_end_the_process():
    # flip-evaluator calls exit() when its exposure range is empty (a black reference, or a
    # constant one where rounding puts the start above the stop); run in a subprocess so that a
    # regression shows as a failed assertion rather than a vanished pytest.
    code = (
        "import numpy as np\n"
        "from pointillist.imaging.metrics import image_errors\n"
        "for ref in (np.zeros((4, 4, 3)), np.full((4, 4, 3), 1e-7), np.full((4, 4, 3), 0.5)):\n"
        "    print(image_errors(ref + 0.05, ref)['flip'], image_errors(np.full((4, 4, 3), np.nan), ref)['flip'])\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                            check=False)
    assert result.returncode == 0, result.stdout + result.stderr
    values = [float(v) for v in result.stdout.split()]
    assert len(values) == 6 and all(0 <= v <= 1 for v in values)
    assert values[1] == 0  # black test image against a black reference: no error
    # where flip-evaluator does not exit (0.5), the value is its own default one
    import flip_evaluator

    ref = np.full((4, 4, 3), 0.5, np.float32)
    assert values[4] == pytest.approx(flip_evaluator.evaluate(ref, ref + 0.05, "HDR", applyMagma=False)[1], abs=1e-6)


def test_flip_against_flip_reference_ldr_agrees_in_order():
    """FLIP grows with the error (independent check: more noise, larger FLIP)."""
    rng = np.random.default_rng(0)
    ref = np.full((32, 32, 3), 0.5, np.float32)
    small = image_errors(ref + rng.normal(0, 0.01, ref.shape).astype(np.float32), ref)["flip"]
    large = image_errors(ref + rng.normal(0, 0.1, ref.shape).astype(np.float32), ref)["flip"]
    assert 0 < small < large


def test_fit_slope_exact_power_law():
    spp = np.array([1, 4, 16, 64, 256])
    assert math.isclose(fit_slope(spp, 3.0 * spp ** -1.5), -1.5, rel_tol=1e-9)
    assert math.isclose(fit_slope(spp, 0.2 / spp), -1.0, rel_tol=1e-9)
    assert math.isnan(fit_slope([4], [1.0]))
    assert math.isclose(fit_slope([1, 2, 0, 4], [1, 0.5, 7, 0.25]), -1.0)  # x = 0 ignored


def test_equal_time_ranking_hand_case():
    rows = [
        {"method": "a", "time": 1.0, "mse": 0.5}, {"method": "a", "time": 4.0, "mse": 0.1},
        {"method": "b", "time": 2.0, "mse": 0.2}, {"method": "b", "time": 8.0, "mse": 0.01},
    ]
    ranking = dict(equal_time_ranking(rows, budgets=[1.0, 2.0, 5.0, 10.0]))
    assert ranking[1.0] == [("a", 0.5)]
    assert ranking[2.0] == [("b", 0.2), ("a", 0.5)]
    assert ranking[5.0] == [("a", 0.1), ("b", 0.2)]
    assert ranking[10.0] == [("b", 0.01), ("a", 0.1)]
    assert equal_time_ranking(rows, budgets=[0.5]) == [(0.5, [])]


def test_equal_error_ranking_hand_case():
    rows = [
        {"method": "a", "value": 4, "time": 1.0, "rmse": 0.5}, {"method": "a", "value": 16, "time": 4.0, "rmse": 0.1},
        {"method": "b", "value": 128, "time": 2.0, "rmse": 0.2},
        {"method": "b", "value": 64, "time": 3.0, "rmse": 0.05},
        {"method": "c", "value": 1, "time": 0.1, "rmse": math.nan},
    ]
    # default budgets: the first method's points (0.5 then 0.1); b's fastest point within each
    assert equal_error_ranking(rows) == [(0.5, [("a", 4.0, 1.0), ("b", 128.0, 2.0)]),
                                         (0.1, [("b", 64.0, 3.0), ("a", 16.0, 4.0)])]
    assert equal_error_ranking(rows, [0.2]) == [(0.2, [("b", 128.0, 2.0), ("a", 16.0, 4.0)])]
    assert equal_error_ranking(rows, [0.01]) == [(0.01, [])]  # nobody that accurate; NaN never is
    assert equal_error_ranking([]) == []


def test_setting_label():
    assert setting_label("jitter", 16.0) == "16 spp"
    assert setting_label("adaptive", 64.0) == "threshold 64"
    assert setting_label("not-registered", 2.5) == "2.5 spp"


def test_render_one_warms_up_once_per_method(mi, tmp_path, monkeypatch):
    """A method's first render in a process is rendered twice (the first untimed, its times
    recorded apart); later renders of that method, and the reference, once."""
    import pointillist.compare.sweep as compare
    import pointillist.scene as scene_module

    calls, timings = [], []
    real = scene_module.timed_render

    def spy(scene, **kwargs):
        calls.append(kwargs["seed"])
        image, timing = real(scene, **kwargs)
        timing = dataclasses.replace(timing, compile=0.25) if len(calls) == 1 else timing
        timings.append(timing)
        return image, timing

    monkeypatch.setattr(scene_module, "timed_render", spy)
    monkeypatch.setattr(compare, "_WARMED", set())
    params = {"res": "8"}
    first = compare.render_one(str(EDGES), "jitter", 2, 0, params, str(tmp_path))
    assert calls == [0, 0]
    # the record is the timed (second) render; the warm-up's times are recorded apart
    timed = timings[1]
    assert first.compile == timed.compile and first.total == timed.total
    assert first.warm_up_compile == 0.25 and first.warm_up == timings[0].total
    compare.render_one(str(EDGES), "jitter", 2, 1, params, str(tmp_path))
    assert calls == [0, 0, 1]
    compare.render_reference(str(EDGES), params, str(tmp_path), 4)
    assert len(calls) == 4  # the reference: no warm-up
    compare.render_one(str(EDGES), "grid", 2, 0, params, str(tmp_path))
    assert len(calls) == 6  # a new method warms up again


# ------------------------------------------------------------------------ render_one
def test_render_one_writes_and_reuses(mi, tmp_path):
    from pointillist.imaging.io import read_exr
    from pointillist.compare import render_one
    from pointillist.compare.records import task_paths

    params = {"res": "12"}
    record = render_one(str(EDGES), "jitter", 4, 0, params, str(tmp_path), warm_up=False)
    assert isinstance(record, RenderRecord) and not record.cached
    assert record.spp == 4 and (record.width, record.height) == (12, 12)
    assert record.total >= record.compile >= 0  # the warm-up is recorded apart (was added to compile)
    exr, js = task_paths(tmp_path, Task("jitter", 4, 0), record.scene_key)
    assert record.exr == f"{record.scene_key}/{exr.name}"
    image, meta, _ = read_exr(exr)
    assert image.shape == (12, 12, 3) and meta["sampler"] == "jitter" and meta["spp"] == 4
    stamp = exr.stat().st_mtime_ns
    again = render_one(str(EDGES), "jitter", 4, 0, params, str(tmp_path))
    assert again.cached and exr.stat().st_mtime_ns == stamp and again.exr == record.exr
    # other parameters: another scene key, so the cache is not reused
    other = render_one(str(EDGES), "jitter", 4, 0, {"res": "8"}, str(tmp_path))
    assert not other.cached and other.width == 8
    # a sampler that rounds the count reports what it took (stratified: a square)
    rounded = render_one(str(EDGES), "stratified", 8, 0, params, str(tmp_path))
    assert rounded.spp == 9


@pytest.mark.slow  # ~11 s on a loaded machine: a reference and 4 renders (and their warm-ups)
def test_compare_sobol_and_zsobol_with_the_error_spectrum(mi, tmp_path):
    """compare sweeps sobol and zsobol by name; every render gets its low-frequency error (results.csv, the
    table) and the spectrum plot is written; zsobol's renders carry what it rounded the count to."""
    from pointillist.compare import compare_scene
    from pointillist.imaging.io import read_exr
    from pointillist.imaging.metrics import luminance_error
    from pointillist.imaging.spectrum import low_frequency_energy

    with pytest.warns(RuntimeWarning, match="zsobol sampler: sample_count 6 is not a power of two; using 8"):
        result = compare_scene(EDGES, methods="sobol,zsobol", spp=[1, 6], reference_spp=16, out_dir=tmp_path,
                               params={"res": "16"}, progress=False, report=False)
    assert {(r.method, r.spp) for r in result.records} == {("sobol", 1), ("sobol", 6), ("zsobol", 1), ("zsobol", 8)}
    assert result.paths["spectrum_plot"] == tmp_path / "error_spectrum.png"
    assert result.paths["spectrum_plot"].stat().st_size > 10_000
    reference = read_exr(result.reference).image
    with open(result.paths["csv"]) as handle:
        rows = list(csv.DictReader(handle))
    for row in rows:  # the luminance error's energy below a quarter of Nyquist, recomputed from the files
        image = read_exr(tmp_path / row["exr"]).image
        expected = low_frequency_energy(luminance_error(image, reference))
        assert float(row["lowfreq"]) == pytest.approx(expected, rel=1e-9) and expected > 0
    assert "| low-freq MSE |" in result.paths["md"].read_text()


def test_render_one_is_picklable():
    import pickle

    from pointillist.compare import render_one

    assert pickle.loads(pickle.dumps(render_one)) is render_one
    assert pickle.loads(pickle.dumps(Task("poisson", 16, 2))) == Task("poisson", 16, 2)


# ----------------------------------------------------------------------- stored scores
def test_run_sweep_keeps_scores_with_each_render(mi, tmp_path, monkeypatch):
    """A render's scores (its record), error spectrum and seed-0 maps (renders/<task>.maps.npz) are stored
    with the key of the render file and the reference: a rerun scores nothing again; a new reference, a render written
    again, a lost or damaged maps file or a new scores version is scored again, and only that."""
    import json
    import os

    import pointillist.compare.records as records
    import pointillist.compare.sweep as compare
    import pointillist.imaging.metrics as metrics
    from pointillist.imaging.io import read_exr, write_exr

    scored = []
    real = metrics.image_errors

    def counting(image, reference, **kwargs):
        scored.append(image.shape)
        return real(image, reference, **kwargs)

    monkeypatch.setattr(metrics, "image_errors", counting)
    params, out = {"res": "10"}, str(tmp_path)
    tasks = [Task("jitter", 2, 0), Task("jitter", 2, 1), Task("grid", 4, 0)]
    reference = compare.render_reference(str(EDGES), params, out, 16)

    def sweep(ref=reference):
        maps = {}
        records = compare.run_sweep(str(EDGES), tasks, params=params, out_dir=out, reference=ref,
                                    progress=False, maps=maps)
        return records, maps

    first, maps = sweep()
    assert len(scored) == 3 and set(maps) == {first[0].exr, first[2].exr}
    ref_image = read_exr(reference).image
    for record in first:
        exr = tmp_path / "renders" / record.exr
        stored = json.loads(exr.with_suffix(".json").read_text())
        expected = real(read_exr(exr).image, ref_image)
        assert set(expected) == {"rmse", "relmse", "flip", "lowfreq"}
        assert {k: stored[k] for k in expected} == pytest.approx(expected, rel=1e-12)
        assert stored["scores_key"] == records.scores_key(exr, records.image_digest(ref_image)) == record.scores_key
        with np.load(records.maps_path(exr)) as kept:  # every render's spectrum, a seed-0 render's maps
            spectrum = metrics.error_spectrum(read_exr(exr).image, ref_image)
            assert np.array_equal(kept["spectrum_power"], spectrum.power, equal_nan=True)
            assert ("flip" in kept and "relmse" in kept) == (record.seed == 0)
    # a rerun: every score and map from the folder, the same values; nothing written
    stamps = {p: p.stat().st_mtime_ns for p in (tmp_path / "renders").rglob("*.*")}
    again, maps_again = sweep()
    assert len(scored) == 3 and all(r.cached for r in again)
    assert [(r.rmse, r.relmse, r.flip) for r in again] == [(r.rmse, r.relmse, r.flip) for r in first]
    for name, kept in maps.items():
        assert all(np.array_equal(kept[k], maps_again[name][k]) for k in ("relmse", "flip"))
    assert stamps == {p: p.stat().st_mtime_ns for p in (tmp_path / "renders").rglob("*.*")}
    # another reference: everything scored again, against it
    other = tmp_path / "other.exr"
    write_exr(other, ref_image[..., :3] * np.float32(1.5))
    swept, _ = sweep(other)
    assert len(scored) == 6 and all(r.rmse != f.rmse for r, f in zip(swept, first))
    sweep(other)
    assert len(scored) == 6
    # a render written again (its file changes), a lost maps file, a damaged one: those alone
    exr = tmp_path / "renders" / first[1].exr
    os.utime(exr, ns=(exr.stat().st_atime_ns, exr.stat().st_mtime_ns + 10**9))
    records.maps_path(tmp_path / "renders" / first[0].exr).unlink()
    records.maps_path(tmp_path / "renders" / first[2].exr).write_bytes(b"not a zip file")
    sweep(other)
    assert len(scored) == 9
    sweep(other)
    assert len(scored) == 9
    # a new definition of the scores
    monkeypatch.setattr(records, "SCORES_VERSION", records.SCORES_VERSION + 1)
    sweep(other)
    assert len(scored) == 12


def test_image_digest_tells_images_apart():
    from pointillist.compare.records import image_digest

    image = np.zeros((4, 5, 3), np.float32)
    changed = image.copy()
    changed[3, 4, 2] = np.float32(1e-30)
    assert image_digest(image) == image_digest(image.copy()) != image_digest(changed)
    assert image_digest(image) != image_digest(image.reshape(5, 4, 3)) != image_digest(image.astype(np.float64))


# --------------------------------------------------------------------------------- CLI
@pytest.mark.slow  # ~30 s: a 24-render sweep, then resumed
def test_cli_compare_end_to_end_and_resume(cli, tmp_path):
    out = tmp_path / "cmp"
    args = ["compare", EDGES, "-D", "res=16", "--spp", "1,4,16", "--reference-spp", "64",
            "--seeds", "2", "--out", out, "--no-progress"]
    done = cli(*args)
    assert done.returncode == 0, done.stderr
    assert "24 renders (24 new, 0 reused)" in done.stdout
    for name in ("results.csv", "results.md", "error_vs_time.png", "error_vs_spp.png", "error_spectrum.png"):
        assert (out / name).stat().st_size > 0
    with open(out / "results.csv") as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 4 * 3 * 2
    assert {r["method"] for r in rows} == {"grid", "jitter", "random", "poisson"}
    for r in rows:
        assert (out / r["exr"]).is_file()
        assert float(r["rmse"]) > 0 and float(r["flip"]) > 0
    text = (out / "results.md").read_text()
    assert "Equal-time ranking" in text and "MSE vs spp" in text and "Equal-error ranking" in text
    assert "| jitter | 4 spp | 4 |" in text  # the setting column
    # the cached reference is named relative to the folder (the page reads the same wherever it lies)
    assert re.search(r"reference `reference/renders/[0-9a-f]+/stratified_spp00064_seed\d+\.exr`", text), text[:600]
    assert str(tmp_path) not in text and str(tmp_path) not in (out / "report.html").read_text()
    # error falls with spp for every sampler (mean over seeds)
    for method in ("grid", "jitter", "random", "poisson"):
        mse = [np.mean([float(r["rmse"]) ** 2 for r in rows if r["method"] == method and r["spp"] == s])
               for s in ("1.0", "4.0", "16.0")]
        assert mse[0] > mse[1] > mse[2], (method, mse)
    written = {name: (out / name).stat().st_mtime_ns for name in ("results.csv", "results.md", "report.html")}
    stamps = {p: p.stat().st_mtime_ns for p in (out / "renders").rglob("*.*")}
    stored = [p for p in stamps if p.name.endswith(".maps.npz")]
    assert len(stored) == 24   # every render's error spectrum; the seed-0 renders' per-pixel maps too
    for path in stored:
        with np.load(path) as held:
            assert ("relmse" in held.files) == path.name.endswith("_seed0.maps.npz"), (path.name, held.files)
            assert held["spectrum_power"].ndim == 1 and np.all(held["spectrum_power"] >= 0)
    again = cli(*args)
    assert again.returncode == 0 and "(0 new, 24 reused)" in again.stdout
    # nothing scored again: no record or map rewritten; nor the report, which shows the same
    assert stamps == {p: p.stat().st_mtime_ns for p in (out / "renders").rglob("*.*")}
    assert written == {name: (out / name).stat().st_mtime_ns for name in written}
    assert "\nkept " in again.stdout and "\nwrote " not in again.stdout and "kept: unchanged)" in again.stdout


def test_cli_compare_reference_file_and_bad_input(cli, tmp_path):
    from pointillist.imaging.io import write_exr

    ref = tmp_path / "ref.exr"
    write_exr(ref, np.full((8, 8, 3), 0.1, np.float32))
    done = cli("compare", EDGES, "-D", "res=8", "--spp", "2", "--samplers", "jitter", "--reference", ref,
               "--out", tmp_path / "o", "--no-progress")
    assert done.returncode == 0, done.stderr
    assert not (tmp_path / "o" / "reference").exists()  # no reference rendered
    bad = cli("compare", EDGES, "--samplers", "grid,bogus", "--out", tmp_path / "x")
    assert bad.returncode == 2 and "unknown sampler 'bogus'" in bad.stderr
    assert len(bad.stderr.strip().splitlines()) == 1
    wrong = cli("compare", EDGES, "-D", "res=16", "--reference", ref, "--out", tmp_path / "y")
    assert wrong.returncode == 2 and "8x8" in wrong.stderr and "16x16" in wrong.stderr
    for spp in ("0", "a,b", "4,-1"):
        r = cli("compare", EDGES, "--spp", spp)
        assert r.returncode == 2 and "--spp" in r.stderr
    missing = cli("compare", tmp_path / "none.xml")
    assert missing.returncode == 2 and "no such file" in missing.stderr


def test_cli_compare_checks_sample_counts_before_rendering(cli, tmp_path):
    """Too many samples for one render, or a film without pixels: exit 2 and one line before any
    render or progress bar starts (they used to fail mid-sweep: a bar line, then an internal error)."""
    out = tmp_path / "c"
    big = cli("compare", EDGES, "-D", "res=4", "--spp", "1,300000000", "--samplers", "random", "--out", out)
    assert big.returncode == 2 and big.stderr.count("\n") == 1, big.stderr
    assert "4x4 pixels at 300000000 spp is 4800000000 samples" in big.stderr
    ref = cli("compare", EDGES, "-D", "res=4", "--spp", "1", "--reference-spp", "300000000", "--out", out)
    assert ref.returncode == 2 and ref.stderr.count("\n") == 1 and "300000000 spp" in ref.stderr, ref.stderr
    empty = cli("compare", EDGES, "-D", "res=0", "--spp", "1", "--samplers", "random", "--out", out)
    assert empty.returncode == 2 and "no pixels" in empty.stderr and empty.stderr.count("\n") == 1, empty.stderr
    huge = cli("compare", EDGES, "--spp", str(2**32), "--out", out)
    assert huge.returncode == 2 and "1..4294967295" in huge.stderr
    assert not out.exists()


def test_docstring_examples_run():
    import doctest

    import pointillist.imaging.metrics as metrics
    from pointillist import plugins
    from pointillist.compare import html, methods, tables

    modules = (tables, html, methods, plugins, metrics)
    results = [doctest.testmod(module, optionflags=doctest.NORMALIZE_WHITESPACE) for module in modules]
    assert all(r.attempted >= 1 for r in results) and sum(r.attempted for r in results) >= 12
    assert all(r.failed == 0 for r in results)
