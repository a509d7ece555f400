"""``pointillist post``: run imaging steps on a render (EXR) or an 8-bit image, in order, and
write PNG/EXR.

Only the steps asked for run (:mod:`pointillist.steps`). EXR input is linear
light: a tone-mapping step (``tonemap:...``) turns it into display intensities on
0..255; when the first step that needs display intensities comes before any tone
mapping, ``tonemap:clip`` (clip to 0..1, sRGB curve, scale to 255) is applied
first and said so. PNG/JPEG input is already on 0..255.

Output: ``.png`` writes 8-bit (display values as they are, or an sRGB preview of
linear values when no step ran that leaves linear light); ``.exr`` writes the
float values as they are.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pointillist.core import signals
from pointillist.core.errors import UsageError
from pointillist.core.files import input_file

__all__ = ["AppliedSteps", "apply_steps", "PostResult", "post_process", "step_list", "histogram_plot", "POST_COPIES"]


@dataclass
class PostResult:
    """What :func:`post_process` did: the output, the steps run (as text), warnings to show
    (``notes``), per-step statistics (``reports``: ``(step, summary, extra figures)``, with
    ``report=True``) and the histogram plot written, if any."""

    output: Path
    done: list[str]
    notes: list[str] = field(default_factory=list)
    reports: list[tuple[str, str, dict[str, float]]] = field(default_factory=list)
    plot: Path | None = None


#: Float32 copies of an image a post run holds at its peak (measured: 2.7 GB resident for a 4000 x
#: 4000 RGB EXR of 192 MB, the conversion to PNG; 2.1 GB with tone mapping and gamma): checked
#: against the machine's memory before the pixels are read.
POST_COPIES = 14

def step_list() -> list[str]:
    """One line per known step: ``name (parameters): help``."""
    from pointillist.steps import steps

    return [f"{name}{f' ({chr(44).join(spec.params)})' if spec.params else ''}: {spec.help}"
            for name, spec in steps().items()]


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
    notes.extend(str(warning.message) for warning in caught)
    return result


@dataclass
class AppliedSteps:
    """What :func:`apply_steps` returns: the image (a lazy Dr.Jit tensor), whether it is still
    linear light, the steps run (as text, ``tonemap:clip`` included when it was added), the
    warnings (``notes``) and, with ``report``, per-step statistics."""

    image: Any
    linear: bool
    done: list[str]
    notes: list[str] = field(default_factory=list)
    reports: list[tuple[str, str, dict[str, float]]] = field(default_factory=list)


def apply_steps(image, pipeline: str | Sequence, *, linear: bool = False, report: bool = False) -> AppliedSteps:
    """Run post-processing steps on an image array, in order; nothing is read or written.

    ``pipeline`` is step text (``"grey;gamma:2.2;sobel"``, see :mod:`pointillist.steps`) or
    what :func:`pointillist.steps.parse_steps` returns. ``linear``: the image is linear
    light (an EXR render); a display step then gets ``tonemap:clip`` first (said in
    ``notes``). The result stays lazy (a Dr.Jit tensor) unless ``report`` asks for
    statistics, so a chain of steps fuses where Dr.Jit can fuse it. ``normalize`` after a
    window step with the zero (or keep) border leaves that step's uncomputed ring out, as
    ``correlate:...,normalize=true`` does (``normalize:ring=N`` overrides).

    Examples
    --------
    >>> import numpy as np
    >>> out = apply_steps(np.array([[0.0, 100.0], [200.0, 255.0]]), "threshold:level=128")
    >>> np.asarray(out.image).tolist(), out.done
    ([[0.0, 0.0], [255.0, 255.0]], ['threshold:level=128'])
    """
    from pointillist.imaging import as_tensor
    from pointillist.imaging.arrays import TensorXu8, is_uint8, uint8_array
    from pointillist.steps import parse_steps
    from pointillist.steps import steps as known_steps

    if isinstance(pipeline, str):
        pipeline = parse_steps(pipeline)
    # 8-bit input stays bytes (shared, no float32 copy) up to the first step that does not `takes_bytes`
    # step, which gets its float32 conversion lazily (computed inside that step's kernel)
    current = TensorXu8(uint8_array(image)) if is_uint8(image) else as_tensor(image)
    known = known_steps()
    reports: list[tuple[str, str, dict[str, float]]] = []
    done: list[str] = []
    notes: list[str] = []
    ring = 0  # the border ring the last window step left uncomputed (zero border), for normalize
    for spec, kwargs in pipeline:
        if spec.name == "normalize" and "ring" not in kwargs and ring:
            kwargs = dict(kwargs, ring=ring)
        if not spec.takes_bytes or linear:
            current = as_tensor(current)
        if linear and not spec.linear:
            current = _run_step(known["tonemap"], current, {"operator": "clip"}, notes)
            linear = False
            done.append("tonemap:clip")
            notes.append("the input is linear light; applied tonemap:clip first")
        elif spec.linear and not linear:
            raise UsageError(f"--steps: {spec.name} expects linear-light (EXR) input, "
                             "but the image is already display-referred")
        previous = current
        current = _run_step(spec, current, kwargs, notes)
        ring = spec.ring(kwargs) if spec.ring is not None else ring
        linear = False if spec.linear else linear
        done.append(spec.name + (":" + ",".join(f"{k}={v}" for k, v in kwargs.items()) if kwargs else ""))
        if report:
            reports.append((spec.name, _stats(current), spec.report(previous, current) if spec.report else {}))
    return AppliedSteps(image=current, linear=linear, done=done, notes=notes, reports=reports)


def post_process(source: str | os.PathLike | None, output: str | os.PathLike | None, *, steps: str = "",
                 step: Sequence[str] = (), dither: str | None = None, report: bool = False, plot: bool = False,
                 plot_file: str | os.PathLike | None = None) -> PostResult:
    """Read ``source``, run ``steps`` (``"a:k=v;b"``), then each of ``step``, then ``dither``
    (``METHOD[:ARGS]``), and write ``output`` (``.png`` or ``.exr``); with ``plot`` (or
    ``plot_file``), a before/after histogram plot too. Without any step the image is converted:
    an EXR becomes the sRGB preview ``render --png`` writes (clipped to 0..1, sRGB curve), an
    8-bit image is written as it is.

    Raises
    ------
    UsageError
        For a missing input, an output that is not .png/.exr, is the input or a folder,
        and any step that refuses its arguments (one line naming the step).
    """
    from pointillist.plan import Output, Plan
    from pointillist.steps import parse_steps

    if source is None:
        raise UsageError("input: expected an input image (EXR, PNG, JPEG or TIFF)")
    if output is None:
        raise UsageError("--output: expected an output .png or .exr file name")
    text = ";".join([steps, *step] + ([f"dither:{dither.replace(':', ',', 1)}"] if dither else []))
    # no step at all is a conversion (an EXR to an sRGB PNG preview, as `render --png` writes it)
    pipeline = parse_steps(text) if any(chunk.strip() for chunk in text.split(";")) else []
    source, out = input_file(source, "input"), Path(output)
    # The plan, before any work: the input image and any file a step reads (a table), the
    # output and the plot.
    inputs = [source] + [Path(value) for _, kwargs in pipeline for value in kwargs.values()
                         if isinstance(value, str) and Path(value).is_file()]
    outputs = [Output(out, "--output", suffixes=(".png", ".exr"))]
    plot_path = None
    if plot or plot_file:
        plot_path = Path(plot_file) if plot_file else out.with_name(out.stem + "_histogram.png")
        outputs.append(Output(plot_path, "--plot-file" if plot_file else "--plot", suffixes=(".png",)))
    Plan(inputs=inputs, outputs=outputs).check()

    from pointillist.imaging.io import read_image, write_exr, write_png

    try:
        image, metadata, _layers = read_image(source, copies=POST_COPIES)
    except ValueError as error:
        raise UsageError(str(error)) from None
    dropped = []
    if image.ndim == 3 and image.shape[2] in (2, 4):  # grey or colour, with alpha
        kind = "grey" if image.shape[2] == 2 else "RGB"
        image = image[..., 0] if image.shape[2] == 2 else image[..., :3]
        dropped.append(f"the input's alpha channel is dropped (the steps run on {kind})")
    before = image
    applied = apply_steps(image, pipeline, linear=source.suffix.lower() == ".exr", report=report)
    current, linear, done, notes, reports = (applied.image, applied.linear, applied.done,
                                             dropped + applied.notes, applied.reports)
    signals.check()  # a safe point: the steps ran, nothing is written yet
    if out.suffix.lower() == ".exr":
        write_exr(out, current, dict(metadata, post_steps=";".join(done)), inputs=inputs)
    elif linear:  # the sRGB preview of linear values (no step ran, or none left display values)
        import numpy as np

        current = np.asarray(current)  # evaluated once: counted here, then written (and plotted)
        bad = int(np.count_nonzero(~np.isfinite(current)))
        if bad:
            notes.append(f"the preview replaced {bad} non-finite value(s) (NaN -> 0, +inf -> white, -inf -> 0)")
        write_png(out, current, inputs=inputs)
    else:
        write_png(out, current, srgb=False, max_value=255.0, inputs=inputs)
    if plot_path is not None:
        histogram_plot(plot_path, before, current, linear_before=source.suffix.lower() == ".exr",
                       title=f"{source.name}: {'; '.join(done)}", inputs=inputs)
    return PostResult(output=out, done=done, notes=notes, reports=reports, plot=plot_path)


def histogram_plot(path: Path, before, after, *, linear_before: bool, title: str, inputs=()) -> None:
    """Write a PNG with the histograms of ``before`` and ``after`` side by side."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from pointillist.core.files import save_figure

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
    save_figure(fig, path, inputs=inputs, name="--plot", dpi=100)

