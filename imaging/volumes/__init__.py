"""Volume data for maximum intensity projection: loaders, a CT phantom, compact Dr.Jit textures.

A :class:`Volume` holds a scalar 3-D array in ``(Z, Y, X)`` order (C order:
``data[z, y, x]``, x varies fastest, like Mitsuba's ``.vol`` files and Dr.Jit's
3-D textures), the voxel spacing ``(sx, sy, sz)`` in physical units (mm for
medical data, 1 per voxel when a format has none), the position of voxel
``(0, 0, 0)``'s centre (``origin``, kept as metadata) and format metadata.

Readers (:func:`load_volume` picks one by the path; one module of
:mod:`pointillist.imaging.volumes.formats` each, listed here from their registry):

READER_TABLE

DICOM slices are sorted by ImagePositionPatient along the slice normal and
converted to Hounsfield units with RescaleSlope / RescaleIntercept. Integer
data keeps its dtype (int16 CT stays 2 bytes a voxel); the .npy reader reads in
slabs so a file is never held twice. Corrupt or truncated files raise
ValueError naming the file.

:func:`volume_texture` turns a volume into a Dr.Jit 3-D texture: 16-bit and
8-bit data go into a half-precision texture (``drjit.llvm.Texture3f16``, 2 bytes
a voxel, shared with numpy without a copy), offset so that every integer value
is exact (float16 holds the integers -2048..2048 exactly, so any 12-bit CT
range fits); other data into float32 textures.
"""

from pointillist.imaging.volumes import formats  # noqa: F401 - registers every reader
from pointillist.imaging.volumes._model import OrientationWarning, Volume
from pointillist.imaging.volumes._phantom import SHEPP_LOGAN_HU, shepp_logan_phantom
from pointillist.imaging.volumes._registry import (VolumeReader, load_volume, reader_table, register,
                                                   volume_files, volume_formats, volume_readers)
from pointillist.imaging.volumes._texture import VolumeTexture, volume_texture
from pointillist.imaging.volumes.formats.dicom import read_dicom_series
from pointillist.imaging.volumes.formats.nifti import read_nifti
from pointillist.imaging.volumes.formats.npy import read_npy
from pointillist.imaging.volumes.formats.nrrd import read_nrrd
from pointillist.imaging.volumes.formats.vol import read_vol, write_vol

__doc__ = __doc__.replace("READER_TABLE", reader_table())

__all__ = [
    "Volume", "load_volume", "read_vol", "write_vol", "read_npy", "read_nrrd", "read_nifti",
    "read_dicom_series", "OrientationWarning", "shepp_logan_phantom", "volume_texture", "VolumeTexture",
    "SHEPP_LOGAN_HU", "VolumeReader", "register", "volume_readers", "volume_formats", "volume_files",
]
