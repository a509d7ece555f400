"""Real data shipped by the packages: scikit-image's images through the imaging operations
(against OpenCV and scikit-image), nibabel's and pydicom's test files through the volume readers
(against nibabel and pydicom themselves). All are test dependencies: imported, not skipped."""

from __future__ import annotations

import shutil

import cv2
import nibabel
import numpy as np
import pydicom
import pytest
from pointillist.imaging import colour, filters, resample, tone
from pointillist.imaging.volumes import load_volume
from skimage import data


@pytest.fixture(scope="module")
def camera():
    return data.camera()  # 512 x 512 uint8 photograph


@pytest.fixture(scope="module")
def astronaut():
    return data.astronaut()  # 512 x 512 x 3 uint8 photograph


# -- imaging operations on photographs ---------------------------------------------------------

def test_median_equals_opencv_on_camera(camera):
    for size in (3, 5):
        np.testing.assert_array_equal(np.asarray(filters.median(camera, size)), cv2.medianBlur(camera, size))


def test_threshold_equals_opencv_on_camera(camera):
    # OpenCV's THRESH_BINARY is "> thresh": on integers, >= 128 is > 127.
    _, expected = cv2.threshold(camera, 127, 255, cv2.THRESH_BINARY)
    np.testing.assert_array_equal(np.asarray(filters.threshold(camera)), expected.astype(np.float32))


def test_sobel_equals_opencv_on_camera(camera):
    image = camera.astype(np.float32)
    gx = cv2.Sobel(image, cv2.CV_32F, 1, 0, ksize=3, borderType=cv2.BORDER_REPLICATE)
    gy = cv2.Sobel(image, cv2.CV_32F, 0, 1, ksize=3, borderType=cv2.BORDER_REPLICATE)
    np.testing.assert_allclose(np.asarray(filters.sobel(camera, border="clamp")), np.hypot(gx, gy),
                               rtol=1e-5, atol=1e-2)


def test_gaussian_correlate_equals_opencv_on_astronaut(astronaut):
    image = astronaut.astype(np.float32)
    expected = cv2.filter2D(image, -1, np.asarray(filters.GAUSSIAN_3, np.float32), borderType=cv2.BORDER_REFLECT_101)
    np.testing.assert_allclose(np.asarray(filters.correlate(astronaut, filters.GAUSSIAN_3, border="mirror")), expected,
                               atol=2e-3)


def test_resize_equals_opencv_on_astronaut(astronaut):
    image = astronaut.astype(np.float32)
    for size in ((200, 130), (700, 611)):
        np.testing.assert_allclose(np.asarray(resample.resize(image, size, "bilinear")),
                                   cv2.resize(image, size, interpolation=cv2.INTER_LINEAR), atol=1e-2)
        np.testing.assert_allclose(np.asarray(resample.resize(image, size, "bicubic", a=-0.75)),
                                   cv2.resize(image, size, interpolation=cv2.INTER_CUBIC), atol=2e-2)


def test_hsv_equals_scikit_image_on_astronaut(astronaut):
    from skimage.color import rgb2hsv

    rgb = astronaut.astype(np.float32) / 255
    ours = np.asarray(colour.rgb_to_hsv(rgb), dtype=np.float64)
    theirs = rgb2hsv(rgb.astype(np.float64))  # h, s, v all on 0..1
    np.testing.assert_allclose(ours[..., 1:], theirs[..., 1:], atol=1e-5)
    hue = ours[..., 0] / 360.0 if ours[..., 0].max() > 1.5 else ours[..., 0]
    coloured = theirs[..., 1] > 1e-3  # hue is arbitrary on greys
    difference = np.abs(hue - theirs[..., 0])[coloured]
    np.testing.assert_allclose(np.minimum(difference, 1 - difference), 0, atol=1e-4)


def test_gamma_equals_scikit_image_on_camera(camera):
    from skimage.exposure import adjust_gamma

    # skimage: out = 255 (I / 255)^g on uint8 (rounded); ours with gamma = 1/g, on floats.
    ours = np.asarray(tone.gamma(camera.astype(np.float32), 1 / 2.2))
    theirs = adjust_gamma(camera, 2.2)
    assert np.abs(ours - theirs).max() <= 0.5 + 1e-3


def test_equalize_histogram_agrees_with_opencv_on_camera(camera):
    ours = np.asarray(tone.equalize_histogram(camera)).astype(np.int64)  # uint8 out: widen before subtracting
    assert np.abs(ours - cv2.equalizeHist(camera)).max() <= 2


# -- volume readers on the packages' own files ---------------------------------------------------

def test_nibabel_anatomical_nii():
    from nibabel.testing import data_path

    path = f"{data_path}/anatomical.nii"
    image = nibabel.load(path)
    vol = load_volume(path)
    np.testing.assert_allclose(vol.data, np.asarray(image.get_fdata()).transpose(2, 1, 0), rtol=1e-6)
    assert vol.shape_xyz == image.shape[:3]
    np.testing.assert_allclose(vol.spacing, image.header.get_zooms()[:3], rtol=1e-6)


def test_nibabel_example4d_needs_a_frame():
    import nibabel
    from nibabel.testing import data_path

    with pytest.raises(ValueError, match="4-D with 2 frames"):
        load_volume(f"{data_path}/example4d.nii.gz")
    image = nibabel.load(f"{data_path}/example4d.nii.gz")
    frame = load_volume(f"{data_path}/example4d.nii.gz", frame=1)
    np.testing.assert_allclose(frame.data, np.asarray(image.dataobj[..., 1], np.float32).transpose(2, 1, 0))


def test_pydicom_ct_small(tmp_path):
    from pydicom.data import get_testdata_file
    from pydicom.pixels import apply_modality_lut

    source = get_testdata_file("CT_small.dcm")
    ds = pydicom.dcmread(source)
    folder = tmp_path / "ct"
    folder.mkdir()
    shutil.copy(source, folder / "slice.dcm")
    vol = load_volume(folder)
    hu = apply_modality_lut(ds.pixel_array, ds)
    assert vol.data.shape == (1, int(ds.Rows), int(ds.Columns))
    np.testing.assert_array_equal(vol.data[0], hu)
    row, column = (float(v) for v in ds.PixelSpacing)
    np.testing.assert_allclose(vol.spacing, (column, row, float(ds.SliceThickness)))
    np.testing.assert_allclose(vol.origin, [float(v) for v in ds.ImagePositionPatient])
    # The same slice three times, moved along the slice normal and written out of order: the
    # reader stacks them by position (not by file name or instance number).
    orientation = np.asarray(ds.ImageOrientationPatient, float)
    normal = np.cross(orientation[:3], orientation[3:])
    series = tmp_path / "series"
    series.mkdir()
    for name, step, offset in (("a.dcm", 2, 0), ("b.dcm", 0, 100), ("c.dcm", 1, -100)):
        copy = pydicom.dcmread(source)
        copy.ImagePositionPatient = [float(p) + 2.5 * step * n for p, n in zip(ds.ImagePositionPatient, normal)]
        copy.InstanceNumber = 10 + step
        copy.PixelData = (ds.pixel_array.astype(np.int32) + offset).astype(ds.pixel_array.dtype).tobytes()
        copy.save_as(folder.parent / "series" / name)
    stacked = load_volume(series)
    np.testing.assert_array_equal(stacked.data, np.stack([hu + 100, hu - 100, hu]))
    assert stacked.spacing[2] == pytest.approx(2.5)
