"""What ``agv-cosim tune`` writes: ``tune.json`` (reproducible: no time, no path of this
machine), ``tuned_variant.toml`` (a manifest fragment), the figures (the search's
history; the original and the tuned parameters on every run, the ``[metrics]`` signals
overlaid), ``index.html``, and the runs of both under ``original/`` and ``tuned/``."""

from __future__ import annotations

import html
import math
from importlib import resources
from pathlib import Path
from string import Template
from typing import Any
from urllib.parse import quote

import numpy as np

from ..files import open_output, write_json, write_text
from ..fitting import TuneResult
from ..manifest import Manifest
from ..report.records import RunResult
from ..system import Job
from ..timeseries import read_timeseries
from ..version import __version__
from .setup import Setup, available_metrics

__all__ = ["FRAGMENT", "HISTORY_FIGURE", "PAGE", "RESULT", "fragment", "key_signals",
           "tune_record", "write_folder"]

RESULT = "tune.json"
FRAGMENT = "tuned_variant.toml"
HISTORY_FIGURE = "tune_history.png"
PAGE = "index.html"
#: Runs drawn one figure each (the first ones of the manifest's order); the table has all.
MAX_FIGURES = 12
_SIGNAL_KEYS = ("lateral_error", "heading_error", "steering_angle", "steering_rate",
                "control")


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) if math.isfinite(value) else None


def _metrics(result: RunResult, names: list[str]) -> dict[str, float | None]:
    return {name: _number(result["metrics"].get(name)) for name in names}


def tune_record(manifest: Manifest, setup: Setup, result: TuneResult,
                failures: list[dict[str, Any]], runs: int,
                original: list[tuple[Job, RunResult]] | None = None,
                tuned: list[tuple[Job, RunResult]] | None = None) -> dict[str, Any]:
    """tune.json's content: the manifest, the parameters with their bounds, the search
    (:meth:`~agv_cosim.fitting.TuneResult.as_json`: best, start, history, seed, ...),
    the runs that failed during the trials, and each run's metrics with the original
    and the tuned parameters."""
    record: dict[str, Any] = {
        "tool": "agv-cosim tune", "version": __version__, "manifest": manifest.name,
        "manifest_sha256": manifest.sha256, "runs_per_candidate": runs,
        "parameters": {p.name: {"start": p.start, "min": p.min, "max": p.max,
                                "best": result.best[p.name]} for p in setup.parameters},
        "budget": {"generations": setup.generations, "popsize": setup.popsize,
                   "tol": setup.tol},
    }
    record.update(result.as_json())
    record["infeasible_trials"] = sum(1 for t in result.history if not
                                      math.isfinite(t.value))
    record["failed_runs"] = failures
    if original is not None and tuned is not None:
        names = available_metrics(manifest.metrics)
        record["comparison"] = {
            job.label: {"original": {"status": a["status"], "metrics": _metrics(a, names)},
                        "tuned": {"status": b["status"], "metrics": _metrics(b, names)}}
            for (job, a), (_, b) in zip(original, tuned)}
    return record


def fragment(manifest: Manifest, result: TuneResult, value: float | None) -> str:
    """``[variants.tuned]``: the base with the tuned parameters (paste into the
    manifest; with variants of its own, ``--set`` gives the values to each)."""
    out = [f"# The parameters tuned by agv-cosim tune on {manifest.path.name} "
           f"(objective {value!r} over its runs; it was {result.start_value!r}).",
           "# Paste into the manifest to run the tuned controller as a variant of the base;",
           "# for a manifest with variants of its own, give the values to every run with",
           "#   agv-cosim run " + manifest.path.name + " "
           + " ".join(f"--set {n}={v!r}" for n, v in result.best.items()), "",
           "[variants.tuned]",
           'description = "Tuned by agv-cosim tune"']
    by_component: dict[str, list[str]] = {}
    for name, v in result.best.items():
        cname, _, pname = name.partition(".")
        key = pname if pname.replace("_", "a").isalnum() else f'"{pname}"'
        by_component.setdefault(cname, []).append(f"{key} = {float(v)!r}")
    for cname, values in by_component.items():
        out.append(f"[variants.tuned.components.{cname}]")
        out.append("parameters = { " + ", ".join(values) + " }")
    return "\n".join(out) + "\n"


def key_signals(manifest: Manifest) -> list[str]:
    """The ``[metrics]`` signals drawn for each run: the error signals, the steering
    and control signals, the saturated one."""
    if manifest.metrics is None:
        return []
    spec = manifest.metrics.spec()
    found = [spec[k] for k in _SIGNAL_KEYS if spec.get(k)]
    if spec.get("reference"):
        found += [spec["reference"]["y"]]
    if spec.get("saturation"):
        found.append(spec["saturation"]["signal"])
    return list(dict.fromkeys(found))


def _figure(rows: int, columns: int = 1) -> Any:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(9.0, 1.0 + 2.1 * rows), layout="constrained")
    FigureCanvasAgg(figure)
    return figure


def _save(figure: Any, path: Path) -> None:
    with open_output(path) as stream:
        figure.savefig(stream, dpi=100, format="png", metadata={"Software": None})


def draw_history(path: Path, result: TuneResult) -> None:
    """Each trial's objective (infeasible ones as crosses on the top edge) and the best
    so far, against the trial number."""
    figure = _figure(2)
    axes = figure.subplots(1, 1)
    numbers = np.array([t.number for t in result.history], dtype=float)
    values = np.array([t.value for t in result.history], dtype=float)
    finite = np.isfinite(values)
    axes.plot(numbers[finite], values[finite], "o", ms=3, color="#1f77b4", alpha=0.6,
              label="trial")
    best = np.minimum.accumulate(np.where(finite, values, np.inf))
    shown = np.isfinite(best)
    axes.step(numbers[shown], best[shown], where="post", color="#d62728", lw=1.5,
              label="best so far")
    if (~finite).any():
        top = float(values[finite].max()) if finite.any() else 1.0
        axes.plot(numbers[~finite], np.full((~finite).sum(), top), "x", color="k",
                  label="infeasible (a run failed)")
    axes.axhline(result.start_value, color="0.4", ls="--", lw=1,
                 label="original") if math.isfinite(result.start_value) else None
    axes.set_xlabel("trial")
    axes.set_ylabel(f"objective ({result.objective.aggregate} over the runs)")
    axes.set_title("agv-cosim tune: the search")
    axes.grid(True, lw=0.4, alpha=0.5)
    axes.legend(loc="best", fontsize=8)
    _save(figure, path)


def draw_run(path: Path, label: str, signals: list[str], original: Path,
             tuned: Path) -> None:
    """The ``signals`` of one run, original (grey, dashed) and tuned (blue)."""
    figure = _figure(len(signals))
    axes_list = figure.subplots(len(signals), 1, sharex=True, squeeze=False)[:, 0]
    for folder, style in ((original, {"color": "0.45", "ls": "--", "label": "original"}),
                          (tuned, {"color": "#1f77b4", "ls": "-", "label": "tuned"})):
        csv = folder / "timeseries.csv"
        if not csv.is_file():
            continue
        t, columns = read_timeseries(csv, signals)
        for axes, name in zip(axes_list, signals):
            axes.plot(t, columns[name], lw=1.1, **style)
    for axes, name in zip(axes_list, signals):
        axes.set_ylabel(name, fontsize=8)
        axes.grid(True, lw=0.4, alpha=0.5)
    axes_list[0].legend(loc="best", fontsize=8)
    axes_list[0].set_title(f"run {label}: original and tuned")
    axes_list[-1].set_xlabel("time [s]")
    _save(figure, path)


def _e(value: Any) -> str:
    return html.escape(str(value), quote=True)


def _cell(value: float | None) -> str:
    """A number's cell (its exact value in the title); an em dash for none."""
    if value is None:
        return "<td>&mdash;</td>"
    return (f'<td class=num data-v="{_e(repr(value))}" title="{_e(repr(value))}">'
            f"{value:.6g}</td>")


def render(manifest: Manifest, setup: Setup, record: dict[str, Any],
           figures: dict[str, str]) -> str:
    """The page: the objective and parameters, the search, every run's metrics with the
    original and the tuned parameters, the figures."""
    title = f"tune {manifest.name}"
    objective = " + ".join(f"{w!r} &times; <code>{_e(m)}</code>"
                           for m, w in setup.objective.metrics.items())
    best, start = record["best"], record["start"]
    body = [f"<h1>{_e(title)}</h1>",
            f'<p class="description">Minimised: the {setup.objective.aggregate} over the '
            f"{record['runs_per_candidate']} run(s) of <code>{_e(manifest.path.name)}"
            f"</code> of {objective}; {_e(record['optimiser'])}"
            f"{', seed ' + str(record['seed']) if record['method'] == 'evolution' else ''}, "
            f"{record['evaluations']} candidate(s) ({record['generations']} generation(s) "
            f"after the first), {record['infeasible_trials']} infeasible. "
            f"{'Converged' if record['converged'] else 'Stopped'}: "
            f"{_e(str(record['message']).rstrip('.'))}.</p>",
            "<h2 id=parameters>Parameters</h2><table><thead><tr><th>parameter</th>"
            "<th>min</th><th>max</th><th>original</th><th>tuned</th></tr></thead><tbody>"]
    for name, entry in record["parameters"].items():
        body.append(f"<tr><td><code>{_e(name)}</code></td>{_cell(entry['min'])}"
                    f"{_cell(entry['max'])}{_cell(entry['start'])}{_cell(entry['best'])}"
                    "</tr>")
    body.append("</tbody></table>")
    body.append("<h2 id=objective>Objective</h2><table><thead><tr><th>run</th>"
                "<th>original</th><th>tuned</th></tr></thead><tbody>")
    for run, value in start["runs"].items():
        body.append(f"<tr><td>{_e(run)}</td>{_cell(value)}"
                    f"{_cell(best['runs'].get(run))}</tr>")
    body.append(f"<tr><td><b>{setup.objective.aggregate}</b></td>{_cell(start['value'])}"
                f"{_cell(best['value'])}</tr></tbody></table>")
    names = available_metrics(manifest.metrics)
    chosen = [m for m in setup.objective.metrics] + \
        [m for m in names if m not in setup.objective.metrics and m != "duration"]
    body.append("<h2 id=runs>Every run, original and tuned</h2><div class=scroll>"
                "<table><thead><tr><th>run</th><th>status</th>"
                + "".join(f"<th>{_e(m)}</th>" for m in chosen)
                + "</tr></thead><tbody>")
    for run, pair in record.get("comparison", {}).items():
        for which in ("original", "tuned"):
            entry = pair[which]
            body.append(f"<tr><td>{_e(run)} <b>{which}</b></td><td>{_e(entry['status'])}"
                        "</td>" + "".join(_cell(entry["metrics"].get(m)) for m in chosen)
                        + "</tr>")
    body.append("</tbody></table></div>")
    if record["failed_runs"]:
        body.append("<h2 id=failed>Runs that failed during the search</h2><p>Their "
                    "candidates were infeasible (objective infinite) and the search went "
                    "on.</p><ul>")
        for failure in record["failed_runs"][:50]:
            body.append(f"<li>trial {failure['trial']}, run {_e(failure['run'])}: "
                        f"{_e(failure['status'])}: {_e(failure['error'])}</li>")
        body.append("</ul>")
    body.append("<h2 id=figures>Figures</h2>")
    for name, caption in figures.items():
        body.append(f'<figure id="fig-{_e(name)}"><a href="{quote(name)}"><img '
                    f'src="{quote(name)}" alt="{_e(name)}" loading="eager"></a>'
                    f"<figcaption><code>{_e(name)}</code> {_e(caption)}</figcaption>"
                    "</figure>")
    body.append("<h2 id=files>Files</h2><ul>"
                + "".join(f'<li><a href="{quote(n)}">{_e(n)}</a></li>'
                          for n in (RESULT, FRAGMENT, "original/", "tuned/"))
                + "</ul>")
    template = Template(resources.files("agv_cosim.report").joinpath("page_template.html")
                        .read_text(encoding="utf-8"))
    return template.substitute(title=_e(title), body="\n".join(body))


def write_folder(path: Path, manifest: Manifest, setup: Setup, result: TuneResult,
                 record: dict[str, Any], original: list[tuple[Job, RunResult]],
                 tuned: list[tuple[Job, RunResult]]) -> None:
    """tune.json (with the comparison), the fragment, the figures and the page into
    ``path`` (the runs are under ``original/`` and ``tuned/`` already)."""
    record.update(tune_record(manifest, setup, result, record["failed_runs"],
                              record["runs_per_candidate"], original, tuned))
    write_json(path / RESULT, record)
    write_text(path / FRAGMENT, fragment(manifest, result, record["best"]["value"]))
    figures = {HISTORY_FIGURE: "each trial's objective and the best so far"}
    draw_history(path / HISTORY_FIGURE, result)
    signals = key_signals(manifest)
    if signals:
        for k, (job, _) in enumerate(original[:MAX_FIGURES]):
            name = f"tune_run{k + 1:02d}.png"
            draw_run(path / name, job.label, signals, path / "original" / job.label,
                     path / "tuned" / job.label)
            figures[name] = f"run {job.label}: the [metrics] signals, original and tuned"
    write_text(path / PAGE, render(manifest, setup, record, figures))
