"""The scene corpus (scenes/corpus/, written in Mitsuba's conventions) rendered by pointillist and
by Mitsuba alone: bit-identical images; each scene also with whitted, every sampler, compare and a
progressive --time render (:mod:`pointillist.differential`). ``pytest --scenes FOLDER`` checks a
folder of your own scenes the same way, each in a process of its own."""

from __future__ import annotations


import numpy as np
import pytest

from tests.conftest import SCENES

CORPUS = SCENES / "corpus"
#: Scenes that Mitsuba refuses, and pointillist must refuse too, with Mitsuba's reason.
REFUSED = {"misspelt.xml": "unreferenced property in emitter plugin of type \"area\": rgb \"radience\"",
           "blackbody.xml": "[BlackBodySpectrum] Not implemented for non-spectral modes"}


def corpus_scenes() -> list[str]:
    return sorted(p.name for p in CORPUS.glob("*.xml"))


def pytest_generate_tests(metafunc):
    if "user_scene" in metafunc.fixturenames:
        from pointillist.differential import scene_files

        paths = metafunc.config.getoption("--scenes")
        files = [str(p) for p in scene_files(paths)] if paths else []
        metafunc.parametrize("user_scene", files or [pytest.param(None, marks=pytest.mark.skip(
            reason="no --scenes given: `pytest tests/test_corpus.py --scenes FOLDER` checks your own scenes"))])


def test_corpus_covers_mitsubas_scene_format():
    """What the corpus is for: each element of Mitsuba's scene format appears in some scene."""
    text = "\n".join(p.read_bytes().decode("utf-16" if p.name == "utf16.xml" else "latin-1")
                     for p in sorted(CORPUS.rglob("*.xml")))
    for needle in ("<path ", "<include ", "<default ", "$", "<ref ", "<alias ", "<translate", "<rotate", "<scale",
                   "<matrix", "<lookat", "<rgb ", "<spectrum ", 'type="blackbody"', 'type="bitmap" name="radiance"',
                   'type="spot"', 'type="projector"', 'type="envmap"', 'type="ply"', 'type="obj"',
                   'type="serialized"', 'type="shapegroup"', 'type="instance"', 'type="volpath"', 'type="gridvolume"',
                   'type="aov"', 'type="moment"', 'type="batch"', "crop_offset_x", "pixel_format", 'type="whitted"',
                   'type="lambert"', 'type="phong"', 'type="orthographic"', 'type="thinlens"'):
        assert needle in text, needle
    assert 'encoding="UTF-16"' in text and 'encoding="ISO-8859-1"' in text
    assert not any("<integrator" in line for line in (CORPUS / "no_integrator.xml").read_text().splitlines()[1:])


@pytest.mark.slow
@pytest.mark.parametrize("name", corpus_scenes())
def test_corpus_scene_renders_as_in_mitsuba(mi, name):
    """Bit-identical to mi.load_file + mi.render (from another working folder); whitted, every
    sampler, compare and a progressive render run. A scene Mitsuba refuses is refused with its
    reason, and nothing more runs."""
    from pointillist.differential import STEPS, check_scene

    report = check_scene(CORPUS / name, spp=2, seed=3)
    failed = [f"{c.name}: {c.detail}" for c in report.checks if not c.ok]
    assert not failed, failed
    if name in REFUSED:
        assert [c.name for c in report.checks] == ["mitsuba"]
        assert report.checks[0].detail.startswith("refused, as Mitsuba refuses it")
        assert REFUSED[name] in report.checks[0].detail
    else:
        assert [c.name for c in report.checks] == list(STEPS)
        assert report.checks[0].detail.startswith("bit-identical to Mitsuba")


@pytest.mark.parametrize("pixel_format, rfilter", [("rgb", "box"), ("luminance", "tent"),
                                                    ("luminance_alpha", "lanczos"), ("rgba", "mitchell"),
                                                    ("rgb", "catmullrom")])
def test_every_film_format_and_filter_renders_as_in_mitsuba(mi, pixel_format, rfilter):
    from pointillist.differential import check_scene

    report = check_scene(CORPUS / "films.xml", params={"format": pixel_format, "filter": rfilter}, steps=["mitsuba"])
    assert report.ok and report.checks[0].detail.startswith("bit-identical"), report.checks


def test_the_check_finds_a_difference(mi, tmp_path, monkeypatch):
    """The differential check is not blind: a render one seed off, or one pixel changed, fails."""
    from pointillist import differential
    from pointillist.differential import check_scene

    real = differential.mitsuba_render

    def off_by_one_seed(path, *, spp, seed, params=None, threads=1):
        return real(path, spp=spp, seed=seed + 1, params=params, threads=threads)

    monkeypatch.setattr(differential, "mitsuba_render", off_by_one_seed)
    report = check_scene(CORPUS / "include_defaults_refs.xml", steps=["mitsuba"])
    assert not report.ok and "pixels differ" in report.checks[0].detail

    def one_pixel(path, *, spp, seed, params=None, threads=1):
        image, scene = real(path, spp=spp, seed=seed, params=params, threads=threads)
        image = image.copy()
        image[3, 4, 1] = np.nextafter(image[3, 4, 1], np.float32(np.inf))
        return image, scene

    monkeypatch.setattr(differential, "mitsuba_render", one_pixel)
    report = check_scene(CORPUS / "include_defaults_refs.xml", steps=["mitsuba"])
    assert not report.ok and "colour: 1 of 576 pixels differ" in report.checks[0].detail


def test_a_scene_whose_mitsuba_image_varies_between_loads(mi, monkeypatch):
    """Mitsuba's own image of some scenes varies from one load to the next (measured: a rare variant
    every few loads): pointillist's must then be one of the images Mitsuba makes, and the check says so."""
    from pointillist import differential
    from pointillist.differential import check_scene

    real, calls = differential.mitsuba_render, []

    def first_load_differs(path, *, spp, seed, params=None, threads=1):
        image, scene = real(path, spp=spp, seed=seed, params=params, threads=threads)
        calls.append(1)
        return (image * np.float32(1.5) if len(calls) == 1 else image), scene

    monkeypatch.setattr(differential, "mitsuba_render", first_load_differs)
    report = check_scene(CORPUS / "include_defaults_refs.xml", steps=["mitsuba"])
    assert report.ok and "varies between loads (2 different images in 2 loads)" in report.checks[0].detail

    def never_ours(path, *, spp, seed, params=None, threads=1):  # varies, and never pointillist's image
        image, scene = real(path, spp=spp, seed=seed, params=params, threads=threads)
        calls.append(1)
        return image * np.float32(1.5 + len(calls) % 2), scene

    monkeypatch.setattr(differential, "mitsuba_render", never_ours)
    report = check_scene(CORPUS / "include_defaults_refs.xml", steps=["mitsuba"])
    assert not report.ok and report.checks[0].detail.endswith(
        f"(Mitsuba's own image of this scene varies between loads (2 different images in "
        f"{differential.REPEATS + 1} loads), pointillist's is none of them)")


def test_pointillists_first_load_may_be_the_rare_variant(mi, monkeypatch):
    """Mitsuba's loads may all give the common image while pointillist's one load gave the rare one:
    pointillist renders again before the check says they differ."""
    from pointillist.imaging import io
    from pointillist.differential import check_scene

    real, reads = io.read_exr, []

    def first_read_differs(path, **kwargs):
        exr = real(path, **kwargs)
        reads.append(1)
        return exr._replace(image=exr.image * np.float32(1.5)) if len(reads) == 1 else exr

    monkeypatch.setattr(io, "read_exr", first_read_differs)
    report = check_scene(CORPUS / "include_defaults_refs.xml", steps=["mitsuba"])
    assert report.ok and "pointillist's first load gave another one" in report.checks[0].detail, report.checks


def test_verify_command_reports_each_scene_and_a_crash(cli, tmp_path):
    """`pointillist verify` on a folder: one line a check, a summary line, exit 1 when one failed;
    a scene whose process dies is reported and the others still run."""
    (tmp_path / "a.xml").write_bytes((CORPUS / "include_defaults_refs.xml").read_bytes())
    for part in ("camera.xml", "room.xml"):
        (tmp_path / "parts").mkdir(exist_ok=True)
        (tmp_path / "parts" / part).write_bytes((CORPUS / "parts" / part).read_bytes())
    done = cli("verify", tmp_path / "a.xml", "--only", "mitsuba")
    assert done.returncode == 0, done.stderr
    assert "ok   mitsuba: bit-identical to Mitsuba (24x24x3 at 2 spp)" in done.stdout
    assert done.stdout.strip().splitlines()[-1] == "1 passed, 0 failed"
    # a -D typo both refuse: agreement, but the summary says that nothing was rendered
    done = cli("verify", tmp_path / "a.xml", "--only", "mitsuba", "-D", 'res=8"<&')
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == ("1 passed (1 of them refused by Mitsuba and pointillist alike: "
                                                     "nothing rendered), 0 failed")
    bad = cli("verify", tmp_path / "missing.xml")
    assert bad.returncode == 2 and "no such file or folder" in bad.stderr and len(bad.stderr.splitlines()) == 1
    bad = cli("verify", tmp_path / "a.xml", "--only", "mitsuba,nothing")
    assert bad.returncode == 2 and "--only: expected some of mitsuba,whitted" in bad.stderr


def test_a_crashing_scene_is_a_finding(monkeypatch, tmp_path):
    """verify_scenes runs each scene in a process of its own: a process that dies becomes a failed check."""
    import subprocess

    from pointillist import differential

    class Died:
        returncode, stdout, stderr = -6, "", "LLVM ERROR: something\nAborted\n"

    monkeypatch.setattr(subprocess, "run", lambda *a, **k: Died())
    report = differential._child(CORPUS / "batch.xml", spp=1, seed=0, params={}, steps=["mitsuba"], timeout=5)
    assert not report.ok and report.checks[0].detail == "killed by signal 6: LLVM ERROR: something"


def test_your_scenes_render_as_in_mitsuba(user_scene):
    """``pytest tests/test_corpus.py --scenes FOLDER``: each of your scenes, in a process of its own."""
    from pointillist.differential import verify_scenes

    (report,) = verify_scenes([user_scene], progress=False)
    failed = [f"{c.name}: {c.detail}" for c in report.checks if not c.ok]
    assert not failed, failed


# ------------------------------------------------------------------ what a user of Mitsuba's scenes met
def test_assets_named_through_path_load_from_any_working_folder(cli, tmp_path):
    """<path value="assets"/> and bare names (meshes/pyramid.obj): the folders the parser adds are kept
    for building the scene (they were dropped: "failed to instantiate shape plugin of type obj")."""
    from pointillist.imaging.io import read_exr

    done = cli("render", CORPUS / "paths_and_assets.xml", "-o", tmp_path / "a.exr", "--spp", "1", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert read_exr(tmp_path / "a.exr").image.shape == (24, 24, 3)


def test_whitted_with_three_textured_area_lights_and_textured_spot_and_projector(cli, tmp_path):
    """Dr.Jit aborted the process ("invalid redefinition of function") with two or more area lights
    whose radiance is a bitmap: whitted calls each emitter through the scene's emitter table."""
    xml = (CORPUS / "textured_emitters.xml").read_text()
    third = xml[xml.rindex("    <shape type=\"rectangle\">"):xml.index("    <emitter type=\"spot\">")]
    xml = xml.replace('<integrator type="path"><integer name="max_depth" value="3"/></integrator>',
                      '<integrator type="whitted"/>').replace(third, third + third.replace('x="2"', 'x="0" z="-2.5"'))
    assert xml.count('name="radiance"') == 3
    (tmp_path / "three.xml").write_text(xml)
    for name in ("parts", "assets"):
        (tmp_path / name).symlink_to(CORPUS / name)
    for seed in ("0", "1"):
        done = cli("render", tmp_path / "three.xml", "-o", tmp_path / "t.exr", "--seed", seed)
        assert done.returncode == 0, done.stderr[-2000:]


@pytest.mark.parametrize("mistake, message", [
    ('<rgb name="radience" value="4"/>', 'unreferenced property in emitter plugin of type "area": rgb "radience"'),
    ('<rgb name="radiance" value="4"/><float name="radius_" value="1"/>', "unreferenced property"),
])
def test_a_misspelt_property_is_refused_as_mitsuba_refuses_it(cli, tmp_path, mistake, message):
    """Reading the scene for camera-relative loading marked every property used, so Mitsuba's check of
    properties no plugin read never fired: a misspelt name rendered with the default value."""
    xml = (CORPUS / "misspelt.xml").read_text().replace('<rgb name="radience" value="4"/>', mistake)
    (tmp_path / "m.xml").write_text(xml)
    (tmp_path / "parts").symlink_to(CORPUS / "parts")
    done = cli("render", tmp_path / "m.xml", "-o", tmp_path / "m.exr")
    assert done.returncode == 2 and message in done.stderr and len(done.stderr.strip().splitlines()) == 1, done.stderr
    sensor = (CORPUS / "parts" / "camera.xml").read_text().replace('name="fov"', 'name="fvo"')
    (tmp_path / "parts2").mkdir()
    (tmp_path / "parts2" / "camera.xml").write_text(sensor)
    (tmp_path / "f.xml").write_text((CORPUS / "no_integrator.xml").read_text().replace("parts/camera", "parts2/camera"))
    (tmp_path / "parts2" / "room.xml").write_bytes((CORPUS / "parts" / "room.xml").read_bytes())
    done = cli("render", tmp_path / "f.xml", "-o", tmp_path / "f.exr")
    assert done.returncode == 2 and 'sensor plugin of type "perspective": float "fvo"' in done.stderr, done.stderr


def test_a_scene_without_integrator_renders_with_path_and_says_so(cli, tmp_path):
    from pointillist.imaging.io import read_exr

    done = cli("render", CORPUS / "no_integrator.xml", "-o", tmp_path / "n.exr", "--spp", "1")
    assert done.returncode == 0, done.stderr
    assert "warning: scene" in done.stderr and "no <integrator>; rendering with Mitsuba's default, " \
           '<integrator type="path"/>' in done.stderr
    assert read_exr(tmp_path / "n.exr").metadata["integrator"] == "path"


def test_mitsubas_own_render_error_is_one_line(cli, tmp_path):
    """It was "internal error: RuntimeError: drjit.custom(...) (see above)" with nothing above."""
    done = cli("render", CORPUS / "blackbody.xml", "-o", tmp_path / "b.exr")
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip() == ("pointillist render: error: Mitsuba could not render the scene: "
                                   "[BlackBodySpectrum] Not implemented for non-spectral modes")
    assert not (tmp_path / "b.exr").exists()


def test_compare_reads_utf16_scenes_and_sensors_from_includes(cli, tmp_path):
    """compare read the XML as UTF-8 text and wanted a top-level <sensor>: both failed after the
    reference render. Samplers are now swapped in the parsed scene."""
    for name in ("utf16.xml", "latin1.xml", "include_defaults_refs.xml"):
        done = cli("compare", CORPUS / name, "--samplers", "jitter,sobol", "--spp", "1,2", "--reference-spp", "4",
                   "--out", tmp_path / name)
        assert done.returncode == 0, (name, done.stderr[-1500:])
        assert (tmp_path / name / "results.csv").read_text().count("\n") == 5


@pytest.mark.parametrize("plugin, name", [("moment", "moment"), ("ptracer", "ptracer"), ("depth", "depth"),
                                          ("volpathmis", "volpathmis"), ("prb", "prb"), ("aov", "aov")])
def test_integrators_are_named_by_their_plugin_names(mi, plugin, name):
    """The EXR header and the summary line name Mitsuba's integrators as a scene writes them (moment was
    "MomentIntegrator", ptracer "ParticleTracerIntegrator")."""
    from pointillist.scene import scene_info

    integrator = {"type": plugin}
    if plugin == "moment":
        integrator["inner"] = {"type": "path"}
    if plugin == "aov":
        integrator["aovs"] = "dd:depth"
    scene = mi.load_dict({"type": "scene", "integrator": integrator,
                          "sensor": {"type": "perspective", "film": {"type": "hdrfilm", "width": 4, "height": 4}}},
                         parallel=False)
    assert scene_info(scene)["integrator"] == name
