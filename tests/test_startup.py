"""A plain render starts as light as Mitsuba: no numpy, no OpenEXR package, no imaging module, and
its EXR (written by Mitsuba's own writer) reads back exactly; the numpy-free arithmetic it uses
agrees with numpy's."""

from __future__ import annotations

import math
import subprocess
import sys

import hypothesis.extra.numpy as hnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import ROOT

#: A plain Mitsuba scene: Mitsuba's own integrator, sampler and BSDF, a mesh file, point lights.
PLAIN = """<scene version="3.0.0">
    <integrator type="direct"/>
    <sensor type="perspective">
        <transform name="to_world"><lookat target="0, 0, 0.2" origin="0, -4, 2" up="0, 0, 1"/></transform>
        <sampler type="independent"><integer name="sample_count" value="4"/></sampler>
        <film type="hdrfilm"><rfilter type="box"/><integer name="width" value="24"/><integer name="height" value="16"/>
            <string name="pixel_format" value="{pixel_format}"/></film>
    </sensor>
    <shape type="ply"><string name="filename" value="{mesh}"/>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.9 0.9 0.0"/></bsdf></shape>
    <emitter type="point"><point name="position" x="3" y="-10" z="6"/><rgb name="intensity" value="100"/></emitter>
</scene>
"""

MESH = ROOT / "scenes" / "corpus" / "assets" / "meshes" / "pyramid.ply"

#: Run in a fresh process: the command line's render, then which heavy modules it loaded.
_RENDER_AND_LIST = (
    "import sys; from pointillist.cli import main; code = main(sys.argv[1:]); "
    "print(sorted(m for m in ('numpy', 'OpenEXR', 'PIL', 'colour', 'pointillist.imaging') if m in sys.modules)); "
    "sys.exit(code)"
)


def _plain_scene(tmp_path, pixel_format: str = "rgb"):
    scene = tmp_path / "plain.xml"
    scene.write_text(PLAIN.format(mesh=MESH, pixel_format=pixel_format))
    return scene


def test_a_plain_render_imports_no_numpy_and_its_exr_reads_back(mi, tmp_path):
    """`render` of a plain scene loads neither numpy, OpenEXR nor the imaging module (a tenth of a
    second of each start); the EXR Mitsuba's writer made holds the image Mitsuba renders and the
    metadata as numbers."""
    from pointillist.imaging.io import read_exr

    scene = _plain_scene(tmp_path)
    out = tmp_path / "plain.exr"
    done = subprocess.run([sys.executable, "-c", _RENDER_AND_LIST, "render", str(scene), "-o", str(out),
                           "--seed", "4294967295", "--threads", "1"],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "[]"
    image, meta, layers = read_exr(out)
    assert image.shape == (16, 24, 3) and image.dtype == np.float32 and layers == {}
    assert meta["spp"] == 4 and meta["integrator"] == "direct" and isinstance(meta["render_seconds"], float)
    assert meta["seed"] == "4294967295"                       # beyond an EXR int (32 bits): exact as text
    assert meta["generatedBy"].startswith("Mitsuba version")
    mi.set_log_level(mi.LogLevel.Error)
    reference = mi.render(mi.load_file(str(scene)), seed=4294967295)
    np.testing.assert_allclose(image, np.asarray(reference), rtol=0, atol=1e-6)
    assert image.mean() > 0.01                                # the pyramid is lit


def test_a_render_with_alpha_and_aovs_keeps_every_channel_by_name(mi, tmp_path):
    """RGBA film and an AOV integrator: the EXR has R G B A and each AOV as a layer, values as rendered."""
    from pointillist.channels import channel_layout
    from pointillist.imaging.io import read_exr
    from pointillist.render_output import write_render_exr

    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": "aov", "aovs": "dd:depth,nn:sh_normal", "inner": {"type": "direct"}},
        "sensor": {"type": "perspective", "film": {"type": "hdrfilm", "width": 8, "height": 6, "pixel_format": "rgba"},
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0])},
        "shape": {"type": "sphere"}, "light": {"type": "constant"}})
    rendered = mi.render(scene, spp=2)
    layout = channel_layout(scene)
    out = tmp_path / "aov.exr"
    extra = np.arange(48, dtype=np.float32).reshape(6, 8)
    write_render_exr(out, rendered, layout, {"spp": 2, "note": "é"}, extra_layers={"variance": extra})
    image, meta, layers = read_exr(out)
    pixels = np.asarray(rendered)
    names = [name for name, _ in layout.kept()]
    assert names[:4] == ["R", "G", "B", "A"]
    np.testing.assert_array_equal(image, pixels[..., :4])
    for name, index in layout.layers:
        np.testing.assert_array_equal(layers[name], pixels[..., index])
    np.testing.assert_array_equal(layers["variance"], extra)
    assert set(layers) == {*layout.layer_names(), "variance"} and meta["note"] == "é" and meta["spp"] == 2
    with pytest.raises(ValueError, match=r"extra_layers\['variance'\]: expected a new \(H, W\)"):
        write_render_exr(tmp_path / "b.exr", rendered, layout, {}, extra_layers={"variance": extra[:2]})
    with pytest.raises(ValueError, match="metadata: 'channels' is a reserved EXR attribute name"):
        write_render_exr(tmp_path / "b.exr", rendered, layout, {"channels": 1})


def test_a_luminance_render_is_a_y_image(mi, tmp_path, cli):
    from pointillist.imaging.io import read_exr

    scene = _plain_scene(tmp_path, "luminance_alpha")
    done = cli("render", scene, "-o", tmp_path / "grey.exr")
    assert done.returncode == 0, done.stderr
    image, _, layers = read_exr(tmp_path / "grey.exr")
    assert image.shape == (16, 24) and list(layers) == ["A"]     # Y is the image, A a layer (as OpenEXR lists it)


@given(image=hnp.arrays(np.float32, st.tuples(st.integers(1, 5), st.integers(1, 5), st.integers(1, 6)),
                        elements=st.floats(width=32, allow_nan=False) | st.sampled_from([np.nan, np.inf])),
       data=st.data())
@settings(max_examples=40, deadline=None, derandomize=True, database=None)
def test_picking_channels_is_numpy_indexing(dr, image, data):
    """`ChannelLayout.pick` on a Dr.Jit tensor (one gather) equals numpy's fancy indexing."""
    from drjit.llvm import TensorXf

    from pointillist.channels import layout_from_names

    channels = image.shape[2]
    layout = layout_from_names(channels, False, [])
    indices = data.draw(st.lists(st.integers(0, channels - 1), min_size=1, max_size=7))
    picked = layout.pick(TensorXf(image), indices)
    np.testing.assert_array_equal(picked.numpy(), image[..., indices])
    np.testing.assert_array_equal(layout.pick(image, indices), image[..., indices])
    with pytest.raises(ValueError, match="image: the film and the integrator name"):
        layout.pick(TensorXf(image[..., :0] if channels > 1 else np.zeros((1, 1, 2), np.float32)), indices)


@given(x=st.floats(allow_nan=True, allow_infinity=True) | st.integers(-2**140, 2**140))
@settings(max_examples=300, deadline=None, derandomize=True, database=None)
def test_float32_arithmetic_without_numpy_is_numpys(x):
    """The checks' float32 rounding and the camera-relative rule's float32 spacing, written on
    Python floats, give numpy's float32 results (inf beyond the range, NaN kept)."""
    from pointillist.camera_relative import float32_spacing
    from pointillist.core.checks import round_to_float32

    with np.errstate(over="ignore", invalid="ignore"):
        as32 = float(np.float32(float(x))) if not abs(x) >= 2**1024 else math.copysign(math.inf, x)
        spacing = float(np.spacing(np.float32(abs(float(x))))) if not abs(x) >= 2**1024 else math.nan
    got = round_to_float32(x)
    assert got == as32 or (math.isnan(got) and math.isnan(as32))
    got = float32_spacing(x)
    if not math.isfinite(as32):
        assert math.isnan(got)                                  # numpy: nan for inf/nan
    else:
        assert got == spacing


def test_writing_a_render_on_a_one_thread_pool_returns(tmp_path):
    """Mitsuba's EXR writer never returns when Dr.Jit's pool has one thread (as in a Dask worker of
    a 2-core machine running 2 workers): the writer widens the pool for the write and restores it."""
    code = (
        "import sys, pointillist, drjit as dr; mi = pointillist.setup(); dr.set_thread_count(1)\n"
        "from pointillist.channels import layout_from_names\n"
        "from pointillist.render_output import write_render_exr\n"
        "image = mi.TensorXf(dr.arange(mi.Float, 4 * 5 * 3), shape=(4, 5, 3))\n"
        "write_render_exr(sys.argv[1], image, layout_from_names(3, False, []), {'spp': 1})\n"
        "print(dr.thread_count())\n")
    out = tmp_path / "one.exr"
    done = subprocess.run([sys.executable, "-c", code, str(out)], cwd=ROOT, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "1"                           # the pool is one thread again
    from pointillist.imaging.io import read_exr

    np.testing.assert_array_equal(read_exr(out).image, np.arange(60, dtype=np.float32).reshape(4, 5, 3))
