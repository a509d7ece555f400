"""What a rerun of ``pointillist compare`` costs: nothing is scored, built or written again that has
not changed. The report's files are left alone while what they show is the same and they are the
files written (pointillist.compare.outputs); the scene's size and film filter are kept per scene
key, so a rerun whose renders are all cached does not build the scene (pointillist.compare.records).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
EDGES = ROOT / "scenes" / "edges.xml"
REPORT = ("results.csv", "results.md", "error_vs_time.png", "error_vs_spp.png", "error_spectrum.png")


def _compare(out: Path, spp=(1, 2), **options):
    from pointillist.compare import compare_scene

    return compare_scene(EDGES, methods="jitter,random", spp=list(spp), reference_spp=4, out_dir=out,
                         params={"res": "8"}, progress=False, **options)


def _files(out: Path) -> dict[str, tuple[bytes, int]]:
    return {name: ((out / name).read_bytes(), (out / name).stat().st_mtime_ns) for name in (*REPORT, "report.html")}


def test_rerun_keeps_unchanged_outputs_and_writes_what_changed(mi, tmp_path):
    out = tmp_path / "cmp"
    first = _compare(out)
    assert first.kept == [] and first.new == 4
    written = _files(out)
    # everything cached: no file of the report written again, and the run says so
    again = _compare(out)
    assert again.new == 0 and sorted(again.kept) == sorted(["csv", "md", "time_plot", "spp_plot", "spectrum_plot",
                                                            "html"])
    assert _files(out) == written and again.notes == first.notes  # the page's summary too
    # a file of the report edited, or removed: its group is written again, as it was
    with open(out / "results.md", "a") as handle:
        handle.write("edited\n")
    (out / "error_vs_spp.png").unlink()
    edited = _compare(out)
    assert edited.kept == ["html"]
    now = _files(out)
    assert {name: now[name][0] for name in now} == {name: written[name][0] for name in written}
    assert now["report.html"] == written["report.html"] and now["results.csv"][1] != written["results.csv"][1]
    # the page replaced by another file: written again
    (out / "report.html").write_text("<html></html>")
    assert "html" not in _compare(out).kept and (out / "report.html").read_bytes() == written["report.html"][0]
    # a new sweep point: new records, so both groups are written again (and show it)
    more = _compare(out, spp=(1, 2, 4))
    assert more.kept == [] and more.new == 2
    assert "| jitter | 4 spp |" in (out / "results.md").read_text()
    # a page not asked for is not kept in step with the records, and a later page is written again
    assert "html" not in _compare(out, spp=(1, 2), report=False).paths
    assert "html" not in _compare(out, spp=(1, 2)).kept


def test_rerun_writes_again_when_the_reference_file_changes(mi, tmp_path):
    """The reference's pixels are in every score's key; its file (its header: the page's label) in the outputs'."""
    import os

    out = tmp_path / "cmp"
    _compare(out)
    reference = next((out / "reference" / "renders").glob("*/*.exr"))
    stat = reference.stat()
    os.utime(reference, ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))  # rewritten, same pixels
    assert _compare(out).kept == []
    assert len(_compare(out).kept) == 6


def test_cached_rerun_does_not_build_the_scene(mi, tmp_path, monkeypatch):
    import pointillist.scene as scene_module

    out = tmp_path / "cmp"
    _compare(out)
    facts = list((out / "renders").glob("*/scene.json"))
    assert len(facts) == 1 and json.loads(facts[0].read_text()) == {
        "width": 8, "height": 8, "film_filter": "BoxFilter[]"}
    built = []
    real = scene_module.instantiate_scene

    def counting(*args, **kwargs):
        built.append(args)
        return real(*args, **kwargs)

    monkeypatch.setattr(scene_module, "instantiate_scene", counting)
    result = _compare(out)
    assert built == [] and result.new == 0
    assert result.notes[0] == "film filter: BoxFilter[] (box: each pixel is the plain average of its samples)"
    # facts that do not read back are learnt again, by building the scene once
    facts[0].write_text("{not json")
    _compare(out)
    assert len(built) == 1 and json.loads(facts[0].read_text())["width"] == 8
    # a sample count the film cannot take is refused from the stored facts too, before any render
    from pointillist.core.errors import UsageError

    with pytest.raises(UsageError, match="sample"):
        _compare(out, spp=(2**31,))


def test_outputs_unchanged_needs_the_key_and_the_files_as_written(tmp_path):
    from pointillist.compare import outputs

    (tmp_path / "renders").mkdir()
    (tmp_path / "a.txt").write_text("a")
    assert outputs.unchanged(tmp_path, "report", "k1") is None  # nothing written yet
    outputs.remember(tmp_path, "report", "k1", [tmp_path / "a.txt"], {"summary": "s"})
    assert outputs.unchanged(tmp_path, "report", "k1") == {"summary": "s"}
    assert outputs.unchanged(tmp_path, "report", "k2") is None and outputs.unchanged(tmp_path, "page", "k1") is None
    (tmp_path / "a.txt").write_text("b")
    assert outputs.unchanged(tmp_path, "report", "k1") is None
    (tmp_path / "a.txt").write_text("a")
    assert outputs.unchanged(tmp_path, "report", "k1") == {"summary": "s"}
    outputs.manifest_path(tmp_path).write_text("[1, 2]")  # damaged: as if nothing was written
    assert outputs.unchanged(tmp_path, "report", "k1") is None


def test_outputs_key_covers_the_code_that_writes_them(monkeypatch):
    """A change to any module of the package or any file of the page changes every key."""
    from pointillist.compare import outputs

    base = outputs.outputs_key(records=[1])
    assert base == outputs.outputs_key(records=[1]) != outputs.outputs_key(records=[2])
    real = outputs.file_digest
    for name in ("main.js", "report.html.in", "tables.py"):
        outputs._code_digest.cache_clear()
        monkeypatch.setattr(outputs, "file_digest", lambda path, name=name: "x" if Path(path).name == name
                            else real(path))
        assert outputs.outputs_key(records=[1]) != base, name
    outputs._code_digest.cache_clear()
    monkeypatch.setattr(outputs, "file_digest", real)
    assert outputs.outputs_key(records=[1]) == base
