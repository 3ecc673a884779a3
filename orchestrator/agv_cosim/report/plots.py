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
    Unit shown in brackets after a signal's name on its axis label, by signal name. By
    default each signal gets the unit its FMU declares (:func:`fmu_units`, from the FMU
    paths in the runs' ``run.json``); this table overrides it.
``title`` : str
    Title of every figure (the trajectory figure gets it too).
``trajectory`` : table
    ``{x = "<signal>", y = "<signal>", path = "<path string, optional>"}``: an x-y plot
    ``trajectory.png`` of every run, with equal axis scales (without a path: unless the
    runs' smaller extent is under 5 % of the larger, then each axis fits its data and
    the panel says "axes not to scale"), over the reference path
    drawn from ``agv_core.numerics.paths.parse_path(path).polyline`` (the whole path when it is
    bounded, otherwise the stretch the runs cover); with a path, a second panel shows
    each run's signed offset from it against the arc length (equal axes hide a 0.3 m
    offset over 45 m; this panel does not).
``dpi`` : int, default 120
    Resolution of the PNG files.

Telling runs apart (:func:`run_styles`): a sweep with a numeric swept value of 3 or more
values colours each run by that value on a colour map with a colour bar, the line style
telling the variants (and other swept values) apart; otherwise up to :data:`LEGEND_CAP`
runs each get a colour and a legend entry (a run marked ``partial``, stopped early, drawn
dashed and labelled ``"<label> (partial)"``); more runs (Monte Carlo samples) are drawn
thin and translucent in one colour per variant, with one legend entry per variant. A
legend never lists more than :data:`LEGEND_CAP` entries. The runs' variants and sweep
points come from their ``run.json`` in the output folder.

The comparison figures of a result folder (a metric against the swept value; Monte Carlo
box plots and scatters with Spearman's rank correlation) are drawn here from the runs'
metrics by :mod:`agv_cosim.report.page`.

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

import functools
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeGuard, TypeVar, cast

import numpy as np
import numpy.typing as npt

from ..files import FMU_LIMIT, open_output, open_regular, read_json_object
from ..manifest import schema
from ..timeseries import CHUNK_ROWS, count_rows, iter_timeseries, timeseries_columns
from .metrics import load_path

if TYPE_CHECKING:  # matplotlib is imported by the functions that draw, when they draw
    from matplotlib.figure import Figure

#: A float64 signal.
Floats = npt.NDArray[np.float64]
#: One line of a figure: its x and y samples.
Line = tuple[np.ndarray, np.ndarray]

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
    signals: dict[str, np.ndarray] = field(default_factory=dict)
    partial: bool = False
    lines: dict[tuple[str, str], "Line"] | None = None
    decimated: bool = False
    #: scenario events (time [s], name): drawn as vertical dotted lines on time axes
    events: list[tuple[float, str]] = field(default_factory=list)
    #: the run's variant and sweep point (run.json's ``variant`` and ``sweep_point``);
    #: None: not known (:func:`plot_runs` reads them from ``<out_dir>/<label>/run.json``)
    variant: str | None = None
    point: dict[str, Any] | None = None


# --------------------------------------------------------------------------- validation

#: matplotlib settings every figure is made and drawn with: no mathtext and no TeX, so
#: that text from manifests and FMUs (variable names, titles, groups, run labels) is
#: drawn as written (a ``$`` drawn as a ``$``, never parsed as a formula).
PLAIN_TEXT: dict[Any, Any] = {"text.parse_math": False, "text.usetex": False}

_Draw = TypeVar("_Draw", bound=Callable[..., Any])


def plain_text(draw: _Draw) -> _Draw:
    """``draw`` (a function that makes a figure) run under :data:`PLAIN_TEXT`: every
    text artist it makes is plain text."""
    @functools.wraps(draw)
    def plain(*args: Any, **kwargs: Any) -> Any:
        from matplotlib import rc_context

        with rc_context(PLAIN_TEXT):
            return draw(*args, **kwargs)

    return cast(_Draw, plain)


def import_drawing() -> None:
    """Import what drawing a figure needs (matplotlib's Figure and Agg canvas, with its
    font list): a command that will draw calls it while its runs are under way, so that
    the figure processes it forks afterwards start with it."""
    import matplotlib.backends.backend_agg  # noqa: F401
    import matplotlib.figure  # noqa: F401


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
        self._carry: Line | None = None
        self._x: list[np.ndarray] = []
        self._y: list[np.ndarray] = []

    def _extremes(self, x: np.ndarray, y: np.ndarray) -> "Line":
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


def _line_specs(spec: dict[str, Any]) -> list[tuple[str, str, str, str, bool]]:
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
          both: bool = False, figure: Any = None) -> Line:
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


def _values(run: "RunData", name: str, key: str) -> Floats:
    if name not in run.signals:
        raise ValueError(f"plots.{key}: run {run.label!r} has no signal {name!r}")
    values = np.asarray(run.signals[name], dtype=float)
    if values.shape != np.shape(run.time):
        raise ValueError(f"plots.{key}: signal {name!r} of run {run.label!r} has shape "
                         f"{values.shape}, its time grid {np.shape(run.time)}")
    return values


def _label(name: str, units: dict[str, str]) -> str:
    unit = units.get(name)
    return f"{name} [{unit}]" if unit else name


# --------------------------------------------------------------------------- units

#: Key of a run's sweep point that holds its Monte Carlo sample index.
SAMPLE_KEY = "montecarlo.sample"


def _variable_unit(variable: Any) -> str | None:
    unit = getattr(variable, "unit", None)
    if not unit and getattr(variable, "declaredType", None) is not None:
        unit = getattr(variable.declaredType, "unit", None)
    return unit or None


def _model_description(path: str) -> Any:
    """fmpy's model description of the FMU at ``path`` (``<package>!/<entry>``: an FMU
    inside an SSP package), or None when it cannot be read (a file that is not a
    regular file is not opened: :func:`~agv_cosim.files.open_regular`)."""
    import io
    import zipfile

    from fmpy import read_model_description

    text = str(path)
    try:
        if "!/" in text:
            package, entry = text.split("!/", 1)
            with open_regular(package) as stream, zipfile.ZipFile(stream) as archive:
                if archive.getinfo(entry).file_size > FMU_LIMIT:
                    return None
                data = io.BytesIO(archive.read(entry))
            return read_model_description(data, validate=False)
        with open_regular(text) as stream:
            return read_model_description(stream, validate=False)
    except Exception:  # noqa: BLE001 - a unit is a label: no FMU, no unit
        return None


def fmu_units(fmus: dict[str, str], base_dir: str | Path | None = None) -> dict[str, str]:
    """Units of the FMUs' variables as their model descriptions declare them.

    Parameters
    ----------
    fmus : dict of str to str
        Component name -> FMU path (run.json's ``fmus``; ``<package>!/<entry>`` for an FMU
        inside an SSP package); a relative path is taken relative to ``base_dir`` when
        the file is not found relative to the working directory.
    base_dir : str or pathlib.Path, optional

    Returns
    -------
    dict of str to str
        ``"component.variable"`` -> unit, for every variable that declares one (an FMU
        that cannot be read contributes nothing).
    """
    units: dict[str, str] = {}
    read: dict[str, Any] = {}  # FMU path -> its model description (fmpy's), or None
    for component, path in fmus.items():
        path = str(path)
        if not Path(path.split("!/", 1)[0]).exists() and base_dir is not None:
            candidate = Path(base_dir) / path
            if Path(str(candidate).split("!/", 1)[0]).exists():
                path = str(candidate)
        if path not in read:
            read[path] = _model_description(path)
        md = read[path]
        if md is None:
            continue
        for variable in md.modelVariables:
            unit = _variable_unit(variable)
            if unit:
                units[f"{component}.{variable.name}"] = unit
    return units


# --------------------------------------------------------------------------- styles

#: Most entries a legend lists; beyond, a colour bar or one entry per group says it.
LEGEND_CAP = 10
#: Line styles of the groups (variants) when colour carries the sweep value.
_LINESTYLES: tuple[Any, ...] = ("-", "--", ":", "-.")
#: Colour map of sweep values.
COLORMAP = "viridis"


def is_number(value: object) -> TypeGuard[float]:
    """True for an int or float (not a bool) that is finite."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and \
        math.isfinite(value)


def sweep_keys(points: list[dict[str, Any]], sampled: Iterable[str] = ()) -> list[str]:
    """The keys of the sweep points whose values differ between the runs, in first-seen
    order, without the Monte Carlo sample index and the ``sampled`` names."""
    sampled = set(sampled)
    keys: list[str] = []
    for point in points:
        for key in point or {}:
            if key not in keys and key != SAMPLE_KEY and key not in sampled:
                keys.append(key)
    return [key for key in keys
            if len({repr((point or {}).get(key)) for point in points}) > 1]


def colour_key(points: list[dict[str, Any]], sampled: Iterable[str] = ()) -> str | None:
    """The swept key that colours the runs: the first one whose values are all numbers
    and take at least 3 values; None when there is none."""
    for key in sweep_keys(points, sampled):
        values = [(point or {}).get(key) for point in points]
        if all(is_number(v) for v in values) and len(set(values)) >= 3:
            return key
    return None


def colour_norm(values: list[float]) -> Any:
    """A matplotlib norm over ``values``: logarithmic when they are positive and span a
    factor of 20 or more, else linear."""
    from matplotlib.colors import LogNorm, Normalize

    low, high = min(values), max(values)
    if low > 0 and high / low >= 20:
        return LogNorm(low, high)
    if low == high:
        return Normalize(low - 1, high + 1)
    return Normalize(low, high)


def _group_label(variant: str | None, point: dict[str, Any] | None,
                 keys: Iterable[str]) -> str:
    parts = [variant] if variant else []
    parts += [f"{key}={(point or {}).get(key)!r}" for key in keys]
    return ", ".join(parts) or "runs"


@dataclass
class Styles:
    """How each run is drawn: ``lines`` (matplotlib keyword arguments per run, its
    ``label`` None when the run has no legend entry of its own), ``legend`` (handles and
    labels of the groups, when the runs are grouped), and the colour bar: ``mappable``
    and ``bar_label`` (None without one)."""

    lines: list[dict[str, Any]]
    legend: list[tuple[Any, str]] = field(default_factory=list)
    mappable: object = None
    bar_label: str | None = None
    bar_ticks: list[float] | None = None


def run_styles(runs: Iterable["RunData"], units: dict[str, str] | None = None,
               sampled: Iterable[str] = ()) -> Styles:
    """The colour, line style and legend label of every run.

    - A sweep with a numeric key of 3 or more values: colour by that value on
      :data:`COLORMAP` with a colour bar; line style by group (variant and the other
      swept values), the legend lists the groups; a partial run is thinner and faded.
    - Otherwise, at most :data:`LEGEND_CAP` runs: a colour and a legend entry per run
      (a partial run dashed and labelled ``(partial)``).
    - Otherwise (many runs, e.g. Monte Carlo samples): one colour per group, thin
      translucent lines, one legend entry per group with its number of runs.
    """
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.lines import Line2D

    units = units or {}
    runs = list(runs)
    points = [run.point or {} for run in runs]
    key = colour_key(points, sampled)
    others = [k for k in sweep_keys(points, sampled) if k != key]
    groups: dict[str, list[RunData]] = {}
    for run, point in zip(runs, points):
        groups.setdefault(_group_label(run.variant, point, others), []).append(run)
    if key is not None:
        values = [point[key] for point in points]
        norm = colour_norm(values)
        cmap = colormaps[COLORMAP]
        lines, legend = [], []
        styles = {name: _LINESTYLES[i % len(_LINESTYLES)] for i, name in enumerate(groups)}
        for run, point in zip(runs, points):
            group = _group_label(run.variant, point, others)
            lines.append({"color": cmap(norm(point[key])), "linestyle": styles[group],
                          "linewidth": 0.8 if run.partial else 1.3,
                          "alpha": 0.5 if run.partial else 1.0, "label": None})
        if len(groups) > 1:
            legend = [(Line2D([], [], color="0.2", linestyle=styles[name]), name)
                      for name in groups]
        if any(run.partial for run in runs):
            legend.append((Line2D([], [], color="0.2", linewidth=0.8, alpha=0.5),
                           "partial run (thin, faded)"))
        distinct = sorted(set(values))
        return Styles(lines, legend, ScalarMappable(norm=norm, cmap=cmap),
                      _label(key, units), distinct if len(distinct) <= 12 else None)
    if len(runs) <= LEGEND_CAP:
        return Styles([{"color": f"C{i % 10}",
                        "label": f"{run.label} (partial)" if run.partial else run.label,
                        "linestyle": "--" if run.partial else "-", "linewidth": 1.2}
                       for i, run in enumerate(runs)])
    colours = {name: f"C{i % 10}" for i, name in enumerate(groups)}
    lines = []
    for run, point in zip(runs, points):
        group = _group_label(run.variant, point, others)
        lines.append({"color": colours[group], "linewidth": 0.7,
                      "alpha": max(0.15, min(0.8, 8.0 / len(groups[group]))),
                      "linestyle": "--" if run.partial else "-", "label": None})
    legend = [(Line2D([], [], color=colours[name], linewidth=1.5),
               f"{name} ({len(members)} runs)") for name, members in groups.items()]
    return Styles(lines, legend)


def _legend(figure: Any, ax: Any, entries: list[tuple[Any, str]] | None = None) -> None:
    """The legend below the axes (never over data): the runs' labelled lines of ``ax``,
    or ``entries`` (handle, label); at most :data:`LEGEND_CAP` entries, the rest counted
    in a last entry."""
    if entries is None:
        handles, labels = ax.get_legend_handles_labels()
    else:
        handles, labels = [h for h, _ in entries], [t for _, t in entries]
    if not handles:
        return
    if len(handles) > LEGEND_CAP:
        from matplotlib.lines import Line2D

        more = len(handles) - (LEGEND_CAP - 1)
        handles = handles[:LEGEND_CAP - 1] + [Line2D([], [], linestyle="none")]
        labels = labels[:LEGEND_CAP - 1] + [f"... and {more} more"]
    # at most 4 columns, and no more than fit the figure's width: a 'small' character
    # is about 4.6 pt wide and each entry adds about 6 characters of line and padding
    fit = int(figure.get_figwidth() * 72.0 / 4.6) // (max(map(len, labels)) + 6)
    figure.legend(handles, labels, loc="outside lower center", fontsize="small",
                  ncols=max(1, min(len(handles), 4, fit)), frameon=False)


def _colour_bar(figure: Any, axes: Iterable[Any], styles: Styles) -> None:
    if styles.mappable is None:
        return
    bar = figure.colorbar(styles.mappable, ax=list(axes), location="right", shrink=0.9,
                          pad=0.01, aspect=40)
    bar.set_label(styles.bar_label)
    if styles.bar_ticks is not None:
        bar.set_ticks(styles.bar_ticks)
        bar.minorticks_off()


def _save(figure: Any, path: Path, dpi: int) -> Path:
    """Draw ``figure`` as PNG in memory, then write it to ``path``: a figure that fails
    to draw leaves no file (never an empty image), one that fails to be written is
    removed."""
    import io

    from matplotlib import rc_context

    settings = dict(PLAIN_TEXT)
    if getattr(figure, "agv_decimated", False):
        # A decimated line of a long run can go from a column's minimum to its
        # maximum and back in every column; Agg's memory for one path grows with the
        # pixels its outline crosses (4 h run: +18.5 MiB to draw, +6.7 MiB in chunks
        # of 1000 points). Only such figures are drawn in chunks, so the others keep
        # their exact bytes.
        settings["agg.path.chunksize"] = _AGG_CHUNK
    image = io.BytesIO()
    with rc_context(settings):  # the ticks' labels are made as the figure is drawn
        figure.savefig(image, dpi=dpi, format="png", metadata={"Software": None})
    try:
        with open_output(path) as stream:  # never written through a symbolic link
            stream.write(image.getbuffer())
    except BaseException:
        Path(path).unlink(missing_ok=True)  # ours: open_output made or truncated it
        raise
    return path


@plain_text
def signals_figure(runs: Iterable["RunData"],
                   spec: "schema.PlotsTable | dict[str, Any] | None",
                   units: dict[str, str] | None = None,
                   sampled: Iterable[str] = ()) -> "Figure":
    """The figure of ``signals.png``: one subplot per signal, every run overlaid.

    Parameters
    ----------
    runs : list of RunData
        The runs to draw, in legend order.
    spec : dict
        The ``[plots]`` table; it must have ``signals``.
    units : dict of str to str, optional
        Units by signal name (the FMUs' declared units, :func:`fmu_units`); the table's
        ``units`` override them.
    sampled : collection of str
        Names of the sweep point that are Monte Carlo samples (not a sweep value).

    Returns
    -------
    matplotlib.figure.Figure
        The figure, on an Agg canvas. How the runs are told apart: :func:`run_styles`.
    """
    spec = _validate(spec)
    if "signals" not in spec:
        raise ValueError("plots.signals: missing")
    names = spec["signals"]
    units = {**(units or {}), **spec["units"]}
    units.setdefault("time", "s")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(_WIDTH, 1.0 + 2.0 * len(names)), layout="constrained")
    axes = figure.subplots(len(names), 1, sharex=True, squeeze=False)[:, 0]
    buckets = _buckets(spec)
    styles = run_styles(runs, units, sampled)
    for run, style in zip(runs, styles.lines):
        for i, (ax, name) in enumerate(zip(axes, names)):
            x, y = _line(run, spec["x"], name, "x", f"signals[{i}]", buckets, figure=figure)
            line, = ax.plot(x, y, **style)
            if spec["x"] == "time":
                for when, _ in run.events:
                    ax.axvline(when, color=line.get_color(), linestyle=":", linewidth=1.0)
    for ax, name in zip(axes, names):
        ax.set_ylabel(_label(name, units))
        ax.grid(True, linewidth=0.4, alpha=0.6)
    axes[-1].set_xlabel(_label(spec["x"], units))
    if spec["title"]:
        figure.suptitle(spec["title"])
    _colour_bar(figure, axes, styles)
    _legend(figure, axes[0], styles.legend if styles.legend or styles.mappable else None)
    FigureCanvasAgg(figure)
    return figure


def _trajectory(run: "RunData", traj: dict[str, Any], buckets: int,
                figure: Any = None) -> "Line":
    return _line(run, traj["x"], traj["y"], "trajectory.x", "trajectory.y", buckets, True,
                 figure)


def _reference_polyline(path: Any, runs: Iterable["RunData"], traj: dict[str, Any],
                        buckets: int) -> Any:
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


#: Most points per run projected onto the path for the lateral-offset panel.
_OFFSET_POINTS = 1500


def _offsets_along(geometry: Any, x: Floats, y: Floats) -> "Line":
    """Arc length [m] and signed offset [m] from ``geometry`` of up to
    :data:`_OFFSET_POINTS` of the points (x, y) (evenly strided, in order)."""
    from agv_core.numerics.paths import project_trajectory

    keep = np.isfinite(x) & np.isfinite(y)
    x, y = x[keep], y[keep]
    step = max(1, -(-len(x) // _OFFSET_POINTS))
    xs, ys = x[::step], y[::step]
    if len(x) and (len(x) - 1) % step:
        xs, ys = np.append(xs, x[-1]), np.append(ys, y[-1])
    offsets, arcs = project_trajectory(geometry, xs, ys)
    return arcs, offsets


#: Without a reference path the x-y panel has equal axis scales unless its data's smaller
#: extent is below this share of the larger (a 0.1 m deviation over 16 m is 0.006).
_EQUAL_AXES_MIN = 0.05


def _spans(ax: Any) -> tuple[float, float] | None:
    """(x extent, y extent) of the finite points drawn on ``ax``; None when it has none."""
    xs = [np.asarray(line.get_xdata(), float) for line in ax.get_lines()]
    ys = [np.asarray(line.get_ydata(), float) for line in ax.get_lines()]
    x = np.concatenate(xs) if xs else np.empty(0)
    y = np.concatenate(ys) if ys else np.empty(0)
    keep = np.isfinite(x) & np.isfinite(y)
    if not keep.any():
        return None
    x, y = x[keep], y[keep]
    return float(x.max() - x.min()), float(y.max() - y.min())


@plain_text
def trajectory_figure(runs: Iterable["RunData"],
                      spec: "schema.PlotsTable | dict[str, Any] | None",
                      geometry: Any = None, units: dict[str, str] | None = None,
                      sampled: Iterable[str] = ()) -> "Figure":
    """The figure of ``trajectory.png``: x-y of every run over the reference path and,
    with a path, each run's lateral offset from it along the path.

    Parameters
    ----------
    runs : list of RunData
        The runs to draw, in legend order.
    spec : dict
        The ``[plots]`` table; it must have ``trajectory``.
    geometry : agv_core.numerics.paths.ReferencePath, optional
        The reference path to draw (parsed from ``trajectory.path`` by :func:`plot_runs`).
        With it a second panel shows the signed offset [m] (positive left of the path)
        against the arc length [m] of each run's point projected onto the path: equal
        axes hide a 0.3 m offset over 45 m of path, this panel does not.
    units : dict of str to str, optional
        Units by signal name (see :func:`signals_figure`).
    sampled : collection of str
        Names of the sweep point that are Monte Carlo samples.

    Returns
    -------
    matplotlib.figure.Figure
        The figure, on an Agg canvas.
    """
    spec = _validate(spec)
    if "trajectory" not in spec:
        raise ValueError("plots.trajectory: missing")
    traj = spec["trajectory"]
    units = {**(units or {}), **spec["units"]}
    buckets = _buckets(spec, trajectory=True)
    styles = run_styles(runs, units, sampled)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    if geometry is None:
        figure = Figure(figsize=(_WIDTH, 6.0), layout="constrained")
        ax = figure.add_subplot()
        axes = [ax]
    else:
        figure = Figure(figsize=(_WIDTH, 8.5), layout="constrained")
        ax, offset_ax = figure.subplots(2, 1, height_ratios=(3.0, 1.6))
        axes = [ax, offset_ax]
        polyline = _reference_polyline(geometry, runs, traj, buckets)
        if polyline is not None:
            ax.plot(polyline[0], polyline[1], color="0.55", linewidth=2.5, alpha=0.7,
                    label="reference path", zorder=1)
        offset_ax.axhline(0.0, color="0.55", linewidth=2.0, alpha=0.7, zorder=1)
    for run, style in zip(runs, styles.lines):
        x, y = _trajectory(run, traj, buckets, figure)
        ax.plot(x, y, zorder=2, **style)
        if geometry is not None:
            arcs, offsets = _offsets_along(geometry, np.asarray(x, float),
                                           np.asarray(y, float))
            offset_ax.plot(arcs, offsets, zorder=2, **dict(style, label=None))
    spans = _spans(ax) if geometry is None else None
    if spans is not None and min(spans) < _EQUAL_AXES_MIN * max(spans):
        # equal axes would draw what moved as a flat line: each axis scaled to its data
        ax.set_title(f"axes not to scale: x spans {spans[0]:.3g}, y {spans[1]:.3g}",
                     fontsize="small", loc="right", color="0.3")
    else:
        ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(_label(traj["x"], units))
    ax.set_ylabel(_label(traj["y"], units))
    ax.grid(True, linewidth=0.4, alpha=0.6)
    if geometry is not None:
        offset_ax.set_xlabel("arc length along the reference path [m]")
        offset_ax.set_ylabel("offset from path [m]\n(+ left)")
        offset_ax.grid(True, linewidth=0.4, alpha=0.6)
    if spec["title"]:
        figure.suptitle(spec["title"])
    _colour_bar(figure, axes, styles)
    if styles.legend or styles.mappable:
        entries = list(styles.legend)
        if geometry is not None:
            from matplotlib.lines import Line2D

            entries.insert(0, (Line2D([], [], color="0.55", linewidth=2.5, alpha=0.7),
                               "reference path"))
        _legend(figure, ax, entries)
    else:
        _legend(figure, ax)
    FigureCanvasAgg(figure)
    return figure


def sampled_names(folder: str | Path) -> list[str]:
    """Names a Monte Carlo result in ``folder`` samples (its ``montecarlo.json``:
    ``parameters`` and ``seeds``); empty without one."""
    data = read_json_object(Path(folder) / "montecarlo.json") or {}
    return list(data.get("parameters") or {}) + list(data.get("seeds") or [])


def describe_runs(runs: list["RunData"], folder: str | Path) -> dict[str, str]:
    """Fill each run's ``variant`` and ``point`` that are None from its
    ``<folder>/<label>/run.json``; return the FMU paths the runs name (component ->
    path, run.json's ``fmus``)."""
    fmus: dict[str, str] = {}
    for run in runs:
        info = read_json_object(Path(folder) / run.label / "run.json") or {}
        if run.variant is None:
            run.variant = info.get("variant")
        if run.point is None:
            point = info.get("sweep_point")
            run.point = point if isinstance(point, dict) else {}
        named = info.get("fmus")  # a damaged run.json's: no FMU known
        for component, path in (named if isinstance(named, dict) else {}).items():
            fmus.setdefault(component, path)
    return fmus


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
    written: list[Path] = []
    if "signals" not in spec and "trajectory" not in spec:
        return written
    # the runs' variants, sweep points and FMUs: from their run.json (when written)
    units = fmu_units(describe_runs(runs, out_dir), base_dir)
    sampled = sampled_names(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if "signals" in spec:
        written.append(_save(signals_figure(runs, raw, units, sampled),
                             out_dir / SIGNALS_FILE, spec["dpi"]))
    if "trajectory" in spec:
        written.append(_save(trajectory_figure(runs, raw, geometry, units, sampled),
                             out_dir / TRAJECTORY_FILE, spec["dpi"]))
    return written


# --------------------------------------------------------------------------- comparisons
#
# Figures drawn from the runs' metrics (run.json and metrics.json of a result folder,
# read by agv_cosim.report.page), not from their time series.

#: File names of the comparison figures.
SWEEP_FILE = "sweep_metrics.png"
MONTECARLO_SCATTER_FILE = "montecarlo_scatter.png"


def _finite(value: object) -> bool:
    return is_number(value)


#: The note of a sweep panel with runs without a value (marked on its top edge).
_MISSING_NOTE = {True: "\u25bd on the top edge: did not settle (or no value)",
                 False: "\u25bd on the top edge: no value (docs/metrics.md)"}


@plain_text
def sweep_metrics_figure(rows: list[dict[str, Any]], key: str, metrics: list[str],
                         units: dict[str, str],
                         title: str | None = None) -> "Figure":
    """Each metric against the swept value ``key``, one line (with markers) per group:
    the variant and the other swept values.

    Parameters
    ----------
    rows : list of dict
        One per run: ``variant`` (str or None), ``point`` (sweep point), ``status``,
        ``metrics`` (name -> value). Complete runs with a finite value are drawn on the
        lines; the others (a settling time of a run that never settled, a run not
        complete) as open triangles on the panel's top edge, noted in its title.
    key : str
        The swept key on the x axis (its values numbers).
    metrics : list of str
        The metrics drawn, one panel each.
    units : dict of str to str
        Units of the swept key and of the metrics, by name.
    title : str, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    points = [row["point"] for row in rows]
    others = [k for k in sweep_keys(points) if k != key]
    cols = 2 if len(metrics) > 3 else 1
    nrows = -(-len(metrics) // cols)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(_WIDTH, 0.8 + 2.4 * nrows), layout="constrained")
    axes = figure.subplots(nrows, cols, squeeze=False).ravel()
    groups: dict[str, list[dict[str, Any]]] = {}
    for row in rows:
        groups.setdefault(_group_label(row["variant"], row["point"], others), []).append(row)
    for ax, metric in zip(axes, metrics):
        any_missing = False
        for i, (name, members) in enumerate(groups.items()):
            pairs = sorted((row["point"][key], row["metrics"].get(metric))
                           for row in members if row["status"] == "complete"
                           and is_number(row["point"].get(key))
                           and _finite(row["metrics"].get(metric)))
            if pairs:
                ax.plot([p[0] for p in pairs], [p[1] for p in pairs], marker="o",
                        markersize=4, linewidth=1.2, color=f"C{i % 10}",
                        linestyle=_LINESTYLES[(i // 10) % len(_LINESTYLES)], label=name)
            missing = sorted(row["point"][key] for row in members
                             if is_number(row["point"].get(key))
                             and not (row["status"] == "complete"
                                      and _finite(row["metrics"].get(metric))))
            if missing:  # marked on the top edge, so a line does not just stop
                any_missing = True
                ax.plot(missing, [1.0] * len(missing), linestyle="none", marker="v",
                        markersize=7, markerfacecolor="none", markeredgewidth=1.4,
                        color=f"C{i % 10}", transform=ax.get_xaxis_transform(),
                        clip_on=False)
        if any_missing:
            settling = metric.endswith("_settling_time") or "_settled_" in metric
            ax.set_title(_MISSING_NOTE[settling],
                         fontsize="x-small", loc="right", color="0.3")
        ax.set_ylabel(_label(metric, units), fontsize="small")
        ax.set_xlabel(_label(key, units), fontsize="small")
        ax.grid(True, linewidth=0.4, alpha=0.6)
    for ax in axes[len(metrics):]:
        ax.set_visible(False)
    figure.suptitle((title + ": " if title else "") + f"metrics against {key}",
                    fontsize="medium")
    _legend(figure, axes[0])
    FigureCanvasAgg(figure)
    return figure


def spearman(x: Any, y: Any) -> float | None:
    """Spearman's rank correlation of ``x`` and ``y`` (``scipy.stats.spearmanr``); None
    with fewer than 3 pairs or a constant side."""
    from scipy.stats import spearmanr

    x, y = np.asarray(x, float), np.asarray(y, float)
    if x.size < 3 or np.all(x == x[0]) or np.all(y == y[0]):
        return None
    rho = float(spearmanr(x, y).statistic)
    return rho if math.isfinite(rho) else None


@plain_text
def montecarlo_figure(rows: list[dict[str, Any]], parameters: list[str], metrics: list[str],
                      units: dict[str, str],
                      title: str | None = None) -> "Figure":
    """Monte Carlo results: per metric (one row of panels), box plots per group in the
    metric's unit, then a scatter of the metric against each sampled parameter with
    Spearman's rank correlation rho per group.

    Parameters
    ----------
    rows : list of dict
        One per run: ``group`` (variant and sweep point), ``point`` (with the sampled
        values), ``status``, ``metrics``. Only complete runs with finite values count.
    parameters : list of str
        The sampled parameters (x of the scatters).
    metrics : list of str
        The metrics, one row each.
    units : dict of str to str
        Units of the parameters and metrics, by name.
    title : str, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    groups = list(dict.fromkeys(row["group"] for row in rows))
    cols = 1 + len(parameters)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(max(_WIDTH, 2.9 * cols), 0.9 + 2.7 * len(metrics)),
                    layout="constrained")
    axes = figure.subplots(len(metrics), cols, squeeze=False)
    for r, metric in enumerate(metrics):
        good = [row for row in rows if row["status"] == "complete"
                and _finite(row["metrics"].get(metric))]
        box = axes[r, 0]
        data = [[row["metrics"][metric] for row in good if row["group"] == g]
                for g in groups]
        shown = [(i, g, d) for i, (g, d) in enumerate(zip(groups, data)) if d]
        if shown:
            parts = box.boxplot([d for _, _, d in shown], whis=(5, 95),
                                patch_artist=True, widths=0.6)
            for patch, (i, _, _) in zip(parts["boxes"], shown):
                patch.set_facecolor(f"C{i % 10}")
                patch.set_alpha(0.45)
            box.set_xticks(range(1, len(shown) + 1),
                           [g if len(g) <= 18 else g[:17] + "…" for _, g, _ in shown],
                           rotation=20 if len(shown) > 2 else 0, fontsize="x-small")
        box.set_ylabel(_label(metric, units), fontsize="small")
        box.grid(True, axis="y", linewidth=0.4, alpha=0.6)
        for c, parameter in enumerate(parameters, start=1):
            ax = axes[r, c]
            notes = []
            for i, g in enumerate(groups):
                pairs = [(row["point"].get(parameter), row["metrics"][metric])
                         for row in good if row["group"] == g
                         and _finite(row["point"].get(parameter))]
                if not pairs:
                    continue
                x, y = zip(*pairs)
                ax.scatter(x, y, s=10, color=f"C{i % 10}", alpha=0.7, linewidths=0,
                           label=g)
                rho = spearman(x, y)
                notes.append((f"C{i % 10}", "rho n/a" if rho is None else
                              f"rho = {rho:+.2f}"))
            for k, (colour, text) in enumerate(notes):
                ax.text(0.02, 0.97 - 0.11 * k, text, transform=ax.transAxes,
                        color=colour, fontsize="x-small", va="top",
                        bbox={"facecolor": "white", "alpha": 0.7, "linewidth": 0,
                              "pad": 1.0})
            ax.set_xlabel(_label(parameter, units), fontsize="small")
            ax.tick_params(labelsize="x-small")
            ax.grid(True, linewidth=0.4, alpha=0.6)
    n = max((sum(1 for row in rows if row["group"] == g) for g in groups), default=0)
    figure.suptitle((title + ": " if title else "") + f"Monte Carlo, {n} samples per group "
                    "(box: p25-p75, whiskers p5-p95; rho: Spearman rank correlation)",
                    fontsize="medium")
    if len(groups) > 1:
        from matplotlib.lines import Line2D

        _legend(figure, axes[0, 0], [(Line2D([], [], marker="o", linestyle="none",
                                             color=f"C{i % 10}"), g)
                                     for i, g in enumerate(groups)])
    FigureCanvasAgg(figure)
    return figure


def save_figure(figure: "Figure", path: str | Path, dpi: int = DEFAULT_DPI) -> Path:
    """Write ``figure`` as a PNG at ``path`` (fixed metadata: same figure, same bytes;
    never through a symbolic link)."""
    return _save(figure, Path(path), dpi)
