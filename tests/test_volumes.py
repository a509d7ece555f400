"""Volume loaders (.vol, .npy, NRRD, NIfTI, DICOM), the CT phantom and compact textures."""

from __future__ import annotations

import numpy as np
import pytest

import pointillist.imaging.volumes as volumes
from pointillist.imaging.volumes import (Volume, load_volume, read_vol, shepp_logan_phantom, volume_texture,
                                 write_vol)


def test_vol_round_trip_and_mitsuba_reads_it(rng, mi, tmp_path):
    data = rng.random((3, 4, 5)).astype(np.float32)
    write_vol(tmp_path / "a.vol", Volume(data, (0.5, 1.0, 2.0)))
    vol = load_volume(tmp_path / "a.vol")
    np.testing.assert_array_equal(vol.data, data)
    assert vol.spacing == (0.5, 1.0, 2.0) and vol.origin == (0.25, 0.5, 1.0)
    grid = mi.load_dict({"type": "gridvolume", "filename": str(tmp_path / "a.vol")})
    params = mi.traverse(grid)
    key = next(k for k in params.keys() if k.endswith("data"))
    np.testing.assert_array_equal(np.asarray(params[key])[..., 0], data)  # Mitsuba's layout (Z, Y, X)


def test_mitsuba_written_vol_is_read(rng, mi, tmp_path):
    data = rng.random((2, 3, 4)).astype(np.float32)
    mi.VolumeGrid(data[..., None]).write(str(tmp_path / "m.vol"))
    np.testing.assert_array_equal(read_vol(tmp_path / "m.vol").data, data)


@pytest.mark.parametrize("damage,message", [
    (lambda b: b[:20], "truncated .vol header"),
    (lambda b: b[:-4], "truncated .vol data"),
    (lambda b: b"XOL" + b[3:], "not a Mitsuba .vol"),
    (lambda b: b[:4] + bytes([2]) + b[5:], ".vol encoding 2"),
])
def test_corrupt_vol_files_raise(tmp_path, damage, message):
    write_vol(tmp_path / "a.vol", np.zeros((2, 2, 2), np.float32))
    (tmp_path / "b.vol").write_bytes(damage((tmp_path / "a.vol").read_bytes()))
    with pytest.raises(ValueError, match=message):
        load_volume(tmp_path / "b.vol")


@pytest.mark.parametrize("dtype", [np.int16, np.uint16, np.float32, ">i2"])
def test_npy_round_trip_keeps_dtype(rng, tmp_path, dtype):
    data = rng.integers(-1000, 3000, size=(4, 5, 6)).astype(dtype)
    if np.dtype(dtype).kind == "u":
        data = np.abs(data.astype(np.int32)).astype(dtype)
    np.save(tmp_path / "v.npy", data)
    vol = load_volume(tmp_path / "v.npy", spacing=(1, 2, 3))
    np.testing.assert_array_equal(vol.data, data)
    assert vol.data.dtype == np.dtype(dtype).newbyteorder("=") and vol.spacing == (1.0, 2.0, 3.0)


def test_npy_errors(tmp_path):
    np.save(tmp_path / "v.npy", np.zeros((8, 8, 8), np.int16))
    raw = (tmp_path / "v.npy").read_bytes()
    (tmp_path / "t.npy").write_bytes(raw[:-10])
    with pytest.raises(ValueError, match="truncated .npy"):
        load_volume(tmp_path / "t.npy")
    np.save(tmp_path / "flat.npy", np.zeros((8, 8), np.int16))
    with pytest.raises(ValueError, match="3-D"):
        load_volume(tmp_path / "flat.npy")
    with pytest.raises(ValueError, match="no such file"):
        load_volume(tmp_path / "missing.npy")
    (tmp_path / "x.xyz").write_bytes(b"")
    with pytest.raises(ValueError, match="unknown format"):
        load_volume(tmp_path / "x.xyz")
    with pytest.raises(ValueError, match="spacing"):
        load_volume(tmp_path / "v.npy", spacing=(1, 0, 1))


def test_nrrd_round_trip_with_spacing(rng, tmp_path):
    import nrrd

    data = rng.integers(-1024, 2000, size=(4, 5, 6)).astype(np.int16)  # (Z, Y, X)
    header = {"space": "left-posterior-superior", "space directions": np.diag([0.7, 0.8, 2.5]),
              "space origin": np.array([-10.0, 5.0, 30.0])}
    nrrd.write(str(tmp_path / "v.nrrd"), data, header, index_order="C")
    vol = load_volume(tmp_path / "v.nrrd")
    np.testing.assert_array_equal(vol.data, data)
    np.testing.assert_allclose(vol.spacing, (0.7, 0.8, 2.5))
    assert vol.data.dtype == np.int16 and vol.origin == (-10.0, 5.0, 30.0)
    (tmp_path / "bad.nrrd").write_bytes((tmp_path / "v.nrrd").read_bytes()[:60])
    with pytest.raises(ValueError, match="NRRD"):
        load_volume(tmp_path / "bad.nrrd")


def test_nifti_round_trip_uses_affine_spacing(rng, tmp_path):
    import nibabel

    data_ijk = rng.integers(0, 4000, size=(6, 5, 4)).astype(np.int16)  # NIfTI order (i=x, j=y, k=z)
    affine = np.diag([0.5, 0.9, 3.0, 1.0])
    affine[:3, 3] = (1.0, 2.0, 3.0)
    nibabel.save(nibabel.Nifti1Image(data_ijk, affine), str(tmp_path / "v.nii.gz"))
    vol = load_volume(tmp_path / "v.nii.gz")
    np.testing.assert_array_equal(vol.data, data_ijk.transpose(2, 1, 0))
    assert vol.shape_xyz == (6, 5, 4) and vol.data.dtype == np.int16
    np.testing.assert_allclose(vol.spacing, (0.5, 0.9, 3.0))
    (tmp_path / "bad.nii").write_bytes(b"\0" * 100)
    with pytest.raises(ValueError, match="NIfTI"):
        load_volume(tmp_path / "bad.nii")


def _write_dicom_series(rng, folder, hu, *, spacing=(0.6, 0.7), dz=2.5, slope=1.0, intercept=-1024.0):
    """One CT slice per file, written in shuffled order with pydicom; stored = (HU - b) / m."""
    import pydicom
    from pydicom.dataset import FileDataset, FileMetaDataset
    from pydicom.uid import CTImageStorage, ExplicitVRLittleEndian, generate_uid

    folder.mkdir()
    series = generate_uid()
    order = rng.permutation(hu.shape[0])
    for n, z in enumerate(order):
        meta = FileMetaDataset()
        meta.MediaStorageSOPClassUID = CTImageStorage
        meta.MediaStorageSOPInstanceUID = generate_uid()
        meta.TransferSyntaxUID = ExplicitVRLittleEndian
        ds = FileDataset(str(folder / f"s{n}.dcm"), {}, file_meta=meta, preamble=b"\0" * 128)
        ds.SOPClassUID, ds.SOPInstanceUID = CTImageStorage, meta.MediaStorageSOPInstanceUID
        ds.SeriesInstanceUID, ds.Modality = series, "CT"
        ds.Rows, ds.Columns = hu.shape[1], hu.shape[2]
        ds.PixelSpacing = [spacing[1], spacing[0]]  # row spacing (y), column spacing (x)
        ds.ImageOrientationPatient = [1, 0, 0, 0, 1, 0]
        ds.ImagePositionPatient = [-50.0, -60.0, 100.0 + dz * z]
        ds.InstanceNumber = int(n + 1)  # deliberately not the z order
        ds.SliceThickness = dz
        ds.RescaleSlope, ds.RescaleIntercept = slope, intercept
        ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
        ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 0
        stored = np.round((hu[z] - intercept) / slope).astype(np.uint16)
        ds.PixelData = stored.tobytes()
        pydicom.dcmwrite(str(folder / f"s{n}.dcm"), ds, enforce_file_format=True)


def test_dicom_series_sorted_and_rescaled_to_hu(rng, tmp_path):
    hu = rng.integers(-1024, 2000, size=(5, 6, 7)).astype(np.int16)
    _write_dicom_series(rng, tmp_path / "ct", hu)
    (tmp_path / "ct" / "notes.txt").write_text("not a DICOM file")
    vol = load_volume(tmp_path / "ct")
    np.testing.assert_array_equal(vol.data, hu)
    assert vol.data.dtype == np.int16
    np.testing.assert_allclose(vol.spacing, (0.6, 0.7, 2.5))
    assert vol.metadata["modality"] == "CT" and vol.origin == (-50.0, -60.0, 100.0)


def test_dicom_fractional_rescale_gives_float(rng, tmp_path):
    hu = rng.integers(0, 100, size=(3, 4, 4)).astype(np.float32) * 0.5
    _write_dicom_series(rng, tmp_path / "ct", hu, slope=0.5, intercept=-10.0)
    vol = load_volume(tmp_path / "ct")
    assert vol.data.dtype == np.float32
    np.testing.assert_array_equal(vol.data, hu)


def test_dicom_errors(rng, tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="no DICOM slices"):
        load_volume(tmp_path / "empty")
    hu = rng.integers(-1024, 2000, size=(3, 6, 7)).astype(np.int16)
    _write_dicom_series(rng, tmp_path / "ct", hu)
    victim = sorted((tmp_path / "ct").iterdir())[0]
    victim.write_bytes(victim.read_bytes()[:-40])  # truncated pixel data
    with pytest.raises(ValueError, match="DICOM"):
        load_volume(tmp_path / "ct")


def test_phantom_values_and_symmetry():
    v = shepp_logan_phantom((40, 48, 56))
    assert v.shape == (40, 48, 56) and v.dtype == np.int16
    assert set(np.unique(v).tolist()) <= {-1000, 5, 40, 70, 100, 800, 1200}
    assert {-1000, 40, 800, 5}.issubset(set(np.unique(v).tolist()))
    assert v[0, 0, 0] == -1000 and v[20, 24, 28] == 40  # air in the corner, brain at the centre
    # the outer two ellipsoids are centred on x = 0: the skull is mirror-symmetric in x
    outer = (v == 800)
    np.testing.assert_array_equal(outer, outer[:, :, ::-1])
    # HU volumes of the skull shell: about (V(a) - V(a')) of the two ellipsoids
    frac = (v != -1000).mean()
    assert abs(frac - 4 / 3 * np.pi * 0.69 * 0.92 * 0.81 / 8) < 0.01


def test_phantom_slab_evaluation_matches_one_slab(monkeypatch):
    whole = shepp_logan_phantom((30, 20, 20), dtype=np.float32)
    monkeypatch.setattr(volumes, "_PHANTOM_SLAB_VOXELS", 400 * 3)  # three slices a slab
    np.testing.assert_array_equal(shepp_logan_phantom((30, 20, 20), dtype=np.float32), whole)


@pytest.mark.parametrize("shape", [0, (1, 2), (2, 0, 3)])
def test_phantom_bad_shape(shape):
    with pytest.raises(ValueError, match="shape"):
        shepp_logan_phantom(shape)


def test_textures_are_compact_and_exact(rng, mi):
    ct = shepp_logan_phantom(16)
    tex = volume_texture(ct)
    assert tex.precision == "half" and tex.exact and tex.nbytes == ct.size * 2
    assert (tex.minimum, tex.maximum) == (float(ct.min()), float(ct.max())) == (-1000.0, 800.0)
    stored = np.asarray(tex.texture.tensor()).reshape(ct.shape).astype(np.float32) + tex.offset
    np.testing.assert_array_equal(stored, ct)
    wide = np.array([0, 40000], np.uint16).repeat(4).reshape(2, 2, 2)
    assert volume_texture(wide).precision == "single"
    forced = volume_texture(wide, precision="half")
    assert forced.precision == "half" and not forced.exact
    floats = volume_texture(rng.random((2, 2, 2)).astype(np.float32))
    assert floats.precision == "single" and floats.nbytes == 32
    with pytest.raises(ValueError, match="filter"):
        volume_texture(ct, filter="cubic")
    nan = volume_texture(np.full((2, 2, 2), np.nan, np.float32))
    assert np.isnan(nan.minimum) and np.isnan(nan.maximum)


def test_volume_validation():
    with pytest.raises(ValueError, match="3-D"):
        Volume(np.zeros((2, 2)))
    with pytest.raises(ValueError, match="non-empty"):
        Volume(np.zeros((0, 2, 2)))
    with pytest.raises(TypeError, match="real numeric"):
        Volume(np.zeros((2, 2, 2), complex))
    with pytest.raises(ValueError, match="spacing"):
        Volume(np.zeros((2, 2, 2)), (1.0, -1.0, 1.0))
    assert Volume(np.zeros((2, 3, 4)), 0.5).extent == (2.0, 1.5, 1.0)
