"""``montecarlo.json`` and ``montecarlo.png`` of a Monte Carlo manifest.

Statistics (``montecarlo.json``): over the runs of a group that are ``complete`` and have
a finite value of the metric; every other run of the group counts as a failure of that
metric (``n + failures`` = runs of the group). ``std`` is the sample standard deviation
(ddof = 1; null for n < 2); the percentiles are ``numpy.percentile``'s linear ones. Every
group lists every metric of any run (a group whose runs all failed too). A statistic
without the values it needs is null (n/a: every one for n = 0, the std for n = 1), and
the metric's ``note`` then says why (:func:`~agv_cosim.report.page.statistics_note`:
``"n/a: 0 of 16 runs have a value (16 complete that did not settle)"``), as the page's
table does.
"""

import csv
import math
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..files import open_text, write_json
from ..manifest.montecarlo import MonteCarlo
from ..plan.sampling import group_name
from ..system.checked import Job
from .page import metric_unit, not_settled, statistics_note
from .plots import plain_text, save_figure
from .records import RunResult

__all__ = ["aggregate", "draw", "figure", "statistics", "write_aggregate", "write_outputs"]


def statistics(values: Iterable[float | None], runs: int,
               not_complete: int | None = None, unsettled: int = 0) -> dict[str, Any]:
    """mean, std (ddof 1), p5, p50, p95, n, failures of finite ``values`` of ``runs``;
    with ``not_complete`` (the runs that are not complete, of ``runs``; ``unsettled``:
    the complete ones empty because their error never settled), the ``note`` that says
    why a statistic is null, where one is."""
    data = np.asarray([v for v in values if v is not None and math.isfinite(v)], float)
    n = int(data.size)
    out: dict[str, Any] = {"n": n, "failures": runs - n, "mean": None, "std": None,
                           "p5": None, "p50": None, "p95": None, "min": None, "max": None}
    if n:
        p5, p50, p95 = np.percentile(data, [5, 50, 95])
        out.update(mean=float(data.mean()), p5=float(p5), p50=float(p50),
                   p95=float(p95), min=float(data.min()), max=float(data.max()))
        if n > 1:
            out["std"] = float(data.std(ddof=1))
    note = (None if not_complete is None else
            statistics_note(n, runs, not_complete, unsettled))
    if note is not None:
        out["note"] = note
    return out


#: A group's runs: (job, result) pairs, in the order run.
_Members = list[tuple[Job, RunResult]]


def _groups(jobs: Sequence[Job], results: Sequence[RunResult]) -> dict[str, _Members]:
    groups: dict[str, _Members] = {}
    for job, result in zip(jobs, results):
        groups.setdefault(group_name(job.variant, job.point), []).append((job, result))
    return groups


def aggregate(mc: MonteCarlo, jobs: Sequence[Job],
              results: Sequence[RunResult]) -> dict[str, Any]:
    """The content of ``montecarlo.json`` (see the module docstring)."""
    out = {**mc.describe(), "groups": {}}
    names: list[str] = []  # every group's: a group whose runs failed has them too
    for result in results:
        for metric in result["metrics"]:
            if metric not in names:
                names.append(metric)
    for name, members in _groups(jobs, results).items():
        complete = [r for _, r in members if r["status"] == "complete"]
        failed = len(members) - len(complete)
        out["groups"][name] = {
            "variant": members[0][0].variant, "runs": len(members),
            "failed_runs": failed,
            "metrics": {m: statistics([_number(r["metrics"].get(m)) for r in complete],
                                      len(members), failed,
                                      sum(not_settled(m, r["metrics"]) for r in complete))
                        for m in names}}
    return out


def _number(value: object) -> float | None:
    return float(value) if isinstance(value, (int, float)) and \
        not isinstance(value, bool) else None


def _band(folder: str | Path, members: _Members,
          signal: str) -> tuple[np.ndarray, np.ndarray] | None:
    """Time and (p5, p50, p95) of ``signal`` over the group's complete runs."""
    series: list[list[float]] = []
    time: list[float] | None = None
    for job, result in members:
        if result["status"] != "complete":
            continue
        path = Path(folder) / job.label / "timeseries.csv"
        with open_text(path) as stream:
            reader = csv.reader(stream)
            header = next(reader)
            column = header.index(signal)
            rows = [(float(row[0]), float(row[column])) for row in reader]
        t = [r[0] for r in rows]
        if time is None or len(t) < len(time):
            time = t
        series.append([r[1] for r in rows])
    if not series or time is None:
        return None
    k = len(time)
    data = np.asarray([s[:k] for s in series])
    return np.asarray(time), np.percentile(data, [5, 50, 95], axis=0)


@plain_text
def figure(mc: MonteCarlo, jobs: Sequence[Job], results: Sequence[RunResult],
           folder: str | Path, title: str | None = None, dpi: int = 110) -> Path | None:
    """``montecarlo.png``: box plots of the key metrics per group; the band of a signal."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    groups = _groups(jobs, results)
    names = mc.metrics
    if names is None:
        names = []
        for result in results:
            for metric in result["metrics"]:
                if metric not in names and len(names) < 4:
                    names.append(metric)
    panels = len(names) + (1 if mc.band else 0)
    if not panels:
        return None
    fig = Figure(figsize=(8.0, 2.6 * panels), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(panels, 1, squeeze=False)[:, 0]
    labels = list(groups)
    for ax, metric in zip(axes, names):
        data = [[v for v in (_number(r["metrics"].get(metric)) for _, r in members
                             if r["status"] == "complete") if v is not None and
                 math.isfinite(v)] for members in groups.values()]
        shown = [(label, d) for label, d in zip(labels, data) if d]
        if shown:
            ax.boxplot([d for _, d in shown], whis=(5, 95), orientation="horizontal")
            ax.set_yticks(range(1, len(shown) + 1), [label for label, _ in shown])
        unit = metric_unit(metric, {}, {})
        ax.set_xlabel(f"{metric} [{unit}]" if unit else metric)
        ax.grid(True, axis="x", alpha=0.3)
    if mc.band:
        ax = axes[-1]
        colours = [f"C{i % 10}" for i in range(len(groups))]
        for colour, (label, members) in zip(colours, groups.items()):
            band = _band(folder, members, mc.band)
            if band is None:
                continue
            t, (p5, p50, p95) = band
            ax.fill_between(t, p5, p95, color=colour, alpha=0.25, linewidth=0)
            ax.plot(t, p50, color=colour, label=f"{label}: median, p5-p95")
        ax.set_xlabel("time [s]")
        ax.set_ylabel(mc.band)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize="small", frameon=False)
    fig.suptitle((title + ": " if title else "") + f"{mc.samples} samples per group "
                 "(box: p25-p75, whiskers p5-p95)", fontsize="medium")
    return save_figure(fig, Path(folder) / "montecarlo.png", dpi)


def write_aggregate(mc: MonteCarlo, jobs: Sequence[Job], results: Sequence[RunResult],
                    folder: str | Path) -> None:
    """Write ``montecarlo.json`` (:func:`aggregate`)."""
    write_json(Path(folder) / "montecarlo.json", aggregate(mc, jobs, results))


def draw(mc: MonteCarlo, jobs: Sequence[Job], results: Sequence[RunResult], folder: str | Path,
         title: str | None = None) -> str | None:
    """Write ``montecarlo.png`` (:func:`figure`); return its error as one line, or
    None."""
    try:
        figure(mc, jobs, results, folder, title)
    except Exception as failure:  # noqa: BLE001 - a figure must not lose the results
        return f"{type(failure).__name__}: {failure}"
    return None


def write_outputs(mc: MonteCarlo, jobs: Sequence[Job], results: Sequence[RunResult],
                  folder: str | Path, title: str | None = None) -> str | None:
    """Write ``montecarlo.json`` and ``montecarlo.png``; return a figure error or None."""
    write_aggregate(mc, jobs, results, folder)
    return draw(mc, jobs, results, folder, title)
