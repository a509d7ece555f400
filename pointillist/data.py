"""Sample inputs every guide uses by name: ``pointillist data DIR`` writes them into a folder.

Made by the project (its Shepp-Logan phantom in each volume format it reads, its default scene)
or taken from packages already installed (scikit-image's astronaut photograph, nibabel's 4-D
example), so that the documentation's shell examples run as written from inside ``DIR``:

=====================  ==========================================================================
file                   what
=====================  ==========================================================================
``scene.xml``          the default scene (Mitsuba XML, ``whitted``, 256x256)
``render.exr``         that scene rendered (128x128, 16 spp): a linear HDR EXR to post-process
``photo.png``          scikit-image's ``astronaut`` (512x512 RGB), an image to post-process
``head.nii.gz``        the 3-D Shepp-Logan phantom, 64^3 int16 HU, NIfTI (RAS affine, 1 mm)
``head.nhdr``          the same, NRRD with a detached header (``head.raw.gz``, gzip data, LPS)
``head.npy``           the same, numpy (Z, Y, X)
``ct_series/``         the same, a DICOM CT series (64 slices, HU through RescaleIntercept)
``fmri.nii.gz``        nibabel's 4-D example (``example4d.nii.gz``: 2 frames), for ``--frame``
=====================  ==========================================================================

Every file is written atomically and an existing file is never replaced (a second run into the
same folder fails with a clear error naming the file).
"""

from __future__ import annotations

import gzip
import os
import shutil
from pathlib import Path

from pointillist.core.errors import UsageError
from pointillist.core.files import atomic_write

__all__ = ["SAMPLE_FILES", "write_sample_data"]

#: The files :func:`write_sample_data` writes (a folder for the DICOM series), in order.
SAMPLE_FILES = ("scene.xml", "render.exr", "photo.png", "head.nii.gz", "head.nhdr", "head.raw.gz", "head.npy",
                "ct_series", "fmri.nii.gz")

#: The phantom's size (voxels a side) and spacing (mm).
_SIZE, _SPACING = 64, 1.0


def write_sample_data(folder: str | os.PathLike) -> list[Path]:
    """Write the sample inputs into ``folder`` (made when missing); returns the paths written.

    Raises
    ------
    UsageError
        When ``folder`` is a file, or already holds one of :data:`SAMPLE_FILES`.
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise UsageError(f"folder: {folder} is a file, not a folder")
    taken = [name for name in SAMPLE_FILES if (folder / name).exists()]
    if taken:
        raise UsageError(f"folder: {folder} already holds {taken[0]} (sample data is never written over a file)")
    folder.mkdir(parents=True, exist_ok=True)
    from pointillist.imaging.volumes import shepp_logan_phantom

    phantom = shepp_logan_phantom(_SIZE)  # (Z, Y, X) int16 HU; z superior, y posterior, x left (LPS)
    written = [_scene(folder / "scene.xml")]
    written += [_render(folder / "scene.xml", folder / "render.exr"), _photo(folder / "photo.png")]
    written += [_nifti(folder / "head.nii.gz", phantom), *_nrrd(folder / "head.nhdr", phantom),
                _npy(folder / "head.npy", phantom), _dicom_series(folder / "ct_series", phantom),
                _copy(_nibabel_example(), folder / "fmri.nii.gz")]
    return written


def _scene(path: Path) -> Path:
    source = Path(__file__).resolve().parent.parent / "scenes" / "default.xml"
    if not source.is_file():
        raise UsageError("the sample scene is the repository's scenes/default.xml: run from a clone of it")
    return _copy(source, path)


def _render(scene: Path, path: Path) -> Path:
    """The sample scene rendered small, as `pointillist render` writes it (metadata included)."""
    from pointillist.render import render_file

    render_file(scene, path, spp=16, params={"res": "128"}, threads=None)
    return path


def _copy(source: Path, path: Path) -> Path:
    atomic_write(path, lambda tmp: shutil.copyfile(source, tmp))
    return path


def _photo(path: Path) -> Path:
    from skimage import data

    from pointillist.imaging.io import write_png

    write_png(path, data.astronaut(), srgb=False, max_value=255.0)
    return path


def _nifti(path: Path, phantom) -> Path:
    import nibabel
    import numpy as np

    # NIfTI is RAS: voxel (i, j, k) = LPS (x, y, z) flipped in x and y, as nibabel writes the affine
    affine = np.diag([-_SPACING, -_SPACING, _SPACING, 1.0])
    image = nibabel.Nifti1Image(np.ascontiguousarray(phantom.transpose(2, 1, 0)), affine)
    image.header.set_xyzt_units("mm")
    data = gzip.compress(image.to_bytes(), mtime=0)  # the same bytes on every run
    atomic_write(path, lambda tmp: Path(tmp).write_bytes(data))
    return path


def _nrrd(path: Path, phantom) -> list[Path]:
    import nrrd
    import numpy as np

    data_path = path.with_name(path.stem + ".raw.gz")
    header = {"space": "left-posterior-superior", "space directions": np.eye(3) * _SPACING,
              "space origin": np.zeros(3), "encoding": "gzip", "kinds": ["domain"] * 3, "data file": data_path.name}
    # pynrrd writes the header and the detached data file itself: write both into a temporary folder
    # beside them, then move each into place
    scratch = path.with_name(f".{path.name}.writing")
    scratch.mkdir()
    try:
        nrrd.write(str(scratch / path.name), np.ascontiguousarray(phantom.transpose(2, 1, 0)), header,
                   detached_header=True, index_order="F")
        for name, target in ((data_path.name, data_path), (path.name, path)):
            _copy(scratch / name, target)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return [path, data_path]


def _npy(path: Path, phantom) -> Path:
    import numpy as np

    def write(tmp: str) -> None:
        with open(tmp, "wb") as stream:
            np.save(stream, phantom)

    atomic_write(path, write)
    return path


def _dicom_series(folder: Path, phantom) -> Path:
    """One CT slice a file: stored = HU + 1024 as uint16, RescaleIntercept -1024, LPS positions."""
    import numpy as np
    from pydicom.dataset import FileDataset, FileMetaDataset
    from pydicom.uid import CTImageStorage, ExplicitVRLittleEndian, generate_uid

    scratch = folder.with_name(f".{folder.name}.writing")
    scratch.mkdir()
    try:
        series, study, frame = generate_uid(), generate_uid(), generate_uid()
        for z, plane in enumerate(phantom):
            meta = FileMetaDataset()
            meta.MediaStorageSOPClassUID = CTImageStorage
            meta.MediaStorageSOPInstanceUID = generate_uid()
            meta.TransferSyntaxUID = ExplicitVRLittleEndian
            ds = FileDataset(None, {}, file_meta=meta, preamble=b"\0" * 128)
            ds.SOPClassUID, ds.SOPInstanceUID = CTImageStorage, meta.MediaStorageSOPInstanceUID
            ds.Modality, ds.PatientName, ds.PatientID = "CT", "Phantom^SheppLogan", "pointillist"
            ds.StudyInstanceUID, ds.SeriesInstanceUID, ds.FrameOfReferenceUID = study, series, frame
            ds.SeriesNumber, ds.InstanceNumber = 1, z + 1
            ds.ImageOrientationPatient = [1, 0, 0, 0, 1, 0]
            ds.ImagePositionPatient = [0.0, 0.0, float(z * _SPACING)]
            ds.PixelSpacing, ds.SliceThickness = [_SPACING, _SPACING], _SPACING
            ds.Rows, ds.Columns = plane.shape
            ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
            ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 0
            ds.RescaleIntercept, ds.RescaleSlope = -1024, 1
            ds.PixelData = (plane.astype(np.int32) + 1024).astype(np.uint16).tobytes()
            ds.save_as(scratch / f"slice_{z:03d}.dcm", enforce_file_format=True)
        os.replace(scratch, folder)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return folder


def _nibabel_example() -> Path:
    from nibabel.testing import data_path

    return Path(data_path) / "example4d.nii.gz"
