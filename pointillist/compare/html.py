"""``report.html``: the comparison as one self-contained page, renders and error maps beside the numbers.

:func:`write_html_report` fills the package's template (``pointillist/compare/page/report.html.in``)
with the results table (:func:`pointillist.compare.tables.results_table`), the page's
script (``pointillist/compare/page/*.js``, inlined) and the data as JSON: every sweep
point's numbers and, for the lowest seed of each point, its render as HDR data
(float16 RGB, base64), its per-pixel relMSE and HDR-FLIP maps (:func:`pointillist.imaging.metrics.error_maps`,
float16), an adaptive method's ``sample_count`` layer and the radially averaged power spectrum of
its luminance error (:func:`pointillist.imaging.metrics.error_spectrum`, plotted beside the maps
of the renders on show); the reference likewise. The
page applies exposure and the sRGB transfer function itself, draws the maps through
colour tables computed here (viridis for relMSE on a log scale, magma for FLIP as in
the FLIP paper, cividis for sample counts) and needs no network, server or build step
(a Content-Security-Policy meta tag forbids any fetch).

Size: about ``4/3 * (6 + 2 + 2 [+ 2])`` bytes per pixel per render (base64 of float16
RGB, two maps, sample count) plus 8 per reference pixel. Above ``max_bytes`` (default
30 MB) every image is subsampled by the same integer stride ``s``: the page holds the
pixels ``(s//2 + i*s, s//2 + j*s)`` of the full-size render and of its full-size error
maps (no averaging: single pixels, and their noise, stay as rendered), and says so.
"""

from __future__ import annotations

import base64
import html
import json
import math
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from pointillist.compare.methods import setting_label, sweep_parameter
from pointillist.compare.tables import TIMING_FLOOR, format_time, results_table, slopes, summarise
from pointillist.core.files import shown_in

__all__ = ["REPORT_NAME", "ReportPage", "write_html_report", "DEFAULT_MAX_BYTES", "encode_half",
           "colormap_table", "subsample_stride", "template_text", "PAGE_SCRIPTS", "page_script"]

#: The page's file name in the comparison folder.
REPORT_NAME = "report.html"

#: Size budget of report.html in bytes (a default sweep's page stays under about 30 MB).
DEFAULT_MAX_BYTES = 30_000_000

#: Decades of the relMSE colour scale below its top (the 99.5th percentile over the shown maps).
RELMSE_DECADES = 4

#: Page bytes besides the images (table, script, colour tables, JSON keys): reserved in the budget.
_OVERHEAD = 200_000

#: The page's scripts (``page/``), in the order they run: the time format and sRGB encoding, the
#: data's decoding, the plots, the image viewer, and the start that connects them.
PAGE_SCRIPTS = ("format.js", "decode.js", "plots.js", "viewer.js", "main.js")


@dataclass(frozen=True)
class ReportPage:
    """What :func:`write_html_report` wrote."""

    path: Path
    bytes: int
    stride: int
    full_size: tuple[int, int]
    shown_size: tuple[int, int]
    renders: int

    @property
    def summary(self) -> str:
        """One line: size, images, and the subsampling if any."""
        size = f"{self.bytes / 1e6:.1f} MB, {self.renders} renders + reference"
        w, h = self.full_size
        if self.stride == 1:
            return f"{size} at {w}x{h}, every pixel"
        return (f"{size}: every {_ordinal(self.stride)} pixel of {w}x{h} in x and y "
                f"(shown {self.shown_size[0]}x{self.shown_size[1]}) to stay under the size budget")


def template_text(name: str) -> str:
    """The text of a file of the page's package data (``page/``): ``report.html.in`` or a script."""
    return resources.files("pointillist.compare").joinpath("page", name).read_text(encoding="utf-8")


def page_script(extra: Sequence[str] = ()) -> str:
    """The page's script: :data:`PAGE_SCRIPTS` in one function scope, after ``PAGE``, the constants
    they share with Python (the time units of :func:`pointillist.compare.tables.format_time`, the
    sRGB transfer function of :mod:`pointillist.imaging.colour`), and before ``extra``: scripts
    that run after them in the same scope (the tests' self-test of the page).

    Examples
    --------
    >>> script = page_script()
    >>> script.startswith('(function () {') and '"time_units": [["s", 1.0], ["ms", 0.001]' in script
    True
    """
    from pointillist.compare.tables import TIME_UNIT_ROUNDING, TIME_UNITS
    from pointillist.imaging.colour import SRGB_EXPONENT, SRGB_LINEAR_THRESHOLD, SRGB_OFFSET, SRGB_SCALE, SRGB_SLOPE

    constants = {"time_units": TIME_UNITS, "time_unit_rounding": TIME_UNIT_ROUNDING,
                 "srgb": {"threshold": SRGB_LINEAR_THRESHOLD, "slope": SRGB_SLOPE, "scale": SRGB_SCALE,
                          "offset": SRGB_OFFSET, "exponent": SRGB_EXPONENT}}
    parts = [f"var PAGE = {json.dumps(constants)};", *(template_text(name) for name in PAGE_SCRIPTS), *extra]
    return "(function () {\n\"use strict\";\n" + "\n".join(part.strip("\n") for part in parts) + "\n})();"


def encode_half(array: np.ndarray) -> str:
    """``array`` as little-endian float16, base64 (the page decodes it with a 65536-entry table).

    Finite values beyond float16's range (+-65504) are clipped to it (the page shows them as the
    brightest value) instead of overflowing to infinity; NaN and infinities stay as they are.

    Examples
    --------
    >>> encode_half(np.array([1.0, -2.0, 0.5]))
    'ADwAwAA4'
    >>> encode_half(np.array([3e38, -1e10])) == encode_half(np.array([65504.0, -65504.0]))
    True
    """
    values = np.asarray(array, dtype=np.float64)
    half = float(np.finfo(np.float16).max)
    values = np.where(np.isfinite(values), np.clip(values, -half, half), values)
    data = np.ascontiguousarray(values.astype("<f2"))
    return base64.b64encode(data.tobytes()).decode("ascii")


def colormap_table(name: str, n: int = 256) -> str:
    """``n`` colours of the matplotlib colour map ``name`` as one hex string (``rrggbb`` each).

    Examples
    --------
    >>> table = colormap_table("magma")
    >>> len(table), table[:6], table[-6:]
    (1536, '000004', 'fcfdbf')
    """
    import matplotlib

    colours = matplotlib.colormaps[name](np.linspace(0.0, 1.0, n))[:, :3]
    return bytes(np.round(colours * 255).astype(np.uint8).ravel()).hex()


def subsample_stride(width: int, height: int, per_pixel: float, max_bytes: int) -> int:
    """The smallest integer stride ``s`` whose subsampled images fit ``max_bytes``.

    ``per_pixel``: page bytes per full-size pixel (all images together); the images keep
    ``ceil(width / s) x ceil(height / s)`` pixels.

    Examples
    --------
    >>> subsample_stride(256, 256, 200.0, 30_000_000), subsample_stride(1024, 1024, 200.0, 30_000_000)
    (1, 3)
    """
    budget = max(max_bytes - _OVERHEAD, 1)
    stride = 1
    while math.ceil(width / stride) * math.ceil(height / stride) * per_pixel > budget:
        stride += 1
    return stride


def _finite(value: Any) -> float | None:
    """JSON has no NaN: non-finite numbers become null."""
    value = float(value)
    return value if math.isfinite(value) else None


def _shown(records: Sequence[Any]) -> dict[tuple[str, float], Any]:
    """The record shown for each (method, value): its lowest seed."""
    chosen: dict[tuple[str, float], Any] = {}
    for record in records:
        key = (record.method, float(record.value))
        if key not in chosen or record.seed < chosen[key].seed:
            chosen[key] = record
    return chosen


def write_html_report(records: Sequence[Any], out_dir: str | os.PathLike, *, scene: str,
                      reference: str | os.PathLike, title: str | None = None,
                      max_bytes: int = DEFAULT_MAX_BYTES,
                      maps: Mapping[str, Mapping[str, np.ndarray]] | None = None) -> ReportPage:
    """Write ``out_dir/report.html`` for the sweep ``records`` (:class:`~pointillist.compare.records.RenderRecord`).

    The renders are read from ``out_dir/renders/<record.exr>`` and compared with the
    EXR ``reference``; records need their errors (``rmse``, ``relmse``, ``flip``).

    Parameters
    ----------
    records : sequence of RenderRecord
        The scored sweep (all seeds; the page shows the lowest seed's image per point).
    out_dir : path
        The comparison folder.
    scene : str
        The scene file (named on the page).
    reference : path
        The reference EXR.
    title : str, optional
        The page title.
    max_bytes : int
        Size budget: images are subsampled by a stride when they would not fit.
    maps : mapping, optional
        Per-pixel error maps already computed (:func:`pointillist.compare.sweep.run_sweep`'s
        ``maps``), by ``record.exr``; those missing are computed (HDR-FLIP costs about
        as much as scoring the render did).

    Returns
    -------
    ReportPage
        Path, size in bytes, stride and sizes.

    Raises
    ------
    ValueError
        ``records`` empty, ``max_bytes`` not positive, or a render of another size than the reference.
    """
    from pointillist.core.files import atomic_write
    from pointillist.imaging.io import read_exr
    from pointillist.imaging.metrics import as_rgb, error_maps, error_spectrum
    from pointillist.imaging.spectrum import LOW_FREQUENCY_CUTOFF, NYQUIST
    from pointillist.render_output import SAMPLE_COUNT_LAYER

    if not records:
        raise ValueError("records: expected at least one scored render, got none")
    if int(max_bytes) <= 0:
        raise ValueError(f"max_bytes: expected a positive size in bytes, got {max_bytes!r}")
    out = Path(out_dir)
    ref_exr = read_exr(reference)
    ref = as_rgb(ref_exr.image)
    height, width = ref.shape[:2]
    chosen = _shown(records)
    per_pixel = 4 / 3 * (6 + 12 * len(chosen))  # base64 of float16: RGB + 2 maps + a sample count (bound)
    stride = subsample_stride(width, height, per_pixel, int(max_bytes))
    offset = stride // 2

    def shrink(image: np.ndarray) -> np.ndarray:
        return image[offset::stride, offset::stride]

    rows = summarise(records)
    fitted = slopes(rows, min_time=TIMING_FLOOR)
    renders, relmse_maps, count_maps = [], [], []
    frequency = None
    for index, ((method, value), record) in enumerate(chosen.items()):
        exr = read_exr(out / "renders" / record.exr)
        image = as_rgb(exr.image)
        if image.shape != ref.shape:
            raise ValueError(f"records: {record.exr} is {image.shape[1]}x{image.shape[0]}, the reference "
                             f"{width}x{height}")
        found = (maps or {}).get(record.exr)
        pixel_maps = found if found is not None and {"relmse", "flip"} <= found.keys() else error_maps(image, ref)
        counts = exr.layers.get(SAMPLE_COUNT_LAYER)
        relmse_maps.append(shrink(pixel_maps["relmse"]))
        spectrum = error_spectrum(image, ref)
        frequency = spectrum.frequency
        entry = {"id": index, "method": method, "value": value, "setting": setting_label(method, value),
                 "seed": record.seed, "spp": _finite(record.spp), "time": _finite(record.time),
                 "relmse": _finite(record.relmse), "flip": _finite(record.flip),
                 "lowfreq": _finite(getattr(record, "lowfreq", math.nan)),
                 "rgb": encode_half(shrink(image)), "relmse_map": encode_half(relmse_maps[-1]),
                 "flip_map": encode_half(shrink(pixel_maps["flip"])), "count_map": None,
                 "spectrum": [_finite(float(f"{v:.4g}")) for v in spectrum.power]}
        if counts is not None:
            count_maps.append(shrink(counts))
            entry["count_map"] = encode_half(count_maps[-1])
        renders.append(entry)
    render_of = {(r["method"], r["value"]): r["id"] for r in renders}
    points = [{"method": r["method"], "value": r["value"], "setting": setting_label(r["method"], r["value"]),
               "seeds": r["seeds"], "spp": _finite(r["spp"]), "time": _finite(r["time"]), "mse": _finite(r["mse"]),
               "relmse": _finite(r["relmse"]), "flip": _finite(r["flip"]), "lowfreq": _finite(r["lowfreq"]),
               "time_text": format_time(r["time"]),
               "short": bool(r["time"] < TIMING_FLOOR), "render": render_of[(r["method"], float(r["value"]))]}
              for r in rows]
    methods = list(dict.fromkeys(r["method"] for r in rows))
    palette = bytes.fromhex(colormap_table("tab10", 10))  # matplotlib's default colour cycle
    shown_h, shown_w = shrink(ref).shape[:2]
    data = {
        "title": title or "Sampler comparison", "width": shown_w, "height": shown_h,
        "full_width": width, "full_height": height, "stride": stride, "offset": offset,
        "reference": {"label": _reference_label(Path(reference), ref_exr.metadata), "rgb": encode_half(shrink(ref))},
        "renders": renders, "points": points,
        "methods": [{"name": m, "colour": "#" + palette[3 * (i % 10):3 * (i % 10) + 3].hex(),
                     "sweeps_spp": sweep_parameter(m) == "spp",
                     "slope_spp": _finite(fitted[m]["mse_vs_spp"]), "slope_time": _finite(fitted[m]["mse_vs_time"])}
                    for i, m in enumerate(methods)],
        "timing_floor": TIMING_FLOOR, "timing_floor_text": format_time(TIMING_FLOOR),
        "scales": _scales(relmse_maps, count_maps),
        "spectrum": {"frequency": [float(f) for f in frequency], "cutoff": LOW_FREQUENCY_CUTOFF,
                     "nyquist": NYQUIST},
        "colormaps": {name: colormap_table(name) for name in ("viridis", "magma", "cividis")},
    }
    header, cells = results_table(rows)
    table = ["<table id=\"results\"><thead><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in header)
             + "</tr></thead><tbody>"]
    for point, row in zip(points, cells):
        table.append(f"<tr data-render=\"{point['render']}\">"
                     + "".join(f"<td>{html.escape(cell)}</td>" for cell in row) + "</tr>")
    table.append("</tbody></table>")
    shown = html.escape(shown_in(reference, out_dir))
    notes = [f"Scene <code>{html.escape(scene)}</code>, reference <code>{shown}</code>, {width}x{height} pixels."]
    if stride > 1:
        notes.append(f"To keep this page under {max_bytes / 1e6:.3g} MB it holds every {_ordinal(stride)} pixel in "
                     f"x and y ({shown_w}x{shown_h}; pixels, not averages): the numbers are those of the full images.")
    if any(p["short"] for p in points):
        notes.append(f"Times marked * are under {format_time(TIMING_FLOOR)}: too short to time reliably; the time "
                     "slopes leave them out.")
    page = _fill(template_text("report.html.in"), {
        "title": html.escape(data["title"]), "table": "\n".join(table),
        "notes": " ".join(notes), "data": _script_safe(json.dumps(data, separators=(",", ":"), allow_nan=False)),
        "script": _script_safe(page_script())})
    path = out / REPORT_NAME
    encoded = page.encode("utf-8")
    atomic_write(path, lambda tmp: Path(tmp).write_bytes(encoded))
    return ReportPage(path=path, bytes=len(encoded), stride=stride, full_size=(width, height),
                      shown_size=(shown_w, shown_h), renders=len(renders))


def _ordinal(n: int) -> str:
    return f"{n}{'th' if 10 <= n % 100 <= 20 else {1: 'st', 2: 'nd', 3: 'rd'}.get(n % 10, 'th')}"


def _reference_label(path: Path, metadata: dict) -> str:
    if "sampler" in metadata and "spp" in metadata:
        return f"reference ({metadata['sampler']}, {float(metadata['spp']):g} spp)"
    return f"reference ({path.name})"


def _scales(relmse_maps: Sequence[np.ndarray], count_maps: Sequence[np.ndarray]) -> dict[str, dict]:
    """Colour scales shared by all panes: relMSE log10 over RELMSE_DECADES below the 99.5th
    percentile, FLIP on [0, 1], sample counts from the smallest to the largest count."""
    values = np.concatenate([m.ravel() for m in relmse_maps])
    values = values[np.isfinite(values) & (values > 0)]
    top = float(np.percentile(values, 99.5)) if values.size else 1.0
    scales = {"relmse": {"map": "viridis", "log": True, "lo": top / 10 ** RELMSE_DECADES, "hi": top,
                         "label": "relMSE per pixel"},
              "flip": {"map": "magma", "log": False, "lo": 0.0, "hi": 1.0, "label": "HDR-FLIP"}}
    if count_maps:
        counts = np.concatenate([m.ravel() for m in count_maps])
        counts = counts[np.isfinite(counts)]
        lo, hi = (float(counts.min()), float(counts.max())) if counts.size else (0.0, 1.0)
        scales["count"] = {"map": "cividis", "log": False, "lo": lo, "hi": hi if hi > lo else lo + 1,
                           "label": "samples per pixel"}
    return scales


def _script_safe(text: str) -> str:
    """Text that can sit inside a <script> element (no ``</`` that would end it early)."""
    return text.replace("</", "<\\/")


def _fill(template: str, values: dict[str, str]) -> str:
    """Replace each ``{{name}}`` of ``template`` in one pass; every placeholder must be given."""
    missing = set(re.findall(r"\{\{(\w+)\}\}", template)) ^ set(values)
    if missing:
        raise ValueError(f"template: placeholders and values differ: {sorted(missing)}")
    return re.sub(r"\{\{(\w+)\}\}", lambda match: values[match.group(1)], template)
