"""Writing a render: the EXR (extra film channels as layers, metadata in the header), the sRGB
PNG preview, and the heat map of a per-pixel sample count (the ``adaptive`` integrator's AOV).

Every file is written atomically and never over an input (:mod:`pointillist.files`).
"""

from __future__ import annotations

from pathlib import Path

from pointillist.errors import UsageError

__all__ = ["SAMPLE_COUNT_LAYER", "output_path", "render_outputs", "check_preview", "write_render",
           "write_sample_heatmap"]


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
    from pointillist.imaging.io import write_exr, write_png

    layout = layout or channel_layout(scene)
    parts = layout.split(image)
    colour = layout.with_colour_alpha(image)
    layers = dict(parts.layers)
    layers.update(extra_layers or {})
    metadata = dict(info, scene=str(scene_path), render_seconds=timing.total,
                    compile_seconds=timing.compile, execute_seconds=timing.execute,
                    trace_seconds=timing.trace)
    protected = [scene_path, *inputs]
    write_exr(out, colour, metadata, layers=layers, inputs=protected)
    if png:
        check_preview(layout, png)
        write_png(out.with_suffix(".png"), parts.colour, inputs=protected)
        if SAMPLE_COUNT_LAYER in layers:
            write_sample_heatmap(out.with_suffix(f".{SAMPLE_COUNT_LAYER}.png"), layers[SAMPLE_COUNT_LAYER],
                                 inputs=protected)



def write_sample_heatmap(path: Path, counts, *, inputs=()) -> None:
    """Write a per-pixel sample count as a heat map PNG (viridis, with a colour bar)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from pointillist.files import save_figure

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

