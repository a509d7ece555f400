"""``pointillist post``: steps in order, EXR in / PNG or EXR out, --plot, one-line errors with exit status 2."""

from __future__ import annotations

import os
import re

import numpy as np
import pytest
from PIL import Image

from pointillist.imaging import tone
from pointillist.imaging.io import read_exr, to_8bit, write_exr, write_png
from pointillist.cli import main

RNG = np.random.default_rng(3)  # module-level data only (drawn once at import); tests use the `rng` fixture
HDR = (RNG.random((12, 16, 3)) ** 3 * 6).astype(np.float32)


@pytest.fixture
def exr(tmp_path):
    path = tmp_path / "render.exr"
    write_exr(path, HDR, {"spp": 4})
    return path


def run(capsys, *args):
    status = main(["post", *map(str, args)])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def png(path):
    with Image.open(path) as image:
        return np.asarray(image)


def test_exr_in_png_out_steps_in_order(exr, tmp_path, capsys):
    out = tmp_path / "out.png"
    status, stdout, err = run(capsys, exr, "-o", out, "--steps", "tonemap:reinhard,exposure=1;gamma:2.2",
                              "--step", "quantize:8")
    assert status == 0, err
    expected = tone.quantize(tone.gamma(tone.tonemap(HDR, "reinhard", 1.0), 2.2), 8)
    np.testing.assert_array_equal(png(out), to_8bit(expected, srgb=False, max_value=255))
    assert "wrote" in stdout
    # the other order gives the other composition (and a different image)
    other = tmp_path / "other.png"
    assert run(capsys, exr, "-o", other, "--steps", "tonemap:reinhard,exposure=1;quantize:8;gamma:2.2")[0] == 0
    expected_other = tone.gamma(tone.quantize(tone.tonemap(HDR, "reinhard", 1.0), 8), 2.2)
    np.testing.assert_array_equal(png(other), to_8bit(expected_other, srgb=False, max_value=255))
    assert not np.array_equal(png(other), png(out))


def test_display_step_on_exr_applies_tonemap_clip_first(exr, tmp_path, capsys):
    out = tmp_path / "eq.exr"
    status, _, err = run(capsys, exr, "-o", out, "--steps", "equalize")
    assert status == 0 and "tonemap:clip" in err
    image, metadata, _ = read_exr(out)
    np.testing.assert_array_equal(image, np.asarray(tone.equalize_histogram(tone.tonemap(HDR, "clip"))))
    assert metadata["post_steps"] == "tonemap:clip;equalize"


def test_png_input_and_plot(rng, tmp_path, capsys):
    source = tmp_path / "in.png"
    grey = rng.integers(0, 256, (20, 30)).astype(np.float32)
    write_png(source, grey, srgb=False, max_value=255)
    out = tmp_path / "stretched.png"
    status, stdout, err = run(capsys, source, "-o", out, "--steps", "stretch:50,20,200,235;equalize:16", "--plot")
    assert status == 0, err
    expected = tone.equalize_histogram(tone.contrast_stretch(grey, 50, 20, 200, 235), 16)
    np.testing.assert_array_equal(png(out), to_8bit(expected, srgb=False, max_value=255))
    plot = tmp_path / "stretched_histogram.png"
    assert plot.is_file() and str(plot) in stdout
    with Image.open(plot) as image:
        assert image.format == "PNG" and image.size[0] > 300


def test_plot_flags_do_not_swallow_the_input(rng, tmp_path, capsys):
    source = tmp_path / "in.png"
    write_png(source, rng.integers(0, 256, (8, 9)).astype(np.float32), srgb=False, max_value=255)
    # --plot first: it takes no value, so IN stays the input
    status, stdout, err = run(capsys, "--plot", source, "-o", tmp_path / "a.png", "--steps", "equalize")
    assert status == 0, err
    assert (tmp_path / "a_histogram.png").is_file()
    status, stdout, err = run(capsys, "--plot-file", tmp_path / "h.png", source, "-o", tmp_path / "b.png",
                              "--steps", "equalize")
    assert status == 0, err
    assert (tmp_path / "h.png").is_file() and not (tmp_path / "b_histogram.png").exists()


def test_non_finite_input_warns_on_one_line(tmp_path, capsys):
    bad = HDR.copy()
    bad[0, 0, 0], bad[1, 1, 1] = np.nan, np.inf
    source = tmp_path / "bad.exr"
    write_exr(source, bad)
    status, _, err = run(capsys, source, "-o", tmp_path / "bad.png", "--steps", "tonemap:aces")
    assert status == 0
    warning = [line for line in err.splitlines() if "non-finite" in line]
    assert len(warning) == 1 and "2 non-finite" in warning[0]


def test_list_steps_needs_no_files(capsys):
    status, stdout, _ = run(capsys, "--list-steps")
    assert status == 0
    for name in ("tonemap", "gamma", "stretch", "equalize", "quantize", "hsv", "grey", "lut"):
        assert f"\n{name}" in "\n" + stdout


def test_lut_step_reads_a_table(rng, tmp_path, capsys):
    table = tmp_path / "invert.txt"
    np.savetxt(table, 255 - np.arange(256))
    source = tmp_path / "g.png"
    grey = rng.integers(0, 256, (5, 6)).astype(np.float32)
    write_png(source, grey, srgb=False, max_value=255)
    out = tmp_path / "inv.png"
    assert run(capsys, source, "-o", out, "--steps", f"lut:{table}")[0] == 0
    np.testing.assert_array_equal(png(out), 255 - grey.astype(np.uint8))


@pytest.mark.parametrize("args, message", [
    (["--steps", "gamma:0"], "gamma"),
    (["--steps", "nosuchstep"], "unknown step"),
    (["--steps", "tonemap:filmic"], "operator"),
    (["--steps", "tonemap:hable,foo=1"], "foo"),
    (["--steps", "stretch:200,0,100,255"], "r1"),
    (["--steps", "quantize:1"], "levels"),
    (["--steps", "quantize"], "levels"),
    (["--steps", "hsv:30"], "RGB"),
    (["--steps", "lut:/no/such/table.txt"], "file"),
    (["--steps", "gamma:2.2", "--plot-file", "x.jpg"], "--plot-file"),
])
def test_bad_input_is_one_line_and_status_2(exr, tmp_path, capsys, args, message):
    source = exr
    if message == "RGB":  # hsv needs colour: give it a grey image
        source = tmp_path / "grey.exr"
        write_exr(source, HDR[..., 0])
    status, _, err = run(capsys, source, "-o", tmp_path / "x.png", *args)
    lines = err.strip().splitlines()  # the error alone: no notice (e.g. the automatic tonemap:clip) before it
    assert status == 2 and len(lines) == 1 and lines[0].startswith("pointillist post: error"), err
    assert message in lines[0], err
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize("steps, message", [
    ("gamma:2,gamma=3", "gamma given twice"),
    ("gamma:=3", "no name before '='"),
    ("gamma:", "missing a required argument: 'gamma'"),
    ("gamma:foo=1,gamma=2", "unexpected keyword argument 'foo'"),
    ("stretch:1,2", "missing a required argument: 'r2'"),
])
def test_step_arguments_are_checked_before_any_step_runs(exr, tmp_path, capsys, steps, message):
    # Before: "gamma:2,gamma=3" silently ran gamma 3; the others failed only after the
    # automatic tonemap:clip had printed its notice (two lines), naming private functions.
    from pointillist.core.errors import UsageError
    from pointillist.steps import parse_steps

    with pytest.raises(UsageError, match=re.escape(message)):
        parse_steps(steps)
    status, _, err = run(capsys, exr, "-o", tmp_path / "x.png", "--steps", steps)
    assert status == 2 and err.count("\n") == 1 and message in err, err
    assert "_gamma" not in err and not (tmp_path / "x.png").exists()


def test_plot_file_is_checked_before_writing_anything(exr, tmp_path, capsys):
    out = tmp_path / "out.png"
    # the plot used to replace the output just written (exit 0, output lost)
    status, _, err = run(capsys, exr, "-o", out, "--steps", "tonemap", "--plot-file", out)
    assert status == 2 and "--output file" in err and not out.exists()
    # a missing plot folder used to fail after the output was written
    status, _, err = run(capsys, exr, "-o", out, "--steps", "tonemap", "--plot-file", tmp_path / "no" / "h.png")
    assert status == 2 and "does not exist" in err and not out.exists()
    status, _, err = run(capsys, exr, "-o", out, "--steps", "tonemap", "--plot-file", tmp_path / "h.jpg")
    assert status == 2 and ".png" in err and not out.exists()
    status, _, err = run(capsys, exr, "-o", out, "--steps", "tonemap", "--plot-file", exr.with_suffix(".png"))
    assert status == 0 and out.is_file() and exr.with_suffix(".png").is_file(), err


def test_bad_files_and_subprocess_exit_status(exr, tmp_path, cli):
    result = cli("post", tmp_path / "missing.exr", "-o", tmp_path / "x.png", "--steps", "gamma:2")
    assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1
    assert "no such file" in result.stderr and "Traceback" not in result.stderr
    result = cli("post", exr, "-o", tmp_path / "x.jpg", "--steps", "gamma:2")
    assert result.returncode == 2 and "--output" in result.stderr
    result = cli("post", exr, "-o", exr, "--steps", "tonemap")
    assert result.returncode == 2 and "overwrite" in result.stderr
    result = cli("post", tmp_path / "x.png", "-o", tmp_path / "y.png", "--steps", "gamma:2")
    assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1


def test_tonemap_on_display_input_is_refused(tmp_path, capsys):
    source = tmp_path / "d.png"
    write_png(source, np.zeros((3, 3)), srgb=False, max_value=255)
    status, _, err = run(capsys, source, "-o", tmp_path / "t.png", "--steps", "tonemap:reinhard")
    assert status == 2 and "linear" in err


def test_apply_steps_docstring_and_linear_input():
    """apply_steps runs on arrays: its example runs, and linear input gets tonemap:clip first."""
    import doctest

    import pointillist.post as post

    result = doctest.testmod(post, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted >= 2 and result.failed == 0
    out = post.apply_steps(np.array([[0.0, 0.5], [1.0, 4.0]], np.float32), "threshold:level=128", linear=True)
    assert out.done == ["tonemap:clip", "threshold:level=128"] and not out.linear
    # clip then sRGB-encode: 0 -> 0, 0.5 -> 188, 1 and 4 -> 255; threshold 128
    assert np.asarray(out.image).tolist() == [[0.0, 255.0], [255.0, 255.0]]
    assert out.notes == ["the input is linear light; applied tonemap:clip first"]


def test_steps_take_and_pass_uint8_tensors(tmp_path, rng):
    """8-bit in, 8-bit out: the tone and dither steps hand uint8 tensors to each other and to the
    PNG writer; apply_steps takes a uint8 tensor as input (it computes on float32)."""
    from drjit.llvm.ad import TensorXu8

    from pointillist.post import apply_steps
    from pointillist.steps import steps

    grey8 = rng.integers(0, 256, (20, 24), dtype=np.uint8)
    known = steps()
    current = grey8
    for name, kwargs in (("gamma", {"gamma": 2.2}), ("equalize", {}), ("quantize", {"levels": 6}),
                         ("stretch", {"r1": 20, "s1": 10, "r2": 200, "s2": 240}),
                         ("dither", {"method": "floyd_steinberg"})):
        current = known[name].function(current, **kwargs)
        assert isinstance(current, TensorXu8), name
    write_png(tmp_path / "chain.png", current, srgb=False, max_value=255.0)
    assert np.array_equal(png(tmp_path / "chain.png"), np.asarray(current))
    applied = apply_steps(TensorXu8(grey8), "gamma:2.2;sobel")
    expected = apply_steps(grey8.astype(np.float32), "gamma:2.2;sobel")
    np.testing.assert_array_equal(np.asarray(applied.image), np.asarray(expected.image))


def test_eight_bit_chains_equal_the_chains_of_their_float_conversion():
    # 8-bit input stays bytes up to the first step that does not take them (grey reads the bytes):
    # the same float32 result, bit for bit, as the chain run on the float32 image
    from skimage import data

    from pointillist.post import apply_steps
    from pointillist.steps import steps

    assert [name for name, spec in steps().items() if spec.takes_bytes] == ["grey"]
    rng = np.random.default_rng(21)
    for image in (data.astronaut(), rng.integers(0, 256, (67, 45, 3), dtype=np.uint8), data.camera()):
        for chain in ("grey;gamma:2.2;sobel;normalize;threshold:level=128", "grey;equalize", "gamma:1.4;grey",
                      "grey", "sobel;normalize"):
            got = np.asarray(apply_steps(image, chain).image)
            expected = np.asarray(apply_steps(image.astype(np.float32), chain).image)
            assert got.dtype == expected.dtype and np.array_equal(got.view(np.uint8), expected.view(np.uint8)), chain


def test_list_steps_into_a_closed_pipe_ends_quietly_with_141():
    """`pointillist post --list-steps | head -1`: the reader leaves early; the command ends as a Unix
    tool killed by SIGPIPE does (status 141, nothing on stderr), not with "error: Broken pipe"."""
    import subprocess
    import sys

    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader is gone before the first write
    try:
        done = subprocess.run([sys.executable, "-c", "from pointillist.console import main; main()",
                               "post", "--list-steps"], stdout=write_end, stderr=subprocess.PIPE, text=True,
                              timeout=120)
    finally:
        os.close(write_end)
    assert done.returncode == 141 and done.stderr == "", (done.returncode, done.stderr)


def test_no_step_converts_an_exr_into_the_preview_render_writes(tmp_path, capsys, rng):
    """`post render.exr -o render.png` without steps writes the PNG that `render --png` writes (the
    preview: clipped, sRGB-encoded, to float32 rounding of an independent float64 encoding); an
    8-bit PNG is written as it is."""
    linear = (rng.random((9, 7, 3)) * 1.5).astype(np.float32)  # some values above 1: clipped
    write_exr(tmp_path / "r.exr", linear)
    status, stdout, _ = run(capsys, str(tmp_path / "r.exr"), "-o", str(tmp_path / "r.png"))
    assert status == 0 and "converted, no step" in stdout
    expected = np.clip(np.round(255 * tone_srgb(np.clip(linear, 0, 1))), 0, 255).astype(np.uint8)
    got = np.asarray(Image.open(tmp_path / "r.png"))
    assert got.shape == expected.shape and np.abs(got.astype(int) - expected).max() <= 1
    assert (got == expected).mean() > 0.99
    status, _, _ = run(capsys, str(tmp_path / "r.png"), "-o", str(tmp_path / "copy.png"))
    assert status == 0
    np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "copy.png")), got)


def tone_srgb(values):
    """The sRGB encoding of IEC 61966-2-1, in float64 (independent of the project's own)."""
    values = np.asarray(values, dtype=np.float64)
    return np.where(values <= 0.0031308, 12.92 * values, 1.055 * values ** (1 / 2.4) - 0.055)
