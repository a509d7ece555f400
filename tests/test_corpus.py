"""The scene corpus (scenes/corpus/, written in Mitsuba's conventions) rendered by pointillist and
by Mitsuba alone: bit-identical images; each scene also with whitted, every sampler, compare and a
progressive --time render (:mod:`pointillist.differential`). ``pytest --scenes FOLDER`` checks a
folder of your own scenes the same way, each in a process of its own."""

from __future__ import annotations

from pathlib import Path

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
