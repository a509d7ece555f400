"""The numbers of a comparison: summaries over seeds, fitted slopes, rankings, the results table.

Everything here works on :class:`~pointillist.compare.records.RenderRecord` values (or the rows
:func:`summarise` makes of them) and writes nothing: :mod:`pointillist.compare.report` makes
``results.csv``, ``results.md`` and the plots of them, :mod:`pointillist.compare.html` the page.
Times read with three significant digits in a fitting unit (:func:`format_time`, whose units the
page's script uses too); renders faster than :data:`TIMING_FLOOR` are too short to time
reliably: they are marked (:data:`SHORT_MARK`), and the time slopes and rankings leave them out.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from pointillist.compare.methods import setting_label

__all__ = ["TIMING_FLOOR", "TIME_UNITS", "TIME_UNIT_ROUNDING", "SHORT_MARK", "format_time", "fit_slope", "summarise",
           "slopes", "equal_time_ranking", "equal_error_ranking", "results_table"]


#: Renders shorter than this (seconds) are too short to time reliably here: timer resolution,
#: thread scheduling on a shared machine and fixed per-launch costs weigh as much as the work.
TIMING_FLOOR = 0.020


#: The units of :func:`format_time`, largest first: (name, seconds). The report page formats its
#: times with this table too (:func:`pointillist.compare.html.page_script`).
TIME_UNITS = (("s", 1.0), ("ms", 1e-3), ("µs", 1e-6))

#: A time is written in the largest unit of which it is at least this fraction: 0.9995 s is
#: "1.00 s" (three significant digits), not "1000 ms".
TIME_UNIT_ROUNDING = 0.9995

#: What ends a time too short to time reliably (under :data:`TIMING_FLOOR`), in the tables.
SHORT_MARK = "*"


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
    for unit, scale in TIME_UNITS:
        if abs(seconds) >= TIME_UNIT_ROUNDING * scale or unit == TIME_UNITS[-1][0]:
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
        time += f" {SHORT_MARK}" if r["time"] < TIMING_FLOOR else ""
        rmse = f"{r['rmse']:.5f}" + (f" ± {r['rmse_std']:.5f}" if several else "")
        cells.append([r["method"], setting_label(r["method"], r["value"]), f"{r['spp']:.4g}", str(r["seeds"]),
                      time, format_time(r["compile"]), rmse, f"{r['relmse']:.3e}", f"{r['flip']:.4f}",
                      f"{r.get('lowfreq', math.nan):.3e}"])
    return header, cells
