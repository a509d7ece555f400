"""Writing a render: the EXR (extra film channels as layers, metadata in the header), the sRGB
PNG preview, and the heat map of a per-pixel sample count (the ``adaptive`` integrator's AOV).

Every file is written atomically and never over an input (:mod:`pointillist.imaging.io`).
"""

from __future__ import annotations

from pathlib import Path

from pointillist.errors import UsageError

__all__ = ["SAMPLE_COUNT_LAYER", "output_path", "write_render", "write_sample_heatmap"]


#: The EXR layer of a per-pixel sample count (written by the ``adaptive`` integrator).
SAMPLE_COUNT_LAYER = "sample_count"



def output_path(scene: str, output: str | None) -> Path:
    """The EXR path to write: ``output`` or ``out/<scene stem>.exr``; checks it is not the scene."""
    path = Path(output) if output else Path("out") / (Path(scene).stem + ".exr")
    if path.suffix.lower() != ".exr":
        raise UsageError(f"--output: expected a .exr file name, got {path}")
    if not output:
        path.parent.mkdir(parents=True, exist_ok=True)
    if path.exists() and Path(scene).exists() and path.resolve() == Path(scene).resolve():
        raise UsageError(f"--output: refusing to overwrite the input {path}")
    return path



def write_render(out: Path, image, scene, scene_path: str, info: dict, timing, *, png: bool,
                 extra_layers: dict | None = None) -> None:
    """Write a render's EXR (extra channels as layers, metadata in the header) and PNG preview.

    ``extra_layers`` adds (H, W) EXR layers by name (e.g. a progressive render's ``variance``).
    """
    import numpy as np

    from pointillist.imaging.io import write_exr, write_png

    pixels = np.asarray(image)
    names = list(scene.integrator().aov_names())
    base = pixels.shape[2] - len(names)
    layers = {name: pixels[..., base + i] for i, name in enumerate(names)}
    layers.update(extra_layers or {})
    metadata = dict(info, scene=str(scene_path), render_seconds=timing.total,
                    compile_seconds=timing.compile, execute_seconds=timing.execute,
                    trace_seconds=timing.trace)
    write_exr(out, pixels[..., :base], metadata, layers=layers, inputs=[scene_path])
    if png:
        write_png(out.with_suffix(".png"), pixels[..., :min(base, 3)], inputs=[scene_path])
        if SAMPLE_COUNT_LAYER in layers:
            write_sample_heatmap(out.with_suffix(f".{SAMPLE_COUNT_LAYER}.png"), layers[SAMPLE_COUNT_LAYER],
                                 inputs=[scene_path])



def write_sample_heatmap(path: Path, counts, *, inputs=()) -> None:
    """Write a per-pixel sample count as a heat map PNG (viridis, with a colour bar)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from pointillist.imaging.io import check_output_path, save_figure

    path = check_output_path(path, inputs, name="sample-count heat map")
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
    save_figure(fig, path)

