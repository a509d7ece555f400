"""`pointillist render` and plugin registration."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pointillist.imaging.io import read_exr
from pointillist.cli import main

ROOT = Path(__file__).resolve().parent.parent
DEFAULT = ROOT / "scenes" / "default.xml"


def test_register_is_idempotent_and_lists_plugins(mi):
    from pointillist import plugins

    first = plugins.register()
    assert plugins.register() == first == plugins.registered()
    assert set(first.values()) <= {"integrator", "sampler", "bsdf"}
    needs = {"adaptive": {"nested": {"type": "path"}}}  # required parameters of some plugins
    for name, kind in first.items():  # every registered plugin instantiates from a dict
        plugin = mi.load_dict({"type": name, **needs.get(name, {})})
        assert isinstance(plugin, {"integrator": mi.Integrator, "sampler": mi.Sampler, "bsdf": mi.BSDF}[kind]), name


def test_register_without_variant_errors(tmp_path):
    import subprocess
    import sys

    code = "from pointillist import plugins\ntry:\n    plugins.register()\nexcept RuntimeError as e:\n    print(e)\n"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert "no Mitsuba variant is set" in proc.stdout and "set_variant" in proc.stdout


def test_render_cli_writes_exr_png_and_metadata(tmp_path, cli, mi):
    out = tmp_path / "x.exr"
    proc = cli("render", DEFAULT, "-o", out, "--spp", "4", "--seed", "3", "--png", "-D", "res=24")
    assert proc.returncode == 0, proc.stderr
    assert "JIT compile" in proc.stdout and "render" in proc.stdout and str(out) in proc.stdout
    image, meta, layers = read_exr(out)
    assert image.shape == (24, 24, 3) and np.isfinite(image).all() and image.mean() > 0.01
    assert meta["spp"] == 4 and meta["seed"] == 3 and meta["width"] == 24
    assert meta["integrator"] and meta["sampler"] == "independent"
    # the timings printed are the ones stored (a render takes time: render_seconds > 0)
    assert meta["render_seconds"] > 0
    assert f"trace {meta['trace_seconds']:.2f} s, JIT compile {meta['compile_seconds']:.2f} s" in proc.stdout
    assert out.with_suffix(".png").stat().st_size > 100
    # Same pixels as an in-process render of the same scene, spp and seed.
    from pointillist.scene import load_scene, timed_render

    expected, _ = timed_render(load_scene(DEFAULT, {"res": "24"}), spp=4, seed=3)
    np.testing.assert_allclose(image, np.asarray(expected), rtol=1e-5, atol=1e-6)


def _bad(capsys, *argv):
    with pytest.raises(SystemExit) as info:
        raise SystemExit(main([str(a) for a in argv]))
    err = capsys.readouterr().err.strip().splitlines()
    return info.value.code, err


@pytest.mark.parametrize("argv, message", [
    (["render", "missing.xml"], "no such file"),
    (["render", DEFAULT, "-D", "res"], "expected key=value"),
    (["render", DEFAULT, "-D", "res=abc"], "could not parse integer value"),
    (["render", DEFAULT, "-D", "nokey=1"], "unused parameters"),
    (["render", DEFAULT, "--spp", "0"], "expected a positive integer"),
    (["render", DEFAULT, "--seed", "-1"], "expected an integer in 0..2^32-1"),
    (["render", DEFAULT, "-o", "x.png"], "expected a .exr file name"),
    (["render", DEFAULT, "-o", "/nonexistent-folder/x.exr"], "does not exist"),
    (["nosuchcommand"], "invalid choice"),
    # These used to end in "internal error" (exit 1): a uint32 overflow, Mitsuba's multi-pass
    # split (sample_count not a multiple of the pass count), a film without pixels.
    (["render", DEFAULT, "--spp", str(2**32)], "expected an integer in 1..2^32-1"),
    (["render", DEFAULT, "-D", "res=64", "--spp", str(2**20)], "64x64 pixels at 1048576 spp is 4294967296"),
    (["render", DEFAULT, "-D", "res=0"], "the film has no pixels (0x0)"),
])
def test_render_bad_input_exit_2_one_line(capsys, tmp_path, mi, argv, message):
    code, err = _bad(capsys, *argv)
    assert code == 2 and len(err) == 1 and message in err[0], err


def test_render_malformed_xml_and_unknown_plugin(capsys, tmp_path, mi):
    broken = tmp_path / "broken.xml"
    broken.write_text('<scene version="3.0.0"><integrator')
    code, err = _bad(capsys, "render", broken, "-o", tmp_path / "a.exr")
    assert code == 2 and len(err) == 1 and "failed" in err[0] and str(broken) in err[0]
    unknown = tmp_path / "unknown.xml"
    unknown.write_text(DEFAULT.read_text().replace('type="$integrator"', 'type="nosuchplugin"'))
    code, err = _bad(capsys, "render", unknown, "-o", tmp_path / "b.exr")
    assert code == 2 and len(err) == 1 and 'Plugin "nosuchplugin" not found' in err[0]
    assert not list(tmp_path.glob("*.exr"))


def test_render_refuses_to_overwrite_its_input(capsys, tmp_path, mi):
    scene = tmp_path / "scene.exr"
    scene.write_text(DEFAULT.read_text())
    code, err = _bad(capsys, "render", scene, "-o", scene)
    assert code == 2 and "refusing to overwrite" in err[0]
    assert scene.read_text() == DEFAULT.read_text()


def test_plugin_constructor_errors_are_one_line_without_traceback(capsys, mi):
    # Mitsuba pastes a Python plugin's traceback into its message; the CLI keeps the exception line.
    code, err = _bad(capsys, "render", DEFAULT, "-D", "integrator=adaptive", "-o", "unused.exr")
    assert code == 2 and len(err) == 1
    assert "Traceback" not in err[0] and 'File "' not in err[0]
    expected = 'integrator plugin of type "adaptive": ValueError: adaptive: expected exactly one nested integrator'
    assert expected in err[0]


def test_a_plugin_warning_is_one_line_said_once(tmp_path, cli):
    """A plugin that warns (jitter at a prime count, configured twice by Mitsuba) shows one line
    ``pointillist render: warning: ...``, not Python's file, line number and source line twice."""
    scene = tmp_path / "prime.xml"
    scene.write_text("""<scene version="3.0.0">
  <integrator type="direct"/>
  <sensor type="perspective">
    <transform name="to_world"><lookat origin="0,0,4" target="0,0,0" up="0,1,0"/></transform>
    <sampler type="jitter"><integer name="sample_count" value="3"/></sampler>
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/>
      <rfilter type="box"/></film>
  </sensor>
  <shape type="sphere"/>
  <emitter type="constant"/>
</scene>""")
    done = cli("render", scene, "-o", tmp_path / "prime.exr")
    assert done.returncode == 0, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith("pointillist render: warning: jitter sampler: sample_count 3 has no"), lines
