"""The files of a comparison's report: ``results.csv``, ``results.md`` and the plots.

:func:`write_report` writes, from the sweep's records (:class:`~pointillist.compare.records.RenderRecord`)
and the numbers :mod:`pointillist.compare.tables` makes of them: ``results.csv`` (every render),
``results.md`` (table, fitted log-log slopes, equal-time and equal-error rankings), the two
log-log plots of error against time and spp, and the plot of the error images' radially averaged
power spectra (``error_spectrum.png``).
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pointillist.compare.methods import setting_label, sweep_parameter
from pointillist.compare.tables import (SHORT_MARK, TIMING_FLOOR, equal_error_ranking, equal_time_ranking,
                                        format_time, results_table, slopes, summarise)

__all__ = ["report_paths", "write_report", "mean_spectra"]


def _sweeps_spp(method: str) -> bool:
    return sweep_parameter(method) == "spp"

_CSV_FIELDS = ("method", "value", "seed", "spp", "time", "compile", "trace", "execute", "total",
               "warm_up", "warm_up_compile", "kernels", "cache_hits", "rmse", "relmse", "flip", "lowfreq", "width",
               "height", "exr")

#: Columns of results.csv in seconds: written with three significant digits.
_CSV_TIMES = ("time", "compile", "trace", "execute", "total", "warm_up", "warm_up_compile")

def report_paths(out_dir: str | os.PathLike) -> dict[str, Path]:
    """The files :func:`write_report` writes into ``out_dir``, by role (``spectrum_plot`` only with spectra)."""
    out = Path(out_dir)
    return {"csv": out / "results.csv", "md": out / "results.md",
            "time_plot": out / "error_vs_time.png", "spp_plot": out / "error_vs_spp.png",
            "spectrum_plot": out / "error_spectrum.png"}


def write_report(records: Sequence[Any], out_dir: str | os.PathLike, *, scene: str,
                 reference: str, title: str | None = None, notes: Sequence[str] = (),
                 spectra: Mapping[str, Any] | None = None) -> dict[str, Path]:
    """Write results.csv, results.md, error_vs_time.png and error_vs_spp.png into ``out_dir``, and
    with ``spectra`` error_spectrum.png.

    ``notes`` (one line each, e.g. why FLIP is NaN) are listed under the table's caption.
    ``spectra``: the radially averaged power spectrum of each render's luminance error
    (:class:`pointillist.imaging.spectrum.RadialSpectrum`) by ``record.exr``, as
    :func:`pointillist.compare.sweep.run_sweep` collects them: the spectrum plot shows their mean
    over seeds, one panel per spp.
    """
    from pointillist.core.files import atomic_write

    paths = report_paths(out_dir)
    if spectra is None:
        del paths["spectrum_plot"]
    atomic_write(paths["csv"], lambda tmp: _write_csv(records, tmp))
    rows = summarise(records)
    fitted = slopes(rows, min_time=TIMING_FLOOR)
    from pointillist.core.files import shown_in

    text = "\n".join(_markdown(rows, fitted, scene=scene, reference=shown_in(reference, out_dir), title=title,
                               notes=notes)) + "\n"
    atomic_write(paths["md"], lambda tmp: Path(tmp).write_text(text))
    _plot(rows, fitted, "time", "render time without JIT compile (s)", "mse_vs_time", paths["time_plot"])
    _plot(rows, fitted, "spp", "samples per pixel", "mse_vs_spp", paths["spp_plot"])
    if spectra is not None:
        _plot_spectra(records, spectra, paths["spectrum_plot"])
    return paths


def _write_csv(records: Sequence[Any], path: str) -> None:
    """results.csv: one row per render (its record), times with three significant digits."""
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=_CSV_FIELDS, extrasaction="ignore")
        writer.writeheader()
        for record in records:
            row = record.as_dict()
            row["exr"] = f"renders/{record.exr}"
            row.update({name: f"{row[name]:.3g}" for name in _CSV_TIMES})
            writer.writerow(row)


def _markdown(rows: Sequence[dict[str, Any]], fitted: dict[str, dict[str, float]], *, scene: str, reference: str,
              title: str | None, notes: Sequence[str]) -> list[str]:
    """The lines of results.md: the table with its caption and notes, the fitted slopes, the two rankings."""
    timed = [r for r in rows if r["time"] >= TIMING_FLOOR]
    return (_table_section(rows, timed, scene=scene, reference=reference, title=title, notes=notes)
            + _slopes_section(rows, fitted, timed) + _equal_time_section(timed) + _equal_error_section(timed))


def _md_text(text: str) -> str:
    """``text`` shown as itself in Markdown: HTML tags and entities, and Markdown's own marks, escaped
    (a scene file may be named ``<img src=x onerror=...>.xml``)."""
    import html
    import re

    return re.sub(r"([\\`*_{}\[\]()#+!|~>-])", r"\\\1", html.escape(text, quote=False))


def _md_code(text: str) -> str:
    """``text`` as a Markdown code span, whatever backticks it holds (the fence is one longer)."""
    import re

    fence = "`" * (max((len(run) for run in re.findall(r"`+", text)), default=0) + 1)
    return f"{fence} {text} {fence}" if "`" in text else f"{fence}{text}{fence}"


def _table_section(rows: Sequence[dict[str, Any]], timed: Sequence[dict[str, Any]], *, scene: str, reference: str,
                   title: str | None, notes: Sequence[str]) -> list[str]:
    """results.md's title, caption, notes and results table, and what its marks mean."""
    floor = format_time(TIMING_FLOOR)
    header, cells = results_table(rows)
    lines = [f"# {_md_text(title or 'Sampler comparison')}", "",
             f"Scene {_md_code(scene)}, reference {_md_code(reference)}. Errors against the reference; time = render "
             "wall time without JIT compilation (compile listed apart); mean ± standard deviation "
             "over seeds. relMSE uses epsilon 0.01; FLIP is HDR-FLIP; low-freq MSE is the part of the "
             "luminance error's mean square at spatial frequencies up to a quarter of Nyquist (1/8 cycle "
             "per pixel): white-noise error keeps about 5 % of its mean square there, blue-noise error "
             "less.", "",
             *[f"- {note}" for note in notes], *([""] if notes else []),
             "| " + " | ".join(header) + " |", "|---|---|" + "---:|" * (len(header) - 2)]
    lines += ["| " + " | ".join(row) + " |" for row in cells]
    lines += ["", "spp: samples per pixel taken (an adaptive method's mean over the pixels). A method's first "
              "render in a process follows an untimed warm-up render; its times are in results.csv "
              "(warm_up, warm_up_compile)."]
    if len(timed) < len(rows):
        lines += ["", f"{SHORT_MARK} {len(rows) - len(timed)} of {len(rows)} points took under {floor}: too short to "
                  "time reliably (timer resolution, scheduling and fixed per-launch costs weigh as much as the "
                  "work); the time slopes and the rankings below leave them out"
                  + ("." if timed else ", which leaves nothing to rank: render more pixels or samples "
                     "(e.g. -D res=...) to compare times.")]
    return lines


def _slopes_section(rows: Sequence[dict[str, Any]], fitted: dict[str, dict[str, float]],
                    timed: Sequence[dict[str, Any]]) -> list[str]:
    """The fitted log-log slopes of MSE against spp and time, per method."""
    floor = format_time(TIMING_FLOOR)
    lines = ["", "## Fitted log-log slopes (least squares over the sweep)", "",
             "| method | MSE vs spp | MSE vs time |", "|---|---:|---:|"]
    for method, s in fitted.items():
        if _sweeps_spp(method):
            by_time = f"{s['mse_vs_time']:.2f}" if math.isfinite(s["mse_vs_time"]) or len(timed) == len(rows) \
                else f"– {SHORT_MARK}"
            lines.append(f"| {method} | {s['mse_vs_spp']:.2f} | {by_time} |")
        else:
            lines.append(f"| {method} | – | – |")
    if not all(_sweeps_spp(method) for method in fitted):
        lines += ["", "–: the method sweeps another parameter than spp; a fit over that sweep is not "
                  "a convergence rate."]
    if len(timed) < len(rows):
        lines += ["", f"MSE vs time: fitted over the points of {floor} or more; – {SHORT_MARK}: fewer than two such "
                  "points."]
    return lines


def _equal_time_section(timed: Sequence[dict[str, Any]]) -> list[str]:
    """The equal-time ranking: the lowest MSE each method reaches within each time budget."""
    floor = format_time(TIMING_FLOOR)
    lines = ["", "## Equal-time ranking (lowest MSE reached within each time budget)", ""]
    if timed:
        lines += ["| budget | ranking (MSE) |", "|---:|---|"]
        for budget, ranked in equal_time_ranking(timed):
            text = ", ".join(f"{i + 1}. {m} ({e:.2e})" for i, (m, e) in enumerate(ranked)) or "none"
            lines.append(f"| {format_time(budget)} | {text} |")
    else:
        lines.append(f"Left out: every render took under {floor} ({SHORT_MARK} above).")
    return lines


def _equal_error_section(timed: Sequence[dict[str, Any]]) -> list[str]:
    """The equal-error ranking: the fastest render of each method reaching each RMSE of the first method."""
    floor = format_time(TIMING_FLOOR)
    anchors = [r for r in timed if r["method"] == timed[0]["method"]] if timed else []
    lines = ["", "## Equal-error ranking (fastest render reaching each RMSE)", ""]
    if anchors:
        lines += [f"Budgets: the RMSE of each {anchors[0]['method']} point; times relative to that point's.", "",
                  "| RMSE budget (from) | ranking (time) |", "|---|---|"]
        for anchor, (budget, ranked) in zip(anchors, equal_error_ranking(timed, [a["rmse"] for a in anchors])):
            text = ", ".join(f"{i + 1}. {m} {setting_label(m, v)} ({format_time(t)}, {t / anchor['time']:.2f}x)"
                             for i, (m, v, t) in enumerate(ranked))
            lines.append(f"| {budget:.5f} ({anchor['method']} {setting_label(anchor['method'], anchor['value'])}, "
                         f"{format_time(anchor['time'])}) | {text} |")
    else:
        lines.append(f"Left out: every render took under {floor} ({SHORT_MARK} above).")
    return lines


def mean_spectra(records: Sequence[Any], spectra: Mapping[str, Any]) -> dict[tuple[str, float], tuple]:
    """Per (method, value): ``(spectrum, mean spp, mean lowfreq)`` over the seeds of the records whose
    spectrum ``spectra`` holds (by ``record.exr``), ``spectrum`` a
    :class:`pointillist.imaging.spectrum.RadialSpectrum` whose power is the seeds' mean."""
    from pointillist.imaging.spectrum import RadialSpectrum

    groups: dict[tuple[str, float], list[Any]] = {}
    for record in records:
        if record.exr in spectra:
            groups.setdefault((record.method, float(record.value)), []).append(record)
    result = {}
    for key, group in groups.items():
        found = [spectra[r.exr] for r in group]
        mean = RadialSpectrum(frequency=found[0].frequency, power=np.mean([s.power for s in found], axis=0),
                              count=found[0].count)
        result[key] = (mean, float(np.mean([r.spp for r in group])), float(np.mean([r.lowfreq for r in group])))
    return result


def _plot_spectra(records: Sequence[Any], spectra: Mapping[str, Any], path: Path) -> None:
    """Radially averaged power spectra of the error images: a panel per spp, a curve per method."""
    from pointillist.core.files import save_figure
    from pointillist.imaging.spectrum import LOW_FREQUENCY_CUTOFF, log_binned

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curves = mean_spectra(records, spectra)
    panels = sorted({value for (method, value) in curves if _sweeps_spp(method)}) or \
        sorted({round(spp) for (_, spp, _) in curves.values()})
    columns = min(max(len(panels), 1), 3)
    rows_n = max(math.ceil(len(panels) / columns), 1)
    fig, axes = plt.subplots(rows_n, columns, figsize=(4.4 * columns, 3.6 * rows_n), dpi=110, squeeze=False)
    methods = list(dict.fromkeys(r.method for r in records))
    for index, panel in enumerate(panels):
        ax = axes.flat[index]
        for (method, value), (spectrum, spp, lowfreq) in curves.items():
            near = value if _sweeps_spp(method) else min(panels, key=lambda p: abs(math.log(max(spp, 1e-9) / p)))
            if near != panel:
                continue
            merged = log_binned(spectrum)  # rings merged into 12 bins a decade: the low rings are few frequencies
            frequency, power = merged.frequency, merged.power
            ok = (frequency > 0) & np.isfinite(power) & (power > 0)
            label = f"{method}" + ("" if _sweeps_spp(method) else f" {setting_label(method, value)}") + \
                f" (low-freq {lowfreq:.2e})"
            if ok.any():
                ax.plot(frequency[ok], power[ok], color=f"C{methods.index(method) % 10}", linewidth=1.2,
                        label=label)
        ax.set_title(f"{panel:g} spp", fontsize=10)
        ax.set_xlabel("frequency (cycles per pixel)")
        ax.set_ylabel("power of the luminance error")
        if ax.lines:  # log axes only for positive data (an error-free render, e.g. a black scene, has none)
            lowest = min(float(line.get_xdata().min()) for line in ax.lines)
            ax.axvspan(lowest, LOW_FREQUENCY_CUTOFF, color="grey", alpha=0.12, linewidth=0)
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlim(right=0.5)
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=7)
        else:
            ax.text(0.5, 0.5, "no spectrum with power > 0", transform=ax.transAxes, ha="center")
    for ax in list(axes.flat)[len(panels):]:
        ax.set_visible(False)
    fig.suptitle("Error spectra (radial mean of the periodogram, 12 bins a decade; shaded: up to 1/4 of Nyquist)",
                 fontsize=10)
    fig.tight_layout()
    save_figure(fig, path)

def _plot(rows, fitted, x_name: str, x_label: str, slope_name: str, path: Path) -> None:
    from pointillist.core.files import save_figure

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.8), dpi=110)
    xs_all, ys_all = [], []
    for method in dict.fromkeys(r["method"] for r in rows):
        spp_sweep = _sweeps_spp(method)
        mine = [r for r in rows if r["method"] == method]  # another parameter: in sweep order
        if spp_sweep:
            mine.sort(key=lambda r: r[x_name])
        x = np.array([r[x_name] for r in mine])
        y = np.array([r["mse"] for r in mine])
        err = np.array([2 * r["rmse"] * r["rmse_std"] for r in mine])  # std of MSE, first order
        ok = (x > 0) & (y > 0)
        xs_all += list(x[ok])
        ys_all += list(y[ok])
        slope = fitted[method][slope_name]
        label = f"{method} (slope {slope:.2f})" if spp_sweep and math.isfinite(slope) else \
            f"{method} (slope –)" if spp_sweep else \
            f"{method} ({sweep_parameter(method)} labelled)"
        ax.errorbar(x[ok], y[ok], yerr=err[ok], marker="o", capsize=2, label=label)
        if not spp_sweep:  # a threshold sweep: say which point is which
            for xi, yi, r in zip(x[ok], y[ok], [r for r, good in zip(mine, ok) if good]):
                ax.annotate(f"{r['value']:g}", (xi, yi), textcoords="offset points", xytext=(4, 4), fontsize=7)
    if xs_all:
        x0, y0 = min(xs_all), max(ys_all)
        x1 = max(xs_all)
        for slope, style in ((-1, ":"), (-1.5, "--"), (-2, "-.")):
            ax.plot([x0, x1], [y0, y0 * (x1 / x0) ** slope], style, color="grey", linewidth=1,
                    label=f"slope {slope:g}")
    if x_name == "time" and xs_all and min(xs_all) < TIMING_FLOOR:
        ax.axvspan(min(xs_all) / 2, TIMING_FLOOR, color="grey", alpha=0.15, linewidth=0,
                   label=f"under {format_time(TIMING_FLOOR)}: not timed reliably")
    if xs_all:
        ax.set_xscale("log")
        ax.set_yscale("log")
    else:  # every MSE 0 (a render equal to the reference, e.g. a black scene): nothing to put on log axes
        ax.text(0.5, 0.5, "no point with MSE > 0 to plot", transform=ax.transAxes, ha="center")
    ax.set_xlabel(x_label)
    ax.set_ylabel("MSE against the reference")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)
