"""Post-process a render (EXR) or an 8-bit image with imaging steps, in order, and write PNG/EXR.

Only the steps asked for run. EXR input is linear light: a tone-mapping step
(``tonemap:...``) turns it into display intensities on 0..255; when the first
step that needs display intensities comes before any tone mapping,
``tonemap:clip`` (clip to 0..1, sRGB curve, scale to 255) is applied first and
said so. PNG/JPEG input is already on 0..255.

Output: ``.png`` writes 8-bit (display values as they are, or an sRGB preview
of linear values when no step ran that leaves linear light); ``.exr`` writes the
float values as they are.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pointillist.errors import UsageError

NAME = "post"
HELP = "tone-map, filter and dither a render (steps run in order)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("input", nargs="?", help="input image: EXR render, or PNG/JPEG/TIFF")
    parser.add_argument("-o", "--output", help="output .png or .exr (required unless --list-steps)")
    parser.add_argument("--steps", default="", metavar="STEPS",
                        help='steps separated by ";", e.g. "tonemap:reinhard,exposure=1;gamma:2.2"')
    parser.add_argument("--step", action="append", default=[], metavar="STEP",
                        help="one step (repeatable; runs after --steps)")
    parser.add_argument("--dither", metavar="METHOD[:ARGS]",
                        help="dither last, e.g. floyd_steinberg or ordered:levels=4")
    parser.add_argument("--report", action="store_true",
                        help="print statistics after each step (and the dither error)")
    parser.add_argument("--plot", action="store_true",
                        help="write a before/after histogram plot (OUTPUT stem + _histogram.png)")
    parser.add_argument("--plot-file", metavar="FILE", help="write the histogram plot here (implies --plot)")
    parser.add_argument("--list-steps", action="store_true", help="list the known steps and exit")


def _stats(image) -> str:
    import numpy as np

    values = np.asarray(image)
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return "no finite values"
    return f"min {finite.min():.4g}, mean {finite.mean():.4g}, max {finite.max():.4g}"


def _run_step(spec, image, kwargs, notes):
    """Run one step; bad arguments become a one-line UsageError, warnings are added to ``notes``
    (printed, one line each, only once every step has succeeded: an error stays one line)."""
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            result = spec.function(image, **kwargs)
        except (TypeError, ValueError) as error:
            raise UsageError(f"--steps: {spec.name}: {error}") from None
    notes.extend(f"post: warning: {warning.message}" for warning in caught)
    return result


def run(args: argparse.Namespace) -> int:
    from pointillist.steps import parse_steps, steps

    if args.list_steps:
        for name, spec in steps().items():
            params = f" ({', '.join(spec.params)})" if spec.params else ""
            print(f"{name}{params}: {spec.help}")
        return 0
    if args.input is None:
        raise UsageError("input: expected an input image (EXR, PNG, JPEG or TIFF)")
    if args.output is None:
        raise UsageError("--output: expected an output .png or .exr file name")
    text = ";".join([args.steps, *args.step] + ([f"dither:{args.dither.replace(':', ',', 1)}"] if args.dither else []))
    pipeline = parse_steps(text)
    source, out = Path(args.input), Path(args.output)
    if out.suffix.lower() not in (".png", ".exr"):
        raise UsageError(f"--output: expected a .png or .exr file name, got {out}")
    if not source.is_file():
        raise UsageError(f"input: no such file: {source}")
    if out.exists() and out.resolve() == source.resolve():
        raise UsageError(f"--output: refusing to overwrite the input {source}")
    if not out.parent.is_dir():
        raise UsageError(f"--output: folder {out.parent} does not exist")
    if out.is_dir():
        raise UsageError(f"--output: {out} is a folder, expected a file name")
    plot = None
    if args.plot or args.plot_file:
        plot = Path(args.plot_file) if args.plot_file else out.with_name(out.stem + "_histogram.png")
        if plot.suffix.lower() != ".png":
            raise UsageError(f"--plot-file: expected a .png file name, got {plot}")
        if plot.resolve() == out.resolve():
            raise UsageError(f"--plot-file: {plot} is the --output file")
        from pointillist.imaging.io import check_output_path

        try:
            check_output_path(plot, [source], name="--plot")
        except ValueError as error:
            raise UsageError(str(error)) from None

    from pointillist.imaging import as_tensor
    from pointillist.imaging.io import read_image, write_exr, write_png

    try:
        image, metadata, _layers = read_image(source)
    except ValueError as error:
        raise UsageError(str(error)) from None
    if image.ndim == 3 and image.shape[2] == 4:
        image = image[..., :3]
    linear = source.suffix.lower() == ".exr"
    before = image
    current = as_tensor(image)
    known = steps()
    done = []
    notes: list[str] = []
    for spec, kwargs in pipeline:
        if linear and not spec.linear:
            current = _run_step(known["tonemap"], current, {"operator": "clip"}, notes)
            linear = False
            done.append("tonemap:clip")
            notes.append("post: input is linear light; applied tonemap:clip first")
        elif spec.linear and not linear:
            raise UsageError(f"--steps: {spec.name} expects linear-light (EXR) input, "
                             "but the image is already display-referred")
        previous = current
        current = _run_step(spec, current, kwargs, notes)
        linear = False if spec.linear else linear
        done.append(spec.name + (":" + ",".join(f"{k}={v}" for k, v in kwargs.items()) if kwargs else ""))
        if args.report:
            print(f"{spec.name}: {_stats(current)}")
            if spec.report is not None:
                for key, value in spec.report(previous, current).items():
                    print(f"  {key}: {value:.6g}")
    if out.suffix.lower() == ".exr":
        write_exr(out, current, dict(metadata, post_steps=";".join(done)), inputs=[source])
    elif linear:
        write_png(out, current, inputs=[source])
    else:
        write_png(out, current, srgb=False, max_value=255.0, inputs=[source])
    for note in notes:
        print(note, file=sys.stderr)
    print(f"wrote {out} ({'; '.join(done)})")
    if plot is not None:
        histogram_plot(plot, before, current, linear_before=source.suffix.lower() == ".exr",
                       title=f"{source.name}: {'; '.join(done)}", inputs=[source])
        print(f"wrote {plot}")
    return 0


def histogram_plot(path: Path, before, after, *, linear_before: bool, title: str, inputs=()) -> None:
    """Write a PNG with the histograms of ``before`` and ``after`` side by side."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from pointillist.imaging.io import atomic_write, check_output_path

    path = check_output_path(path, inputs, name="--plot")
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.5))
    for ax, data, label in ((axes[0], before, "before"), (axes[1], after, "after")):
        values = np.asarray(data, dtype=np.float64)
        values = values.reshape(values.shape[0], values.shape[1], -1)
        finite = values[np.isfinite(values)]
        linear = label == "before" and linear_before
        # Linear renders: a few very bright pixels would squash the plot; show up to the 99.9th percentile.
        high = float(np.percentile(finite, 99.9)) if linear and finite.size else None
        low = float(finite.min()) if finite.size else 0.0
        span = (low, high if high is not None and high > low else low + 1.0) if linear else (
            (min(low, 0.0), max(float(finite.max()) if finite.size else 255.0, 255.0)))
        colours = ("tab:red", "tab:green", "tab:blue") if values.shape[2] == 3 else ("0.3",) * values.shape[2]
        names = ("R", "G", "B") if values.shape[2] == 3 else ("grey",) * values.shape[2]
        for c in range(values.shape[2]):
            channel = values[..., c]
            channel = channel[np.isfinite(channel)]
            ax.hist(channel, bins=256, range=span, histtype="step", color=colours[c], label=names[c])
        if values.shape[2] == 3:
            ax.legend(fontsize=7)
        ax.set_title(label + (" (linear, to the 99.9th percentile)" if linear else " (0..255)"))
        ax.set_xlabel("value")
        ax.set_ylabel("pixels")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    try:
        atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=100, format="png"))
    finally:
        plt.close(fig)
