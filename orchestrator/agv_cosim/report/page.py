"""The report of a result folder: ``index.html``, a static page read from disk.

:func:`write_report` reads a result folder of ``agv-cosim run`` from disk only (each
run's ``run.json`` and ``metrics.json``, ``summary.csv``, ``montecarlo.json``,
``partial.txt``, the error notes, the PNG figures and the manifest: ``manifest.toml`` in
the folder when present, else the file run.json names when its SHA-256 is still the one
run) and writes into it:

- ``index.html``: the manifest's description, the runs with their status, sweep values
  and metrics (units in the headers; a table sorts by a click on its header), the
  Monte Carlo statistics, every figure, the paths, hashes and versions from run.json, and
  links to the raw files. One file with its style and script inline: it opens from disk
  with no network. It shows no timing (it links ``timings.csv``): the same folder
  contents give the same page, byte for byte.
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
import json
import math
import os
import stat
import tomllib
from collections.abc import Iterable
from functools import partial
from importlib import resources
from pathlib import Path
from string import Template
from urllib.parse import quote

from ..errors import OutputError
from ..files import (
    FolderLock,
    create_file,
    marker_data,
    printable,
    read_json_object,
    write_json,
)
from . import plots
from .records import TIMINGS

#: The page, at the top of the result folder.
REPORT_FILE = "index.html"
#: What the report wrote (JSON: ``files``), so that it replaces only its own files.
RECORD = ".agv-cosim-report.json"
#: The manifest's copy in a result folder, when there is one.
MANIFEST_COPY = "manifest.toml"
#: Metrics shown first (and in the figures and the terminal table), in this order.
MAIN_METRICS = ("lateral_error_max", "lateral_error_rms", "lateral_error_settled_max",
                "lateral_error_settled_signed_mean", "lateral_error_settling_time",
                "lateral_error_overshoot", "path_error_max", "path_error_rms",
                "path_error_settled_max", "heading_error_max", "steering_angle_peak",
                "steering_rate_peak", "control_peak", "control_effort")
#: Known figures of a result folder, with their captions (others are shown by name).
CAPTIONS = {
    "signals.png": "The recorded signals of every run ([plots] signals).",
    "trajectory.png": "The runs' paths over the reference path, and their offset from "
                      "it along the path ([plots] trajectory).",
    plots.SWEEP_FILE: "The main metrics against the swept value, one line per variant.",
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
#: Files of the result folder linked from the page.
_RAW_FILES = ("summary.csv", TIMINGS, "montecarlo.json", "partial.txt", "plots_error.txt",
              "montecarlo_error.txt", MANIFEST_COPY)


# --------------------------------------------------------------------------- reading

def _read_text(path, limit=1 << 16):
    try:
        with open(path, encoding="utf-8", errors="replace") as stream:
            return stream.read(limit)
    except OSError:
        return None


def _summary_order(folder):
    """Run labels in summary.csv's order (empty without one)."""
    try:
        with open(folder / "summary.csv", encoding="utf-8", newline="") as stream:
            return [row.get("run", "") for row in csv.DictReader(stream)]
    except (OSError, csv.Error):
        return []


def read_runs(folder: str | Path) -> list[dict]:
    """Every run of a result folder: its run.json with ``metrics`` (its metrics.json)
    and ``folder`` (the run folder's name), in summary.csv's order (then by name)."""
    folder = Path(folder)
    found = {}
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


def _sha256(path):
    digest = hashlib.sha256()
    with open(path, "rb") as stream:
        while block := stream.read(1 << 20):
            digest.update(block)
    return digest.hexdigest()


def read_manifest(folder: str | Path, runs: list[dict]) -> tuple[dict, str]:
    """The manifest of the runs as TOML data, and where it came from (a sentence).

    ``manifest.toml`` in the folder first; else the file run.json names, when its SHA-256
    is the run's (a manifest changed since is not used). An SSP package or a missing file
    gives ``{}``."""
    copy = Path(folder) / MANIFEST_COPY
    if copy.is_file() and not copy.is_symlink():
        try:
            with open(copy, "rb") as stream:
                return tomllib.load(stream), f"the copy {MANIFEST_COPY} in this folder"
        except (OSError, tomllib.TOMLDecodeError):
            pass
    if not runs:
        return {}, "no run"
    path, digest = runs[0].get("manifest"), runs[0].get("manifest_sha256")
    if not path:
        return {}, "run.json names no manifest"
    path = Path(path)
    if path.suffix == ".ssp":
        return {}, f"an SSP package ({path}); its description is not read"
    try:
        if _sha256(path) != digest:
            return {}, f"{path} changed since the run (its SHA-256 differs); not used"
        with open(path, "rb") as stream:
            return tomllib.load(stream), f"{path} (SHA-256 as run)"
    except OSError:
        return {}, f"{path} not found from {os.getcwd()}"
    except tomllib.TOMLDecodeError:
        return {}, f"{path} is not valid TOML"


# --------------------------------------------------------------------------- units

def metric_unit(name: str, spec: dict, units: dict) -> str | None:
    """Unit of metric ``name`` (see :mod:`agv_cosim.report.metrics`): the unit of the signal the
    ``[metrics]`` table ``spec`` computes it from where ``units`` has it, else the
    documented one; None for an unknown metric."""
    def signal_unit(key, default):
        signal = spec.get(key)
        if isinstance(signal, dict):
            signal = signal.get("x")
        return units.get(signal) or default

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


def _metric_names(runs, varying=False):
    """Names of the runs' numeric metrics in first-seen order; ``varying``: only those
    whose values differ between the runs (beyond 1e-9 of their size)."""
    names = []
    for run in runs:
        for name, value in run["metrics"].items():
            if name not in names and plots.is_number(value):
                names.append(name)
    if varying:
        def spread(name):
            values = [v for v in (r["metrics"].get(name) for r in runs) if plots.is_number(v)]
            return max(values) - min(values) > 1e-9 * max(map(abs, values))
        names = [name for name in names if spread(name)]
    return names


def collect_units(runs: list[dict], manifest: dict) -> dict:
    """Units by name: signals and parameters (FMUs, then ``[plots.units]``) and metrics."""
    fmus: dict[str, str] = {}
    for run in runs:
        for component, path in (run.get("fmus") or {}).items():
            fmus.setdefault(component, path)
    base = Path(runs[0]["manifest"]).parent if runs and runs[0].get("manifest") else None
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

def _comparison_figures(runs, manifest, units, sampled, title):
    """(file name, function that draws the figure) of the comparison figures the result
    calls for."""
    figures = []
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


def _group(run, sampled):
    point = run["sweep_point"]
    swept = [k for k in point if k != plots.SAMPLE_KEY and k not in sampled]
    parts = [run.get("variant") or "base"] + [f"{k}={point[k]!r}" for k in sorted(swept)]
    return ", ".join(parts)


# --------------------------------------------------------------------------- the page

def _e(value):
    return html.escape(str(value), quote=True)


def _href(*parts):
    return "/".join(quote(str(part)) for part in parts)


def _fmt(value):
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


def _cell(value):
    sort = value if plots.is_number(value) else None
    attrs = f' data-v="{_e(repr(float(sort)))}"' if sort is not None else ""
    title = f' title="{_e(repr(value))}"' if isinstance(value, float) else ""
    classes = ' class="num"' if sort is not None else ""
    return f"<td{attrs}{title}{classes}>{_e(_fmt(value))}</td>"


def _th(name, units):
    unit = units.get(name)
    text = _e(name) + (f" <span class=unit>[{_e(unit)}]</span>" if unit else "")
    return f"<th>{text}</th>"


def _runs_table(runs, folder, units, sampled):
    points = [run["sweep_point"] for run in runs]
    swept = plots.sweep_keys(points, sampled)
    if not swept:  # a single sweep value: still shown when there is one
        swept = [k for k in dict.fromkeys(k for p in points for k in p)
                 if k != plots.SAMPLE_KEY and k not in sampled]
    mc_keys = ([plots.SAMPLE_KEY] if any(plots.SAMPLE_KEY in p for p in points) else []) + \
        [k for k in sampled if any(k in p for p in points)]
    names = main_metrics(_metric_names(runs), 10 ** 6)
    head = ["<th>run</th>", "<th>variant</th>", "<th>status</th>"]
    head += [_th(k, units) for k in swept + mc_keys + names]
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
        cells += [_cell(run["metrics"].get(k)) for k in names]
        links = [f'<a href="{_href(label, name)}">{_e(name.split(".")[0])}</a>'
                 for name in _RUN_FILES if (Path(folder) / label / name).is_file()]
        cells.append(f"<td class=files>{' '.join(links)}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    return (f'<div class=scroll><table class="sortable runs"><thead><tr>{"".join(head)}'
            f'</tr></thead><tbody>{"".join(body)}</tbody></table></div>')


def _montecarlo_table(data, units, names):
    groups = data.get("groups") or {}
    if not groups:
        return ""
    stats = ("mean", "std", "p5", "p50", "p95", "min", "max", "n", "failures")
    rows = []
    for group, info in groups.items():
        for metric in names:
            values = (info.get("metrics") or {}).get(metric)
            if not isinstance(values, dict):
                continue
            unit = units.get(metric)
            rows.append("<tr>" + f"<td>{_e(metric)}</td><td>{_e(unit or '')}</td>"
                        f"<td>{_e(group)}</td>" +
                        "".join(_cell(values.get(s)) for s in stats) + "</tr>")
    head = "".join(f"<th>{s}</th>" for s in ("metric", "unit", "group") + stats)
    design = (f"{_e(data.get('samples'))} samples per group, design {_e(data.get('design'))}, "
              f"seed {_e(data.get('seed'))}")
    return (f"<p>{design}; statistics over the complete runs with a finite value "
            f"(<a href=\"montecarlo.json\">montecarlo.json</a> has every metric).</p>"
            f'<div class=scroll><table class="sortable"><thead><tr>{head}</tr></thead>'
            f'<tbody>{"".join(rows)}</tbody></table></div>')


def _provenance(runs, manifest_source):
    first = runs[0] if runs else {}
    parts = [f"<p>Manifest: <code>{_e(first.get('manifest', '?'))}</code>, SHA-256 "
             f"<code>{_e(first.get('manifest_sha256', '?'))}</code>; read from "
             f"{_e(manifest_source)}.</p>"]
    sim = [(k, first.get(k)) for k in ("start", "stop", "step", "algorithm",
                                        "record_every")]
    parts.append("<p>Simulation: " + ", ".join(f"{k} = <code>{_e(v)}</code>"
                                               for k, v in sim) + ".</p>")
    fmus = {}
    for run in runs:
        for component, path in (run.get("fmus") or {}).items():
            key = (component, path, (run.get("fmu_sha256") or {}).get(component, ""))
            fmus[key] = fmus.get(key, 0) + 1
    rows = "".join(f"<tr><td>{_e(c)}</td><td><code>{_e(p)}</code></td>"
                   f"<td><code>{_e(h)}</code></td><td class=num>{n}</td></tr>"
                   for (c, p, h), n in sorted(fmus.items()))
    parts.append('<table class="sortable"><thead><tr><th>component</th><th>FMU</th>'
                 f"<th>SHA-256</th><th>runs</th></tr></thead><tbody>{rows}</tbody></table>")
    versions = {}
    for run in runs:
        key = json.dumps(run.get("versions") or {}, sort_keys=True)
        versions[key] = versions.get(key, 0) + 1
    for key, n in versions.items():
        items = json.loads(key)
        parts.append(f"<p>Versions ({n} run(s)): " + ", ".join(
            f"{_e(k)} <code>{_e(v)}</code>" for k, v in items.items()) + ".</p>")
    return "".join(parts)


def _figures(folder, written):
    names = {p.name for p in Path(folder).glob("*.png")
             if p.is_file() and not p.is_symlink()} | set(written)
    ordered = [n for n in _FIGURE_ORDER if n in names] + sorted(names - set(_FIGURE_ORDER))
    out = []
    for name in ordered:
        caption = CAPTIONS.get(name, "")
        out.append(f'<figure id="fig-{_e(name)}"><a href="{_href(name)}">'
                   f'<img src="{_href(name)}" alt="{_e(name)}" loading="eager"></a>'
                   f"<figcaption><code>{_e(name)}</code> {_e(caption)}</figcaption></figure>")
    return "".join(out), ordered


def render(folder: str | Path, runs: list[dict], manifest: dict, manifest_source: str,
           units: dict, written: list[str]) -> str:
    """The page's HTML (pure: everything it shows is passed in or read from ``folder``)."""
    folder = Path(folder)
    name = manifest.get("name") or (Path(runs[0]["manifest"]).stem if runs and
                                    runs[0].get("manifest") else folder.name)
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
                       ("montecarlo_error.txt", "warning")):
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
                + f'{nav}<a href="#provenance">provenance</a><a href="#files">files</a></nav>')
    body.append("<h2 id=runs>Runs</h2><p class=hint>Click a column's header to sort by it; "
                "hover a number for its exact value.</p>")
    body.append(_runs_table(runs, folder, units, sampled))
    mc = read_json_object(folder / "montecarlo.json")
    if mc:
        body.append("<h2 id=montecarlo>Monte Carlo</h2>")
        body.append(_montecarlo_table(mc, units, main_metrics(_metric_names(runs), 8)))
    if figures:
        body.append("<h2>Figures</h2>" + figures)
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

def _record(folder):
    data = read_json_object(folder / RECORD)
    files = (data or {}).get("files")
    return set(files) if isinstance(files, list) else set()


def _check_writable(folder, names, record):
    for name in names:
        path = folder / name
        try:
            info = os.lstat(path)
        except FileNotFoundError:
            continue
        if name not in record or not stat.S_ISREG(info.st_mode):
            raise OutputError(f"{path}: exists and was not written by agv-cosim report; "
                              "refusing to replace it")


def _fresh(path):
    """``path`` removed when it is there (a file of ours, checked before)."""
    Path(path).unlink(missing_ok=True)
    return path


def _inputs(folder):
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


def _draw(folder, figures, dpi, drawn=()):
    """Check the page's files (``drawn``: figures of ours written already), record
    them, and draw the figures not in ``drawn``."""
    names = [name for name, _ in figures] + [REPORT_FILE]
    record = _record(folder)
    _check_writable(folder, [name for name in names if name not in drawn], record)
    write_json(folder / RECORD, {"files": sorted(record | set(names))}, replace=True)
    for name, draw in figures:
        if name not in drawn:
            plots.save_figure(draw(), _fresh(folder / name), dpi)


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
    """
    path = _checked_folder(folder)
    lock = None if locked else FolderLock(path.parent / f".{path.name}.lock", path)
    try:
        runs, manifest, source, units, figures, dpi = _inputs(path)
        _draw(path, figures, dpi, set(drawn))
        page = render(path, runs, manifest, source, units, [n for n, _ in figures])
        with create_file(_fresh(path / REPORT_FILE)) as stream:
            stream.write(page)
        return path / REPORT_FILE
    finally:
        if lock is not None:
            lock.release()


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

def _text_table(head, rows, width, shrink=0):
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


def _shown_metrics(runs, manifest=None):
    """The runs' numeric metrics in an order that depends on their names only (the same
    columns for every run of a manifest, whatever values differ): the metrics of the
    signals of the manifest's ``[metrics]`` table in its order (``reference``: the
    ``path_error_*`` metrics), within each and then :data:`MAIN_METRICS` in theirs, then
    by name."""
    runs = [{"metrics": r.get("metrics") or {}} for r in runs]
    spec = (manifest or {}).get("metrics") or {}
    families = ["path_error" if key == "reference" else key for key, value in spec.items()
                if isinstance(value, (str, dict))]

    def rank(name):
        family = next((k for k, f in enumerate(families) if name.startswith(f + "_")),
                      len(families))
        main = MAIN_METRICS.index(name) if name in MAIN_METRICS else len(MAIN_METRICS)
        return family, main, name

    return sorted(_metric_names(runs), key=rank)


def _headers(names, units):
    return [n + (f" [{units[n]}]" if units.get(n) else "") for n in names]


def _fitting(names, units, label_width, width, cell=9):
    """As many of ``names`` as fit ``width`` beside a label column of ``label_width``."""
    shown = []
    used = label_width + 2 + 8 + 2
    for header, name in zip(_headers(names, units), names):
        need = max(len(header), cell) + 2
        if used + need > width and shown:
            break
        shown.append(name)
        used += need
    return shown


def summary_table(runs: list[dict], units: dict | None = None, count: int = 4,
                  width: int = 100, manifest: dict | None = None) -> str:
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
    names = _fitting(names, units, min(max(map(len, labels), default=3), 40), width)
    rows = [[label, str(r.get("status", ""))] +
            [_fmt((r.get("metrics") or {}).get(n)) for n in names]
            for label, r in zip(labels, runs)]
    return _text_table(["run", "status"] + _headers(names, units), rows, width)


def group_table(runs: list[dict], units: dict | None = None, count: int = 3,
                width: int = 100, manifest: dict | None = None) -> str:
    """Many runs (Monte Carlo samples) in one line per group (a run's ``group``, else its
    ``variant``): runs complete, and the median (min - max) of each main metric over the
    complete runs."""
    units = units or {}
    groups: dict[str, list[dict]] = {}
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


def _median(values):
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
