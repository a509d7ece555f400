"""What a progressive render reports: the ``.progress.csv`` log and ``.progress.png`` plot of its
estimated error against time, and the warnings a finished render prints."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from pointillist.progressive.estimate import FIREFLY_RANGE, HALVES_AGREEMENT, MIN_PASSES
from pointillist.progressive.stats import HISTORY_COLUMNS, PassStats

__all__ = ["progress_paths", "write_progress", "render_warnings"]


def progress_paths(out: str | Path) -> tuple[Path, Path]:
    """``(OUT.progress.csv, OUT.progress.png)`` beside the EXR ``OUT.exr``."""
    return Path(out).with_suffix(".progress.csv"), Path(out).with_suffix(".progress.png")


def write_progress(out: str | Path, history: list, *, png: bool = False, inputs=()) -> list[Path]:
    """Write ``OUT.progress.csv`` and, with ``png``, ``OUT.progress.png``.

    The CSV has one row per pass: ``pass, seconds, spp, estimated_relmse, halves_ratio, floored,
    estimate_state`` (``none``, ``trusted`` or ``untrusted``; empty numbers where there is no
    estimate; :class:`~pointillist.progressive.estimate.ErrorEstimate`). The plot shows the
    estimated relMSE against render seconds on log-log axes, trusted estimates filled and
    untrusted ones hollow, with a line of slope -1 (error proportional to 1/t, the Monte Carlo
    rate) through the last estimate. Returns the paths written.
    """
    from pointillist.core.files import atomic_write, check_output_path, save_figure

    csv_path, png_path = progress_paths(out)
    check_output_path(csv_path, inputs)
    data = np.asarray(history, np.float64).reshape(-1, len(HISTORY_COLUMNS))
    states = np.where(np.isnan(data[:, 6]), "none", np.where(data[:, 6] > 0, "trusted", "untrusted"))

    def number(x: float, fmt: str) -> str:
        return "" if not math.isfinite(x) else format(x, fmt)

    rows = [",".join(HISTORY_COLUMNS[:6] + ("estimate_state",))] + [
        f"{int(k)},{t:.6f},{int(n)},{number(e, '.6g')},{number(q, '.4g')},{number(f, '.3g')},{state}"
        for (k, t, n, e, q, f, _), state in zip(data, states)]
    atomic_write(csv_path, lambda tmp: Path(tmp).write_text("\n".join(rows) + "\n"))
    written = [csv_path]
    if png:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        ok = np.isfinite(data[:, 3]) & (data[:, 3] > 0) & (data[:, 1] > 0)
        fig, ax = plt.subplots(figsize=(5.5, 4), dpi=110)
        if ok.any():
            t, e, trusted = data[ok, 1], data[ok, 3], states[ok] == "trusted"
            ax.loglog(t, e, "-", color="C0", lw=1, label="estimated relMSE")
            ax.loglog(t[trusted], e[trusted], "o", ms=3, color="C0", label="trusted (halves agree)")
            if (~trusted).any():
                ax.loglog(t[~trusted], e[~trusted], "o", ms=4, mfc="none", color="C3",
                          label="untrusted (halves disagree)")
            span = np.array([t.min(), t.max()])
            ax.loglog(span, e[-1] * t[-1] / span, "--", color="grey", label="1/t (slope -1)")
            ax.legend(fontsize=8)
        else:
            ax.text(0.5, 0.5, f"no estimate yet (from {MIN_PASSES} passes on)", ha="center", transform=ax.transAxes)
        ax.set_xlabel("render seconds")
        ax.set_ylabel("estimated relMSE")
        ax.set_title(f"{int(data[-1, 0]) if len(data) else 0} passes, {int(data[-1, 2]) if len(data) else 0} spp",
                     fontsize=9)
        ax.grid(True, which="both", lw=0.3)
        fig.tight_layout()
        save_figure(fig, png_path, inputs=inputs)
        written.append(png_path)
    return written


def render_warnings(stats: PassStats, first_nonfinite: int | None, stop: str = "") -> list[str]:
    """The lines a finished render warns with: NaN/inf pixels, an estimate that is not trusted (not after an
    interruption: the render is known to be unfinished, and says so in one line)."""
    warnings = []
    if stats.nonfinite:
        since = "in the resumed passes" if first_nonfinite is None else f"from pass {first_nonfinite} on"
        warnings.append(f"{stats.nonfinite} of {stats.width * stats.height} pixels are NaN or inf ({since}); "
                        "they stay so in the image and are left out of the error estimate")
    if stats.estimate_state == "untrusted" and stop != "interrupted":
        why = (f"its two halves differ {stats.halves_ratio:.3g}x (more than {HALVES_AGREEMENT:g}x)"
               if not stats.halves_ratio <= HALVES_AGREEMENT else
               f"{stats.floored:.0%} of it comes from single samples more than {FIREFLY_RANGE}x their pixel's "
               "neighbourhood")
        warnings.append(f"the error estimate is not trusted: {why}, so rare bright paths dominate it and the true "
                        "error may be far from it; render longer")
    return warnings
