"""EXR/PNG I/O: exact round trips, metadata, atomic writes that never replace an input."""

from __future__ import annotations

import os

import numpy as np
import pytest
from PIL import Image

import colour
from pointillist.imaging.io import read_exr, read_image, to_8bit, write_exr, write_png


@pytest.mark.parametrize("shape", [(1, 1), (3, 5), (4, 2, 1), (3, 4, 3), (2, 3, 4)])
def test_exr_round_trip_is_exact(tmp_path, shape):
    rng = np.random.default_rng(1)
    image = (rng.standard_normal(shape) * 1e3).astype(np.float32)
    image.flat[0] = 1e30  # huge HDR values survive float32 EXR
    path = tmp_path / "x.exr"
    write_exr(path, image, {"spp": 16, "sampler": "jitter", "render_seconds": 1.25, "flag": True})
    back, meta, layers = read_exr(path)
    expected = image[..., 0] if image.ndim == 3 and image.shape[2] == 1 else image
    assert back.dtype == np.float32 and back.shape == expected.shape
    np.testing.assert_array_equal(back, expected)
    assert meta == {"spp": 16, "sampler": "jitter", "render_seconds": 1.25, "flag": 1}
    assert layers == {}


def test_exr_nan_inf_and_layers(tmp_path):
    image = np.array([[[np.nan, np.inf, -np.inf]]], np.float32)
    counts = np.array([[7.0]], np.float32)
    write_exr(tmp_path / "x.exr", image, layers={"spp": counts})
    back, _, layers = read_exr(tmp_path / "x.exr")
    assert np.isnan(back[0, 0, 0]) and back[0, 0, 1] == np.inf and back[0, 0, 2] == -np.inf
    np.testing.assert_array_equal(layers["spp"], counts)


def test_exr_accepts_drjit_tensor(tmp_path):
    from drjit.llvm import TensorXf

    image = np.arange(24, dtype=np.float32).reshape(2, 4, 3)
    write_exr(tmp_path / "t.exr", TensorXf(image))
    np.testing.assert_array_equal(read_exr(tmp_path / "t.exr").image, image)


def test_write_refuses_inputs_and_bad_arguments(tmp_path):
    path = tmp_path / "in.exr"
    write_exr(path, np.zeros((2, 2, 3), np.float32))
    read_exr(path)
    with pytest.raises(ValueError, match="refusing to overwrite the input"):
        write_exr(path, np.ones((2, 2, 3), np.float32))
    with pytest.raises(ValueError, match="refusing to overwrite the input"):
        write_png(path, np.ones((2, 2, 3), np.float32))
    other = tmp_path / "other.exr"
    other.write_bytes(b"")
    with pytest.raises(ValueError, match="refusing"):
        write_exr(other, np.ones((2, 2)), inputs=[other])
    with pytest.raises(ValueError, match="image: expected 1 or 2 or 3 or 4 channels"):  # 2: Y and A
        write_exr(tmp_path / "y.exr", np.zeros((2, 2, 5)))
    with pytest.raises(ValueError, match="shape"):
        write_exr(tmp_path / "y.exr", np.zeros(5))
    with pytest.raises(TypeError, match=r"metadata\['bad'\]"):
        write_exr(tmp_path / "y.exr", np.zeros((2, 2)), {"bad": [1, 2]})
    with pytest.raises(ValueError, match="reserved"):
        write_exr(tmp_path / "y.exr", np.zeros((2, 2)), {"channels": 1})
    with pytest.raises(ValueError, match="does not exist"):
        write_exr(tmp_path / "nofolder" / "y.exr", np.zeros((2, 2)))
    with pytest.raises(ValueError, match="layers"):
        write_exr(tmp_path / "y.exr", np.zeros((2, 2)), layers={"n": np.zeros((3, 3))})
    assert not (tmp_path / "y.exr").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.exr", "other.exr"]  # no temp files left


def test_read_errors(tmp_path):
    with pytest.raises(ValueError, match="no such EXR file"):
        read_exr(tmp_path / "missing.exr")
    bad = tmp_path / "bad.exr"
    bad.write_bytes(b"\x76\x2f\x31\x01garbage")
    with pytest.raises(ValueError, match="not a readable EXR"):
        read_exr(bad)
    with pytest.raises(ValueError, match="not a readable image"):
        read_image(_write(tmp_path / "b.png", b"nope"))


def _write(path, data):
    path.write_bytes(data)
    return path


def test_atomic_write_keeps_old_file_on_failure(tmp_path, monkeypatch):
    path = tmp_path / "x.exr"
    write_exr(path, np.ones((2, 2), np.float32))
    import OpenEXR

    class Boom(Exception):
        pass

    def explode(*args, **kwargs):
        raise Boom

    monkeypatch.setattr(OpenEXR, "File", explode)
    with pytest.raises(Boom):
        write_exr(path, np.zeros((2, 2), np.float32))
    monkeypatch.undo()
    np.testing.assert_array_equal(read_exr(path).image, np.ones((2, 2), np.float32))
    assert os.listdir(tmp_path) == ["x.exr"]


def test_png_is_srgb_encoded_through_colour(tmp_path):
    ramp = np.linspace(0, 1, 64, dtype=np.float32).reshape(8, 8)
    rgb = np.stack([ramp, ramp[::-1], np.full_like(ramp, 0.5)], axis=-1)
    write_png(tmp_path / "p.png", rgb)
    png = np.asarray(Image.open(tmp_path / "p.png"))
    expected = np.round(colour.cctf_encoding(rgb.astype(np.float64), function="sRGB") * 255).astype(np.uint8)
    np.testing.assert_array_equal(png, expected)
    # display-referred 0..255 data written as is
    write_png(tmp_path / "q.png", np.array([[0.0, 127.6, 255.0, 300.0]]), srgb=False, max_value=255)
    assert np.asarray(Image.open(tmp_path / "q.png")).tolist() == [[0, 128, 255, 255]]


def test_png_policy_for_nan_inf_negative():
    values = np.array([[np.nan, np.inf, -np.inf, -1.0, 2.0, 1e30]], np.float32)
    assert to_8bit(values).tolist() == [[0, 255, 0, 0, 255, 255]]
    with pytest.raises(ValueError, match="max_value"):
        to_8bit(values, max_value=0)


def test_read_image_png(tmp_path):
    data = np.arange(12, dtype=np.uint8).reshape(2, 2, 3) * 20
    Image.fromarray(data).save(tmp_path / "a.png")
    image, meta, layers = read_image(tmp_path / "a.png")
    np.testing.assert_array_equal(image, data.astype(np.float32))
    assert meta == {} and layers == {}


# ----------------------------------------------------------------------------------------------
# EXR through other readers and writers: OpenEXR's own API with explicit channel names and
# Mitsuba's Bitmap, both ways. Every channel holds other values (channel c: 10 c + a ramp), so a
# swapped channel order cannot go unnoticed.


def _asymmetric(channels, height=3, width=5):
    ramp = np.arange(height * width, dtype=np.float32).reshape(height, width) / 8
    return np.stack([10.0 * (c + 1) + ramp for c in range(channels)], axis=-1).astype(np.float32)


@pytest.mark.parametrize("channels, names", [(3, "RGB"), (4, "RGBA")])
def test_exr_written_by_us_has_named_channels_for_openexr(tmp_path, channels, names):
    import OpenEXR

    image = _asymmetric(channels)
    write_exr(tmp_path / "ours.exr", image, layers={"spp": image[..., 0] * 0 + 7})
    with OpenEXR.File(str(tmp_path / "ours.exr"), separate_channels=True) as exr:
        found = {name: np.asarray(channel.pixels) for name, channel in exr.channels().items()}
    assert sorted(found) == sorted([*names, "spp"])
    for c, name in enumerate(names):
        np.testing.assert_array_equal(found[name], image[..., c], err_msg=name)
    np.testing.assert_array_equal(found["spp"], np.full(image.shape[:2], 7, np.float32))


def test_exr_written_by_us_reads_the_same_in_mitsuba(mi, tmp_path):
    image = _asymmetric(3)
    write_exr(tmp_path / "ours.exr", image)
    bitmap = mi.Bitmap(str(tmp_path / "ours.exr"))
    assert bitmap.pixel_format() == mi.Bitmap.PixelFormat.RGB
    assert [field.name for field in bitmap.struct_()] == ["R", "G", "B"]
    np.testing.assert_array_equal(np.asarray(bitmap), image)


def test_grey_exr_is_a_y_channel(tmp_path):
    import OpenEXR

    image = _asymmetric(1)[..., 0]
    write_exr(tmp_path / "grey.exr", image)
    with OpenEXR.File(str(tmp_path / "grey.exr"), separate_channels=True) as exr:
        assert list(exr.channels()) == ["Y"]
        np.testing.assert_array_equal(exr.channels()["Y"].pixels, image)


@pytest.mark.parametrize("names", ["RGB", "RGBA"])
def test_exr_written_by_openexr_with_explicit_channels_reads_in_our_order(tmp_path, names):
    import OpenEXR

    image = _asymmetric(len(names))
    # Channels written one by one, by name, in an order that is neither RGB nor BGR.
    order = {"RGB": "GBR", "RGBA": "AGBR"}[names]
    channels = {name: np.ascontiguousarray(image[..., names.index(name)]) for name in order}
    with OpenEXR.File({"type": OpenEXR.scanlineimage}, channels) as exr:
        exr.write(str(tmp_path / "theirs.exr"))
    back = read_exr(tmp_path / "theirs.exr").image
    np.testing.assert_array_equal(back, image)


def test_exr_written_by_mitsuba_reads_in_our_order(mi, tmp_path):
    image = _asymmetric(3)
    mi.Bitmap(image, pixel_format=mi.Bitmap.PixelFormat.RGB).write(str(tmp_path / "mitsuba.exr"))
    np.testing.assert_array_equal(read_exr(tmp_path / "mitsuba.exr").image, image)
    rgba = _asymmetric(4)
    mi.Bitmap(rgba, pixel_format=mi.Bitmap.PixelFormat.RGBA).write(str(tmp_path / "rgba.exr"))
    np.testing.assert_array_equal(read_exr(tmp_path / "rgba.exr").image, rgba)
