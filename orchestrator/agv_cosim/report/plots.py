"""Plots of one or more runs' recorded signals (matplotlib, Agg, no display).

The orchestrator calls :func:`plot_runs` with the runs to overlay (each a :class:`RunData`)
and the manifest's ``[plots]`` table, and :func:`referenced_signals` beforehand to know
what it must record. Figures are drawn on an Agg canvas without ``pyplot`` (no global
backend state, no window), and saved without a ``Software`` tag and with fixed metadata,
so the same data give the same PNG bytes.

The ``[plots]`` table
---------------------
Every key is optional; a figure is written only when its key is present.

``signals`` : list of str
    Signals ``"component.variable"`` drawn in ``signals.png``, one subplot per signal,
    stacked with a shared x axis, every run overlaid with a legend of the run labels.
``x`` : str, default ``"time"``
    The x axis of ``signals.png``: ``"time"`` [s] or a signal, e.g. ``"vehicle.distance"``
    to plot against the distance travelled.
``units`` : table of str to str
    Unit shown in brackets after a signal's name on its axis label, by signal name.
``title`` : str
    Title of every figure (the trajectory figure gets it too).
``trajectory`` : table
    ``{x = "<signal>", y = "<signal>", path = "<path string, optional>"}``: an x-y plot
    ``trajectory.png`` of every run, with equal axis scales, over the reference path
    drawn from ``agv_core.numerics.paths.parse_path(path).polyline`` (the whole path when it is
    bounded, otherwise the stretch the runs cover).
``dpi`` : int, default 120
    Resolution of the PNG files.

Runs marked ``partial`` (stopped early) are drawn dashed and labelled ``"<label> (partial)"``.

Long runs
---------
A line is drawn from a bounded number of points, whatever the run's length (M4
aggregation: Jugel et al., "M4: a visualization-oriented time series data aggregation",
VLDB 2014). Its samples are cut into consecutive buckets and each bucket keeps its first
and last sample and those of its minimum and maximum (for the trajectory: of x and of y),
in their order. A signal line has 2 buckets per pixel column of the figure's width (8 in x
``dpi``), so each column still spans the same minimum and maximum and peaks stay visible.
The trajectory has 8 buckets per column; where a bucket covers a length c of a curve of
radius R, the drawn chord leaves the curve by at most c^2 / (8 R) (1 h at 1 m/s and 120
dpi: c <= 0.47 m, 5.5 mm on a 5 m radius; much longer runs on tight loops get visibly
coarser). A line with no more samples than its buckets would keep is drawn whole, as
before (the plotted runs of the existing experiments have at most 3 001 rows; a signal
line keeps up to 4 x 2 x 8 x ``dpi`` points, 7 040 at 110 dpi). :func:`read_run` reads a
``timeseries.csv`` in chunks into these points, so the plotting process never holds a
run's time series.

Complete example::

    [plots]
    title = "Sine path, gain sweep"
    signals = ["sensor.lateral_error", "vehicle.heading", "act.alpha", "ctrl.u"]
    x = "time"
    dpi = 120
    trajectory = { x = "vehicle.x", y = "vehicle.y", path = "sine:amplitude=2,wavelength=18.85" }

    [plots.units]
    "sensor.lateral_error" = "m"
    "vehicle.heading" = "rad"
    "act.alpha" = "rad"
    "ctrl.u" = "V"
"""

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import rc_context
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..files import open_output
from ..manifest import schema
from ..timeseries import CHUNK_ROWS, count_rows, iter_timeseries, timeseries_columns
from .metrics import load_path

#: File names of the figures (stable, so that a rerun overwrites them).
SIGNALS_FILE = "signals.png"
TRAJECTORY_FILE = "trajectory.png"
DEFAULT_DPI = schema.DEFAULT_DPI

#: Points of the drawn reference path.
_PATH_POINTS = 2000
#: Points per run projected onto an unbounded path to find the stretch to draw.
_PROJECTED_POINTS = 400
#: Width [in] of every figure.
_WIDTH = 8.0
#: Buckets per pixel column of the figure's width: signal lines, trajectory.
_SIGNAL_BUCKETS_PER_COLUMN = 2
_TRAJECTORY_BUCKETS_PER_COLUMN = 8
#: Points per piece when Agg draws a figure with decimated lines (``agg.path.chunksize``).
_AGG_CHUNK = 1000


@dataclass
class RunData:
    """The recorded result of one run, as plotted.

    Parameters
    ----------
    label : str
        Legend label of the run.
    time : numpy.ndarray
        Sample times [s], shape (n,).
    signals : dict of str to numpy.ndarray
        Recorded signals by name ``"component.variable"``, each of shape (n,).
    partial : bool
        True when the run stopped before its stop time (drawn dashed).
    lines : dict, optional
        The lines already decimated, ``(x name, y name) -> (x, y)`` arrays (x name
        ``"time"`` for the time), as :func:`read_run` gives them; when set, ``time`` and
        ``signals`` are not used.
    decimated : bool
        True when some of ``lines`` has fewer points than the run has samples.
    """

    label: str
    time: np.ndarray
    signals: dict = field(default_factory=dict)
    partial: bool = False
    lines: dict | None = None
    decimated: bool = False
    #: scenario events (time [s], name): drawn as vertical dotted lines on time axes
    events: list = field(default_factory=list)


# --------------------------------------------------------------------------- validation

def _validate(spec: "schema.PlotsTable | dict[str, Any] | None") -> dict[str, Any]:
    """``spec`` normalised (defaults filled in): a :class:`~agv_cosim.manifest.schema.PlotsTable`
    as the manifest's schema checked it, or a plain ``[plots]`` table checked here (a
    problem is a ValueError naming ``plots.<key>``)."""
    if isinstance(spec, schema.PlotsTable):
        return spec.spec()
    return schema.check(schema.PlotsTable, {} if spec is None else spec, "plots").spec()


def referenced_signals(spec: "schema.PlotsTable | dict[str, Any] | None") -> list[str]:
    """Every signal ``"component.variable"`` that the ``[plots]`` table names.

    Parameters
    ----------
    spec : dict
        The ``[plots]`` table (see the module docstring).

    Returns
    -------
    list of str
        The names, each once, in the order the table defines them (``signals``, ``x``,
        ``trajectory``).

    Raises
    ------
    ValueError
        If the table is malformed (the message names the key).
    """
    spec = _validate(spec)
    names = list(spec.get("signals", []))
    if spec["x"] != "time":
        names.append(spec["x"])
    if "trajectory" in spec:
        names += [spec["trajectory"]["x"], spec["trajectory"]["y"]]
    return list(dict.fromkeys(names))


# --------------------------------------------------------------------------- decimation

class Decimator:
    """M4 decimation of one line (x, y) whose ``n`` samples arrive in chunks.

    The samples are cut into consecutive buckets of ``ceil(n / buckets)``; each bucket keeps
    its first and last sample and the first sample of its minimum and of its maximum of y
    (``both``: also of x), in their order. Fed in any chunks, the result is the one of the
    whole arrays: a bucket split by a chunk boundary carries only its kept samples over
    (the extremes of a union are among the extremes of its parts, the earlier one on a
    tie). When ``n`` is at most the points the buckets would keep, every sample is kept.

    Parameters
    ----------
    n : int
        Samples that will be fed.
    buckets : int
        Number of buckets (>= 1).
    both : bool
        Keep the extremes of x too (an x-y trajectory).
    """

    def __init__(self, n: int, buckets: int, both: bool = False) -> None:
        self.both = both
        self.size = 1 if n <= (6 if both else 4) * buckets else -(-n // buckets)
        self.row = 0
        self._carry = None
        self._x: list[np.ndarray] = []
        self._y: list[np.ndarray] = []

    def _extremes(self, x, y):
        keys = [0, x.size - 1, int(np.argmin(y)), int(np.argmax(y))]
        if self.both:
            keys += [int(np.argmin(x)), int(np.argmax(x))]
        index = np.unique(keys)
        return x[index], y[index]

    def add(self, x: np.ndarray, y: np.ndarray) -> None:
        """Feed the next samples (1-D arrays of equal length)."""
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        if self.size == 1:
            self._x.append(x)
            self._y.append(y)
            self.row += x.size
            return
        pos = 0
        while pos < x.size:
            end = (self.row // self.size + 1) * self.size
            take = min(x.size - pos, end - self.row)
            bx, by = x[pos:pos + take], y[pos:pos + take]
            if self._carry is not None:
                bx, by = np.concatenate((self._carry[0], bx)), np.concatenate((self._carry[1], by))
            pos += take
            self.row += take
            self._carry = self._extremes(bx, by)
            if self.row == end:
                self._flush()

    def _flush(self) -> None:
        if self._carry is not None:
            self._x.append(self._carry[0])
            self._y.append(self._carry[1])
            self._carry = None

    def result(self) -> tuple[np.ndarray, np.ndarray]:
        """(x, y) of the kept samples."""
        self._flush()
        if not self._x:
            return np.empty(0), np.empty(0)
        if len(self._x) == 1:
            return self._x[0], self._y[0]
        return np.concatenate(self._x), np.concatenate(self._y)


def _buckets(spec: dict[str, Any], trajectory: bool = False) -> int:
    per_column = _TRAJECTORY_BUCKETS_PER_COLUMN if trajectory else _SIGNAL_BUCKETS_PER_COLUMN
    return per_column * int(round(_WIDTH * spec["dpi"]))


def _line_specs(spec):
    """The lines the figures draw: (x name, y name, x key, y key, is trajectory)."""
    lines = [(spec["x"], name, "x", f"signals[{i}]", False)
             for i, name in enumerate(spec.get("signals", []))]
    if "trajectory" in spec:
        traj = spec["trajectory"]
        lines.append((traj["x"], traj["y"], "trajectory.x", "trajectory.y", True))
    return lines


def read_run(path: str | Path, spec: "schema.PlotsTable | dict[str, Any]", label: str, *,
             partial: bool = False, rows: int | None = None,
             chunk_rows: int | None = None) -> "RunData":
    """The lines of one run's ``timeseries.csv`` as the ``[plots]`` table draws them,
    read in chunks of ``chunk_rows`` rows and decimated (see "Long runs").

    Parameters
    ----------
    path : str or pathlib.Path
        The run's ``timeseries.csv``.
    spec : dict
        The ``[plots]`` table.
    label : str
        Legend label of the run.
    partial : bool
        True when the run stopped early (drawn dashed).
    rows : int, optional
        Rows of the file, when known (otherwise counted first).
    chunk_rows : int, optional
        Rows read at a time (default ``results.CHUNK_ROWS``).

    Returns
    -------
    RunData
        With ``lines`` set; memory bounded by the chunk and the buckets.

    Raises
    ------
    ValueError
        If the file lacks a signal the table names (the message names the key).
    """
    spec = _validate(spec)
    present = set(timeseries_columns(path))
    lines = _line_specs(spec)
    for xname, yname, xkey, ykey, _ in lines:
        for name, key in ((xname, xkey), (yname, ykey)):
            if name != "time" and name not in present:
                raise ValueError(f"plots.{key}: run {label!r} has no signal {name!r}")
    n = count_rows(path) if rows is None else rows
    chunk_rows = chunk_rows or CHUNK_ROWS
    decimators = {(x, y): Decimator(n, _buckets(spec, both), both)
                  for x, y, _, _, both in lines}
    names = list(dict.fromkeys(name for x, y, *_ in lines for name in (x, y)
                               if name != "time"))
    for t, signals in iter_timeseries(path, names, chunk_rows):
        for (x, y), decimator in decimators.items():
            decimator.add(t if x == "time" else signals[x], signals[y])
    return RunData(label=label, time=np.empty(0), partial=partial,
                   lines={key: decimator.result() for key, decimator in decimators.items()},
                   decimated=any(decimator.size > 1 for decimator in decimators.values()))


# --------------------------------------------------------------------------- drawing

def _line(run: "RunData", xname: str, yname: str, xkey: str, ykey: str, buckets: int,
          both: bool = False, figure: Any = None) -> Any:
    """(x, y) of one line of ``run``, decimated to ``buckets``; a decimated line marks
    ``figure`` (see :func:`_save`)."""
    if run.lines is not None:
        if (xname, yname) not in run.lines:
            raise ValueError(f"plots.{ykey}: run {run.label!r} was read without the line "
                             f"{yname!r} against {xname!r}")
        if run.decimated and figure is not None:
            figure.agv_decimated = True
        return run.lines[(xname, yname)]
    x = np.asarray(run.time, dtype=float) if xname == "time" else _values(run, xname, xkey)
    y = _values(run, yname, ykey)
    decimator = Decimator(x.size, buckets, both)
    if decimator.size == 1:
        return x, y
    if figure is not None:
        figure.agv_decimated = True
    decimator.add(x, y)
    return decimator.result()


def _values(run, name, key):
    if name not in run.signals:
        raise ValueError(f"plots.{key}: run {run.label!r} has no signal {name!r}")
    values = np.asarray(run.signals[name], dtype=float)
    if values.shape != np.shape(run.time):
        raise ValueError(f"plots.{key}: signal {name!r} of run {run.label!r} has shape "
                         f"{values.shape}, its time grid {np.shape(run.time)}")
    return values


def _label(name, units):
    unit = units.get(name)
    return f"{name} [{unit}]" if unit else name


def _style(run):
    return {"label": f"{run.label} (partial)" if run.partial else run.label,
            "linestyle": "--" if run.partial else "-", "linewidth": 1.2}


def _legend(figure: Any, ax: Any) -> None:
    # outside the axes, below them: never hides data, and no costly 'best' placement
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        # at most 4 columns, and no more than fit the figure's width: a 'small' character
        # is about 4.6 pt wide and each entry adds about 6 characters of line and padding
        fit = int(figure.get_figwidth() * 72.0 / 4.6) // (max(map(len, labels)) + 6)
        figure.legend(handles, labels, loc="outside lower center", fontsize="small",
                      ncols=max(1, min(len(handles), 4, fit)), frameon=False)


def _save(figure, path, dpi):
    with open_output(path) as stream:  # never written through a symbolic link
        if getattr(figure, "agv_decimated", False):
            # A decimated line of a long run can go from a column's minimum to its
            # maximum and back in every column; Agg's memory for one path grows with the
            # pixels its outline crosses (4 h run: +18.5 MiB to draw, +6.7 MiB in chunks
            # of 1000 points). Only such figures are drawn in chunks, so the others keep
            # their exact bytes.
            with rc_context({"agg.path.chunksize": _AGG_CHUNK}):
                figure.savefig(stream, dpi=dpi, format="png", metadata={"Software": None})
        else:
            figure.savefig(stream, dpi=dpi, format="png", metadata={"Software": None})
    return path


def signals_figure(runs: Iterable["RunData"],
                   spec: "schema.PlotsTable | dict[str, Any] | None") -> Figure:
    """The figure of ``signals.png``: one subplot per signal, every run overlaid.

    Parameters
    ----------
    runs : list of RunData
        The runs to draw, in legend order.
    spec : dict
        The ``[plots]`` table; it must have ``signals``.

    Returns
    -------
    matplotlib.figure.Figure
        The figure, on an Agg canvas.
    """
    spec = _validate(spec)
    if "signals" not in spec:
        raise ValueError("plots.signals: missing")
    names = spec["signals"]
    units = dict(spec["units"])
    units.setdefault("time", "s")
    figure = Figure(figsize=(_WIDTH, 1.0 + 2.0 * len(names)), layout="constrained")
    axes = figure.subplots(len(names), 1, sharex=True, squeeze=False)[:, 0]
    buckets = _buckets(spec)
    for run in runs:
        for i, (ax, name) in enumerate(zip(axes, names)):
            x, y = _line(run, spec["x"], name, "x", f"signals[{i}]", buckets, figure=figure)
            line, = ax.plot(x, y, **_style(run))
            if spec["x"] == "time":
                for when, _ in run.events:
                    ax.axvline(when, color=line.get_color(), linestyle=":", linewidth=1.0)
    for ax, name in zip(axes, names):
        ax.set_ylabel(_label(name, units))
        ax.grid(True, linewidth=0.4, alpha=0.6)
    axes[-1].set_xlabel(_label(spec["x"], units))
    if spec["title"]:
        figure.suptitle(spec["title"])
    _legend(figure, axes[0])
    FigureCanvasAgg(figure)
    return figure


def _trajectory(run, traj, buckets, figure=None):
    return _line(run, traj["x"], traj["y"], "trajectory.x", "trajectory.y", buckets, True,
                 figure)


def _reference_polyline(path, runs, traj, buckets):
    """x, y [m] of the reference ``path`` (a ReferencePath) over the stretch worth drawing."""
    from agv_core.numerics.paths import project_trajectory

    length = float(getattr(path, "length", math.inf))
    if math.isfinite(length):
        s0, s1 = 0.0, length
    else:
        # unbounded path: from its start to the furthest projection of any run's point
        s1 = 0.0
        for run in runs:
            x, y = _trajectory(run, traj, buckets)
            keep = np.isfinite(x) & np.isfinite(y)
            x, y = x[keep], y[keep]
            step = max(1, len(x) // _PROJECTED_POINTS)
            _, arcs = project_trajectory(path, x[::step], y[::step])
            if len(arcs):
                s1 = max(s1, float(arcs.max()))
        s0 = 0.0
        if s1 <= 0.0:
            return None
    return path.polyline(s0, s1, (s1 - s0) / _PATH_POINTS)


def trajectory_figure(runs: Iterable["RunData"],
                      spec: "schema.PlotsTable | dict[str, Any] | None",
                      geometry: Any = None) -> Figure:
    """The figure of ``trajectory.png``: x-y of every run over the reference path.

    Parameters
    ----------
    runs : list of RunData
        The runs to draw, in legend order.
    spec : dict
        The ``[plots]`` table; it must have ``trajectory``.
    geometry : agv_core.numerics.paths.ReferencePath, optional
        The reference path to draw (parsed from ``trajectory.path`` by :func:`plot_runs`).

    Returns
    -------
    matplotlib.figure.Figure
        The figure, on an Agg canvas.
    """
    spec = _validate(spec)
    if "trajectory" not in spec:
        raise ValueError("plots.trajectory: missing")
    traj = spec["trajectory"]
    units = spec["units"]
    buckets = _buckets(spec, trajectory=True)
    figure = Figure(figsize=(_WIDTH, 6.0), layout="constrained")
    ax = figure.add_subplot()
    if geometry is not None:
        polyline = _reference_polyline(geometry, runs, traj, buckets)
        if polyline is not None:
            ax.plot(polyline[0], polyline[1], color="0.55", linewidth=2.5, alpha=0.7,
                    label="reference path", zorder=1)
    for run in runs:
        x, y = _trajectory(run, traj, buckets, figure)
        ax.plot(x, y, zorder=2, **_style(run))
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(_label(traj["x"], units))
    ax.set_ylabel(_label(traj["y"], units))
    ax.grid(True, linewidth=0.4, alpha=0.6)
    if spec["title"]:
        figure.suptitle(spec["title"])
    _legend(figure, ax)
    FigureCanvasAgg(figure)
    return figure


def plot_runs(runs: Iterable["RunData"], spec: "schema.PlotsTable | dict[str, Any] | None",
              out_dir: str | Path, *, base_dir: str | Path | None = None) -> list[Path]:
    """Draw the figures the ``[plots]`` table asks for, every run overlaid.

    Parameters
    ----------
    runs : list of RunData
        The runs to draw, in legend order.
    spec : dict
        The ``[plots]`` table (see the module docstring).
    out_dir : pathlib.Path
        Folder the PNG files are written to (created if missing).
    base_dir : str or pathlib.Path, optional
        Folder that relative file names in ``trajectory.path`` are relative to (the
        manifest's folder); the working directory when None.

    Returns
    -------
    list of pathlib.Path
        The files written: ``signals.png`` and/or ``trajectory.png``, in that order.

    Raises
    ------
    ValueError
        If the table is malformed, or a run lacks a signal it names (the message names
        the key).
    """
    raw, spec = spec, _validate(spec)
    runs = list(runs)
    for run in runs:
        if not isinstance(run, RunData):
            raise TypeError(f"plot_runs: expected RunData, got {type(run).__name__}")
        # every signal checked before any file is written
        if run.lines is not None:
            for xname, yname, xkey, ykey, both in _line_specs(spec):
                _line(run, xname, yname, xkey, ykey, 1, both)
            continue
        for i, name in enumerate(spec.get("signals", [])):
            _values(run, name, f"signals[{i}]")
        if spec["x"] != "time" and "signals" in spec:
            _values(run, spec["x"], "x")
        if "trajectory" in spec:
            for sub in ("x", "y"):
                _values(run, spec["trajectory"][sub], f"trajectory.{sub}")
    geometry = None
    if "trajectory" in spec and spec["trajectory"]["path"] is not None:

        geometry = load_path(spec["trajectory"]["path"], "plots.trajectory.path", base_dir)
    out_dir = Path(out_dir)
    written = []
    if "signals" in spec or "trajectory" in spec:
        out_dir.mkdir(parents=True, exist_ok=True)
    if "signals" in spec:
        written.append(_save(signals_figure(runs, raw), out_dir / SIGNALS_FILE,
                             spec["dpi"]))
    if "trajectory" in spec:
        written.append(_save(trajectory_figure(runs, raw, geometry),
                             out_dir / TRAJECTORY_FILE, spec["dpi"]))
    return written
