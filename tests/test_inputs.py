"""inputs read silently wrong, and parameters checked in float64 but used in float32.

Each test holds one defect of the issue (or one found beyond it while trying hostile inputs): it
failed before the fix. Independent references: OpenCV's readers (``cv2.imread``), numpy, nibabel's
and pydicom's own test files, and the float32 arithmetic itself.
"""

from __future__ import annotations

import gzip
import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import ROOT

FLOAT32_MAX = float(np.finfo(np.float32).max)


def _no_nan(image) -> bool:
    return not np.isnan(np.asarray(image, dtype=np.float32)).any()


# =============================================================================== defect 9: float32
# Parameters were checked as Python floats (float64) and then used in float32 Dr.Jit kernels.

GREY = np.linspace(0.0, 255.0, 64, dtype=np.float32).reshape(8, 8)
RGB = np.stack([GREY, GREY[::-1], GREY.T], axis=-1)


def test_resize_a_beyond_float32_is_refused_not_a_nan_image():
    """resize a=4e38 wrote a NaN image; a=1e30 too (its weights overflow float32). Keys' a is
    taken in -3..0, where the kernel falls from W(0) = 1 without a negative central lobe."""
    from pointillist.imaging.resample import KEYS_A_RANGE, keys_kernel, resize

    for a in (4e38, 1e30, -1e30, 0.5, -3.5):
        with pytest.raises(ValueError, match="^a: expected a number"):
            resize(GREY, (5, 5), "bicubic", a=a)
    assert KEYS_A_RANGE == (-3.0, 0.0)
    t = np.linspace(0.0, 1.0, 101)

    def central(a):  # Keys' W on [0, 1], written out
        return (a + 2) * t**3 - (a + 3) * t**2 + 1

    for a in KEYS_A_RANGE:   # the range's ends: W non-negative and non-increasing on [0, 1]
        np.testing.assert_allclose(keys_kernel(t, a), central(a))
        assert (central(a) >= -1e-12).all() and (np.diff(central(a)) <= 1e-12).all()
        assert _no_nan(resize(GREY, (5, 5), "bicubic", a=a))
    assert (central(0.25) < 0).any()                      # a > 0: W < 0 inside (0, 1)
    assert (np.diff(central(-3.25)) > 0).any()            # a < -3: W rises above W(0) = 1


def test_hsv_hue_beyond_float32_is_refused_and_huge_hues_wrap_exactly():
    """hsv:hue=4e38 wrote NaN; a hue float32 holds is wrapped in float64 first, so 1e30 degrees
    shifts as 1e30 mod 360 does (in float32, H + 1e30 loses H)."""
    from pointillist.imaging.colour import adjust_hsv

    with pytest.raises(ValueError, match=r"^hue: expected a number float32 can hold"):
        adjust_hsv(RGB, hue=4e38, max_value=255.0)
    for hue in (1e30, -1e30, 7.5e20, -1e-30):
        np.testing.assert_allclose(np.asarray(adjust_hsv(RGB, hue=hue, max_value=255.0)),
                                   np.asarray(adjust_hsv(RGB, hue=hue % 360.0, max_value=255.0)), atol=1e-3)


def test_hsv_value_overflow_is_capped_not_nan():
    """V x value beyond float32 was inf, and then V (1 - S) = inf x 0 = NaN for saturated colours:
    V is capped at float32's largest value."""
    from pointillist.imaging.colour import adjust_hsv

    red = np.zeros((1, 2, 3), np.float32)
    red[..., 0] = [200.0, 255.0]
    out = np.asarray(adjust_hsv(red, value=1e37, max_value=255.0))
    assert _no_nan(out)
    np.testing.assert_array_equal(out[0, :, 1:], 0.0)      # G and B of pure red stay 0
    np.testing.assert_array_equal(out[0, :, 0], np.float32(FLOAT32_MAX))


def test_stretch_slope_beyond_float32_is_refused():
    """stretch:0,0,1e-300,255 passed the float64 checks and wrote NaN: its slope 2.55e302 is
    inf in float32. Each derived slope is checked and names its breakpoint."""
    from pointillist.imaging.tone import contrast_stretch

    with pytest.raises(ValueError, match=r"^r2: the slope \(s2 - s1\) / \(r2 - r1\) is 2\.55e\+302, beyond float32"):
        contrast_stretch(GREY, 0, 0, 1e-300, 255)
    with pytest.raises(ValueError, match=r"^r1: the slope s1 / r1 is 2\.55e\+42"):
        contrast_stretch(GREY, 1e-40, 255, 200, 255)
    # a steep but finite slope is fine, and a step (r1 = r2) has no slope at all
    assert _no_nan(contrast_stretch(GREY, 0, 0, 1e-30, 255))
    assert _no_nan(contrast_stretch(GREY, 100, 0, 100, 255))


@pytest.mark.parametrize("call, name", [
    (lambda t: t.gamma(GREY, 2.0, a=1e-45), "a"),                 # 1 / (a max_value) overflows
    (lambda t: t.gamma(GREY, 2.0, max_value=4e38), "max_value"),
    (lambda t: t.quantize(GREY, 4, max_value=1e-42), "max_value"),  # (levels - 1) / max_value overflows
    (lambda t: t.quantize(GREY, 2**24, max_value=1e32), "max_value"),  # max_value (levels - 1) overflows
    (lambda t: t.equalize_histogram(GREY, max_value=1e-42), "max_value"),
    (lambda t: t.histogram(GREY, max_value=1e-42), "max_value"),
    (lambda t: t.tonemap(RGB, "reinhard", white=4e38), "white"),
    (lambda t: t.tonemap(RGB, "hable", white=1e-42), "white"),     # was ZeroDivisionError
    (lambda t: t.lut(GREY, np.full(256, 1e39)), "table"),
])
def test_tone_parameters_and_their_scales_hold_in_float32(call, name):
    from pointillist.imaging import tone

    with pytest.raises(ValueError, match=f"^{name}: "):
        call(tone)


@pytest.mark.parametrize("call, name", [
    (lambda: __import__("pointillist.imaging.filters", fromlist=["f"]).threshold(GREY, 4e38), "level"),
    (lambda: __import__("pointillist.imaging.filters", fromlist=["f"]).threshold(GREY, 1, max_value=4e38),
     "max_value"),
    (lambda: __import__("pointillist.imaging.filters", fromlist=["f"]).zero_crossings(GREY - 100, max_value=4e38),
     "max_value"),
    (lambda: __import__("pointillist.imaging.filters", fromlist=["f"]).correlate(GREY, [[1e39]]), "kernel"),
    (lambda: __import__("pointillist.imaging.dither", fromlist=["f"]).floyd_steinberg(GREY, level=4e38), "level"),
    (lambda: __import__("pointillist.imaging.window", fromlist=["f"]).window_image(GREY, 1e39, 1.0), "window level"),
    (lambda: __import__("pointillist.imaging.window", fromlist=["f"]).window_image(GREY, 100, 1e-300),
     "window width"),
    (lambda: __import__("pointillist.imaging.colour", fromlist=["f"]).luminance(RGB, max_value=4e38), "max_value"),
])
def test_other_imaging_reals_hold_in_float32(call, name):
    """Each was taken (an inf or all-black image; the window's 1 / 1e-300 is inf in float32)."""
    with pytest.raises(ValueError, match=f"^{name}: "):
        call()


def test_gamma_keeps_its_limits_beyond_float32():
    """gamma itself never reaches float32 (the kernel sees 1 / gamma, whose overflow to 0 or inf
    the curve takes as its limits): gammas beyond float32 keep a defined result."""
    from pointillist.imaging.tone import gamma

    x = np.array([[0.0, 128.0, 255.0]], np.float32)
    assert np.asarray(gamma(x, 1e300)).tolist() == [[0.0, 255.0, 255.0]]
    assert np.asarray(gamma(x, 1e-300)).tolist() == [[0.0, 0.0, 255.0]]
    with pytest.raises(ValueError, match="^gamma: expected a number > 0"):
        gamma(x, 0.0)


_REAL = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                  st.sampled_from([4e38, -4e38, 3.4e38, 1e-300, -1e-300, 1e-45, 1e-40, 1e30, -1e30, 0.0]))


@settings(max_examples=60, deadline=None)
@given(step=st.sampled_from(["gamma", "stretch", "hsv", "resize", "threshold", "tonemap", "quantize"]),
       values=st.lists(_REAL, min_size=4, max_size=4))
def test_no_post_step_turns_a_finite_image_into_nan(step, values):
    """The class (defect 9): any real parameter of the post steps either is refused with a ValueError
    naming it, or gives an image without NaN (a NaN pixel is written as black)."""
    from pointillist.post import apply_steps

    v = values
    text = {"gamma": f"gamma:{v[0]!r},a={v[1]!r}",
            "stretch": "stretch:" + ",".join(repr(x) for x in sorted(abs(x) for x in v)),
            "hsv": f"hsv:hue={v[0]!r},saturation={abs(v[1])!r},value={abs(v[2])!r}",
            "resize": f"resize:5,3,bicubic,a={v[0]!r}",
            "threshold": f"threshold:{v[0]!r}",
            "tonemap": f"tonemap:hable,exposure={v[0]!r},white={v[1]!r}",
            "quantize": "quantize:7"}[step].replace("inf", "1e999")  # "1e999" parses as inf
    image = RGB * 0.01 if step == "tonemap" else RGB
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = apply_steps(image, text, linear=step == "tonemap")
    except ValueError as error:   # UsageError is a ValueError
        assert "\n" not in str(error) and ": " in str(error)
        return
    assert _no_nan(result.image), text


# =============================================================================== defect 8: volumes

def _nifti_gz(path: Path, data: np.ndarray) -> bytes:
    import nibabel

    nibabel.save(nibabel.Nifti1Image(data, np.eye(4)), str(path))
    return path.read_bytes()


def test_nifti_gz_with_a_bad_crc_is_refused_not_projected(tmp_path, rng):
    """nibabel reads a .nii.gz only up to the end of the voxel data, so the gzip trailer (CRC-32,
    length) was never checked: a damaged file was projected with other values, exit 0."""
    from pointillist.imaging.volumes import load_volume

    data = rng.integers(0, 1000, (40, 40, 40)).astype(np.int16)   # large enough to span deflate blocks
    raw = bytearray(_nifti_gz(tmp_path / "ok.nii.gz", data))
    np.testing.assert_array_equal(load_volume(tmp_path / "ok.nii.gz").data, data.transpose(2, 1, 0))
    damaged = {"crc.nii.gz": (len(raw) - 8, "CRC check failed"),        # the trailer's CRC-32
               "length.nii.gz": (len(raw) - 2, "Incorrect length"),      # the trailer's length
               "middle.nii.gz": (len(raw) // 2, "CRC check failed")}     # a byte of the voxel data
    for name, (offset, why) in damaged.items():
        bad = raw.copy()
        bad[offset] ^= 0xFF
        (tmp_path / name).write_bytes(bad)
        with pytest.raises(ValueError, match=f"damaged or truncated gzip data \\({why}"):
            load_volume(tmp_path / name)
    (tmp_path / "cut.nii.gz").write_bytes(raw[:-10])
    with pytest.raises(ValueError, match="damaged or truncated gzip data"):
        load_volume(tmp_path / "cut.nii.gz")


def test_nifti_real_files_still_read(tmp_path):
    """nibabel's own compressed test files (NIfTI-1 4-D, NIfTI-2) read through the checked stream."""
    import nibabel
    from nibabel.testing import data_path

    from pointillist.imaging.volumes import load_volume

    for name, frame in (("example4d.nii.gz", 1), ("example_nifti2.nii.gz", 0), ("standard.nii.gz", None)):
        path = os.path.join(data_path, name)
        expected = np.asanyarray(nibabel.load(path).dataobj)
        expected = expected[..., frame] if frame is not None else expected
        np.testing.assert_array_equal(load_volume(path, frame=frame).data, expected.transpose(2, 1, 0))


def test_nifti_header_claiming_more_than_the_file_holds_is_refused_first(tmp_path):
    """A 480-byte file claiming 4000^3 int16 voxels (128 GB): refused from its size, before
    reading (was an empty 'not a readable NIfTI file ()' after a MemoryError, or an allocation)."""
    import nibabel

    from pointillist.imaging.volumes import load_volume

    header = nibabel.Nifti1Image(np.zeros((4, 4, 4), np.int16), np.eye(4)).header.copy()
    header.set_data_shape((4000, 4000, 4000))
    raw = header.binaryblock + b"\0" * 4 + np.zeros(64, np.int16).tobytes()
    (tmp_path / "huge.nii").write_bytes(raw)
    (tmp_path / "huge.nii.gz").write_bytes(gzip.compress(raw))
    with pytest.raises(ValueError, match=r"claims 4000x4000x4000 voxels of int16 \(128000000000 bytes\) but the file "
                                         r"holds 480 bytes"):
        load_volume(tmp_path / "huge.nii")
    with pytest.raises(ValueError, match=r"holds at most \d+ bytes once decompressed"):   # deflate: 1032:1 at most
        load_volume(tmp_path / "huge.nii.gz")


def _dicom_file(path: Path, rows: int, cols: int, pixels: bytes, **tags):
    sys.path.insert(0, str(Path(__file__).parent))
    from medical_files import _dataset
    from pydicom.uid import generate_uid

    ds, pydicom = _dataset(path, rows, cols, generate_uid())
    for key, value in tags.items():
        setattr(ds, key, value)
    ds.PixelData = pixels
    pydicom.dcmwrite(str(path), ds, enforce_file_format=True)


@pytest.mark.timeout(120)  # before the fix: 167 s and 4.3 GB (a regression fails here, not hangs)
def test_dicom_claiming_millions_of_frames_is_refused_before_allocating(tmp_path):
    from pointillist.imaging.volumes import load_volume

    folder = tmp_path / "frames"
    folder.mkdir()
    _dicom_file(folder / "a.dcm", 4, 4, np.zeros((4, 4), "<i2").tobytes(), NumberOfFrames=4_000_000)
    assert (folder / "a.dcm").stat().st_size < 1000
    with pytest.raises(ValueError, match=r"claims 4000000 frame\(s\) of 4 x 4 at 16 bits \(128000000 bytes\) but the "
                                         r"file holds 32 bytes of pixel data"):
        load_volume(folder)
    (folder / "a.dcm").unlink()
    _dicom_file(folder / "b.dcm", 60000, 60000, b"\0" * 64)      # Rows x Columns alone: 7.2 GB claimed
    with pytest.raises(ValueError, match="claims 1 frame"):
        load_volume(folder)


def _axial_series(folder: Path):
    sys.path.insert(0, str(Path(__file__).parent))
    from medical_files import asymmetric_object, write_dicom_axial

    obj = asymmetric_object()
    write_dicom_axial(folder, obj)
    return obj, sorted(folder.iterdir())


@pytest.mark.parametrize("which", [0, -1])
def test_dicom_orientation_rule_does_not_depend_on_the_file_order(tmp_path, which):
    """A zero ImageOrientationPatient on the slice read first was taken as axial with a warning,
    the same files with it elsewhere were refused: one rule now, refused either way."""
    import pydicom

    from pointillist.imaging.volumes import load_volume

    _, files = _axial_series(tmp_path / "s")
    ds = pydicom.dcmread(files[which])
    ds.ImageOrientationPatient = [0.0] * 6
    ds.save_as(files[which])
    with pytest.raises(ValueError, match=r"has a degenerate \[0\.0, 0\.0, 0\.0, 0\.0, 0\.0, 0\.0\] "
                                         r"ImageOrientationPatient, image .* has "
                                         r"\[1\.0, 0\.0, 0\.0, 0\.0, 1\.0, 0\.0\]"):
        load_volume(tmp_path / "s")


def test_dicom_without_any_usable_orientation_is_axial_with_one_warning(tmp_path):
    import pydicom

    from pointillist.imaging.volumes import OrientationWarning, load_volume

    obj, files = _axial_series(tmp_path / "s")
    for file in files:
        ds = pydicom.dcmread(file)
        ds.ImageOrientationPatient = [0.0] * 6
        ds.save_as(file)
    with pytest.warns(OrientationWarning, match=r"degenerate ImageOrientationPatient .*; assumed axial"):
        volume = load_volume(tmp_path / "s")
    np.testing.assert_array_equal(volume.data, obj)


@pytest.mark.parametrize("cut", [100, 300, -50])
def test_dicom_slice_cut_short_is_an_error_never_a_slice_left_out(tmp_path, cut):
    """pydicom reads a file cut short without a word (up to where it ends): a slice without pixel
    data was skipped (and one cut in its preamble taken as "not DICOM"), giving a volume with a
    slice missing and only an uneven-spacing warning."""
    from pointillist.imaging.volumes import load_volume

    obj, files = _axial_series(tmp_path / "s")
    data = files[2].read_bytes()
    files[2].write_bytes(data[:cut])
    with pytest.raises(ValueError, match=files[2].name):
        load_volume(tmp_path / "s")


def test_dicom_colour_and_palette_images_are_refused_by_name(tmp_path):
    """pydicom's own colour files: RGB was 'slice X is (60, 80, 3), expected (60, 80)', a two-frame
    RGB 'cannot reshape array', and a palette image was projected as its palette indices."""
    from pydicom.data import get_testdata_file

    from pointillist.imaging.volumes import read_dicom_series

    import shutil

    for name, kind in (("SC_rgb_rle_2frame.dcm", "RGB with 3 sample"), ("examples_palette.dcm", "PALETTE COLOR"),
                       ("SC_ybr_full_422_uncompressed.dcm", "YBR_FULL_422")):
        folder = tmp_path / name
        folder.mkdir()
        shutil.copy(get_testdata_file(name), folder)
        with pytest.raises(ValueError, match=f"PhotometricInterpretation {kind}"):
            read_dicom_series(folder)


def test_library_messages_reach_the_user_as_one_line(tmp_path, monkeypatch):
    """pydicom's 'no plugin can decode' message is 3-4 lines (a missing JPEG-LS decoder here);
    every reader passes library messages on as one line."""
    import shutil

    import pydicom
    from pydicom.data import get_testdata_file

    from pointillist.imaging.volumes import load_volume

    folder = tmp_path / "jls"
    folder.mkdir()
    shutil.copy(get_testdata_file("MR_small_jpeg_ls_lossless.dcm"), folder)

    def fail(self):
        raise RuntimeError("Unable to decompress:\n  gdcm - requires gdcm\n  pylibjpeg - requires pylibjpeg\n")

    monkeypatch.setattr(pydicom.dataset.Dataset, "pixel_array", property(fail))
    with pytest.raises(ValueError) as caught:
        load_volume(folder)
    assert "\n" not in str(caught.value)
    assert "Unable to decompress: gdcm - requires gdcm pylibjpeg - requires pylibjpeg" in str(caught.value)


def test_one_line():
    from pointillist.core.errors import one_line

    assert one_line("a\n  b \n\n c") == "a b c"
    assert one_line("x" * 500) == "x" * 397 + "..."
    assert one_line(ValueError("")) == ""


def test_int32_volume_above_2_24_is_not_labelled_exact():
    """float32 holds integers exactly only up to 2^24: an int32 volume above was 'exact'."""
    from pointillist.imaging.volumes import volume_texture

    above = np.array([[[0, 2**24 + 1, 7]]], np.int32)
    at = np.array([[[0, 2**24, 7]]], np.int32)
    assert volume_texture(above, ad=False).exact is False
    assert float(np.asarray(volume_texture(above, ad=False).texture.tensor()).ravel()[1]) == 2**24   # rounded
    assert volume_texture(at, ad=False).exact is True
    assert volume_texture(np.full((2, 2, 2), 0.1), ad=False).exact is False      # float64 0.1 is rounded
    assert volume_texture(np.full((2, 2, 2), 0.5), ad=False).exact is True
    near = np.arange(8, dtype=np.int32).reshape(2, 2, 2) + 2**24 + 1              # narrow: was half + offset
    texture = volume_texture(near, ad=False)
    assert texture.exact is False and texture.precision == "single"


def test_float64_volume_beyond_float32_is_refused_not_projected_as_inf():
    from pointillist.imaging.volumes import volume_texture

    for data in (np.full((2, 2, 2), 1e300), np.array([[[1.0, -1e39]]])):
        with pytest.raises(ValueError, match="beyond float32"):
            volume_texture(data, ad=False)
    assert volume_texture(np.array([[[np.inf, 1.0]]]), ad=False).precision == "single"   # inf is data


def _nrrd(path: Path, fields: str, data: np.ndarray) -> None:
    head = (f"NRRD0004\ntype: short\ndimension: 3\nsizes: {data.shape[2]} {data.shape[1]} {data.shape[0]}\n"
            f"endian: little\nencoding: raw\n{fields}\n")
    path.write_bytes(head.encode() + data.astype("<i2").tobytes())


def test_nrrd_space_directions_none_falls_back(tmp_path, rng):
    """'space directions: none ...' in a 3-D file was refused; it falls back like a file without
    directions (with a warning), and one 'none' axis of three is completed as the normal."""
    from pointillist.imaging.volumes import OrientationWarning, load_volume

    data = rng.integers(0, 100, (3, 4, 5)).astype(np.int16)
    _nrrd(tmp_path / "none.nrrd", "space directions: none none none\nspacings: 0.5 2 3\n", data)
    with pytest.warns(OrientationWarning, match="give none, none, none; voxel axes x, y, z taken as L, P, S"):
        volume = load_volume(tmp_path / "none.nrrd")
    np.testing.assert_array_equal(volume.data, data)
    assert volume.spacing == (0.5, 2.0, 3.0) and volume.axis_codes == "LPS"
    _nrrd(tmp_path / "one.nrrd", "space: right-anterior-superior\nspace directions: (0,2,0) none (0,0,3)\n"
          "spacings: nan 4 nan\n", data)
    with pytest.warns(OrientationWarning, match=r"axis 1 has no space direction \('none'\); taken as the right-handed "
                                                "normal of the other two, 4 long"):
        volume = load_volume(tmp_path / "one.nrrd")
    # axis 0 runs anterior (RAS +y), axis 2 superior; the missing axis 1 = axis 2 x axis 0 (right-handed
    # axes) runs to the left (RAS -x), 4 long; in LPS: axis 0 = (0, -2, 0), axis 1 = (4, 0, 0)
    np.testing.assert_allclose(volume.affine[:3, :3], [[0, 4, 0], [-2, 0, 0], [0, 0, 3]])
    assert np.linalg.det(volume.affine[:3, :3]) > 0


def test_nrrd_header_claiming_more_than_the_file_holds_is_refused_first(tmp_path):
    from pointillist.imaging.volumes import load_volume

    path = tmp_path / "short.nrrd"
    path.write_bytes(b"NRRD0004\ntype: short\ndimension: 3\nsizes: 40 30 20\nendian: little\nencoding: raw\n\n"
                     + b"\0" * 1000)
    with pytest.raises(ValueError, match=r"claims 40x30x20 values of type short \(48000 bytes\) but the file holds "
                                         r"1080 bytes"):
        load_volume(path)


def test_vol_bounding_box_must_be_finite_and_ordered(tmp_path):
    """A NaN or inverted .vol box was taken as a flat one (spacing 1); inf gave a message without the file."""
    import struct

    from pointillist.imaging.volumes import load_volume

    for name, box in (("nan", (0, 0, 0, np.nan, 1, 1)), ("inf", (0, 0, 0, np.inf, 1, 1)),
                      ("inverted", (1, 1, 1, 0, 0, 0))):
        path = tmp_path / f"{name}.vol"
        path.write_bytes(b"VOL\x03" + struct.pack("<i3ii6f", 1, 2, 2, 2, 1, *box) + np.zeros(8, "<f4").tobytes())
        with pytest.raises(ValueError, match=f"{name}.vol: bad .vol bounding box"):
            load_volume(path)


# =============================================================================== EXR

def _exr(path: Path, channels: dict, **header) -> None:
    import OpenEXR

    with OpenEXR.File({"type": OpenEXR.scanlineimage, "compression": OpenEXR.ZIP_COMPRESSION, **header},
                      channels) as exr:
        exr.write(str(path))


def _box(x0, y0, x1, y1):
    return (np.array([x0, y0], np.int32), np.array([x1, y1], np.int32))


def test_multipart_exr_reads_rgb_from_any_part(tmp_path, rng):
    """RGB in part 1 was refused ('has no Y or RGB channels'): only part 0 was read."""
    import OpenEXR

    from pointillist.imaging.io import read_exr

    r, z = rng.random((4, 5)).astype(np.float32), rng.random((4, 5)).astype(np.float32)
    header = {"type": OpenEXR.scanlineimage, "compression": OpenEXR.ZIP_COMPRESSION}
    parts = [OpenEXR.Part(header, {"Z": z}, name="depth"),
             OpenEXR.Part(dict(header, spp=16), {"R": r, "G": r + 1, "B": r + 2, "A": r * 0 + 1}, name="beauty")]
    with OpenEXR.File(parts) as exr:
        exr.write(str(tmp_path / "m.exr"))
    image, metadata, layers = read_exr(tmp_path / "m.exr")
    np.testing.assert_array_equal(image, np.stack([r, r + 1, r + 2, r * 0 + 1], axis=-1))
    assert sorted(layers) == ["depth.Z"] and metadata["spp"] == 16
    np.testing.assert_array_equal(layers["depth.Z"], z)


def test_deep_exr_is_refused_by_name(tmp_path):
    """A deep EXR gave 'setting an array element with a sequence'."""
    import OpenEXR

    from pointillist.imaging.io import read_exr

    samples = np.empty((2, 3), dtype=object)
    for index in np.ndindex(samples.shape):
        samples[index] = np.arange(sum(index) + 1, dtype=np.float32)
    with OpenEXR.File({"type": OpenEXR.deepscanline, "compression": OpenEXR.ZIPS_COMPRESSION},
                      {"R": samples, "G": samples, "B": samples}) as exr:
        exr.write(str(tmp_path / "deep.exr"))
    with pytest.raises(ValueError, match=r"is a deep EXR \(part 'part0': several samples a pixel\); only flat images "
                                         r"are read: flatten it first"):
        read_exr(tmp_path / "deep.exr")


def test_exr_data_window_is_placed_in_the_display_window(tmp_path, rng):
    """Windows were ignored: the data window came back without its offset (as OpenCV's imread reads
    it). The image is the display window, the data-window pixels at their offset, zeros elsewhere
    (as exrdisplay and oiiotool --croptofull show it); hand-placed expectations."""
    from pointillist.imaging.io import read_exr

    r = rng.random((4, 5)).astype(np.float32)
    channels = {"R": r, "G": r + 1, "B": r + 2}
    _exr(tmp_path / "inside.exr", channels, dataWindow=_box(2, 1, 6, 4), displayWindow=_box(0, 0, 9, 7))
    image = read_exr(tmp_path / "inside.exr").image
    assert image.shape == (8, 10, 3)
    np.testing.assert_array_equal(image[1:5, 2:7], np.stack([r, r + 1, r + 2], axis=-1))
    outside = np.ones(image.shape[:2], bool)
    outside[1:5, 2:7] = False
    assert (image[outside] == 0).all()
    # overscan: data beyond the display window (negative coordinates) is left out
    _exr(tmp_path / "over.exr", channels, dataWindow=_box(-3, -2, 1, 1), displayWindow=_box(0, 0, 3, 2))
    over = read_exr(tmp_path / "over.exr").image
    assert over.shape == (3, 4, 3)
    np.testing.assert_array_equal(over[:2, :2, 0], r[2:, 3:])
    assert (over[2:] == 0).all() and (over[:, 2:] == 0).all()
    # both windows offset alike: the data as it is; disjoint: refused (it was an all-black image without a word)
    _exr(tmp_path / "moved.exr", channels, dataWindow=_box(10, 20, 14, 23), displayWindow=_box(10, 20, 14, 23))
    np.testing.assert_array_equal(read_exr(tmp_path / "moved.exr").image[..., 0], r)
    _exr(tmp_path / "apart.exr", channels, dataWindow=_box(100, 100, 104, 103), displayWindow=_box(0, 0, 4, 3))
    with pytest.raises(ValueError, match=r"its data window \(100, 100, 104, 103\) lies wholly outside its display "
                                         r"window \(0, 0, 4, 3\)"):
        read_exr(tmp_path / "apart.exr")


def test_damaged_exr_pixels_say_so(tmp_path, rng):
    """OpenEXR gives up on damaged pixel data with a warning and no parts: that was 'holds no channels'."""
    from pointillist.imaging.io import _framed, read_exr

    r = rng.random((64, 64)).astype(np.float32)
    _exr(tmp_path / "g.exr", {"R": r, "G": r, "B": r})
    data = (tmp_path / "g.exr").read_bytes()
    (tmp_path / "cut.exr").write_bytes(data[:-1])
    with pytest.raises(ValueError, match=r"cut.exr: its pixel data cannot be read, a damaged or truncated file \("):
        read_exr(tmp_path / "cut.exr")
    # a subsampled channel (luminance/chroma images) is refused, not stretched: the data window is 4 x 2
    with pytest.raises(ValueError, match=r"channel 'RY' is subsampled \(2 x 1 values for a 4 x 2 data window\)"):
        _framed(tmp_path / "yc.exr", "RY", np.zeros((1, 2), np.float32), (0, 0, 3, 1), (0, 0, 3, 1))


def test_exr_huge_display_window_is_refused_before_allocating(tmp_path):
    from pointillist.imaging.io import read_exr

    r = np.zeros((2, 2), np.float32)
    _exr(tmp_path / "big.exr", {"R": r, "G": r, "B": r}, displayWindow=_box(0, 0, 2**20, 2**20))
    with pytest.raises(ValueError, match=r"display window 1048577 x 1048577 .* more than 2147483647"):
        read_exr(tmp_path / "big.exr")


# =============================================================================== other images

def _cv2(path: Path) -> np.ndarray:
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)   # BGR, BGRA
    return image if image.ndim == 2 else image[..., [2, 1, 0, 3][:image.shape[2]]]


def test_float_tiff_keeps_its_values_as_opencv_reads_them(tmp_path, rng):
    """A float TIFF was clipped to 0..255, rounded and made RGB."""
    from PIL import Image

    from pointillist.imaging.io import read_image

    values = (rng.random((4, 5)) * 1000 - 100).astype(np.float32)
    Image.fromarray(values, mode="F").save(tmp_path / "f.tif")
    image = read_image(tmp_path / "f.tif").image
    np.testing.assert_array_equal(image, values)
    np.testing.assert_array_equal(image, _cv2(tmp_path / "f.tif"))


def test_integer_tiffs_keep_their_values_as_opencv_reads_them(tmp_path, rng):
    """int32 was divided by 257 (taken as 16-bit), signed 16-bit too, and signed 8-bit read as unsigned."""
    import cv2
    from PIL import Image

    from pointillist.imaging.io import read_image

    int32 = rng.integers(-2**20, 2**20, (4, 5)).astype(np.int32)   # float32 holds these exactly
    Image.fromarray(int32, mode="I").save(tmp_path / "i32.tif")
    int16 = np.arange(-10, 10, dtype=np.int16).reshape(4, 5)
    Image.fromarray(int16).save(tmp_path / "i16.tif")
    int8 = np.arange(-10, 10, dtype=np.int8).reshape(4, 5)
    cv2.imwrite(str(tmp_path / "i8.tif"), int8)
    for name, values in (("i32.tif", int32), ("i16.tif", int16), ("i8.tif", int8)):
        image = read_image(tmp_path / name).image
        np.testing.assert_array_equal(image, values.astype(np.float32), err_msg=name)
        np.testing.assert_array_equal(image, _cv2(tmp_path / name), err_msg=name)


def test_sixteen_bit_grey_and_8_bit_modes_as_documented(tmp_path, rng):
    """16-bit grey stays value / 257; LAB was taken as RGBA (its mode name holds an 'A'); a palette
    with transparency lost its alpha."""
    import cv2
    from PIL import Image

    from pointillist.imaging.io import read_image

    grey16 = rng.integers(0, 65536, (4, 5)).astype(np.uint16)
    cv2.imwrite(str(tmp_path / "g16.png"), grey16)
    np.testing.assert_allclose(read_image(tmp_path / "g16.png").image, grey16 / 257.0, rtol=1e-6)
    rgb = (rng.random((4, 5, 3)) * 255).astype(np.uint8)
    Image.fromarray(rgb).convert("LAB").save(tmp_path / "lab.tif")
    lab = read_image(tmp_path / "lab.tif").image
    assert lab.shape == (4, 5, 3)  # was (4, 5, 4): the L, a, b bytes and a fourth channel
    np.testing.assert_array_equal(lab, np.asarray(Image.open(tmp_path / "lab.tif").convert("RGB")))
    assert np.abs(lab - rgb).max() <= 10  # back near the RGB it came from (Pillow's 8-bit LAB round trip)
    Image.fromarray(np.dstack([rgb, np.full((4, 5), 128, np.uint8)]), "RGBA").convert("P").save(tmp_path / "p.png")
    np.testing.assert_array_equal(read_image(tmp_path / "p.png").image, _cv2(tmp_path / "p.png"))


def test_decompression_bomb_is_one_line(tmp_path):
    """A PNG header claiming 100000 x 100000 pixels: Pillow's DecompressionBombError escaped (exit 1)."""
    import struct
    import zlib

    from PIL import Image

    from pointillist.imaging.io import read_image

    Image.fromarray(np.zeros((4, 4), np.uint8)).save(tmp_path / "ok.png")
    data = bytearray((tmp_path / "ok.png").read_bytes())
    data[16:24] = struct.pack(">II", 100_000, 100_000)                  # IHDR width and height
    data[29:33] = struct.pack(">I", zlib.crc32(bytes(data[12:29])))    # and its CRC, so Pillow opens it
    (tmp_path / "bomb.png").write_bytes(data)
    with pytest.raises(ValueError, match=r"bomb.png is too large to read \(Image size \(10000000000 pixels") as caught:
        read_image(tmp_path / "bomb.png")
    assert "\n" not in str(caught.value)


# =============================================================================== mip

def test_neurological_leaves_the_sagittal_view_and_refuses_a_turntable(mi, tmp_path):
    """--neurological mirrored the sagittal view too, whose horizontal axis is anterior-posterior
    (3D Slicer and ITK-SNAP flip only axial and coronal views); a turntable would flip mid-way."""
    from pointillist.core.errors import UsageError
    from pointillist.mip import patient_view, render_mip

    assert patient_view("sagittal", neurological=True)["labels"] == patient_view("sagittal")["labels"]
    assert patient_view("coronal", neurological=True)["labels"]["left"] == "L"
    oblique = patient_view(None, 30.0, 10.0, neurological=True)["labels"]["left"]
    assert "L" in oblique or "R" in oblique  # an oblique view keeps a left-right component, and is mirrored
    np.save(tmp_path / "v.npy", np.zeros((4, 4, 4), np.float32))
    with pytest.raises(UsageError, match="--neurological is for still views"):
        render_mip(tmp_path / "v.npy", tmp_path / "t.png", turntable=4, neurological=True, size=(8, 8))


def test_native_size_equals_numpy_max_exactly_only_with_nearest(mi, rng):
    """The README said --native-size equals numpy.max exactly; with the default trilinear lookups
    it agrees to float32 rounding, a few 1e-6 of the largest value (as the MIP guide now says)."""
    from pointillist.imaging.volumes import Volume
    from pointillist.mip import project_volume

    data = rng.integers(-1000, 3000, (9, 12, 10)).astype(np.int16)
    volume = Volume(data, (1.0, 1.0, 1.0))
    nearest, _ = project_volume(volume, view="axial", native=True, interpolation="nearest")
    np.testing.assert_array_equal(nearest, data.max(axis=0))
    trilinear, _ = project_volume(volume, view="axial", native=True)
    error = np.abs(trilinear - data.max(axis=0)).max()
    assert error <= 1e-5 * np.abs(data).max()


def test_perspective_too_narrow_is_refused_before_mitsuba(mi):
    """--perspective 1e-300 put the camera at 1e302 radii: Mitsuba refused its near/far clip (exit 1)."""
    from pointillist.mip import PERSPECTIVE_MIN_FOV, check_perspective, project_volume

    with pytest.raises(ValueError, match=r"^--perspective: expected a number >= 0\.0279"):
        project_volume(np.zeros((4, 4, 4), np.float32), view="axial", perspective=1e-300, size=(8, 8))
    assert check_perspective(PERSPECTIVE_MIN_FOV) == PERSPECTIVE_MIN_FOV
    assert 1.0 / np.sin(np.radians(PERSPECTIVE_MIN_FOV) / 2) == pytest.approx(4096.0)
    with pytest.raises(ValueError, match="< 180"):
        check_perspective(180.0)


def test_huge_spacing_is_not_called_sheared():
    """A spacing of 1e300: the column norms overflowed and the axes were 'not orthogonal'."""
    from pointillist.imaging.orientation import check_affine

    _, spacing, directions = check_affine(np.diag([1e300, 1e300, 2e300, 1.0]))
    assert spacing == (1e300, 1e300, 2e300)
    np.testing.assert_array_equal(directions, np.eye(3))


# =============================================================================== the command line

CASES = [
    # (id, argv, expected exit status, a piece of the one stderr line)
    ("stretch-1e-300", ["post", "{d}/g.png", "-o", "{o}/x.png", "--steps", "stretch:0,0,1e-300,255"], 2,
     "--steps: stretch: r2: the slope"),
    ("hsv-4e38", ["post", "{d}/c.png", "-o", "{o}/x.png", "--steps", "hsv:hue=4e38"], 2, "hue: expected a number"),
    ("resize-a-4e38", ["post", "{d}/g.png", "-o", "{o}/x.png", "--steps", "resize:4,4,bicubic,a=4e38"], 2,
     "a: expected a number"),
    ("mip-background-4e38", ["mip", "{d}/v.npy", "-o", "{o}/x.exr", "--size", "8", "--background", "4e38"], 2,
     "background: expected a number float32 can hold"),
    ("mip-perspective-tiny", ["mip", "{d}/v.npy", "-o", "{o}/x.png", "--size", "8", "--perspective", "1e-300"], 2,
     "--perspective"),
    ("mip-window-1e39", ["mip", "{d}/v.npy", "-o", "{o}/x.png", "--size", "8", "--window", "1e39,10"], 2,
     "window level"),
    ("mip-crc", ["mip", "{d}/crc.nii.gz", "-o", "{o}/x.png", "--size", "8"], 2, "CRC check failed"),
    ("mip-turntable-neurological", ["mip", "{d}/v.npy", "-o", "{o}/x.png", "--size", "8", "--turntable", "4",
                                    "--neurological"], 2, "--neurological is for still views"),
    ("mip-sagittal-neurological", ["mip", "{d}/v.npy", "-o", "{o}/x.exr", "--size", "8", "--view", "sagittal",
                                   "--neurological"], 0, None),
    ("post-float-tiff", ["post", "{d}/f.tif", "-o", "{o}/x.exr", "--steps", "grey"], 0, None),
]


@pytest.fixture(scope="module")
def command_line(tmp_path_factory):
    """Run :data:`CASES` in one process through the hostile suite's driver; results by id."""
    import nibabel
    from PIL import Image

    root = tmp_path_factory.mktemp("inputs")
    d = root / "in"
    d.mkdir()
    rng = np.random.default_rng(26)
    Image.fromarray((rng.random((8, 8)) * 255).astype(np.uint8)).save(d / "g.png")
    Image.fromarray((rng.random((8, 8, 3)) * 255).astype(np.uint8)).save(d / "c.png")
    Image.fromarray((rng.random((8, 8)) * 1000).astype(np.float32), mode="F").save(d / "f.tif")
    np.save(d / "v.npy", np.arange(512, dtype=np.float32).reshape(8, 8, 8))
    nibabel.save(nibabel.Nifti1Image(rng.integers(0, 1000, (40, 40, 40)).astype(np.int16), np.eye(4)),
                 str(d / "crc.nii.gz"))
    raw = bytearray((d / "crc.nii.gz").read_bytes())
    raw[-8] ^= 0xFF
    (d / "crc.nii.gz").write_bytes(raw)
    cases, folders = [], {}
    for name, argv, _, _ in CASES:
        folders[name] = root / "out" / name
        folders[name].mkdir(parents=True)
        cases.append({"id": name, "argv": [a.format(d=d, o=folders[name]) for a in argv]})
    (root / "cases.json").write_text(json.dumps(cases))
    env = {k: v for k, v in os.environ.items() if k != "POINTILLIST_DEBUG"}
    subprocess.run([sys.executable, str(Path(__file__).with_name("_hostile_driver.py")), str(root / "cases.json"),
                    str(root / "results.jsonl")], cwd=ROOT, env=env, timeout=600, capture_output=True)
    results = {}
    for line in (root / "results.jsonl").read_text().splitlines():
        entry = json.loads(line)
        results[entry["id"]] = entry
    return results, folders, d


@pytest.mark.parametrize("name, argv, status, text", CASES, ids=[c[0] for c in CASES])
def test_command_line(command_line, name, argv, status, text):
    results, folders, d = command_line
    result = results.get(name, {})
    assert result.get("rc") == status, result
    assert "Traceback" not in result["stderr"]
    if status == 2:
        lines = result["stderr"].splitlines()
        assert len(lines) == 1 and text in lines[0], lines
        assert list(folders[name].iterdir()) == []
    elif name == "mip-sagittal-neurological":
        from pointillist.imaging.io import read_exr

        meta = read_exr(folders[name] / "x.exr").metadata
        assert (meta["image_left"], meta["image_right"], meta["view_right"]) == ("A", "P", "0,1,0")
    else:
        from PIL import Image

        from pointillist.imaging.io import read_exr

        written = read_exr(folders[name] / "x.exr").image
        np.testing.assert_array_equal(written, np.asarray(Image.open(d / "f.tif"), np.float32))
