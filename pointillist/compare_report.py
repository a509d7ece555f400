"""The report of a comparison: summaries over seeds, fitted slopes, rankings, tables, plots.

Everything here works on :class:`pointillist.compare.RenderRecord` values (or the
rows :func:`summarise` makes of them) and renders nothing: :func:`write_report`
writes ``results.csv``, ``results.md`` (table, fitted log-log slopes, equal-time and
equal-error rankings) and the two log-log plots of error against time and spp.
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pointillist.compare_methods import setting_label, sweep_parameter

__all__ = ["fit_slope", "summarise", "slopes", "equal_time_ranking", "equal_error_ranking", "write_report"]


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
        for name in ("spp", "time", "compile", "rmse", "relmse", "flip"):
            data = np.array([getattr(r, name) for r in group], float)
            row[name] = float(data.mean())
            row[f"{name}_std"] = float(data.std(ddof=1)) if len(data) > 1 else 0.0
        row["mse"] = float(np.mean([r.rmse ** 2 for r in group]))
        rows.append(row)
    return rows

def slopes(rows: Sequence[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Fitted log-log slopes per method: MSE against spp and against time."""
    result = {}
    for method in dict.fromkeys(r["method"] for r in rows):
        mine = [r for r in rows if r["method"] == method]
        result[method] = {"mse_vs_spp": fit_slope([r["spp"] for r in mine], [r["mse"] for r in mine]),
                          "mse_vs_time": fit_slope([r["time"] for r in mine], [r["mse"] for r in mine])}
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
               "warm_up", "warm_up_compile", "kernels", "cache_hits", "rmse", "relmse", "flip", "width", "height",
               "exr")

def write_report(records: Sequence[Any], out_dir: str | os.PathLike, *, scene: str,
                 reference: str, title: str | None = None, notes: Sequence[str] = ()) -> dict[str, Path]:
    """Write results.csv, results.md, error_vs_time.png and error_vs_spp.png into ``out_dir``.

    ``notes`` (one line each, e.g. why FLIP is NaN) are listed under the table's caption.
    """
    from pointillist.imaging.io import atomic_write

    out = Path(out_dir)
    paths = {"csv": out / "results.csv", "md": out / "results.md",
             "time_plot": out / "error_vs_time.png", "spp_plot": out / "error_vs_spp.png"}
    def write_csv(tmp: str) -> None:
        with open(tmp, "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=_CSV_FIELDS, extrasaction="ignore")
            writer.writeheader()
            for record in records:
                row = record.as_dict()
                row["exr"] = f"renders/{record.exr}"
                writer.writerow(row)

    atomic_write(paths["csv"], write_csv)

    rows = summarise(records)
    fitted = slopes(rows)
    lines = [f"# {title or 'Sampler comparison'}", "",
             f"Scene `{scene}`, reference `{reference}`. Errors against the reference; time = render "
             "wall time without JIT compilation (compile listed apart); mean ± standard deviation "
             "over seeds. relMSE uses epsilon 0.01; FLIP is HDR-FLIP.", "",
             *[f"- {note}" for note in notes], *([""] if notes else []),
             "| method | setting | spp | seeds | time (s) | compile (s) | RMSE | relMSE | FLIP |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['method']} | {setting_label(r['method'], r['value'])} | {r['spp']:.4g} | {r['seeds']} "
                     f"| {r['time']:.3f} ± {r['time_std']:.3f} "
                     f"| {r['compile']:.3f} | {r['rmse']:.5f} ± {r['rmse_std']:.5f} "
                     f"| {r['relmse']:.3e} | {r['flip']:.4f} |")
    lines += ["", "spp: samples per pixel taken (an adaptive method's mean over the pixels). A method's first "
              "render in a process follows an untimed warm-up render; its times are in results.csv "
              "(warm_up, warm_up_compile).", "",
              "## Fitted log-log slopes (least squares over the sweep)", "",
              "| method | MSE vs spp | MSE vs time |", "|---|---:|---:|"]
    for method, s in fitted.items():
        if _sweeps_spp(method):
            lines.append(f"| {method} | {s['mse_vs_spp']:.2f} | {s['mse_vs_time']:.2f} |")
        else:
            lines.append(f"| {method} | – | – |")
    if not all(_sweeps_spp(method) for method in fitted):
        lines += ["", "–: the method sweeps another parameter than spp; a fit over that sweep is not "
                  "a convergence rate."]
    lines += ["", "## Equal-time ranking (lowest MSE reached within each time budget)", "",
              "| budget (s) | ranking (MSE) |", "|---:|---|"]
    for budget, ranked in equal_time_ranking(rows):
        text = ", ".join(f"{i + 1}. {m} ({e:.2e})" for i, (m, e) in enumerate(ranked)) or "none"
        lines.append(f"| {budget:.3f} | {text} |")
    anchors = [r for r in rows if r["method"] == rows[0]["method"]] if rows else []
    lines += ["", "## Equal-error ranking (fastest render reaching each RMSE)", "",
              f"Budgets: the RMSE of each {anchors[0]['method'] if anchors else ''} point; times relative to "
              "that point's.", "",
              "| RMSE budget (from) | ranking (time) |", "|---|---|"]
    for anchor, (budget, ranked) in zip(anchors, equal_error_ranking(rows, [a["rmse"] for a in anchors])):
        text = ", ".join(f"{i + 1}. {m} {setting_label(m, v)} ({t:.3f} s, {t / anchor['time']:.2f}x)"
                         if anchor["time"] > 0 else f"{i + 1}. {m} {setting_label(m, v)} ({t:.3f} s)"
                         for i, (m, v, t) in enumerate(ranked))
        lines.append(f"| {budget:.5f} ({anchor['method']} {setting_label(anchor['method'], anchor['value'])}, "
                     f"{anchor['time']:.3f} s) | {text} |")
    atomic_write(paths["md"], lambda tmp: Path(tmp).write_text("\n".join(lines) + "\n"))

    _plot(rows, fitted, "time", "render time without JIT compile (s)", "mse_vs_time", paths["time_plot"])
    _plot(rows, fitted, "spp", "samples per pixel", "mse_vs_spp", paths["spp_plot"])
    return paths

def _plot(rows, fitted, x_name: str, x_label: str, slope_name: str, path: Path) -> None:
    from pointillist.imaging.io import atomic_write

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
        label = f"{method} (slope {fitted[method][slope_name]:.2f})" if spp_sweep else \
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
    try:
        atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))
    finally:
        plt.close(fig)
