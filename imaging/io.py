"""EXR and PNG input/output.

EXR goes through the OpenEXR package (float32 scanline images, ZIP compression):
``Y`` for grey images, ``R G B`` and ``R G B A`` for colour, plus any number of
extra single-channel layers (for example a per-pixel sample count). Header
attributes carry metadata (``spp``, ``sampler``, ``integrator``,
``render_seconds`` ...): ints, floats and strings round-trip exactly.

Every write is atomic (written to a temporary file beside the target, then
renamed over it) and refuses to overwrite a file that this process read as an
input with :func:`read_exr` (or that is named in ``inputs=``).

PNG previews are 8-bit, sRGB-encoded by the imaging module's curve (in float64). Policy for values
PNG cannot hold: NaN becomes 0, values are clipped to the displayable range.
"""

from __future__ import annotations

import errno
import os
import sys
import tempfile
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from pointillist.core import checks
from pointillist.core.errors import one_line
from pointillist.core.files import atomic_write, check_output_path, mark_input
from pointillist.imaging.arrays import as_tensor, to_numpy

__all__ = ["EXRImage", "read_exr", "write_exr", "write_png", "read_image", "to_8bit"]

class EXRImage(NamedTuple):
    """What :func:`read_exr` returns.

    Attributes
    ----------
    image : numpy.ndarray
        float32, (H, W) for a ``Y`` image, (H, W, 3) RGB or (H, W, 4) RGBA.
    metadata : dict
        The header attributes that are not OpenEXR's own.
    layers : dict
        Extra channels by name, each float32 (H, W).
    """

    image: np.ndarray
    metadata: dict[str, Any]
    layers: dict[str, np.ndarray]


EXRImage.image.__doc__ = "The pixels: float32, (H, W) for a ``Y`` image, (H, W, 3) RGB or (H, W, 4) RGBA."
EXRImage.metadata.__doc__ = "The header attributes that are not OpenEXR's own."
EXRImage.layers.__doc__ = "Extra channels by name, each float32 (H, W)."


def read_exr(path: str | os.PathLike, *, copies: int = 2) -> EXRImage:
    """Read an OpenEXR file as float32 numpy arrays.

    Parameters
    ----------
    path : str or path-like
        The EXR file.
    copies : int, optional
        How many float32 copies of the image the caller will hold at once (default 2, the reading
        itself): the memory they take is checked against what the machine has before any pixel is
        read (:func:`pointillist.core.checks.memory`), so an 8x8 file claiming a 20000 x 20000 display
        window is a ValueError, not a MemoryError or the kernel's out-of-memory killer.

    Returns
    -------
    EXRImage
        ``(image, metadata, layers)``: the ``Y``/``RGB``/``RGBA`` pixels, the
        non-standard header attributes, and the other channels by name.

    Raises
    ------
    ValueError
        If the file is missing, is not a readable EXR image, is a deep image (several samples a
        pixel: flatten it first, e.g. ``oiiotool --flatten``), has subsampled channels, or has a
        display window beyond :data:`MAX_EXR_VALUES`.

    Notes
    -----
    Parts: the image is the first part holding ``R``, ``G`` and ``B`` (else the first holding
    ``Y``, else a part's single channel); its other channels are layers by their names, and the
    channels of the other parts are layers named ``PART.CHANNEL``. Metadata is the image part's.

    Windows: the image is the display window (the frame a viewer shows, as ``exrdisplay``,
    Nuke and ``oiiotool --croptofull`` do), whatever the data window: pixels of the display
    window outside the data window are 0 (alpha too), and data outside the display window
    (overscan) is left out. OpenCV's ``imread`` returns the data window instead, without its
    offset. Every part is framed by the image part's display window; a data window wholly outside
    it (nothing to show) is a ValueError, as are luminance-chroma files (``Y``, ``RY``, ``BY``) and
    files whose only channel is ``A``.

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> from pointillist.imaging.io import read_exr, write_exr
    >>> path = os.path.join(tempfile.mkdtemp(), "x.exr")
    >>> write_exr(path, np.ones((2, 3, 3), np.float32), metadata={"spp": 16})
    >>> image, meta, layers = read_exr(path)
    >>> image.shape, meta["spp"]
    ((2, 3, 3), 16)
    """
    import OpenEXR

    copies = checks.integer(copies, "copies", low=1)
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"path: no such EXR file: {path}")
    with _OutputCapture() as captured:
        try:
            # through a Python file (OpenEXR takes a path only as UTF-8 text: not every file name is)
            with open(path, "rb") as stream, OpenEXR.File(stream, separate_channels=True) as exr:
                parts = [_ExrPart(index, part) for index, part in enumerate(exr.parts)]
        except Exception as error:  # noqa: BLE001 - OpenEXR raises bare RuntimeErrors
            failure = error
        else:
            failure = None
    if failure is not None:
        # OpenEXR prints its own diagnosis (captured): its first line says more than the exception.
        lines = [line.removeprefix(f"{path}: ").strip() for line in captured.text.splitlines() if line.strip()]
        detail = next((line for line in lines if not line.startswith("Warning:")), None) or one_line(failure)
        raise ValueError(f"path: {path} is not a readable EXR file ({detail})") from None
    if parts and any(part.channels for part in parts):
        captured.replay()
    for part in parts:
        if part.deep:
            raise ValueError(f"path: {path} is a deep EXR (part {part.name!r}: several samples a pixel); only flat "
                             "images are read: flatten it first (e.g. oiiotool --flatten)")
    if not any(part.channels for part in parts):
        # OpenEXR gives up on damaged pixel data with a warning (captured) and no parts or channels
        lines = [line.strip().removeprefix("Warning:").strip() for line in captured.text.splitlines() if line.strip()]
        if lines:
            raise ValueError(f"path: {path}: its pixel data cannot be read, a damaged or truncated file "
                             f"({one_line(lines[0])})")
        raise ValueError(f"path: {path} holds no channels")
    chroma = next((p for p in parts if {"RY", "BY"} & p.channels.keys()), None)
    if chroma is not None and not {"R", "G", "B"} <= chroma.channels.keys():
        raise ValueError(f"path: {path} stores luminance and chroma (Y, RY, BY: OpenEXR's lossy colour encoding), "
                         "which is not read as colour here; convert it to RGB first (e.g. oiiotool IN -o OUT)")
    main = next((p for p in parts if {"R", "G", "B"} <= p.channels.keys()), None) \
        or next((p for p in parts if "Y" in p.channels), None) \
        or next((p for p in parts if len(p.channels) == 1 and "A" not in p.channels), None)
    if main is None:
        names = sorted(f"{p.name}.{c}" if len(parts) > 1 else c for p in parts for c in p.channels)
        raise ValueError(f"path: {path} has no Y or RGB channels (has {names})")
    frame = main.display
    width, height = frame[2] - frame[0] + 1, frame[3] - frame[1] + 1
    if width < 1 or height < 1:
        raise ValueError(f"path: {path}: empty display window {frame} (xmin, ymin, xmax, ymax)")
    data = main.data or frame
    if data[0] > frame[2] or data[2] < frame[0] or data[1] > frame[3] or data[3] < frame[1]:
        raise ValueError(f"path: {path}: its data window {data} lies wholly outside its display window {frame} "
                         "(xmin, ymin, xmax, ymax): the image would hold none of its pixels")
    count = width * height * sum(len(p.channels) for p in parts)
    if count > MAX_EXR_VALUES:
        raise ValueError(f"path: {path}: display window {width} x {height} with {count} values in all, more than "
                         f"{MAX_EXR_VALUES} (2^31 - 1)")
    # every channel framed in float32, then the image's channels stacked (2), and what the caller makes of it
    checks.memory(count * 4 * max(int(copies), 2),
                  f"path: {path}: its display window {width} x {height} ({count} values)")
    channels: dict[str, np.ndarray] = {}
    for part in [main] + [p for p in parts if p is not main]:
        for name, pixels in part.channels.items():
            key = name if part is main else f"{part.name}.{name}"
            if key in channels:
                raise ValueError(f"path: {path}: two channels are named {key!r} (part {part.name!r})")
            channels[key] = _framed(path, key, pixels, part.data, frame)
    mark_input(path)

    def take(*names: str) -> np.ndarray:
        return np.stack([channels.pop(n) for n in names], axis=-1)

    if {"R", "G", "B"} <= main.channels.keys():
        image = take("R", "G", "B", "A") if "A" in main.channels else take("R", "G", "B")
    elif "Y" in main.channels:
        image = channels.pop("Y")
    else:
        image = channels.pop(next(iter(main.channels)))
    metadata = {k: _plain(v) for k, v in main.header.items() if k not in checks.EXR_RESERVED}
    return EXRImage(np.ascontiguousarray(image), metadata, channels)


#: The most values (pixels of the display window x channels, all parts) :func:`read_exr` makes: the
#: imaging operations' limit (32-bit signed indices).
MAX_EXR_VALUES = 2**31 - 1


class _ExrPart:
    """One part of an EXR file, read: name, header, channels (numpy, float32 unless deep), windows."""

    def __init__(self, index: int, part: Any) -> None:
        import OpenEXR

        self.header = dict(part.header)
        self.name = str(part.name() or self.header.get("name") or f"part{index}")
        self.deep = part.type() in (OpenEXR.deepscanline, OpenEXR.deeptile)
        raw = {name: channel.pixels for name, channel in part.channels.items()}
        self.channels = raw if self.deep else {name: np.asarray(pixels, dtype=np.float32)
                                               for name, pixels in raw.items()}
        self.data = _window(self.header.get("dataWindow"))
        self.display = _window(self.header.get("displayWindow")) or self.data


def _window(box: Any) -> tuple[int, int, int, int] | None:
    """An EXR box2i attribute ((xmin, ymin), (xmax, ymax)) as (xmin, ymin, xmax, ymax)."""
    if box is None:
        return None
    low, high = box
    return int(low[0]), int(low[1]), int(high[0]), int(high[1])


def _framed(path: Path, name: str, pixels: np.ndarray, data: tuple[int, int, int, int],
            display: tuple[int, int, int, int]) -> np.ndarray:
    """A channel's data-window pixels placed in the display window (zeros where there is no data)."""
    x0, y0, x1, y1 = data
    if pixels.shape != (y1 - y0 + 1, x1 - x0 + 1):
        raise ValueError(f"path: {path}: channel {name!r} is subsampled ({pixels.shape[1]} x {pixels.shape[0]} "
                         f"values for a {x1 - x0 + 1} x {y1 - y0 + 1} data window); not supported")
    if data == display:
        return pixels
    dx0, dy0, dx1, dy1 = display
    out = np.zeros((dy1 - dy0 + 1, dx1 - dx0 + 1), np.float32)
    ix0, iy0, ix1, iy1 = max(x0, dx0), max(y0, dy0), min(x1, dx1), min(y1, dy1)
    if ix0 <= ix1 and iy0 <= iy1:
        out[iy0 - dy0:iy1 - dy0 + 1, ix0 - dx0:ix1 - dx0 + 1] = pixels[iy0 - y0:iy1 - y0 + 1, ix0 - x0:ix1 - x0 + 1]
    return out


class _OutputCapture:
    """Capture what C++ libraries write to file descriptors 1 and 2 inside the block (OpenEXR prints
    its diagnostics there, some on stdout).

    ``text`` holds both afterwards; :meth:`replay` writes them back where they were going (when
    they were not an error's).
    """

    def __enter__(self):
        self._saved = []
        for stream in (sys.stdout, sys.stderr):
            stream.flush()
        for fd in (1, 2):
            try:
                saved = os.dup(fd)
            except OSError:  # a closed descriptor: nothing to capture
                continue
            capture = tempfile.TemporaryFile()
            self._saved.append((fd, saved, capture))
            os.dup2(capture.fileno(), fd)
        return self

    def __exit__(self, *exc):
        for stream in (sys.stdout, sys.stderr):
            stream.flush()
        self.parts = []
        for fd, saved, capture in self._saved:
            os.dup2(saved, fd)
            os.close(saved)
            capture.seek(0)
            self.parts.append(capture.read().decode(errors="replace"))
            capture.close()
        return False

    @property
    def text(self) -> str:
        return "".join(self.parts)

    def replay(self) -> None:
        for (fd, _, _), text in zip(self._saved, self.parts):
            stream = sys.stdout if fd == 1 else sys.stderr
            if text:
                stream.write(text)
                stream.flush()


def _plain(value: Any) -> Any:
    """A header attribute's value as plain Python: a one-element double vector (how Mitsuba's
    writer stores a float) is that float, other arrays lists."""
    if isinstance(value, np.ndarray):
        return float(value[0]) if value.shape == (1,) and value.dtype == np.float64 else value.tolist()
    return value


def write_exr(path: str | os.PathLike, image: Any, metadata: Mapping[str, Any] | None = None, *,
              layers: Mapping[str, Any] | None = None, inputs: Iterable[str | os.PathLike] = ()) -> None:
    """Write a float32 OpenEXR file atomically.

    Parameters
    ----------
    path : str or path-like
        Target file; its folder must exist. Never an input of this process.
    image : array_like or Dr.Jit tensor, or None
        (H, W) or (H, W, 1) writes ``Y``; (H, W, 2) ``Y`` and ``A``; (H, W, 3) ``RGB``;
        (H, W, 4) ``RGBA``. None: only ``layers`` (a render without colour, e.g. depth and
        normals alone).
    metadata : mapping, optional
        Header attributes: str keys, values int, float, str or bool (stored as int); an integer
        beyond 32 bits is stored as its decimal text (:func:`pointillist.core.checks.exr_attribute`).
    layers : mapping, optional
        Extra channels, each (H, W), e.g. ``{"spp": counts}``.
    inputs : iterable of paths
        Files this write must not replace (besides those read by :func:`read_exr`).

    Raises
    ------
    TypeError
        For metadata values of another type.
    ValueError
        For a bad shape, a reserved or clashing name, or a forbidden path.
    OSError
        When the file cannot be written (a full disk, a file size limit: OpenEXR's reason); no
        partial file is left.
    """
    import OpenEXR

    path = check_output_path(path, inputs)
    channels: dict[str, np.ndarray] = {}
    shape = None
    if image is not None:
        pixels = to_numpy(as_tensor(image, "image", channels=(1, 2, 3, 4))).astype(np.float32, copy=False)
        if pixels.ndim == 3 and pixels.shape[2] == 1:
            pixels = pixels[..., 0]
        if pixels.ndim == 3 and pixels.shape[2] == 2:  # luminance and alpha: Y, A
            channels = {"Y": np.ascontiguousarray(pixels[..., 0]), "A": np.ascontiguousarray(pixels[..., 1])}
        else:
            names = {2: "Y", 3: "RGB", 4: "RGBA"}[pixels.ndim if pixels.ndim == 2 else pixels.shape[2]]
            channels = {names: np.ascontiguousarray(pixels)}
        shape = pixels.shape[:2]
    elif not layers:
        raise ValueError("image: expected an image, or layers to write without one")
    for name, layer in (layers or {}).items():
        if not isinstance(name, str) or not name or name in {"R", "G", "B", "A", "Y"}:
            raise ValueError(f"layers: invalid or clashing channel name {name!r}")
        data = to_numpy(as_tensor(layer, f"layers[{name!r}]")).astype(np.float32, copy=False)
        if shape is None:
            if data.ndim != 2:
                raise ValueError(f"layers[{name!r}]: expected an (H, W) array, got shape {data.shape}")
            shape = data.shape
        if data.shape != shape:
            raise ValueError(f"layers[{name!r}]: expected shape {shape}, got {data.shape}")
        channels[name] = np.ascontiguousarray(data)
    header: dict[str, Any] = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    for key, value in (metadata or {}).items():
        header[key] = checks.exr_attribute(key, value)

    def write(tmp: str) -> None:
        try:  # through a Python file (OpenEXR takes a path only as UTF-8 text: not every file name is)
            with OpenEXR.File(header, channels) as exr, open(tmp, "wb") as stream:
                exr.write(stream)
        except RuntimeError as error:  # OpenEXR's own failures: a full disk, a file size limit
            reason = str(error).rsplit('". ', 1)[-1].strip() or str(error)
            raise OSError(errno.EIO, reason.rstrip(".")) from None

    atomic_write(path, write)


def to_8bit(image: Any, *, srgb: bool = True, max_value: float = 1.0) -> np.ndarray:
    """Return ``image`` as uint8 for display: divide by ``max_value``, sRGB-encode, clip, round.

    NaN becomes 0; +inf becomes 255, -inf 0. The sRGB curve is the imaging module's one
    definition (:func:`pointillist.imaging.colour.srgb_encode_values`), computed here in float64:
    the bytes equal colour-science's ``cctf_encoding`` rounded (the tests check every float32
    input near a rounding boundary); the ``adaptive`` integrator evaluates the same function in
    its kernel's float32.
    """
    from drjit.llvm.ad import Float64

    from pointillist.imaging.colour import srgb_encode_values

    checks.real(max_value, "max_value", low=0.0, low_open=True, float32=False)
    pixels = to_numpy(as_tensor(image, "image", channels=(1, 3, 4))).astype(np.float64)
    pixels = np.nan_to_num(pixels / max_value, nan=0.0, posinf=1.0, neginf=0.0)
    pixels = np.clip(pixels, 0.0, 1.0)
    if srgb:
        colour = pixels[..., :3] if pixels.ndim == 3 and pixels.shape[2] == 4 else pixels  # alpha stays linear
        encoded = srgb_encode_values(Float64(np.ascontiguousarray(colour).ravel())).numpy()
        colour[...] = encoded.reshape(colour.shape)
    return np.round(np.clip(pixels, 0.0, 1.0) * 255.0).astype(np.uint8)


def write_png(path: str | os.PathLike, image: Any, *, srgb: bool = True, max_value: float = 1.0,
              inputs: Iterable[str | os.PathLike] = ()) -> None:
    """Write an 8-bit PNG preview atomically.

    Parameters
    ----------
    path : str or path-like
        Target ``.png`` file.
    image : array_like or Dr.Jit tensor
        (H, W), (H, W, 1), (H, W, 3) or (H, W, 4).
    srgb : bool
        ``True`` (default): ``image`` is linear light and is sRGB-encoded
        (:func:`to_8bit`). ``False``: values are already
        display-encoded.
    max_value : float
        The value shown as full white: 1.0 for renders, 255 for the imaging
        operations' 0..255 intensities.

    Notes
    -----
    NaN is written as 0, +inf as 255; other values are clipped to 0..255.
    """
    from PIL import Image

    path = check_output_path(path, inputs)
    pixels = to_8bit(image, srgb=srgb, max_value=max_value)
    if pixels.ndim == 3 and pixels.shape[2] == 1:
        pixels = pixels[..., 0]
    atomic_write(path, lambda tmp: Image.fromarray(pixels).save(tmp, format="PNG"))


def read_image(path: str | os.PathLike, *, copies: int = 2) -> EXRImage:
    """Read an EXR (:func:`read_exr`, linear float) or another image through Pillow (PNG, JPEG, TIFF...).

    Non-EXR images come back with empty metadata and no layers, as float32 values:

    - 8-bit images (grey, bilevel, palette, colour; CMYK, YCbCr, LAB and HSV converted to RGB by
      Pillow): 0..255, as (H, W) or (H, W, 3), and (H, W, 2) or (H, W, 4) when there is alpha (a
      palette with transparency included), as scikit-image's ``imread`` reads them;
    - 16-bit grey: value / 257, 0..255 with 16 bits of precision;
    - 16-bit colour: 0..255 at 8-bit precision (Pillow keeps the high byte of each value);
    - float, 32-bit integer and signed integer (TIFF) images: their values unchanged, not scaled
      nor clipped, as OpenCV's ``imread(..., IMREAD_UNCHANGED)`` reads them.

    A multi-page file (TIFF, GIF) gives its first page, as OpenCV's ``imread`` does.

    ``copies``: for an EXR, as :func:`read_exr` takes it.

    Raises
    ------
    ValueError
        For a missing or unreadable file, or one larger than Pillow's decompression-bomb limit
        (twice ``PIL.Image.MAX_IMAGE_PIXELS``).
    """
    copies = checks.integer(copies, "copies", low=1)
    path = Path(path)
    if path.suffix.lower() == ".exr":
        return read_exr(path, copies=copies)
    if not path.is_file():
        raise ValueError(f"path: no such image file: {path}")
    import warnings

    from PIL import Image, UnidentifiedImageError

    try:
        with warnings.catch_warnings():
            # below twice the limit Pillow only warns (several lines); above it, it raises (caught below)
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(path) as img:
                pixels = _pillow_values(img)
    except Image.DecompressionBombError as error:
        raise ValueError(f"path: {path} is too large to read ({one_line(error)})") from None
    except (UnidentifiedImageError, OSError, ValueError) as error:
        raise ValueError(f"path: {path} is not a readable image ({one_line(error)})") from None
    mark_input(path)
    return EXRImage(np.ascontiguousarray(pixels), {}, {})


#: Pillow modes whose values are read as they are (float, 32-bit signed integer).
_RAW_MODES = ("F", "I", "I;32", "I;32S", "I;32B", "I;32BS", "I;32L", "I;32LS")
#: Pillow modes with an alpha channel.
_ALPHA_MODES = ("RGBA", "RGBa", "LA", "La", "PA")


def _pillow_values(img: Any) -> np.ndarray:
    """The float32 values of an open Pillow image, by the rules of :func:`read_image`."""
    mode = img.mode
    tags = getattr(img, "tag_v2", None) or {}
    bits = tuple(np.atleast_1d(tags.get(258, ()))) if tags else ()
    signed = tags.get(339) in (2, (2,)) if tags else False  # TIFF SampleFormat: 2 = signed integer
    if mode.startswith("I;16") or (mode == "I" and (img.format == "PNG" or (bits == (16,) and not signed))):
        return np.asarray(img, dtype=np.float32) / 257.0   # 16-bit unsigned grey (older Pillow: mode I)
    if mode in _RAW_MODES:
        return np.asarray(img, dtype=np.float32)
    if mode == "L" and signed:  # signed 8-bit TIFF: Pillow takes the bytes as unsigned
        return np.asarray(img).view(np.int8).astype(np.float32)
    alpha = mode in _ALPHA_MODES or (mode == "P" and "transparency" in img.info)
    grey = mode in ("L", "1", "LA", "La")
    target = ("LA" if grey else "RGBA") if alpha else ("L" if grey else "RGB")
    return np.asarray(img.convert(target) if mode != target else img, dtype=np.float32)
