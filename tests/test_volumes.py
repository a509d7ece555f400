"""Volume loaders (.vol, .npy, NRRD, NIfTI, DICOM), the CT phantom and compact textures."""

from __future__ import annotations

import numpy as np
import pytest

import pointillist.imaging.volumes as volumes
import pointillist.imaging.volumes._phantom as volumes_phantom
import pointillist.imaging.volumes._texture as volumes_texture
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
    monkeypatch.setattr(volumes_phantom, "_PHANTOM_SLAB_VOXELS", 400 * 3)  # three slices a slab
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


@pytest.mark.parametrize("dtype, low, high, shape", [(np.int16, -1000, 1200, (20, 30, 40)),
                                                     (np.int16, -32768, 32767, (7, 9, 10)),
                                                     (np.uint16, 0, 65535, (8, 9, 10)),
                                                     (np.uint16, 100, 3000, (8, 9, 10)),
                                                     (np.uint8, 0, 256, (5, 7, 9)),
                                                     (np.int16, -5, 5, (3, 3, 3))])
def test_half_storage_of_integers_equals_numpys_conversion(rng, mi, monkeypatch, dtype, low, high, shape):
    # 8- and 16-bit integers go to half precision in one Dr.Jit pass (16-bit read as words); the
    # stored halves equal numpy's slab-by-slab conversion, exact (offset subtracted) or rounded
    # (forced half on a wide range), and an odd voxel count (no whole words) takes numpy's way
    data = rng.integers(low, high, shape).astype(dtype)
    for precision in ("auto", "half"):
        ours = volume_texture(data, precision=precision)
        with monkeypatch.context() as patch:
            patch.setattr(volumes_texture, "_half_of_integers", lambda *args: None)
            numpy_way = volume_texture(data, precision=precision)
        assert (ours.precision, ours.offset, ours.exact, ours.nbytes) == \
            (numpy_way.precision, numpy_way.offset, numpy_way.exact, numpy_way.nbytes)
        a = np.asarray(ours.texture.tensor().array).view(np.uint16 if ours.precision == "half" else np.uint32)
        b = np.asarray(numpy_way.texture.tensor().array).view(a.dtype)
        assert np.array_equal(a, b)
    import drjit as dr

    whole_words = data.size % 2 == 0 or dtype == np.uint8
    assert (volumes_texture._half_of_integers(data, 0.0, dr.llvm.ad) is not None) == whole_words
    assert volumes_texture._half_of_integers(data.astype(np.float32), 0.0, dr.llvm.ad) is None  # numpy converts floats


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


# ---------------------------------------------------------------------------------------------
# Patient space (LPS): every reader's voxel-to-patient transform
# ---------------------------------------------------------------------------------------------
def _lps_points(vol, ijk):
    """Patient LPS positions of voxel indices (i, j, k) = (x, y, z) of ``vol``."""
    ijk = np.asarray(ijk, dtype=np.float64)
    return ijk @ vol.affine[:3, :3].T + vol.affine[:3, 3]


def _patient_grid_equal(vol, obj, spacing, origin):
    """``vol`` holds ``obj`` (LPS order) voxel for voxel: each voxel value lies at the same patient point."""
    nz, ny, nx = obj.shape
    z, y, x = (a.ravel() for a in np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing="ij"))
    points = np.stack([x * spacing[0], y * spacing[1], z * spacing[2]], axis=1) + np.asarray(origin)
    ijk = np.linalg.solve(vol.affine[:3, :3], (points - vol.affine[:3, 3]).T).T
    index = np.round(ijk).astype(int)
    np.testing.assert_allclose(ijk, index, atol=1e-6)
    np.testing.assert_array_equal(vol.data[index[:, 2], index[:, 1], index[:, 0]], obj[z, y, x])


@pytest.mark.parametrize("axcodes", ["RAS", "LAS", "LPI", "PSL", "LPS"])
def test_nifti_affine_converted_from_ras_to_lps(tmp_path, axcodes):
    import nibabel

    from medical_files import ORIGIN, SPACING, asymmetric_object, write_nifti
    from pointillist.imaging.orientation import LPS_FROM_RAS

    obj = asymmetric_object()
    image = write_nifti(tmp_path / "o.nii.gz", obj, axcodes)
    vol = load_volume(tmp_path / "o.nii.gz")
    np.testing.assert_allclose(vol.affine, np.diag([-1, -1, 1, 1]) @ image.affine)
    np.testing.assert_allclose(vol.affine, LPS_FROM_RAS @ image.affine)
    assert vol.axis_codes == "".join(nibabel.aff2axcodes(image.affine)) == axcodes and vol.oriented
    np.testing.assert_allclose(sorted(vol.spacing), sorted(SPACING))
    _patient_grid_equal(vol, obj, SPACING, ORIGIN)


def test_nrrd_space_directions_in_lps_and_ras(tmp_path):
    from medical_files import ORIGIN, SPACING, asymmetric_object, write_nrrd_permuted

    obj = asymmetric_object()
    for space in ("left-posterior-superior", "right-anterior-superior"):
        write_nrrd_permuted(tmp_path / f"{space}.nrrd", obj, space=space)
        vol = load_volume(tmp_path / f"{space}.nrrd")
        assert vol.axis_codes == "ASL" and vol.spacing == (SPACING[1], SPACING[2], SPACING[0])
        _patient_grid_equal(vol, obj, SPACING, ORIGIN)


def test_nrrd_scanner_space_and_no_space_warn_and_assume_lps(tmp_path):
    import nrrd

    data = np.zeros((2, 3, 4), np.int16)
    nrrd.write(str(tmp_path / "s.nrrd"), data, {"space": "scanner-xyz", "space directions": np.diag([1.0, 2, 3])},
               index_order="C")
    with pytest.warns(volumes.OrientationWarning, match="scanner-xyz.*taken as LPS"):
        vol = load_volume(tmp_path / "s.nrrd")
    assert vol.axis_codes == "LPS" and vol.spacing == (1.0, 2.0, 3.0)
    nrrd.write(str(tmp_path / "n.nrrd"), data, {"spacings": [0.5, 0.5, 2.0]}, index_order="C")
    with pytest.warns(volumes.OrientationWarning, match="without 'space directions'"):
        vol = load_volume(tmp_path / "n.nrrd")
    assert vol.axis_codes == "LPS" and not vol.oriented


def test_dicom_coronal_series_placed_in_lps(tmp_path):
    from medical_files import ORIGIN, SPACING, asymmetric_object, write_dicom_coronal

    obj = asymmetric_object()
    write_dicom_coronal(tmp_path / "cor", obj)
    vol = load_volume(tmp_path / "cor")
    assert vol.axis_codes == "LIP" and vol.data.shape == (obj.shape[1], obj.shape[0], obj.shape[2])
    np.testing.assert_allclose(vol.spacing, (SPACING[0], SPACING[2], SPACING[1]))
    _patient_grid_equal(vol, obj, SPACING, ORIGIN)


def test_npy_and_vol_have_no_orientation():
    vol = Volume(np.zeros((2, 3, 4)), (0.5, 1.0, 2.0), (1.0, 2.0, 3.0))
    assert not vol.oriented and vol.axis_codes == "LPS"
    np.testing.assert_array_equal(vol.affine, [[0.5, 0, 0, 1], [0, 1, 0, 2], [0, 0, 2, 3], [0, 0, 0, 1]])
    respaced = vol.respaced((1.0, 1.0, 1.0))
    assert respaced.spacing == (1.0, 1.0, 1.0) and respaced.origin == (1.0, 2.0, 3.0)


def test_sheared_affines_are_refused(tmp_path):
    import nibabel

    sheared = np.array([[1.0, 0.3, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    with pytest.raises(ValueError, match="not orthogonal"):
        Volume(np.zeros((2, 2, 2)), affine=sheared)
    nibabel.save(nibabel.Nifti1Image(np.zeros((3, 3, 3), np.int16), sheared), str(tmp_path / "s.nii"))
    with pytest.raises(ValueError, match=r"s\.nii.*sheared"):
        load_volume(tmp_path / "s.nii")
    from medical_files import write_dicom_slices

    images = [np.full((4, 4), n, np.int16) for n in range(3)]
    tilted = [(0.0, 0.5 * n, 2.0 * n) for n in range(3)]  # a gantry tilt: slices slide posterior
    write_dicom_slices(tmp_path / "tilt", images, (1, 0, 0, 0, 1, 0), tilted, (1.0, 1.0))
    with pytest.raises(ValueError, match="sheared"):
        load_volume(tmp_path / "tilt")


def test_missing_or_degenerate_dicom_orientation_warns_one_line(tmp_path):
    from medical_files import write_dicom_slices

    images = [np.full((3, 4), n, np.int16) for n in range(3)]
    positions = [(0.0, 0.0, 3.0 * n) for n in range(3)]
    write_dicom_slices(tmp_path / "no_iop", images, None, positions, (1.0, 1.0))
    with pytest.warns(volumes.OrientationWarning) as caught:
        vol = load_volume(tmp_path / "no_iop")
    assert len(caught) == 1 and "\n" not in str(caught[0].message)
    assert "assumed axial (1,0,0,0,1,0)" in str(caught[0].message)
    assert vol.axis_codes == "LPS" and vol.spacing == (1.0, 1.0, 3.0)
    write_dicom_slices(tmp_path / "zero_iop", images, (0, 0, 0, 0, 0, 0), positions, (1.0, 1.0))
    with pytest.warns(volumes.OrientationWarning, match="degenerate ImageOrientationPatient"):
        load_volume(tmp_path / "zero_iop")
    write_dicom_slices(tmp_path / "no_ipp", images, (1, 0, 0, 0, 1, 0), None, (1.0, 1.0))
    with pytest.warns(volumes.OrientationWarning, match="no ImagePositionPatient"):
        vol = load_volume(tmp_path / "no_ipp")
    np.testing.assert_array_equal(vol.data[:, 0, 0], [0, 1, 2])  # InstanceNumber order


def test_nifti_without_sform_or_qform_warns(tmp_path):
    import nibabel

    image = nibabel.Nifti1Image(np.zeros((2, 3, 4), np.int16), None)
    image.header.set_sform(None, code=0)
    image.header.set_qform(None, code=0)
    nibabel.save(image, str(tmp_path / "bare.nii"))
    with pytest.warns(volumes.OrientationWarning, match="without sform or qform.*LAS"):
        vol = load_volume(tmp_path / "bare.nii")
    assert vol.axis_codes == "LAS"


def test_dicom_folder_with_two_series_needs_a_choice(tmp_path):
    from medical_files import asymmetric_object, write_dicom_axial

    obj = asymmetric_object()
    first = write_dicom_axial(tmp_path / "mixed", obj, series="1.2.3.4")
    second = write_dicom_axial(tmp_path / "mixed", obj[:3] + 1, series="1.2.3.5")
    with pytest.raises(ValueError, match=r"2 DICOM series.*0: 1\.2\.3\.4 \(MR, 6 file.*1: 1\.2\.3\.5 \(MR, 3 file"):
        load_volume(tmp_path / "mixed")
    np.testing.assert_array_equal(load_volume(tmp_path / "mixed", series=first).data, obj)
    np.testing.assert_array_equal(load_volume(tmp_path / "mixed", series="1").data, obj[:3] + 1)
    assert second == "1.2.3.5"
    with pytest.raises(ValueError, match="series: 7 is not a series"):
        load_volume(tmp_path / "mixed", series=7)


def test_enhanced_multiframe_4d_dicom(tmp_path):
    from medical_files import ORIGIN, SPACING, asymmetric_object, write_enhanced

    volumes_t = [asymmetric_object(seed=1), asymmetric_object(seed=2)]
    (tmp_path / "mf").mkdir()
    write_enhanced(tmp_path / "mf" / "enhanced.dcm", volumes_t)
    with pytest.raises(ValueError, match="4-D with 2 frames.*--frame"):
        load_volume(tmp_path / "mf")
    for t in (0, 1):
        vol = load_volume(tmp_path / "mf" / "enhanced.dcm", frame=t)
        assert vol.axis_codes == "PIR" and vol.metadata["frames"] == 2
        _patient_grid_equal(vol, volumes_t[t], SPACING, ORIGIN)
    with pytest.raises(ValueError, match=r"2 frames \(0..1\), got frame=2"):
        load_volume(tmp_path / "mf", frame=2)


def test_4d_nifti_needs_a_frame(tmp_path, rng):
    import nibabel

    data = rng.integers(0, 100, size=(4, 3, 2, 3)).astype(np.int16)
    nibabel.save(nibabel.Nifti1Image(data, np.diag([2.0, 2, 2, 1])), str(tmp_path / "t.nii"))
    with pytest.raises(ValueError, match="4-D with 3 frames; choose one with frame=0..2"):
        load_volume(tmp_path / "t.nii")
    np.testing.assert_array_equal(load_volume(tmp_path / "t.nii", frame=2).data, data[..., 2].transpose(2, 1, 0))
    with pytest.raises(ValueError, match="frame: .* is a 3-D volume"):
        load_volume(_npy(tmp_path), frame=1)
    with pytest.raises(ValueError, match="frame: expected an integer >= 0"):
        load_volume(tmp_path / "t.nii", frame=-1)
    nibabel.save(nibabel.Nifti1Image(data[..., 0], np.eye(4)), str(tmp_path / "3d.nii"))
    np.testing.assert_array_equal(load_volume(tmp_path / "3d.nii", frame=0).data, data[..., 0].T)
    with pytest.raises(ValueError, match="3-D volume .one frame.; got frame=1"):
        load_volume(tmp_path / "3d.nii", frame=1)


def _npy(tmp_path):
    np.save(tmp_path / "v.npy", np.zeros((2, 2, 2), np.float32))
    return tmp_path / "v.npy"


# ---------------------------------------------------------------------------------------------
# Real data shipped by nibabel and pydicom
# ---------------------------------------------------------------------------------------------
def test_nibabel_anatomical_and_example4d():
    import os

    import nibabel
    from nibabel.testing import data_path

    image = nibabel.load(os.path.join(data_path, "anatomical.nii"))
    vol = load_volume(os.path.join(data_path, "anatomical.nii"))
    assert vol.axis_codes == "LAS" == "".join(nibabel.aff2axcodes(image.affine))
    np.testing.assert_allclose(vol.affine, np.diag([-1, -1, 1, 1]) @ image.affine)
    np.testing.assert_array_equal(vol.data, np.asarray(image.dataobj).transpose(2, 1, 0))
    path4d = os.path.join(data_path, "example4d.nii.gz")
    with pytest.raises(ValueError, match="4-D with 2 frames"):
        load_volume(path4d)
    image = nibabel.load(path4d)
    vol = load_volume(path4d, frame=1)
    np.testing.assert_array_equal(vol.data, np.asarray(image.dataobj)[..., 1].transpose(2, 1, 0))
    np.testing.assert_allclose(vol.affine, np.diag([-1, -1, 1, 1]) @ image.affine)
    np.testing.assert_allclose(vol.spacing, image.header.get_zooms()[:3], rtol=1e-6)
    tilt = np.degrees(np.arccos(vol.directions[2, 2]))  # oblique: k tilted ~9 degrees from superior
    assert 8 < tilt < 10 and vol.axis_codes == "LAS"


def test_pydicom_ct_small_and_rtdose_multiframe(tmp_path):
    import shutil

    import pydicom
    from pydicom.data import get_testdata_file

    (tmp_path / "ct").mkdir()
    shutil.copy(get_testdata_file("CT_small.dcm"), tmp_path / "ct")
    ds = pydicom.dcmread(get_testdata_file("CT_small.dcm"))
    vol = load_volume(tmp_path / "ct")
    np.testing.assert_array_equal(vol.data[0], ds.pixel_array * float(ds.RescaleSlope) + float(ds.RescaleIntercept))
    assert vol.axis_codes == "LPS"
    np.testing.assert_allclose(vol.origin, [float(v) for v in ds.ImagePositionPatient])
    np.testing.assert_allclose(vol.spacing, (float(ds.PixelSpacing[1]), float(ds.PixelSpacing[0]),
                                             float(ds.SliceThickness)))
    (tmp_path / "dose").mkdir()
    shutil.copy(get_testdata_file("rtdose.dcm"), tmp_path / "dose")
    ds = pydicom.dcmread(get_testdata_file("rtdose.dcm"))
    vol = load_volume(tmp_path / "dose")
    offsets = [float(v) for v in ds.GridFrameOffsetVector]
    np.testing.assert_allclose(vol.data, ds.pixel_array * float(ds.DoseGridScaling), rtol=1e-6)
    np.testing.assert_allclose(vol.spacing, (float(ds.PixelSpacing[1]), float(ds.PixelSpacing[0]),
                                             offsets[1] - offsets[0]))
    np.testing.assert_allclose(_lps_points(vol, [[0, 0, 14]])[0],
                               np.array([float(v) for v in ds.ImagePositionPatient]) + (0, 0, offsets[14]))


def test_pydicom_enhanced_functional_groups_file(tmp_path):
    import shutil

    import pydicom
    from pydicom.data import get_testdata_file

    (tmp_path / "seg").mkdir()
    shutil.copy(get_testdata_file("liver_1frame.dcm"), tmp_path / "seg")
    ds = pydicom.dcmread(get_testdata_file("liver_1frame.dcm"))
    vol = load_volume(tmp_path / "seg")
    frame = ds.PerFrameFunctionalGroupsSequence[0]
    np.testing.assert_allclose(vol.origin, [float(v) for v in frame.PlanePositionSequence[0].ImagePositionPatient])
    measures = ds.SharedFunctionalGroupsSequence[0].PixelMeasuresSequence[0]  # shared, not per frame
    np.testing.assert_allclose(vol.spacing, (float(measures.PixelSpacing[1]), float(measures.PixelSpacing[0]),
                                             float(measures.SpacingBetweenSlices)))
    np.testing.assert_array_equal(vol.data[0], ds.pixel_array)
    assert vol.axis_codes == "LPS"
