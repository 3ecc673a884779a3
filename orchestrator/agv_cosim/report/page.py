"""The report of a result folder: ``index.html``, a static page read from disk.

:func:`write_report` reads a result folder of ``agv-cosim run`` from disk only (each
run's ``run.json`` and ``metrics.json``, ``summary.csv``, ``montecarlo.json``,
``partial.txt``, the error notes, the PNG figures and the manifest: ``manifest.toml`` in
the folder when present, else the file run.json names when its SHA-256 is still the one
run) and writes into it:

- ``index.html``: the manifest's description, the runs with their status, sweep values
  and key metrics (:func:`key_metrics`; units in the headers, which wrap and link to
  the metric's definition; a table sorts by a click on its header; "did not settle"
  where a run's error never settled), every metric in a folded table, the
  definitions of the metrics shown (:data:`agv_cosim.report.metrics.METRICS`, as
  docs/metrics.md), the Monte Carlo statistics, every figure, the paths, hashes and
  versions from run.json, and links to the raw files. One file with its style and
  script inline: it opens from disk with no network. It shows no timing (it links
  ``timings.csv``): the same folder contents give the same page, byte for byte.
- ``sweep_metrics.png`` (a sweep with a numeric swept value): the main metrics against
  it, one line per variant (:func:`agv_cosim.report.plots.sweep_metrics_figure`);
- ``montecarlo_scatter.png`` (a Monte Carlo result): box plots of the main metrics per
  group in their units, and each against each sampled parameter with Spearman's rank
  correlation (:func:`agv_cosim.report.plots.montecarlo_figure`).

Units: of the signals and parameters, the FMUs' model descriptions (read with fmpy from
the FMU paths in run.json) and the manifest's ``[plots.units]`` over them; of the metrics,
the units the metrics module documents, from the unit of the signal they are computed from
where it has one.

Output safety (as :mod:`agv_cosim.files`): the folder must carry this tool's marker
(``.agv-cosim``); the run lock beside it is taken so that no run replaces the folder
meanwhile; a file the report writes is replaced only when the report wrote it before (its
record, ``.agv-cosim-report.json``, lists them), otherwise the report refuses, naming
the file, and writes nothing; no file is written through a symbolic link.
"""

from __future__ import annotations

import csv
import hashlib
import html
import io
import json
import math
import os
import stat
import tomllib
from collections.abc import Callable, Collection, Iterable
from functools import partial
from importlib import resources
from pathlib import Path
from string import Template
from typing import TYPE_CHECKING, Any
from urllib.parse import quote

from ..errors import OutputError, ReportError, UnreadableFile
from ..files import (
    CSV_LIMIT,
    FolderLock,
    create_file,
    displayable,
    marker_data,
    open_regular,
    printable,
    read_bytes,
    read_head,
    read_json_object,
    write_json,
)
from ..manifest.load import MAX_MANIFEST_BYTES
from . import plots
from .metrics import METRICS
from .records import TIMINGS

if TYPE_CHECKING:  # matplotlib is imported by the functions that draw, when they draw
    from matplotlib.figure import Figure

#: One run as the page reads it: its run.json (a JSON object, not trusted: a field may
#: be damaged), with ``metrics`` (its metrics.json, or {}), ``folder`` (the run
#: folder's name) and ``sweep_point`` (a table).
Run = dict[str, Any]
#: A comparison figure: its file name and the function that draws it.
Drawing = tuple[str, Callable[[], "Figure"]]

#: The page, at the top of the result folder.
REPORT_FILE = "index.html"
#: What the report wrote (JSON: ``files``), so that it replaces only its own files.
RECORD = ".agv-cosim-report.json"
#: The manifest's copy in a result folder, when there is one.
MANIFEST_COPY = "manifest.toml"
#: The key metrics (docs/metrics.md, "Key metrics"): the report's runs table shows these
#: (every metric: its folded table); first in the figures and the terminal table,
#: in this order within a signal's metrics. Not ``*_settled_max``: without
#: ``settle_after`` it is the settling band whenever the error settles.
MAIN_METRICS = ("lateral_error_max", "lateral_error_rms", "lateral_error_settling_time",
                "lateral_error_overshoot", "path_error_max", "path_error_rms",
                "path_error_settling_time", "path_error_overshoot", "heading_error_max",
                "steering_angle_peak", "steering_rate_peak", "control_effort",
                "control_peak", "saturated_fraction")
#: Most key metrics in the runs table (so that it fits a 1280 px window).
RUNS_TABLE_METRICS = 8
#: What the page and the terminal write for a settling metric of a run that never settled.
NOT_SETTLED = "did not settle"
#: Known figures of a result folder, with their captions (others are shown by name).
CAPTIONS = {
    "signals.png": "The recorded signals of every run ([plots] signals).",
    "trajectory.png": "The runs' paths over the reference path, and their offset from "
                      "it along the path ([plots] trajectory).",
    plots.SWEEP_FILE: "The main metrics against the swept value, one line per variant "
                      "(an open triangle on a panel's top edge: a run without a value).",
    "montecarlo.png": "Monte Carlo: box plots of the key metrics per group, and the "
                      "p5-p95 band of a signal over time.",
    plots.MONTECARLO_SCATTER_FILE: "Monte Carlo: each main metric per group (box "
                                   "plots, in its unit) and against each sampled "
                                   "parameter, with Spearman's rank correlation rho.",
}
_FIGURE_ORDER = ("signals.png", "trajectory.png", plots.SWEEP_FILE, "montecarlo.png",
                 plots.MONTECARLO_SCATTER_FILE)
#: Files of a run folder linked from the runs table.
_RUN_FILES = ("timeseries.csv", "metrics.json", "run.json", "output.txt")
#: The note of the page's figures that could not be drawn (one line each), written
#: by the report (it is among its files): the page shows it, and no image for them.
FIGURES_ERROR = "figures_error.txt"
#: Files of the result folder linked from the page.
_RAW_FILES = ("summary.csv", TIMINGS, "montecarlo.json", "partial.txt", "plots_error.txt",
              "montecarlo_error.txt", FIGURES_ERROR, MANIFEST_COPY, "step_check.json")
#: The metrics in docs/metrics.md's order (the step check's table)
METRIC_ORDER = {name: i for i, name in enumerate(METRICS)}
#: ``run --check-step``'s findings (:mod:`agv_cosim.pipeline.stepcheck`)
STEP_CHECK_FILE = "step_check.json"


# --------------------------------------------------------------------------- reading

def _read_text(path: Path) -> str | None:
    """The beginning of a note of the folder (:data:`~agv_cosim.files.NOTE_LIMIT`
    bytes), or None when there is none; a note that is not a regular file raises
    :class:`~agv_cosim.errors.UnreadableFile`."""
    try:
        return read_head(path).decode("utf-8", errors="replace")
    except OSError:
        return None


def _summary_order(folder: Path) -> list[str]:
    """Run labels in summary.csv's order (empty without one)."""
    try:
        text = read_bytes(folder / "summary.csv", CSV_LIMIT).decode("utf-8")
        return [row.get("run", "") for row in csv.DictReader(io.StringIO(text, newline=""))]
    except (OSError, UnicodeDecodeError, csv.Error):
        return []


def _table(value: object) -> dict[str, Any]:
    """``value`` when it is a JSON object (a table of run.json), else {} (a damaged
    field: what it would say is unknown)."""
    return value if isinstance(value, dict) else {}


def _text(value: object) -> str:
    """A value of run.json that should be text (a path, a hash), as text."""
    return value if isinstance(value, str) else json.dumps(value)


def _manifest_path(run: Run) -> str | None:
    """The manifest file run.json names, or None (none, or not text)."""
    path = run.get("manifest")
    return path if isinstance(path, str) and path else None


def read_runs(folder: str | Path) -> list[Run]:
    """Every run of a result folder: its run.json with ``metrics`` (its metrics.json)
    and ``folder`` (the run folder's name), in summary.csv's order (then by name)."""
    folder = Path(folder)
    found: dict[str, Run] = {}
    for entry in sorted(folder.iterdir()):
        if entry.is_symlink() or not entry.is_dir():
            continue
        info = read_json_object(entry / "run.json")
        if info is None:
            continue
        info["folder"] = entry.name
        metrics = read_json_object(entry / "metrics.json")
        info["metrics"] = metrics if metrics is not None else {}
        if not isinstance(info.get("sweep_point"), dict):
            info["sweep_point"] = {}
        found[entry.name] = info
    order = [label for label in _summary_order(folder) if label in found]
    order += [label for label in found if label not in order]
    return [found[label] for label in order]


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open_regular(path) as stream:
        while block := stream.read(1 << 20):
            digest.update(block)
    return digest.hexdigest()


def _toml(path: Path) -> dict[str, Any]:
    """The TOML data of the manifest file ``path`` (a regular file of at most
    :data:`~agv_cosim.manifest.MAX_MANIFEST_BYTES`)."""
    return tomllib.loads(read_bytes(path, MAX_MANIFEST_BYTES).decode("utf-8"))


def read_manifest(folder: str | Path, runs: list[Run]) -> tuple[dict[str, Any], str]:
    """The manifest of the runs as TOML data, and where it came from (a sentence).

    ``manifest.toml`` in the folder first; else the file run.json names, when its SHA-256
    is the run's (a manifest changed since is not used). An SSP package or a missing file
    gives ``{}``."""
    copy = Path(folder) / MANIFEST_COPY
    if copy.is_file() and not copy.is_symlink():
        try:
            return _toml(copy), f"the copy {MANIFEST_COPY} in this folder"
        except (OSError, ValueError, UnreadableFile):
            pass
    if not runs:
        return {}, "no run"
    named, digest = _manifest_path(runs[0]), runs[0].get("manifest_sha256")
    if not named:
        return {}, "run.json names no manifest"
    path = Path(named)
    if path.suffix == ".ssp":
        return {}, f"an SSP package ({path}); its description is not read"
    try:
        if _sha256(path) != digest:
            return {}, f"{path} changed since the run (its SHA-256 differs); not used"
        return _toml(path), f"{path} (SHA-256 as run)"
    except OSError:
        return {}, f"{path} not found from {os.getcwd()}"
    except UnreadableFile as error:
        return {}, f"{error}; not used"
    except ValueError:  # tomllib.TOMLDecodeError, UnicodeDecodeError
        return {}, f"{path} is not valid TOML"


# --------------------------------------------------------------------------- units

def metric_unit(name: str, spec: dict[str, Any], units: dict[str, str]) -> str | None:
    """Unit of metric ``name`` (see :mod:`agv_cosim.report.metrics`): the unit of the signal the
    ``[metrics]`` table ``spec`` computes it from where ``units`` has it, else the
    documented one; None for an unknown metric."""
    def signal_unit(key: str, default: str | None) -> str | None:
        signal = spec.get(key)
        if isinstance(signal, dict):
            signal = signal.get("x")
        return (units.get(signal) if isinstance(signal, str) else None) or default

    for prefix, key in (("lateral_error_", "lateral_error"), ("path_error_", "reference")):
        if name.startswith(prefix):
            tail = name[len(prefix):]
            if tail == "settling_time":
                return "s"
            if tail == "overshoot_ratio":
                return "1"
            return signal_unit(key, "m")
    for prefix, key, default in (("heading_error_", "heading_error", "rad"),
                                 ("steering_angle_", "steering_angle", "rad"),
                                 ("steering_rate_", "steering_rate", "rad/s")):
        if name.startswith(prefix):
            return signal_unit(key, default)
    if name == "control_effort":
        unit = signal_unit("control", None)
        return f"({unit})^2 s" if unit else None
    if name in ("control_peak", "control_rms"):
        return signal_unit("control", None)
    if name == "saturated_fraction":
        return "1"
    if name in ("saturated_time", "duration"):
        return "s"
    return None


def main_metrics(names: list[str], count: int = 6) -> list[str]:
    """Up to ``count`` of ``names``: those of :data:`MAIN_METRICS` in that order, then
    the others in theirs."""
    first = [name for name in MAIN_METRICS if name in names]
    return (first + [name for name in names if name not in first])[:count]


def _metric_names(runs: list[Run], varying: bool = False) -> list[str]:
    """Names of the runs' numeric metrics (empty ones too: a settling time of runs that
    never settled) in first-seen order; ``varying``: only those whose values differ
    between the runs (beyond 1e-9 of their size)."""
    names: list[str] = []
    for run in runs:
        for name, value in run["metrics"].items():
            if name not in names and (value is None or plots.is_number(value)):
                names.append(name)
    if varying:
        def spread(name: str) -> bool:
            values = [v for v in (r["metrics"].get(name) for r in runs) if plots.is_number(v)]
            empty = any(name in r["metrics"] and r["metrics"][name] is None for r in runs)
            return bool(values) and (empty or max(values) - min(values) >
                                     1e-9 * max(map(abs, values)))
        names = [name for name in names if spread(name)]
    return names


def collect_units(runs: list[Run], manifest: dict[str, Any]) -> dict[str, str]:
    """Units by name: signals and parameters (FMUs, then ``[plots.units]``) and metrics."""
    fmus: dict[str, str] = {}
    for run in runs:
        for component, path in _table(run.get("fmus")).items():
            fmus.setdefault(component, _text(path))
    manifest_path = _manifest_path(runs[0]) if runs else None
    base = Path(manifest_path).parent if manifest_path else None
    units = plots.fmu_units(fmus, base)
    table = (manifest.get("plots") or {}).get("units") or {}
    units.update({k: v for k, v in table.items() if isinstance(v, str)})
    spec = manifest.get("metrics") or {}
    for name in _metric_names(runs):
        unit = metric_unit(name, spec, units)
        if unit:
            units[name] = unit
    return units


# --------------------------------------------------------------------------- figures

def _comparison_figures(runs: list[Run], manifest: dict[str, Any], units: dict[str, str],
                        sampled: list[str], title: str | None) -> list[Drawing]:
    """(file name, function that draws the figure) of the comparison figures the result
    calls for."""
    figures: list[Drawing] = []
    names = _metric_names(runs, varying=True)
    if not runs or not names:
        return figures
    points = [run["sweep_point"] for run in runs]
    if sampled:
        mc = manifest.get("montecarlo") or {}
        chosen = [m for m in (mc.get("metrics") or []) if m in names] or \
            main_metrics(names, 4)
        parameters = [p for p in sampled if any(plots.is_number(pt.get(p)) for pt in points)
                      and p not in (mc.get("seeds") or [])]
        rows = [{"group": _group(run, sampled), "point": run["sweep_point"],
                 "status": run.get("status"), "metrics": run["metrics"]} for run in runs]
        figures.append((plots.MONTECARLO_SCATTER_FILE,
                        partial(plots.montecarlo_figure, rows, parameters, chosen, units,
                                title)))
        return figures
    key = plots.colour_key(points)
    if key is None:
        keys = [k for k in plots.sweep_keys(points)
                if all(plots.is_number(p.get(k)) for p in points)]
        key = keys[0] if keys else None
    if key is not None:
        rows = [{"variant": run.get("variant"), "point": run["sweep_point"],
                 "status": run.get("status"), "metrics": run["metrics"]} for run in runs]
        figures.append((plots.SWEEP_FILE, partial(
            plots.sweep_metrics_figure, rows, key, main_metrics(names, 6), units, title)))
    return figures


def _group(run: Run, sampled: list[str]) -> str:
    point = run["sweep_point"]
    swept = [k for k in point if k != plots.SAMPLE_KEY and k not in sampled]
    parts = [run.get("variant") or "base"] + [f"{k}={point[k]!r}" for k in sorted(swept)]
    return ", ".join(parts)


# --------------------------------------------------------------------------- the page

def _e(value: object) -> str:
    """``value`` as HTML text; a file name's undecodable bytes as escapes (``\\xff``:
    :func:`~agv_cosim.files.displayable`), so that the page is always UTF-8."""
    return html.escape(displayable(value), quote=True)


def _href(*parts: object) -> str:
    """A relative link to the file ``parts`` (a file name's undecodable bytes
    percent-encoded as the bytes they are)."""
    return "/".join(quote(str(part), errors="surrogateescape") for part in parts)


def _fmt(value: object) -> str:
    """A number in 4 significant digits (exact value in the cell's title)."""
    if isinstance(value, bool) or value is None:
        return "" if value is None else str(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            return repr(value)
        return f"{value:.4g}"
    return str(value)


def _cell(value: object) -> str:
    sort = value if plots.is_number(value) else None
    attrs = f' data-v="{_e(repr(float(sort)))}"' if sort is not None else ""
    title = f' title="{_e(repr(value))}"' if isinstance(value, float) else ""
    classes = ' class="num"' if sort is not None else ""
    return f"<td{attrs}{title}{classes}>{_e(_fmt(value))}</td>"


def not_settled(name: str, metrics: dict[str, Any]) -> bool:
    """Whether the empty metric ``name`` is empty because the run's error never settled
    (``*_settling_time`` empty while its ``*_max`` has a value): for ``*_settling_time``
    and the ``*_settled_*`` metrics."""
    for prefix in ("lateral_error_", "path_error_"):
        tail = name.removeprefix(prefix)
        if tail != name and (tail == "settling_time" or tail.startswith("settled_")):
            return metrics.get(name) is None and prefix + "max" in metrics and \
                metrics.get(prefix + "settling_time") is None and \
                plots.is_number(metrics.get(prefix + "max"))
    return False


def _metric_cell(name: str, metrics: dict[str, Any]) -> str:
    """A metric's cell: its value, "did not settle", or an empty value marked with the
    reason (docs/metrics.md); blank when the run has no such metric."""
    if name in metrics and metrics[name] is None:
        if not_settled(name, metrics):
            return f'<td class=empty title="{_e(METRICS[name].empty)}">{NOT_SETTLED}</td>'
        reason = METRICS[name].empty if name in METRICS else "undefined"
        return f'<td class=empty title="{_e(reason)}">\u2014</td>'
    return _cell(metrics.get(name))


def _metric_th(name: str, units: dict[str, str]) -> str:
    """A metric's header: its name (wrapping at the underscores), unit, and a link to its
    definition in the page's metrics section (the definition also on hover)."""
    unit = units.get(name)
    doc = METRICS.get(name)
    title = f' title="{_e(doc.definition)}"' if doc else ""
    text = "_<wbr>".join(_e(part) for part in name.split("_"))
    text += f" <span class=unit>[{_e(unit)}]</span>" if unit else ""
    if doc:
        text += f' <a class=def href="#metric-{_e(name)}" title="definition">?</a>'
    return f"<th class=metric{title}>{text}</th>"


def _metric_definitions(names: list[str], units: dict[str, str]) -> str:
    """The page's metrics section: each metric shown, its unit, definition and what an
    empty value means (docs/metrics.md, where they come from)."""
    rows = "".join(
        f'<tr id="metric-{_e(n)}"><td><code>{_e(n)}</code></td>'
        f"<td>{_e(units.get(n) or METRICS[n].unit)}</td><td>{_e(METRICS[n].definition)}</td>"
        f"<td>{_e(METRICS[n].empty)}</td></tr>" for n in names if n in METRICS)
    return ("<p class=hint>From <code>docs/metrics.md</code> of agv-cosim: e is the "
            "lateral (or path) error, t_0 ... t_N the recorded times, T = t_N - t_0.</p>"
            "<table class=defs><thead><tr><th>metric</th><th>unit</th><th>definition</th>"
            f"<th>empty when</th></tr></thead><tbody>{rows}</tbody></table>")


def _all_metrics_table(runs: list[Run], names: list[str], units: dict[str, str]) -> str:
    """Every metric of every run (runs x metrics), folded: it may be wider than the
    window (it scrolls within its box)."""
    head = "<th>run</th>" + "".join(_metric_th(n, units) for n in names)
    body = "".join("<tr>" + f"<td>{_e(run['folder'])}</td>" +
                   "".join(_metric_cell(n, run["metrics"]) for n in names) + "</tr>"
                   for run in runs)
    return (f"<details><summary>Every metric of every run ({len(names)})</summary>"
            '<div class=scroll><table class="sortable all"><thead><tr>'
            f"{head}</tr></thead><tbody>{body}</tbody></table></div></details>")


def _step_rows(run: object, group: str, entries: dict[str, Any],
               names: list[str]) -> list[str]:
    """Rows of the step check's table: ``names`` of ``entries`` (one run's metrics or
    signals), each with its changes, observed order, estimate, tolerance and flag."""
    rows = []
    for name in names:
        one = entries[name]
        flag = str(one.get("flag"))
        value = one["values"][0] if group == "metrics" else one.get("scale")
        rows.append(f"<tr class=\"{_e(flag.replace(' ', '-'))}\"><td>{_e(run)}</td>"
                    f"<td><code>{_e(name)}</code></td>{_cell(value)}"
                    f"{_cell(one.get('change'))}{_cell(one.get('change_fine'))}"
                    f"{_cell(one.get('order'))}{_cell(one.get('estimate'))}"
                    f"{_cell(one.get('tolerance'))}"
                    f"<td class=\"flag {_e(flag.replace(' ', '-'))}\">{_e(flag)}</td></tr>")
    return rows


def _step_check_section(data: object) -> str:
    """The page's step-check section (``step_check.json``): one table of the metrics,
    one folded table of the recorded signals, the quantities not converged first."""
    if not isinstance(data, dict):
        return ""
    factors = data.get("factors") or [1, 2, 4]
    intro = (f"<p class=hint>Each run again at step/{factors[1]} and step/{factors[-1]} "
             "(Model Exchange tolerances divided alike). Change: m(h/2) - m(h), then "
             "m(h/4) - m(h/2) (a signal: the largest difference over the recorded "
             "times); p = log2 of their ratio; estimate: the base's remaining error "
             "|change| 2^p / (2^p - 1); converged when it is within the tolerance "
             f"{data.get('rtol')} |value| + {data.get('atol')}. "
             f'<a href="{_href(STEP_CHECK_FILE)}">{STEP_CHECK_FILE}</a></p>')
    if data.get("error"):
        return intro + f"<p class=warning>The step check did not run: {_e(data['error'])}</p>"
    notes: list[str] = []
    metric_rows: list[str] = []
    signal_rows: list[str] = []
    rank = {"not converged": 0, "order unusable": 0, "undefined": 1, "converged": 2}
    for run in data.get("runs") or []:
        label = run.get("label")
        if run.get("status") != "checked":
            notes.append(f"<li>{_e(label)}: {_e(run.get('status'))}: "
                         f"{_e(run.get('error'))}</li>")
            continue
        for group, rows in (("metrics", metric_rows), ("signals", signal_rows)):
            entries = run.get(group) or {}
            names = sorted(entries, key=lambda n, e=entries: (
                rank.get(e[n].get("flag"), 1), METRIC_ORDER.get(n, len(METRIC_ORDER)), n))
            rows.extend(_step_rows(label, group, entries, names))
    head = ("<thead><tr><th>run</th><th>{}</th><th>{}</th><th>change h&rarr;h/2</th>"
            "<th>change h/2&rarr;h/4</th><th>order p</th><th>estimate</th>"
            "<th>tolerance</th><th>flag</th></tr></thead>")
    bad = sum('"not-converged"' in r or '"order-unusable"' in r
              for r in metric_rows + signal_rows)
    checked = sum(run.get("status") == "checked" for run in data.get("runs") or [])
    out = [intro, f"<p class=summary>{bad} quantit{'y' if bad == 1 else 'ies'} not "
           f"converged in the step ({checked} run(s) checked).</p>" if checked else
           "<p class=summary>No run was checked.</p>"]
    if notes:
        out.append("<ul class=warning>" + "".join(notes) + "</ul>")
    if metric_rows:
        out.append('<div class=scroll><table class="sortable stepcheck">'
                   + head.format("metric", "value at h") + "<tbody>"
                   + "".join(metric_rows) + "</tbody></table></div>")
    if signal_rows:
        out.append(f"<details><summary>Recorded signals ({len(signal_rows)})</summary>"
                   '<div class=scroll><table class="sortable stepcheck">'
                   + head.format("signal", "max |x| at h/4") + "<tbody>"
                   + "".join(signal_rows) + "</tbody></table></div></details>")
    return "".join(out)


def _th(name: str, units: dict[str, str]) -> str:
    unit = units.get(name)
    text = _e(name) + (f" <span class=unit>[{_e(unit)}]</span>" if unit else "")
    return f"<th>{text}</th>"


def _runs_table(runs: list[Run], folder: Path, units: dict[str, str], sampled: list[str],
               manifest: dict[str, Any] | None = None) -> str:
    points = [run["sweep_point"] for run in runs]
    swept = plots.sweep_keys(points, sampled)
    if not swept:  # a single sweep value: still shown when there is one
        swept = [k for k in dict.fromkeys(k for p in points for k in p)
                 if k != plots.SAMPLE_KEY and k not in sampled]
    mc_keys = ([plots.SAMPLE_KEY] if any(plots.SAMPLE_KEY in p for p in points) else []) + \
        [k for k in sampled if any(k in p for p in points)]
    names = key_metrics(runs, manifest)
    head = ["<th>run</th>", "<th>variant</th>", "<th>status</th>"]
    head += [_th(k, units) for k in swept + mc_keys] + [_metric_th(k, units) for k in names]
    head.append("<th>files</th>")
    body = []
    for run in runs:
        label = run["folder"]
        status = run.get("status") or "?"
        error = f' title="{_e(run["error"])}"' if run.get("error") else ""
        cells = [f'<td><a href="{_href(label, "run.json")}">{_e(label)}</a></td>',
                 f"<td>{_e(run.get('variant') or '')}</td>",
                 f'<td class="status {_e(status.replace(" ", "-"))}"{error}>{_e(status)}</td>']
        cells += [_cell(run["sweep_point"].get(k)) for k in swept + mc_keys]
        cells += [_metric_cell(k, run["metrics"]) for k in names]
        links = [f'<a href="{_href(label, name)}">{_e(name.split(".")[0])}</a>'
                 for name in _RUN_FILES if (Path(folder) / label / name).is_file()]
        cells.append(f"<td class=files>{' '.join(links)}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    return (f'<div class=scroll><table class="sortable runs"><thead><tr>{"".join(head)}'
            f'</tr></thead><tbody>{"".join(body)}</tbody></table></div>')


def key_metrics(runs: list[Run], manifest: dict[str, Any] | None = None) -> list[str]:
    """The runs table's metrics: those of :data:`MAIN_METRICS` the runs have, in the
    terminal's order (:func:`_shown_metrics`), at most :data:`RUNS_TABLE_METRICS`; the
    first of every metric when none is a key one."""
    shown = _shown_metrics(runs, manifest)
    return ([n for n in shown if n in MAIN_METRICS] or shown)[:RUNS_TABLE_METRICS]


#: A Monte Carlo statistic that has not the values it needs (montecarlo.json's null).
NOT_AVAILABLE = "n/a"


def statistics_note(n: int, runs: int, not_complete: int, unsettled: int = 0) -> str | None:
    """Why some of a metric's Monte Carlo statistics are n/a (null in montecarlo.json),
    from ``n`` (the runs with a finite value), ``runs`` (the group's), ``not_complete``
    (the group's runs that are not complete) and ``unsettled`` (its complete runs whose
    value is empty because the error never settled, :func:`not_settled`): every
    statistic with no value (n = 0), the std with one (n = 1); None when every statistic
    has a value. The same text is montecarlo.json's ``note`` and the page's."""
    if n >= 2:
        return None
    empty = runs - n - not_complete - unsettled  # other complete runs without a value
    why = [f"{k} {what}" for k, what in ((not_complete, "not complete"),
                                          (unsettled, f"complete that {NOT_SETTLED}"),
                                          (empty, "complete without a finite value"))
           if k > 0]
    detail = f" ({', '.join(why)})" if why else ""
    plural = "run has" if runs == 1 else "runs have"
    if n == 0:
        return f"{NOT_AVAILABLE}: 0 of {runs} {plural} a value{detail}"
    one = "run has" if runs == 1 else "runs has"
    return f"std {NOT_AVAILABLE}: 1 of {runs} {one} a value, std needs 2{detail}"


def _statistic_cell(value: object, note: str | None) -> str:
    """A statistic's cell: its value, or n/a saying why (``note``) where it has none."""
    if value is None and note:
        return f'<td class=empty title="{_e(note)}">{NOT_AVAILABLE}</td>'
    return _cell(value)


def _montecarlo_table(data: dict[str, Any], units: dict[str, str], names: list[str]) -> str:
    groups = data.get("groups") or {}
    if not groups:
        return ""
    stats = ("mean", "std", "p5", "p50", "p95", "min", "max", "n", "failures")
    rows: list[tuple[str, str | None]] = []
    for group, info in groups.items():
        for metric in names:
            values = (info.get("metrics") or {}).get(metric)
            if not isinstance(values, dict):
                continue
            note = values.get("note")
            if not isinstance(note, str):  # a montecarlo.json of an earlier agv-cosim
                n, runs, failed = values.get("n"), info.get("runs"), info.get("failed_runs")
                note = (statistics_note(n, runs, failed) if isinstance(n, int)
                        and isinstance(runs, int) and isinstance(failed, int) else None)
            unit = units.get(metric)
            rows.append(("<tr>" + f"<td>{_e(metric)}</td><td>{_e(unit or '')}</td>"
                         f"<td>{_e(group)}</td>" +
                         "".join(_statistic_cell(values.get(s), note) for s in stats),
                         note))
    if not rows:  # no group has a metric: say why there is no table
        runs = sum(i.get("runs", 0) for i in groups.values() if isinstance(i, dict)
                   and isinstance(i.get("runs"), int))
        failed = sum(i.get("failed_runs", 0) for i in groups.values() if isinstance(i, dict)
                     and isinstance(i.get("failed_runs"), int))
        return (f"<p class=warning>No Monte Carlo statistics: no run has a metric "
                f"({failed} of {runs} runs not complete; <a href=\"montecarlo.json\">"
                "montecarlo.json</a>).</p>")
    noted = any(note for _, note in rows)
    head = "".join(f"<th>{s}</th>" for s in ("metric", "unit", "group") + stats
                   + (("note",) if noted else ()))
    body = "".join(row + (f"<td class=note>{_e(note or '')}</td>" if noted else "")
                   + "</tr>" for row, note in rows)
    design = (f"{_e(data.get('samples'))} samples per group, design {_e(data.get('design'))}, "
              f"seed {_e(data.get('seed'))}")
    return (f"<p>{design}; statistics over the complete runs with a finite value "
            f"(<a href=\"montecarlo.json\">montecarlo.json</a> has every metric)"
            + (f"; {NOT_AVAILABLE}: a statistic without the values it needs (every one "
               "without a value, the std with one), the note says why" if noted else "")
            + ".</p>"
            f'<div class=scroll><table class="sortable"><thead><tr>{head}</tr></thead>'
            f'<tbody>{body}</tbody></table></div>')


def _provenance(runs: list[Run], manifest_source: str) -> str:
    first = runs[0] if runs else {}
    parts = [f"<p>Manifest: <code>{_e(first.get('manifest', '?'))}</code>, SHA-256 "
             f"<code>{_e(first.get('manifest_sha256', '?'))}</code>; read from "
             f"{_e(manifest_source)}.</p>"]
    sim = [(k, first.get(k)) for k in ("start", "stop", "step", "algorithm",
                                        "record_every")]
    parts.append("<p>Simulation: " + ", ".join(f"{k} = <code>{_e(v)}</code>"
                                               for k, v in sim) + ".</p>")
    fmus: dict[tuple[str, str, str], int] = {}
    for run in runs:
        hashes = _table(run.get("fmu_sha256"))
        for component, path in _table(run.get("fmus")).items():
            key = (component, _text(path), _text(hashes.get(component, "")))
            fmus[key] = fmus.get(key, 0) + 1
    rows = "".join(f"<tr><td>{_e(c)}</td><td><code>{_e(p)}</code></td>"
                   f"<td><code>{_e(h)}</code></td><td class=num>{n}</td></tr>"
                   for (c, p, h), n in sorted(fmus.items()))
    parts.append('<table class="sortable"><thead><tr><th>component</th><th>FMU</th>'
                 f"<th>SHA-256</th><th>runs</th></tr></thead><tbody>{rows}</tbody></table>")
    versions: dict[str, int] = {}
    for run in runs:
        text = json.dumps(_table(run.get("versions")), sort_keys=True)
        versions[text] = versions.get(text, 0) + 1
    for text, n in versions.items():
        items = json.loads(text)
        parts.append(f"<p>Versions ({n} run(s)): " + ", ".join(
            f"{_e(k)} <code>{_e(v)}</code>" for k, v in items.items()) + ".</p>")
    return "".join(parts)


def _is_image(path: Path) -> bool:
    """True for a regular file (not a link) that holds something: a figure that was
    drawn (an empty one is never shown as a figure)."""
    try:
        info = os.lstat(path)
    except OSError:
        return False
    return stat.S_ISREG(info.st_mode) and info.st_size > 0


def _figures(folder: Path, written: list[str]) -> tuple[str, list[str]]:
    names = {p.name for p in Path(folder).glob("*.png")} | set(written)
    names = {name for name in names if _is_image(Path(folder) / name)}
    ordered = [n for n in _FIGURE_ORDER if n in names] + sorted(names - set(_FIGURE_ORDER))
    out = []
    for name in ordered:
        caption = CAPTIONS.get(name, "")
        out.append(f'<figure id="fig-{_e(name)}"><a href="{_href(name)}">'
                   f'<img src="{_href(name)}" alt="{_e(name)}" loading="eager"></a>'
                   f"<figcaption><code>{_e(name)}</code> {_e(caption)}</figcaption></figure>")
    return "".join(out), ordered


def render(folder: str | Path, runs: list[Run], manifest: dict[str, Any], manifest_source: str,
           units: dict[str, str], written: list[str]) -> str:
    """The page's HTML (pure: everything it shows is passed in or read from ``folder``)."""
    folder = Path(folder)
    manifest_path = _manifest_path(runs[0]) if runs else None
    name = manifest.get("name") or (Path(manifest_path).stem if manifest_path
                                    else folder.name)
    sampled = plots.sampled_names(folder)
    statuses: dict[str, int] = {}
    for run in runs:
        statuses[run.get("status") or "?"] = statuses.get(run.get("status") or "?", 0) + 1
    body = [f"<h1>{_e(name)}</h1>"]
    if manifest.get("description"):
        body.append(f'<p class="description">{_e(manifest["description"])}</p>')
    variants = manifest.get("variants") or {}
    if variants:
        body.append("<ul class=variants>" + "".join(
            f"<li><b>{_e(v)}</b>"
            + (f": {_e(t['description'])}" if isinstance(t, dict) and t.get("description")
               else "") + "</li>"
            for v, t in variants.items()) + "</ul>")
    body.append("<p class=summary>" + ", ".join(
        f'<span class="status {_e(s.replace(" ", "-"))}">{n} {_e(s)}</span>'
        for s, n in statuses.items()) + f" of {len(runs)} run(s).</p>")
    for note, kind in (("partial.txt", "warning"), ("plots_error.txt", "warning"),
                       ("montecarlo_error.txt", "warning"), (FIGURES_ERROR, "warning")):
        text = _read_text(folder / note)
        if text:
            body.append(f'<p class="{kind}"><a href="{_href(note)}">{_e(note)}</a>: '
                        f"{_e(text.strip())}</p>")
    failed = [run for run in runs if run.get("error") or run.get("metrics_error")]
    if failed:
        body.append("<ul class=warning>" + "".join(
            f"<li>{_e(run['folder'])}: {_e(run.get('error') or run.get('metrics_error'))}"
            "</li>" for run in failed) + "</ul>")
    figures, ordered = _figures(folder, written)
    nav = "".join(f'<a href="#fig-{_e(n)}">{_e(n)}</a>' for n in ordered)
    body.append('<nav><a href="#runs">runs</a>'
                + ('<a href="#montecarlo">Monte Carlo</a>' if sampled else "")
                + ('<a href="#step-check">step check</a>'
                   if (folder / STEP_CHECK_FILE).is_file() else "")
                + f'{nav}<a href="#metrics">metrics</a><a href="#provenance">provenance</a>'
                '<a href="#files">files</a></nav>')
    body.append("<h2 id=runs>Runs</h2><p class=hint>Click a column's header to sort by it; "
                "hover a number for its exact value, a metric's name for its definition (? links "
                "to it).</p>")
    body.append(_runs_table(runs, folder, units, sampled, manifest))
    every = _shown_metrics(runs, manifest)
    if every:
        body.append(_all_metrics_table(runs, every, units))
    mc = read_json_object(folder / "montecarlo.json")
    if mc:
        body.append("<h2 id=montecarlo>Monte Carlo</h2>")
        body.append(_montecarlo_table(mc, units, main_metrics(_metric_names(runs), 8)))
    if figures:
        body.append("<h2>Figures</h2>" + figures)
    step_check = read_json_object(folder / STEP_CHECK_FILE)
    if step_check is not None:
        body.append("<h2 id=step-check>Step check</h2>" + _step_check_section(step_check))
    if every:
        body.append("<h2 id=metrics>Metrics</h2>" + _metric_definitions(every, units))
    body.append("<h2 id=provenance>Provenance</h2>" + _provenance(runs, manifest_source))
    raw = [n for n in _RAW_FILES if (folder / n).is_file()]
    body.append("<h2 id=files>Files</h2><ul>" + "".join(
        f'<li><a href="{_href(n)}">{_e(n)}</a></li>' for n in raw) + "</ul>"
        "<p>Each run's folder holds <code>timeseries.csv</code> (time, then "
        "component.variable), <code>metrics.json</code>, <code>run.json</code> (inputs, "
        "hashes, versions) and <code>output.txt</code> when its FMUs printed: linked in "
        "the runs table.</p>"
        + (f"<p><code>{TIMINGS}</code> holds each run's wall time (and a paced run's "
           "real-time factor): the one file that differs between two runs of the same "
           "manifest; this page shows no timings, so that it does not.</p>"
           if TIMINGS in raw else ""))
    template = Template(resources.files(__package__).joinpath("page_template.html")
                        .read_text(encoding="utf-8"))
    return template.substitute(title=_e(name), body="\n".join(body))


# --------------------------------------------------------------------------- writing

def _record(folder: Path) -> set[str]:
    data = read_json_object(folder / RECORD)
    files = (data or {}).get("files")
    return set(files) if isinstance(files, list) else set()


def _check_writable(folder: Path, names: list[str], record: set[str]) -> None:
    for name in names:
        path = folder / name
        try:
            info = os.lstat(path)
        except FileNotFoundError:
            continue
        if name not in record or not stat.S_ISREG(info.st_mode):
            raise OutputError(f"{path}: exists and was not written by agv-cosim report; "
                              "refusing to replace it")


def _fresh(path: Path) -> Path:
    """``path`` removed when it is there (a file of ours, checked before)."""
    Path(path).unlink(missing_ok=True)
    return path


def _inputs(folder: Path) -> tuple[list[Run], dict[str, Any], str, dict[str, str],
                                 list[Drawing], int]:
    """What the page of ``folder`` shows: (runs, manifest, its source, units, the
    comparison figures (name, function that draws it), their dpi)."""
    runs = read_runs(folder)
    if not runs:
        raise OutputError(f"{folder}: holds no run (no <run>/run.json)")
    manifest, source = read_manifest(folder, runs)
    units = collect_units(runs, manifest)
    sampled = plots.sampled_names(folder)
    title = (manifest.get("plots") or {}).get("title") or manifest.get("name")
    dpi = (manifest.get("plots") or {}).get("dpi")
    dpi = dpi if isinstance(dpi, int) and 20 <= dpi <= 600 else plots.DEFAULT_DPI
    figures = _comparison_figures(runs, manifest, units, sampled, title)
    return runs, manifest, source, units, figures, dpi


def _checked_folder(folder: str | Path) -> Path:
    folder = Path(os.path.abspath(folder))
    if folder.is_symlink() or not folder.is_dir():
        raise OutputError(f"{folder}: not a folder")
    if marker_data(folder) is None:
        raise OutputError(f"{folder}: not a result folder of agv-cosim (no .agv-cosim "
                          "marker); refusing to write a report into it")
    return folder


def _draw(folder: Path, figures: list[Drawing], dpi: int,
          drawn: Collection[str] = ()) -> list[str]:
    """Check the page's files (``drawn``: figures of ours written already), record
    them, and draw the figures not in ``drawn``. A figure that fails leaves no file;
    its name and error go into :data:`FIGURES_ERROR` (one line each), which a later
    drawing of every figure without a failure removes. Returns those lines."""
    names = [name for name, _ in figures] + [REPORT_FILE]
    record = _record(folder)
    _check_writable(folder, [name for name in names if name not in drawn] + [FIGURES_ERROR],
                    record)
    write_json(folder / RECORD, {"files": sorted(record | set(names))}, replace=True)
    failures = []
    for name, draw in figures:
        if name not in drawn:
            try:
                plots.save_figure(draw(), _fresh(folder / name), dpi)
            except Exception as failure:  # noqa: BLE001 - the page says which, and why
                failures.append(printable(f"{name}: {type(failure).__name__}: "
                                          f"{failure}"))
    if failures:  # recorded as the report's own file only when it writes one
        write_json(folder / RECORD, {"files": sorted(record | set(names) | {FIGURES_ERROR})},
                   replace=True)
        with create_file(_fresh(folder / FIGURES_ERROR)) as stream:
            stream.write("".join(f"{line}\n" for line in failures))
    elif not drawn:
        _fresh(folder / FIGURES_ERROR)
    return failures


def write_report(folder: str | Path, *, locked: bool = False,
                 drawn: Iterable[str] = ()) -> Path:
    """Write (or rewrite) the report of the result folder ``folder``.

    Parameters
    ----------
    folder : str or pathlib.Path
        A result folder of agv-cosim (it carries the marker ``.agv-cosim``).
    locked : bool
        The caller holds the folder (a run writing its temporary folder): no lock taken.
    drawn : iterable of str
        The page's figures written already by :func:`draw_figures` of the same folder
        (with ``locked``): not drawn again.

    Returns
    -------
    pathlib.Path
        The page, ``folder/index.html``.

    Raises
    ------
    OutputError
        The folder is not one of ours, another run is writing it, or a file the report
        would write is there and not its own (the message names it); nothing is written.
    ReportError
        The page could not be written (none is left), or it was written without a figure
        that could not be drawn (it says which and why: :data:`FIGURES_ERROR`).
    """
    path = _checked_folder(folder)
    lock = None if locked else FolderLock(path.parent / f".{path.name}.lock", path)
    try:
        runs, manifest, source, units, figures, dpi = _inputs(path)
        _draw(path, figures, dpi, set(drawn))
        page = render(path, runs, manifest, source, units, [n for n, _ in figures])
        _write_page(path / REPORT_FILE, page)
        failed = _read_text(path / FIGURES_ERROR)
        if failed:
            lines = failed.strip().splitlines()
            raise ReportError(f"{path / REPORT_FILE}: written without {len(lines)} "
                              f"figure(s) that could not be drawn ({FIGURES_ERROR}: "
                              f"{lines[0]})")
        return path / REPORT_FILE
    finally:
        if lock is not None:
            lock.release()


def _write_page(path: Path, page: str) -> None:
    """Write the page's text into the new file ``path``: encoded before the file is
    made; a page that cannot be written is removed (never left empty or cut) and
    raises :class:`~agv_cosim.errors.ReportError`."""
    data = page.encode("utf-8")
    try:
        with create_file(_fresh(path), binary=True) as stream:
            stream.write(data)
    except OSError as error:
        Path(path).unlink(missing_ok=True)
        raise ReportError(f"{path}: could not be written: "
                          f"{error.strerror or error}") from None


def draw_figures(folder: str | Path) -> list[str]:
    """Draw the page's figures of the result folder ``folder``, which the caller holds,
    without the page: :func:`write_report` with ``locked`` and ``drawn`` (the names
    returned) writes it after. Lets a run draw them in a process of their own, next to
    its other figures (which the page lists, so the page comes last). Raises as
    :func:`write_report`."""
    folder = _checked_folder(folder)
    _, _, _, _, figures, dpi = _inputs(folder)
    _draw(folder, figures, dpi)
    return [name for name, _ in figures]


def write_report_quietly(folder: str | Path, drawn: Iterable[str] = ()) -> str | None:
    """:func:`write_report` for a run's own folder (locked by the run; ``drawn`` as
    there); returns the problem as one line instead of raising (a report must not lose
    the results)."""
    try:
        write_report(folder, locked=True, drawn=drawn)
    except Exception as failure:  # noqa: BLE001 - reported, the run's results stay
        return printable(f"{type(failure).__name__}: {failure}")
    return None


# --------------------------------------------------------------------------- terminal

def _text_table(head: list[str], rows: list[list[str]], width: int, shrink: int = 0) -> str:
    """Rows of cells as aligned text (first two columns left, the rest right); the
    column ``shrink`` is cut with an ellipsis so that a line fits ``width``."""
    widths = [max(len(row[i]) for row in [head] + rows) for i in range(len(head))]
    rest = sum(w for i, w in enumerate(widths) if i != shrink) + 2 * (len(widths) - 1)
    widths[shrink] = max(8, min(widths[shrink], width - rest))
    lines = []
    for row in [head] + rows:
        cells = [(c if len(c) <= widths[i] else c[:widths[i] - 1] + "…").ljust(widths[i])
                 if i < 2 else c.rjust(widths[i]) for i, c in enumerate(row)]
        lines.append(printable("  ".join(cells).rstrip()))
    return "\n".join(lines)


def _shown_metrics(runs: list[Run], manifest: dict[str, Any] | None = None) -> list[str]:
    """The runs' numeric metrics in an order that depends on their names only (the same
    columns for every run of a manifest, whatever values differ): the metrics of the
    signals of the manifest's ``[metrics]`` table in its order (``reference``: the
    ``path_error_*`` metrics), within each and then :data:`MAIN_METRICS` in theirs, then
    by name."""
    runs = [{"metrics": r.get("metrics") or {}} for r in runs]
    spec = (manifest or {}).get("metrics") or {}
    families = ["path_error" if key == "reference" else key for key, value in spec.items()
                if isinstance(value, (str, dict))]

    def rank(name: str) -> tuple[int, int, str]:
        family = next((k for k, f in enumerate(families) if name.startswith(f + "_")),
                      len(families))
        main = MAIN_METRICS.index(name) if name in MAIN_METRICS else len(MAIN_METRICS)
        return family, main, name

    return sorted(_metric_names(runs), key=rank)


def _metric_text(name: str, metrics: dict[str, Any]) -> str:
    """A metric's value as the terminal writes it: :data:`NOT_SETTLED` for a settling
    metric of a run that never settled, blank for another empty value."""
    return NOT_SETTLED if not_settled(name, metrics) else _fmt(metrics.get(name))


def _headers(names: list[str], units: dict[str, str]) -> list[str]:
    return [n + (f" [{units[n]}]" if units.get(n) else "") for n in names]


def _fitting(names: list[str], units: dict[str, str], label_width: int, width: int,
             cell: int = 9, cells: dict[str, int] | None = None) -> list[str]:
    """As many of ``names`` as fit ``width`` beside a label column of ``label_width``
    (``cells``: the widest cell of a column by name, when wider than ``cell``)."""
    shown: list[str] = []
    used = label_width + 2 + 8 + 2
    for header, name in zip(_headers(names, units), names):
        need = max(len(header), cell, (cells or {}).get(name, 0)) + 2
        if used + need > width and shown:
            break
        shown.append(name)
        used += need
    return shown


def summary_table(runs: list[Run], units: dict[str, str] | None = None, count: int = 4,
                  width: int = 100, manifest: dict[str, Any] | None = None) -> str:
    """A compact text table of the main metrics per run (for the terminal).

    Parameters
    ----------
    runs : list of dict
        Each with ``label``, ``status`` and ``metrics`` (a run's result or run.json).
    units : dict, optional
        Metric units by name (see :func:`metric_unit`).
    count : int
        Most metrics shown (the first of :func:`main_metrics`; fewer when they would not
        fit ``width`` beside the run labels).
    width : int
        Longest line; a long run label is cut with an ellipsis.
    manifest : dict, optional
        The manifest's tables: its ``[metrics]`` sets the order of the metrics
        (:func:`_shown_metrics`).
    """
    units = units or {}
    labels = [str(r.get("label", r.get("folder", ""))) for r in runs]
    names = _shown_metrics(runs, manifest)[:count]
    texts = [{n: _metric_text(n, r.get("metrics") or {}) for n in names} for r in runs]
    widest = {n: max((len(t[n]) for t in texts), default=0) for n in names}
    names = _fitting(names, units, min(max(map(len, labels), default=3), 40), width,
                     cells=widest)
    rows = [[label, str(r.get("status", ""))] + [t[n] for n in names]
            for label, r, t in zip(labels, runs, texts)]
    return _text_table(["run", "status"] + _headers(names, units), rows, width)


def group_table(runs: list[Run], units: dict[str, str] | None = None, count: int = 3,
                width: int = 100, manifest: dict[str, Any] | None = None) -> str:
    """Many runs (Monte Carlo samples) in one line per group (a run's ``group``, else its
    ``variant``): runs complete, and the median (min - max) of each main metric over the
    complete runs."""
    units = units or {}
    groups: dict[str, list[Run]] = {}
    for run in runs:
        groups.setdefault(run.get("group") or run.get("variant") or "base", []).append(run)
    names = _shown_metrics(runs, manifest)[:count]
    names = _fitting(names, units, min(max(map(len, groups), default=5), 30), width, 24)
    rows = []
    for key, members in groups.items():
        done = [r for r in members if r.get("status") == "complete"]
        row = [key, f"{len(done)}/{len(members)}"]
        for name in names:
            values: list[float] = sorted(
                v for v in ((r.get("metrics") or {}).get(name) for r in done)
                if plots.is_number(v))
            row.append(f"{_fmt(float(_median(values)))} ({_fmt(values[0])} - "
                       f"{_fmt(values[-1])})" if values else "")
        rows.append(row)
    head = ["group", "complete"] + [h + " median (min - max)"
                                    for h in _headers(names, units)]
    return _text_table(head, rows, width)


def _median(values: list[float]) -> float:
    n = len(values)
    return values[n // 2] if n % 2 else 0.5 * (values[n // 2 - 1] + values[n // 2])


def terminal_summary(folder: str | Path, width: int = 100, most_runs: int = 20) -> str:
    """The table ``agv-cosim run`` prints at the end: :func:`summary_table` of the runs
    of the result folder, or :func:`group_table` when it has more than ``most_runs``
    runs; read from the folder's files like the page. Empty when no run has a metric."""
    runs = read_runs(folder)
    if not _metric_names(runs):  # no metric: the one-line summary says it all
        return ""
    manifest, _ = read_manifest(folder, runs)
    units = collect_units(runs, manifest)
    for run in runs:
        run["label"] = run["folder"]
    if len(runs) <= most_runs:
        return summary_table(runs, units, width=width, manifest=manifest)
    sampled = plots.sampled_names(folder)
    for run in runs:
        run["group"] = _group(run, sampled)
    return group_table(runs, units, width=width, manifest=manifest)
