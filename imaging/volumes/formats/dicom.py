"""DICOM series (a folder of slices, or multi-frame files) as Hounsfield units, placed in LPS."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pointillist.core import checks
from pointillist.core.errors import one_line
from pointillist.imaging.volumes._model import Volume, _pick_frame, _warn
from pointillist.imaging.volumes._registry import VolumeReader, optional_package, register

__all__ = ["read_dicom_series"]

@dataclass
class _Frame:
    """One 2-D DICOM image (a file, or a frame of a multi-frame file) and where it lies."""

    source: str
    pixels: Any  # callable -> (rows, cols) array
    position: np.ndarray | None
    orientation: np.ndarray | None
    pixel_spacing: tuple[float, float] | None
    slope: float
    intercept: float
    order: tuple  # temporal sort key within one slice position


def _item(ds: Any, *path: str) -> Any:
    """``ds.A[0].B[0]...`` or None (functional-group look-ups)."""
    for name in path:
        value = getattr(ds, name, None) if ds is not None else None
        if value is None:
            return None
        if name.endswith("Sequence"):
            if len(value) == 0:
                return None
            value = value[0]
        ds = value
    return ds


def _floats(value: Any, count: int) -> np.ndarray | None:
    try:
        out = np.asarray([float(v) for v in value], dtype=np.float64)
    except (TypeError, ValueError):
        return None
    return out if out.shape == (count,) and np.all(np.isfinite(out)) else None


def _dicom_number(ds: Any, file: Path, tag: str, default: float, *, integer: bool = False,
                  nonzero: bool = False) -> float | int:
    """A numeric tag of ``ds`` (``default`` when absent or empty), checked: a ValueError names the
    file and the tag for text that is not a number, a non-finite value or one float32 cannot hold."""
    value = ds.get(tag, None)
    if value is None or value == "":
        return default
    try:
        number = float(value)
        if integer and not number.is_integer():
            raise ValueError
        checks.real(number, tag)
    except (TypeError, ValueError):
        raise ValueError(f"volume: {file}: {tag} {value!r} is not a{'n integer' if integer else ' finite number'}") \
            from None
    if nonzero and number == 0:
        raise ValueError(f"volume: {file}: {tag} is 0 (every voxel would be the intercept)")
    return int(number) if integer else number


def _dicom_frame_count(file: Path, ds: Any) -> int:
    """NumberOfFrames, checked against the pixel data the file holds before anything is allocated
    (a 930-byte file claiming 4e6 frames took minutes and gigabytes before its error), and the
    image kind: one sample a pixel (grey), not palette indices."""
    count = _dicom_number(ds, file, "NumberOfFrames", 1, integer=True)
    if count < 1:
        raise ValueError(f"volume: {file}: NumberOfFrames is {count}, expected at least 1")
    rows, cols = (_dicom_number(ds, file, tag, -1, integer=True) for tag in ("Rows", "Columns"))
    if rows < 0 or cols < 0:
        raise ValueError(f"volume: {file}: pixel data without its size (no Rows or Columns)")
    if rows < 1 or cols < 1:
        raise ValueError(f"volume: {file}: expected Rows and Columns of at least 1, got {rows} x {cols}")
    samples = _dicom_number(ds, file, "SamplesPerPixel", 1, integer=True)
    photometric = str(ds.get("PhotometricInterpretation", "") or "").strip().upper()
    if samples != 1 or photometric not in ("", "MONOCHROME1", "MONOCHROME2"):
        raise ValueError(f"volume: {file}: PhotometricInterpretation {photometric or '(none)'} with {samples} "
                         "sample(s) a pixel; a volume needs one grey value a voxel (MONOCHROME1 or MONOCHROME2)")
    bits = _dicom_number(ds, file, "BitsAllocated", 16, integer=True)
    if bits not in (1, 8, 16, 32, 64):
        raise ValueError(f"volume: {file}: BitsAllocated {bits}, expected 1, 8, 16, 32 or 64")
    nbytes = len(ds.PixelData)
    syntax = getattr(getattr(ds, "file_meta", None), "TransferSyntaxUID", None)
    if syntax is not None and getattr(syntax, "is_encapsulated", False):
        need, what = 8 * count, f"{count} compressed frame(s) (8 bytes of item header each at least)"
    else:
        need, what = (rows * cols * count * bits + 7) // 8, f"{count} frame(s) of {rows} x {cols} at {bits} bits"
    if nbytes < need:
        raise ValueError(f"volume: {file}: the DICOM header claims {what} ({need} bytes) but the file holds {nbytes} "
                         "bytes of pixel data; a damaged or truncated file")
    return count


def _dicom_frames(file: Path, ds: Any) -> list[_Frame]:
    """The 2-D frames of one DICOM dataset: classic single-frame, classic multi-frame, enhanced."""
    count = _dicom_frame_count(file, ds)
    slope = _dicom_number(ds, file, "RescaleSlope", 1.0, nonzero=True)
    intercept = _dicom_number(ds, file, "RescaleIntercept", 0.0)
    if "DoseGridScaling" in ds and "RescaleSlope" not in ds:
        slope = _dicom_number(ds, file, "DoseGridScaling", 1.0, nonzero=True)  # RT Dose: stored x DoseGridScaling = Gy
    iop = _floats(ds.get("ImageOrientationPatient"), 6)
    ipp = _floats(ds.get("ImagePositionPatient"), 3)
    spacing = _floats(ds.get("PixelSpacing"), 2)
    instance = int(ds.get("InstanceNumber", 0) or 0)
    when = str(ds.get("AcquisitionTime", "") or ds.get("ContentTime", ""))
    if count == 1 and "PerFrameFunctionalGroupsSequence" not in ds:
        return [_Frame(file.name, lambda: ds.pixel_array, ipp, iop, tuple(spacing) if spacing is not None else None,
                       slope, intercept, (int(ds.get("TemporalPositionIdentifier", 0) or 0), when, instance))]
    cache: dict[str, np.ndarray] = {}

    def frame_pixels(n: int):
        def read():
            if "all" not in cache:
                pixels = ds.pixel_array
                cache["all"] = pixels.reshape((count,) + pixels.shape[-2:])
            return cache["all"][n]
        return read

    frames = []
    per_frame = ds.get("PerFrameFunctionalGroupsSequence")
    shared = _item(ds, "SharedFunctionalGroupsSequence")
    if per_frame is not None:  # enhanced multi-frame: per-frame (else shared) functional groups
        for n in range(count):
            group = per_frame[n] if n < len(per_frame) else None

            def look(*path, group=group):
                found = _item(group, *path)
                return found if found is not None else _item(shared, *path)

            position = _floats(getattr(look("PlanePositionSequence"), "ImagePositionPatient", None), 3)
            orientation = _floats(getattr(look("PlaneOrientationSequence"), "ImageOrientationPatient", None), 6)
            measures = look("PixelMeasuresSequence")
            pixel_spacing = _floats(getattr(measures, "PixelSpacing", None), 2)
            transform = look("PixelValueTransformationSequence")
            s = _dicom_number(transform, file, "RescaleSlope", slope, nonzero=True) if transform is not None \
                else slope
            b = _dicom_number(transform, file, "RescaleIntercept", intercept) if transform is not None else intercept
            content = look("FrameContentSequence")
            temporal = int(getattr(content, "TemporalPositionIndex", 0) or 0) if content is not None else 0
            stamp = str(getattr(content, "FrameAcquisitionDateTime", "") or "") if content is not None else ""
            frames.append(_Frame(f"{file.name}[{n}]", frame_pixels(n),
                                 position if position is not None else ipp,
                                 orientation if orientation is not None else iop,
                                 tuple(pixel_spacing) if pixel_spacing is not None else
                                 (tuple(spacing) if spacing is not None else None), s, b, (temporal, stamp, n)))
        return frames
    # classic multi-frame (e.g. RT Dose): frame n at ImagePositionPatient + offset[n] along the normal
    offsets = _floats(ds.get("GridFrameOffsetVector"), count)
    if offsets is None or ipp is None or iop is None:
        _warn(f"volume: {file}: multi-frame file without GridFrameOffsetVector/position/orientation; "
              "frames stacked 1 mm apart along the slice normal")
        offsets = np.arange(count, dtype=np.float64)
    for n in range(count):
        position = None
        if ipp is not None:
            normal = np.cross(iop[:3], iop[3:]) if iop is not None else np.array([0.0, 0.0, 1.0])
            position = ipp + (offsets[n] - (offsets[0] if offsets[0] != 0 else 0.0)) * normal
        frames.append(_Frame(f"{file.name}[{n}]", frame_pixels(n), position, iop,
                             tuple(spacing) if spacing is not None else None, slope, intercept, (0, "", n)))
    return frames


#: A DICOM file's 'DICM' marker ends here (after its 128-byte preamble).
_DICOM_MARKER_END = 132


def _image_storage(ds: Any) -> str | None:
    """The name of ``ds``'s SOP class when it is an image (or dose) storage class, whose files carry
    pixel data; else None (reports, structures, plans and other files a DICOM folder may hold)."""
    meta = getattr(ds, "file_meta", None)
    uid = (meta.get("MediaStorageSOPClassUID") if meta is not None else None) or ds.get("SOPClassUID")
    name = str(getattr(uid, "name", "") or "")
    return name if ("Image Storage" in name or "Dose Storage" in name) else None


def _dicom_series_label(datasets: list) -> str:
    first = datasets[0][1]
    description = str(first.get("SeriesDescription", "") or "").strip()
    frames = sum(int(ds.get("NumberOfFrames", 1) or 1) for _, ds in datasets)
    text = f"{first.get('Modality', '?')}, {len(datasets)} file(s), {frames} image(s)"
    return text + (f", {description!r}" if description else "")


def _image_files(folder: Path, pydicom: Any, invalid: type) -> list[tuple[Path, Any]]:
    """``(file, dataset)`` of every DICOM image file of ``folder`` (sorted by name); files that are not
    DICOM, and DICOM files without images, are left out; a damaged or truncated one is an error."""
    datasets = []
    problems = []
    for file in sorted(p for p in folder.iterdir() if p.is_file()):
        try:
            ds = pydicom.dcmread(str(file))
        except invalid as error:  # not DICOM (no 'DICM' marker): not part of any series...
            if file.suffix.lower() == ".dcm" and file.stat().st_size < _DICOM_MARKER_END:
                # ...unless its name says it is and it ends before the marker could: cut short
                raise ValueError(f"volume: {folder}: {file.name} ends at byte {file.stat().st_size}, before the DICOM "
                                 f"marker (byte {_DICOM_MARKER_END}); a truncated file, or remove it from the "
                                 "folder") from None
            problems.append(f"{file.name}: {one_line(error)}")
            continue
        except Exception as error:  # noqa: BLE001 - a DICOM file cut short or damaged: never drop a slice
            raise ValueError(f"volume: {folder}: unreadable DICOM file {file.name} "
                             f"({one_line(error) or type(error).__name__})") from None
        if "PixelData" in ds:
            datasets.append((file, ds))
        elif _image_storage(ds):  # pydicom reads a file cut short without a word, up to where it ends
            raise ValueError(f"volume: {folder}: {file.name} is a {_image_storage(ds)} file without pixel data; "
                             "a damaged or truncated file")
    if not datasets:
        detail = f" ({problems[0]})" if problems else ""
        raise ValueError(f"volume: {folder}: no DICOM slices with pixel data{detail}")
    return datasets


def _choose_series(folder: Path, datasets: list[tuple[Path, Any]], series: str | int | None) -> list:
    """The files of one series (SeriesInstanceUID): the one asked for (UID, or index in the sorted
    list), or the only one; several without ``series`` is an error listing them."""
    groups: dict[str, list] = {}
    for file, ds in datasets:
        groups.setdefault(str(ds.get("SeriesInstanceUID", "") or ""), []).append((file, ds))
    uids = sorted(groups)
    if series is not None:
        key = str(series).strip()
        if key in groups:
            chosen = key
        elif key.isdigit() and int(key) < len(uids):
            chosen = uids[int(key)]
        else:
            listing = "; ".join(f"{n}: {uid} ({_dicom_series_label(groups[uid])})" for n, uid in enumerate(uids))
            raise ValueError(f"series: {series!r} is not a series of {folder}; it holds {listing}")
    elif len(uids) > 1:
        listing = "; ".join(f"{n}: {uid} ({_dicom_series_label(groups[uid])})" for n, uid in enumerate(uids))
        raise ValueError(f"volume: {folder} holds {len(uids)} DICOM series; choose one with series= "
                         f"(--series UID or index): {listing}")
    else:
        chosen = uids[0]
    return groups[chosen]


def read_dicom_series(folder: str | os.PathLike, *, frame: int | None = None,
                      series: str | int | None = None) -> Volume:
    """Read a DICOM series (a folder of slices, or a multi-frame file) as Hounsfield units, placed in LPS.

    Files that are not DICOM, and DICOM files that carry no images (reports, structures,
    plans), are skipped; an image file without its pixel data is an error. A folder with several
    series (SeriesInstanceUID) needs ``series`` (the UID, or its index in the sorted
    list the error shows). Images come from single-frame files, classic multi-frame
    files (e.g. RT Dose: ``GridFrameOffsetVector``) or enhanced multi-frame files
    (per-frame or shared functional groups: PlanePositionSequence,
    PlaneOrientationSequence, PixelMeasuresSequence, PixelValueTransformationSequence).

    Geometry: voxel x runs along ImageOrientationPatient's row direction (spacing
    PixelSpacing[1]), y along its column direction (PixelSpacing[0]), z along the slice
    normal (row x column) with the slices sorted by ImagePositionPatient projected on it;
    the slice spacing is the median distance between consecutive positions (not
    SliceThickness, used only for a single slice). Slices not stacked along the normal
    (gantry tilt) are refused as sheared. Several images at each position (the same
    count everywhere) make a 4-D series: ``frame`` picks one (images at a position
    ordered by TemporalPositionIdentifier / TemporalPositionIndex, acquisition time,
    instance or frame number). When no image has a usable ImageOrientationPatient (missing, or
    not two orthogonal unit vectors) the series is taken as axial (1,0,0,0,1,0) with a one-line
    warning; when some have one and others not, it is refused, whatever the order of the files.
    A missing ImagePositionPatient falls back to InstanceNumber order, with a warning.

    Every file is checked before its pixels are read: one grey sample a pixel (MONOCHROME1/2;
    colour and palette images are refused), numeric tags that are numbers, and pixel data at least
    as long as Rows x Columns x NumberOfFrames claim. A file that is DICOM but cannot be read (cut
    short, damaged) is an error naming it, never a slice left out.

    Values = stored * RescaleSlope + RescaleIntercept, kept int16 when slope and
    intercept are integers and the result fits, float32 otherwise.
    """
    if frame is not None:
        checks.integer(frame, "frame", low=0)
    pydicom = optional_package("pydicom", "DICOM", "pydicom")
    from pydicom.errors import InvalidDicomError
    folder = Path(folder)
    datasets = _choose_series(folder, _image_files(folder, pydicom, InvalidDicomError), series)
    first = datasets[0][1]
    try:
        frames = [f for file, ds in datasets for f in _dicom_frames(file, ds)]
        return _stack_dicom(folder, frames, first, frame)
    except ValueError as error:
        if str(error).startswith(("volume:", "frame:")):
            raise
        raise ValueError(f"volume: {folder}: bad DICOM series ({one_line(error)})") from None
    except Exception as error:  # noqa: BLE001 - pydicom decoding errors of truncated files
        raise ValueError(f"volume: {folder}: unreadable DICOM slice ({type(error).__name__}: {one_line(error)})") \
            from None


def _usable_orientation(iop: np.ndarray | None) -> bool:
    """Whether ImageOrientationPatient is two orthogonal unit vectors (to 1e-3)."""
    return iop is not None and abs(np.linalg.norm(iop[:3]) - 1) <= 1e-3 and abs(np.linalg.norm(iop[3:]) - 1) <= 1e-3 \
        and abs(float(np.dot(iop[:3], iop[3:]))) <= 1e-3


def _stack_dicom(folder: Path, frames: list[_Frame], first: Any, frame: int | None) -> Volume:
    """Sort DICOM images into a volume (one frame of a 4-D series) with its LPS affine."""
    axial = np.array([1.0, 0.0, 0.0, 0.0, 1.0, 0.0])
    # One rule whatever the order of the files: every image usable (then all the same), or none.
    usable = [f for f in frames if _usable_orientation(f.orientation)]
    if not usable:
        seen = next((f.orientation for f in frames if f.orientation is not None), None)
        what = "no ImageOrientationPatient" if seen is None else f"degenerate ImageOrientationPatient {seen.tolist()}"
        _warn(f"volume: {folder}: {what}; assumed axial (1,0,0,0,1,0)")
        iop = axial
    elif len(usable) < len(frames):
        bad = next(f for f in frames if not _usable_orientation(f.orientation))
        what = "no" if bad.orientation is None else f"a degenerate {bad.orientation.tolist()}"
        raise ValueError(f"volume: {folder}: image {bad.source} has {what} ImageOrientationPatient, image "
                         f"{usable[0].source} has {usable[0].orientation.tolist()}; cannot stack them")
    else:
        iop = usable[0].orientation
        for f in usable[1:]:
            if np.abs(f.orientation - iop).max() > 1e-4:
                raise ValueError(f"volume: {folder}: images {usable[0].source} and {f.source} have different "
                                 "orientations (a localizer or several stacks); cannot stack them")
    row = iop[:3] / np.linalg.norm(iop[:3])
    col = iop[3:] - np.dot(iop[3:], row) * row
    col /= np.linalg.norm(col)
    normal = np.cross(row, col)
    if any(f.position is None for f in frames):
        _warn(f"volume: {folder}: no ImagePositionPatient; slices in instance order, 1 mm apart (or SliceThickness)")
        thickness = float(first.get("SpacingBetweenSlices", 0) or first.get("SliceThickness", 1.0) or 1.0)
        for n, f in enumerate(sorted(frames, key=lambda f: f.order[2])):
            f.position = normal * thickness * n
    distances = np.array([float(np.dot(f.position, normal)) for f in frames])
    order = np.argsort(distances, kind="stable")
    # group images at the same position (within 1e-3 mm): several per position = frames in time
    stacks: list[list[int]] = []
    for index in order:
        if stacks and abs(distances[index] - distances[stacks[-1][0]]) < 1e-3:
            stacks[-1].append(int(index))
        else:
            stacks.append([int(index)])
    counts = {len(s) for s in stacks}
    if len(counts) != 1:
        raise ValueError(f"volume: {folder}: slice positions hold different numbers of images "
                         f"({min(counts)}..{max(counts)}); cannot make a volume")
    per_position = counts.pop()
    pick = 0
    if per_position > 1:
        pick = _pick_frame(folder, per_position, frame)
    elif frame not in (None, 0):
        raise ValueError(f"frame: {folder} is a 3-D volume (one frame); got frame={frame}")
    chosen = [frames[sorted(s, key=lambda i: frames[i].order)[pick]] for s in stacks]
    first_frame = chosen[0]
    rows, cols = (int(first.Rows), int(first.Columns))
    integral = True
    data = np.empty((len(chosen), rows, cols), dtype=np.float32)
    for z, f in enumerate(chosen):
        pixels = f.pixels()
        if pixels.shape != (rows, cols):
            raise ValueError(f"slice {f.source} is {pixels.shape}, expected {(rows, cols)}")
        integral = integral and float(f.slope).is_integer() and float(f.intercept).is_integer()
        data[z] = pixels.astype(np.float32) * np.float32(f.slope) + np.float32(f.intercept)
        if not np.all(np.isfinite(data[z])):
            raise ValueError(f"volume: {folder}: image {f.source}: RescaleSlope {f.slope:g} and RescaleIntercept "
                             f"{f.intercept:g} take its values beyond float32 (|x| <= 3.4e38)")
    if integral and data.min() >= -32768 and data.max() <= 32767:
        data = data.astype(np.int16)
    pixel_spacing = first_frame.pixel_spacing
    if pixel_spacing is None or not all(s > 0 for s in pixel_spacing):
        _warn(f"volume: {folder}: no usable PixelSpacing; assumed 1 mm")
        pixel_spacing = (1.0, 1.0)
    positions = np.array([f.position for f in chosen])
    if len(chosen) > 1:
        steps = np.diff(positions, axis=0)
        along = steps @ normal
        dz = float(np.median(along))
        if not dz > 0:
            raise ValueError(f"volume: {folder}: slices share one position; cannot stack them")
        across = np.linalg.norm(steps - along[:, None] * normal, axis=1)
        if float(across.max()) > 1e-3 * max(dz, 1.0) + 1e-4:
            raise ValueError(f"volume: {folder}: slices are not stacked along their normal (sheared, e.g. a "
                             f"gantry tilt: {float(across.max()):.3g} mm sideways a slice); resample it first")
        if float(np.abs(along - dz).max()) > 0.01 * dz:
            _warn(f"volume: {folder}: uneven slice spacing ({float(along.min()):g}..{float(along.max()):g} mm); "
                  f"used the median {dz:g} mm")
    else:
        dz = float(first.get("SpacingBetweenSlices", 0) or first.get("SliceThickness", 1.0) or 1.0)
    affine = np.eye(4)
    affine[:3, 0] = row * pixel_spacing[1]
    affine[:3, 1] = col * pixel_spacing[0]
    affine[:3, 2] = normal * dz
    affine[:3, 3] = positions[0]
    meta = {"format": "dicom", "slices": len(chosen), "frames": per_position,
            "modality": str(first.get("Modality", "")), "series": str(first.get("SeriesInstanceUID", "")),
            "rescale_slope": first_frame.slope, "rescale_intercept": first_frame.intercept}
    return Volume(data, metadata=meta, affine=affine)


register(VolumeReader(name="DICOM series", label="DICOM", suffixes=(".dcm",), read=read_dicom_series,
                      spacing_from="PixelSpacing, slice positions", needs="pydicom", options=("frame", "series"),
                      folder=True, order=50))
