"""The report of a comparison: summaries over seeds, fitted slopes, rankings, tables, plots.

Everything here works on :class:`pointillist.compare.RenderRecord` values (or the
rows :func:`summarise` makes of them) and renders nothing: :func:`write_report`
writes ``results.csv``, ``results.md`` (table, fitted log-log slopes, equal-time and
equal-error rankings), the two log-log plots of error against time and spp, and the
plot of the error images' radially averaged power spectra (``error_spectrum.png``).
Times read with three significant digits in a fitting unit (:func:`format_time`);
renders faster than :data:`TIMING_FLOOR` are too short to time reliably: they are
marked, and the time slopes and rankings leave them out.
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pointillist.compare_methods import setting_label, sweep_parameter

__all__ = ["fit_slope", "summarise", "slopes", "equal_time_ranking", "equal_error_ranking", "report_paths",
           "write_report", "format_time", "results_table", "mean_spectra", "TIMING_FLOOR"]


#: Renders shorter than this (seconds) are too short to time reliably here: timer resolution,
#: thread scheduling on a shared machine and fixed per-launch costs weigh as much as the work.
TIMING_FLOOR = 0.020


def format_time(seconds: float, spread: float | None = None) -> str:
    """``seconds`` with three significant digits in s, ms or µs (and ``± spread`` in that unit).

    Examples
    --------
    >>> format_time(0.001234), format_time(0.0123), format_time(1.5), format_time(123.4)
    ('1.23 ms', '12.3 ms', '1.50 s', '123 s')
    >>> format_time(0.0000456), format_time(0.9996), format_time(4321.0), format_time(0.0)
    ('45.6 µs', '1.00 s', '4321 s', '0 s')
    >>> format_time(0.0123, 0.00045)
    '12.3 ± 0.45 ms'
    """
    if not math.isfinite(seconds):
        return "nan" if math.isnan(seconds) else str(seconds)
    if seconds == 0:
        return "0 s" if spread is None else f"0 ± {format_time(spread)}"
    for unit, scale in (("s", 1.0), ("ms", 1e-3), ("µs", 1e-6)):
        if abs(seconds) >= 0.9995 * scale or unit == "µs":
            break
    value = seconds / scale
    text = f"{value:.0f}" if abs(value) >= 999.5 else f"{value:#.3g}".rstrip(".")
    if spread is not None:
        text += f" ± {spread / scale:.3g}"
    return f"{text} {unit}"


def fit_slope(x: Sequence[float], y: Sequence[float]) -> float:
    """Least-squares slope of log(y) against log(x); NaN with fewer than two usable points."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y) & (x > 0) & (y > 0)
    if np.unique(x[ok]).size < 2:
        return math.nan
    return float(np.polyfit(np.log(x[ok]), np.log(y[ok]), 1)[0])

def summarise(records: Sequence[Any]) -> list[dict[str, Any]]:
    """Mean and standard deviation over seeds per (method, value)."""
    groups: dict[tuple[str, float], list[Any]] = {}
    for record in records:
        groups.setdefault((record.method, record.value), []).append(record)
    rows = []
    for (method, value), group in groups.items():
        row: dict[str, Any] = {"method": method, "value": value, "seeds": len(group)}
        for name in ("spp", "time", "compile", "rmse", "relmse", "flip", "lowfreq"):
            data = np.array([getattr(r, name) for r in group], float)
            row[name] = float(data.mean())
            row[f"{name}_std"] = float(data.std(ddof=1)) if len(data) > 1 else 0.0
        row["mse"] = float(np.mean([r.rmse ** 2 for r in group]))
        rows.append(row)
    return rows

def slopes(rows: Sequence[dict[str, Any]], min_time: float = 0.0) -> dict[str, dict[str, float]]:
    """Fitted log-log slopes per method: MSE against spp and against time.

    The time slope is fitted over the points whose mean time is at least ``min_time``
    (e.g. :data:`TIMING_FLOOR`): NaN when fewer than two remain.
    """
    result = {}
    for method in dict.fromkeys(r["method"] for r in rows):
        mine = [r for r in rows if r["method"] == method]
        timed = [r for r in mine if r["time"] >= min_time]
        result[method] = {"mse_vs_spp": fit_slope([r["spp"] for r in mine], [r["mse"] for r in mine]),
                          "mse_vs_time": fit_slope([r["time"] for r in timed], [r["mse"] for r in timed])}
    return result

def equal_time_ranking(rows: Sequence[dict[str, Any]], budgets: Sequence[float] | None = None,
                       metric: str = "mse") -> list[tuple[float, list[tuple[str, float]]]]:
    """For each time budget, the methods ranked by the lowest ``metric`` reached within it.

    A method reaches, within budget ``T``, the lowest mean error among its sweep
    points whose mean render time is at most ``T``; methods with no point that fast
    are left out of that budget. Default budgets: 6 log-spaced times from the
    fastest to the slowest mean render.
    """
    times = np.array([r["time"] for r in rows], float)
    if budgets is None:
        lo, hi = float(times.min()), float(times.max())
        budgets = np.geomspace(lo, hi, 6) if hi > lo else [hi]
    ranking = []
    for budget in budgets:
        best: dict[str, float] = {}
        for r in rows:
            if r["time"] <= budget * (1 + 1e-9) and np.isfinite(r[metric]):
                best[r["method"]] = min(best.get(r["method"], math.inf), r[metric])
        ranking.append((float(budget), sorted(best.items(), key=lambda kv: kv[1])))
    return ranking

def equal_error_ranking(rows: Sequence[dict[str, Any]], budgets: Sequence[float] | None = None,
                        metric: str = "rmse") -> list[tuple[float, list[tuple[str, float, float]]]]:
    """For each error budget, the methods ranked by the shortest time reaching it.

    The dual of :func:`equal_time_ranking`: a method reaches budget ``E`` with its
    fastest sweep point whose mean ``metric`` is at most ``E``; methods with no point
    that accurate are left out of that budget. Each entry is ``(method, value,
    time)``. Default budgets: the errors of the first method's points in ``rows``
    (e.g. ``jitter`` at each spp, so a line answers "how long does each method take
    to get as close as jitter at 16 spp").

    Examples
    --------
    >>> rows = [{"method": "a", "value": 4, "time": 1.0, "rmse": 0.2},
    ...         {"method": "b", "value": 64, "time": 0.5, "rmse": 0.1}]
    >>> equal_error_ranking(rows)
    [(0.2, [('b', 64.0, 0.5), ('a', 4.0, 1.0)])]
    """
    if budgets is None:
        first = rows[0]["method"] if rows else None
        budgets = [r[metric] for r in rows if r["method"] == first]
    ranking = []
    for budget in budgets:
        best: dict[str, tuple[float, float]] = {}
        for r in rows:
            if r[metric] <= budget * (1 + 1e-9) and np.isfinite(r["time"]):
                if r["time"] < best.get(r["method"], (math.inf, math.inf))[1]:
                    best[r["method"]] = (float(r["value"]), float(r["time"]))
        ranked = sorted(((m, v, t) for m, (v, t) in best.items()), key=lambda entry: entry[2])
        ranking.append((float(budget), ranked))
    return ranking

def _sweeps_spp(method: str) -> bool:
    return sweep_parameter(method) == "spp"

_CSV_FIELDS = ("method", "value", "seed", "spp", "time", "compile", "trace", "execute", "total",
               "warm_up", "warm_up_compile", "kernels", "cache_hits", "rmse", "relmse", "flip", "lowfreq", "width",
               "height", "exr")

#: Columns of results.csv in seconds: written with three significant digits.
_CSV_TIMES = ("time", "compile", "trace", "execute", "total", "warm_up", "warm_up_compile")

_SHORT = "*"

def results_table(rows: Sequence[dict[str, Any]]) -> tuple[list[str], list[list[str]]]:
    """The results table as text: ``(header, cells)``, one list of cells per row of
    :func:`summarise`: means ± standard deviations over seeds (means alone for one seed);
    a time under :data:`TIMING_FLOOR` ends in ``*``.

    Examples
    --------
    >>> rows = [{"method": "jitter", "value": 4.0, "spp": 4.0, "seeds": 2, "time": 0.0123, "time_std": 0.0004,
    ...          "compile": 0.5, "rmse": 0.01, "rmse_std": 0.001, "relmse": 2e-3, "flip": 0.05, "lowfreq": 4e-6}]
    >>> results_table(rows)[1][0]
    ['jitter', '4 spp', '4', '2', '12.3 ± 0.4 ms *', '500 ms', '0.01000 ± 0.00100', '2.000e-03', '0.0500', '4.000e-06']
    """
    header = ["method", "setting", "spp", "seeds", "time", "compile", "RMSE", "relMSE", "FLIP", "low-freq MSE"]
    cells = []
    for r in rows:
        several = r["seeds"] > 1  # one seed: no spread to show
        time = format_time(r["time"], r["time_std"] if several else None)
        time += f" {_SHORT}" if r["time"] < TIMING_FLOOR else ""
        rmse = f"{r['rmse']:.5f}" + (f" ± {r['rmse_std']:.5f}" if several else "")
        cells.append([r["method"], setting_label(r["method"], r["value"]), f"{r['spp']:.4g}", str(r["seeds"]),
                      time, format_time(r["compile"]), rmse, f"{r['relmse']:.3e}", f"{r['flip']:.4f}",
                      f"{r.get('lowfreq', math.nan):.3e}"])
    return header, cells

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
    :func:`pointillist.compare.run_sweep` collects them: the spectrum plot shows their mean
    over seeds, one panel per spp.
    """
    from pointillist.files import atomic_write

    paths = report_paths(out_dir)
    if spectra is None:
        del paths["spectrum_plot"]

    def write_csv(tmp: str) -> None:
        with open(tmp, "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=_CSV_FIELDS, extrasaction="ignore")
            writer.writeheader()
            for record in records:
                row = record.as_dict()
                row["exr"] = f"renders/{record.exr}"
                row.update({name: f"{row[name]:.3g}" for name in _CSV_TIMES})
                writer.writerow(row)

    atomic_write(paths["csv"], write_csv)

    rows = summarise(records)
    fitted = slopes(rows, min_time=TIMING_FLOOR)
    timed = [r for r in rows if r["time"] >= TIMING_FLOOR]
    floor = format_time(TIMING_FLOOR)
    header, cells = results_table(rows)
    lines = [f"# {title or 'Sampler comparison'}", "",
             f"Scene `{scene}`, reference `{reference}`. Errors against the reference; time = render "
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
        lines += ["", f"{_SHORT} {len(rows) - len(timed)} of {len(rows)} points took under {floor}: too short to "
                  "time reliably (timer resolution, scheduling and fixed per-launch costs weigh as much as the "
                  "work); the time slopes and the rankings below leave them out"
                  + ("." if timed else ", which leaves nothing to rank: render more pixels or samples "
                     "(e.g. -D res=...) to compare times.")]
    lines += ["", "## Fitted log-log slopes (least squares over the sweep)", "",
              "| method | MSE vs spp | MSE vs time |", "|---|---:|---:|"]
    for method, s in fitted.items():
        if _sweeps_spp(method):
            by_time = f"{s['mse_vs_time']:.2f}" if math.isfinite(s["mse_vs_time"]) or len(timed) == len(rows) \
                else f"– {_SHORT}"
            lines.append(f"| {method} | {s['mse_vs_spp']:.2f} | {by_time} |")
        else:
            lines.append(f"| {method} | – | – |")
    if not all(_sweeps_spp(method) for method in fitted):
        lines += ["", "–: the method sweeps another parameter than spp; a fit over that sweep is not "
                  "a convergence rate."]
    if len(timed) < len(rows):
        lines += ["", f"MSE vs time: fitted over the points of {floor} or more; – {_SHORT}: fewer than two such "
                  "points."]
    lines += ["", "## Equal-time ranking (lowest MSE reached within each time budget)", ""]
    if timed:
        lines += ["| budget | ranking (MSE) |", "|---:|---|"]
        for budget, ranked in equal_time_ranking(timed):
            text = ", ".join(f"{i + 1}. {m} ({e:.2e})" for i, (m, e) in enumerate(ranked)) or "none"
            lines.append(f"| {format_time(budget)} | {text} |")
    else:
        lines.append(f"Left out: every render took under {floor} ({_SHORT} above).")
    anchors = [r for r in timed if r["method"] == timed[0]["method"]] if timed else []
    lines += ["", "## Equal-error ranking (fastest render reaching each RMSE)", ""]
    if anchors:
        lines += [f"Budgets: the RMSE of each {anchors[0]['method']} point; times relative to that point's.", "",
                  "| RMSE budget (from) | ranking (time) |", "|---|---|"]
        for anchor, (budget, ranked) in zip(anchors, equal_error_ranking(timed, [a["rmse"] for a in anchors])):
            text = ", ".join(f"{i + 1}. {m} {setting_label(m, v)} ({format_time(t)}, {t / anchor['time']:.2f}x)"
                             for i, (m, v, t) in enumerate(ranked))
            lines.append(f"| {budget:.5f} ({anchor['method']} {setting_label(anchor['method'], anchor['value'])}, "
                         f"{format_time(anchor['time'])}) | {text} |")
    else:
        lines.append(f"Left out: every render took under {floor} ({_SHORT} above).")
    atomic_write(paths["md"], lambda tmp: Path(tmp).write_text("\n".join(lines) + "\n"))

    _plot(rows, fitted, "time", "render time without JIT compile (s)", "mse_vs_time", paths["time_plot"])
    _plot(rows, fitted, "spp", "samples per pixel", "mse_vs_spp", paths["spp_plot"])
    if spectra is not None:
        _plot_spectra(records, spectra, paths["spectrum_plot"])
    return paths


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
    from pointillist.files import save_figure
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
    from pointillist.files import save_figure

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
