"""Writing a render: the EXR (extra film channels as layers, metadata in the header), the sRGB
PNG preview, and the heat map of a per-pixel sample count (the ``adaptive`` integrator's AOV).

A render's EXR is written by Mitsuba's own writer (``mitsuba.Bitmap``, as ``Bitmap.write``
writes a render: float32, lossless PIZ compression, a ``generatedBy`` attribute), so that a
plain render never imports numpy or the OpenEXR package (a tenth of a second of every start).
:func:`pointillist.imaging.io.read_exr` reads it as it reads the imaging module's EXRs. Every
file is written atomically and never over an input (:mod:`pointillist.core.files`).
"""

from __future__ import annotations

from pathlib import Path

from pointillist.core.errors import UsageError

__all__ = ["SAMPLE_COUNT_LAYER", "output_path", "render_outputs", "check_preview", "write_render",
           "write_render_exr", "write_sample_heatmap"]


#: The EXR layer of a per-pixel sample count (written by the ``adaptive`` integrator).
SAMPLE_COUNT_LAYER = "sample_count"



def output_path(scene: str, output: str | None) -> Path:
    """The EXR path to write: ``output`` or ``out/<scene stem>.exr`` (the folder ``out`` is made only
    when the work starts: :meth:`pointillist.plan.Plan.writing`; the plan of :func:`render_outputs`
    checks the name)."""
    return Path(output) if output else Path("out") / (Path(scene).stem + ".exr")


def render_outputs(out: Path, *, png: bool, layout=None, default: bool = False) -> list:
    """The files :func:`write_render` writes for ``out``, as :class:`pointillist.plan.Output`:
    the EXR, and with ``png`` the preview (and the sample-count heat map when ``layout`` has a
    ``sample_count`` layer). ``default``: ``out`` is the default name, whose folder may be made."""
    from pointillist.plan import Output

    outputs = [Output(out, "--output", make_parent=default, suffixes=(".exr",))]
    if png:
        outputs.append(Output(out.with_suffix(".png"), "--png (preview)", make_parent=default))
        if layout is not None and SAMPLE_COUNT_LAYER in layout.layer_names():
            outputs.append(Output(out.with_suffix(f".{SAMPLE_COUNT_LAYER}.png"), "--png (sample-count heat map)",
                                  make_parent=default))
    return outputs


def check_preview(layout, png: bool) -> None:
    """UsageError when a PNG preview is asked of a render without colour."""
    if png and not layout.colour:
        raise UsageError("--png: the render has no colour channels (Mitsuba's aov integrator without a nested "
                         f"integrator renders only AOVs: {', '.join(layout.names)}); drop --png")


def write_render(out: Path, image, scene, scene_path: str, info: dict, timing, *, png: bool,
                 extra_layers: dict | None = None, layout=None, inputs=()) -> None:
    """Write a render's EXR (extra channels as layers, metadata in the header) and PNG preview.

    The image is split by the scene's :class:`pointillist.channels.ChannelLayout` (``layout``,
    read from ``scene`` when not given): colour (and alpha) are the EXR's ``Y``/``RGB``/``RGBA``
    channels, every AOV a layer of its own name; a render without colour (Mitsuba's ``aov``
    integrator alone) is an EXR of layers only. ``extra_layers`` adds (H, W) layers by name
    (e.g. a progressive render's ``variance``). ``inputs``: files no write may replace (the
    scene file is always one).
    """
    from pointillist.channels import channel_layout

    layout = layout or channel_layout(scene)
    metadata = dict(info, scene=str(scene_path), render_seconds=timing.total,
                    compile_seconds=timing.compile, execute_seconds=timing.execute,
                    trace_seconds=timing.trace)
    protected = [scene_path, *inputs]
    write_render_exr(out, image, layout, metadata, extra_layers=extra_layers, inputs=protected)
    if png:
        from pointillist.imaging.io import write_png

        check_preview(layout, png)
        parts = layout.split(image)
        write_png(out.with_suffix(".png"), parts.colour, inputs=protected)
        if SAMPLE_COUNT_LAYER in parts.layers:
            write_sample_heatmap(out.with_suffix(f".{SAMPLE_COUNT_LAYER}.png"), parts.layers[SAMPLE_COUNT_LAYER],
                                 inputs=protected)


def write_render_exr(out: Path, image, layout, metadata: dict, *, extra_layers: dict | None = None,
                     inputs=()) -> None:
    """Write a render's EXR through Mitsuba's writer: the channels of ``layout.kept()`` (colour,
    alpha, AOV layers), then ``extra_layers`` ((H, W) each, by name), with ``metadata`` (see
    :func:`pointillist.core.checks.exr_attribute`) in the header. A Dr.Jit ``image`` without extra layers goes to the
    file without numpy.
    """
    import drjit as dr
    import mitsuba as mi

    from pointillist.core.checks import exr_attribute
    from pointillist.core.files import atomic_write, check_output_path
    from pointillist.scene import thread_count

    out = check_output_path(out, inputs)
    kept = layout.kept()
    names = [name for name, _ in kept]
    if not names and not extra_layers:
        raise ValueError("image: the render has no channels to write")
    pixels = layout.pick(image, [index for _, index in kept])
    if extra_layers:
        import numpy as np

        height, width = pixels.shape[:2]
        extra = []
        for name, layer in extra_layers.items():
            layer = np.asarray(layer, dtype=np.float32)
            if layer.shape != (height, width) or name in names:
                raise ValueError(f"extra_layers[{name!r}]: expected a new (H, W) = ({height}, {width}) layer, "
                                 f"got shape {layer.shape}")
            names.append(name)
            extra.append(layer[..., None])
        pixels = np.ascontiguousarray(np.concatenate([np.asarray(pixels, dtype=np.float32), *extra], axis=2))
    bitmap = mi.Bitmap(pixels, mi.Bitmap.PixelFormat.MultiChannel, names)
    header = bitmap.metadata()
    for key, value in metadata.items():
        header[key] = exr_attribute(key, value)

    def write(tmp: str) -> None:
        stream = mi.MemoryStream()  # through Python's file: Mitsuba takes a path only as UTF-8 text
        with thread_count(max(dr.thread_count(), 2)):  # on a pool of one thread Mitsuba's EXR writer never returns
            bitmap.write(stream, mi.Bitmap.FileFormat.OpenEXR)
        with open(tmp, "wb") as file:
            file.write(stream.raw_buffer())

    atomic_write(out, write)



def write_sample_heatmap(path: Path, counts, *, inputs=()) -> None:
    """Write a per-pixel sample count as a heat map PNG (viridis, with a colour bar)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from pointillist.core.files import save_figure

    counts = np.asarray(counts, dtype=np.float64)
    height, width = counts.shape
    scale = 6.0 / max(height, width)
    fig, ax = plt.subplots(figsize=(max(width * scale, 2.5) + 1.2, max(height * scale, 2.0)), dpi=110)
    shown = ax.imshow(counts, cmap="viridis", interpolation="nearest",
                      vmin=float(counts.min()), vmax=max(float(counts.max()), float(counts.min()) + 1))
    fig.colorbar(shown, ax=ax, label="samples per pixel")
    ax.set_title(f"samples per pixel: mean {counts.mean():.1f}, max {counts.max():.0f}", fontsize=9)
    ax.set_axis_off()
    fig.tight_layout()
    save_figure(fig, path, inputs=inputs, name="sample-count heat map")

