"""Small synthetic medical files for the orientation tests: one object, many voxel orders.

The object lives in patient LPS: ``obj[z, y, x]`` with voxel x along the patient's left,
y posterior, z superior (a DICOM axial stack's order), voxel (0, 0, 0)'s centre at
``origin`` and voxel size ``spacing`` (sx, sy, sz). The writers store the same object in
other voxel orders with each format's own library (nibabel's reorientation, pynrrd,
pydicom), so the files agree only if the reader places them correctly.
"""

from __future__ import annotations

import numpy as np

SPACING = (0.75, 1.25, 2.0)
ORIGIN = (-12.0, 30.0, -40.0)


def asymmetric_object(seed: int = 5, shape=(6, 7, 9)) -> np.ndarray:
    """An int16 object with no symmetry: random background and a bright voxel at the
    patient's right-anterior-superior corner region (low x, low y, high z)."""
    rng = np.random.default_rng(seed)
    obj = rng.integers(0, 1000, size=shape).astype(np.int16)
    obj[-2, 1, 1] = 3000  # right (low x), anterior (low y), superior (high z)
    return obj


def ras_affine(spacing=SPACING, origin=ORIGIN) -> np.ndarray:
    """The RAS+ affine of the LPS-ordered object (NIfTI's convention), written out by hand."""
    sx, sy, sz = spacing
    affine = np.diag([-sx, -sy, sz, 1.0])
    affine[:3, 3] = (-origin[0], -origin[1], origin[2])
    return affine


def write_nifti(path, obj, axcodes, *, spacing=SPACING, origin=ORIGIN):
    """Save ``obj`` as NIfTI in voxel order ``axcodes`` (e.g. "RAS", "LAS", "LPI") with nibabel's reorientation."""
    import nibabel
    from nibabel.orientations import axcodes2ornt, io_orientation, ornt_transform

    image = nibabel.Nifti1Image(np.ascontiguousarray(obj.transpose(2, 1, 0)), ras_affine(spacing, origin))
    reoriented = image.as_reoriented(ornt_transform(io_orientation(image.affine), axcodes2ornt(tuple(axcodes))))
    assert "".join(nibabel.aff2axcodes(reoriented.affine)) == axcodes
    out = nibabel.Nifti1Image(np.asarray(reoriented.dataobj), reoriented.affine)
    nibabel.save(out, str(path))
    return out


def write_nrrd_permuted(path, obj, *, spacing=SPACING, origin=ORIGIN, space="left-posterior-superior"):
    """Save ``obj`` as NRRD whose axes (fastest first) run anterior, superior, left (LPS space, or RAS)."""
    import nrrd

    sx, sy, sz = spacing
    ny = obj.shape[1]
    data = obj.transpose(2, 0, 1)[:, :, ::-1]  # C order [a2, a1, a0] = obj[z=a1, y=ny-1-a0, x=a2]
    directions = np.array([[0.0, -sy, 0.0], [0.0, 0.0, sz], [sx, 0.0, 0.0]])
    start = np.array(origin) + np.array([0.0, sy * (ny - 1), 0.0])
    if space == "right-anterior-superior":
        directions = directions * np.array([-1.0, -1.0, 1.0])
        start = start * np.array([-1.0, -1.0, 1.0])
    header = {"space": space, "space directions": directions, "space origin": start}
    nrrd.write(str(path), np.ascontiguousarray(data), header, index_order="C")


def _dataset(path, rows, cols, series, *, modality="MR", sop=None):
    import pydicom
    from pydicom.dataset import FileDataset, FileMetaDataset
    from pydicom.uid import ExplicitVRLittleEndian, MRImageStorage, generate_uid

    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = sop or MRImageStorage
    meta.MediaStorageSOPInstanceUID = generate_uid()
    meta.TransferSyntaxUID = ExplicitVRLittleEndian
    ds = FileDataset(str(path), {}, file_meta=meta, preamble=b"\0" * 128)
    ds.SOPClassUID, ds.SOPInstanceUID = meta.MediaStorageSOPClassUID, meta.MediaStorageSOPInstanceUID
    ds.SeriesInstanceUID, ds.Modality = series, modality
    ds.Rows, ds.Columns = rows, cols
    ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
    ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 1
    return ds, pydicom


def write_dicom_slices(folder, images, orientation, positions, pixel_spacing, *, series=None, modality="MR",
                       shuffle_seed=3, times=None):
    """One signed 16-bit image per file (written in shuffled order), with the given geometry tags.

    ``orientation``: ImageOrientationPatient (or None: omitted); ``positions``: one
    ImagePositionPatient each (or None); ``pixel_spacing``: (row spacing, column spacing).
    """
    from pydicom.uid import generate_uid

    folder.mkdir(exist_ok=True)
    series = series or generate_uid()
    order = np.random.default_rng(shuffle_seed).permutation(len(images))
    for n, index in enumerate(order):
        ds, pydicom = _dataset(folder / f"{series[-6:]}_{n}.dcm", images[index].shape[0], images[index].shape[1],
                               series, modality=modality)
        if orientation is not None:
            ds.ImageOrientationPatient = [float(v) for v in orientation]
        if positions is not None:
            ds.ImagePositionPatient = [float(v) for v in positions[index]]
        ds.PixelSpacing = [float(pixel_spacing[0]), float(pixel_spacing[1])]
        ds.InstanceNumber = int(index + 1)
        if times is not None:
            ds.TemporalPositionIdentifier = int(times[index])
        ds.PixelData = np.asarray(images[index], dtype="<i2").tobytes()
        pydicom.dcmwrite(str(folder / f"{series[-6:]}_{n}.dcm"), ds, enforce_file_format=True)
    return series


def write_dicom_coronal(folder, obj, *, spacing=SPACING, origin=ORIGIN, series=None):
    """``obj`` as a coronal DICOM series: rows run inferior (IOP 1,0,0, 0,0,-1), slices go posterior."""
    sx, sy, sz = spacing
    nz, ny, nx = obj.shape
    images = [obj[::-1, s, :] for s in range(ny)]  # image[r, c] = obj[nz-1-r, s, c]
    positions = [np.array(origin) + (0.0, s * sy, (nz - 1) * sz) for s in range(ny)]
    return write_dicom_slices(folder, images, (1, 0, 0, 0, 0, -1), positions, (sz, sx), series=series)


def write_dicom_axial(folder, obj, *, spacing=SPACING, origin=ORIGIN, series=None, modality="MR"):
    """``obj`` as an axial DICOM series (IOP 1,0,0, 0,1,0; slices go superior)."""
    sx, sy, sz = spacing
    images = [obj[z] for z in range(obj.shape[0])]
    positions = [np.array(origin) + (0.0, 0.0, z * sz) for z in range(obj.shape[0])]
    return write_dicom_slices(folder, images, (1, 0, 0, 0, 1, 0), positions, (sy, sx), series=series,
                              modality=modality)


def write_enhanced(path, volumes, *, spacing=SPACING, origin=ORIGIN):
    """An enhanced multi-frame MR file: ``volumes`` (T of them, LPS order) as sagittal frames with
    per-frame PlanePositionSequence / FrameContentSequence and shared orientation and pixel measures.

    Sagittal: rows run inferior, columns posterior (IOP 0,1,0, 0,0,-1); the normal (row x column)
    points to the patient's right, so frames are written from the left to the right.
    """
    from pydicom.dataset import Dataset
    from pydicom.sequence import Sequence
    from pydicom.uid import EnhancedMRImageStorage, generate_uid

    sx, sy, sz = spacing
    nz, ny, nx = volumes[0].shape
    ds, pydicom = _dataset(path, nz, ny, generate_uid(), sop=EnhancedMRImageStorage)
    frames, groups = [], []
    for t, obj in enumerate(volumes):
        for s in range(nx):
            x = nx - 1 - s  # slice s at the left-most remaining x
            frames.append(obj[::-1, :, x])  # image[r, c] = obj[nz-1-r, c, x]
            group = Dataset()
            position = Dataset()
            position.ImagePositionPatient = [float(v) for v in np.array(origin) + (x * sx, 0.0, (nz - 1) * sz)]
            group.PlanePositionSequence = Sequence([position])
            content = Dataset()
            content.TemporalPositionIndex = t + 1
            group.FrameContentSequence = Sequence([content])
            groups.append(group)
    order = np.random.default_rng(9).permutation(len(frames))  # frames stored out of order
    ds.PerFrameFunctionalGroupsSequence = Sequence([groups[i] for i in order])
    shared = Dataset()
    plane = Dataset()
    plane.ImageOrientationPatient = [0.0, 1.0, 0.0, 0.0, 0.0, -1.0]
    measures = Dataset()
    measures.PixelSpacing = [float(sz), float(sy)]
    measures.SliceThickness = float(sx)
    shared.PlaneOrientationSequence = Sequence([plane])
    shared.PixelMeasuresSequence = Sequence([measures])
    ds.SharedFunctionalGroupsSequence = Sequence([shared])
    ds.NumberOfFrames = len(frames)
    ds.PixelData = np.stack([frames[i] for i in order]).astype("<i2").tobytes()
    pydicom.dcmwrite(str(path), ds, enforce_file_format=True)
