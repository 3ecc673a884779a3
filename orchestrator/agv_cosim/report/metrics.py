"""Path-tracking metrics computed from a run's recorded signals.

:func:`compute_metrics` takes a run's time grid, its recorded signals (named
``"component.variable"``) and the manifest's ``[metrics]`` table; the orchestrator calls
:func:`compute_metrics_csv`, the same computation streamed from the run's
``timeseries.csv`` (see "Bounded memory"), and :func:`referenced_signals` beforehand to
know what it must record.

The ``[metrics]`` table
-----------------------
Every key is optional; a metric is computed only when the signals it needs are named.

``lateral_error`` : str
    Signal of the signed lateral error e [m] (e.g. ``"sensor.lateral_error"``). Gives the
    ``lateral_error_*`` metrics.
``reference`` : table
    ``{path = "<path string>", x = "<signal>", y = "<signal>"}``: the lateral error is
    computed geometrically, as the signed offset of the recorded point (x, y) [m] from the
    path ``agv_core.numerics.paths.parse_path(path)`` (positive left of the path). Gives the
    ``path_error_*`` metrics (same set as ``lateral_error_*``), so a measured and a true
    lateral error can be reported side by side.
``heading_error`` : str
    Signal of the heading error [rad]. Gives ``heading_error_rms``, ``heading_error_max``.
``steering_angle`` : str
    Signal of the steered-wheel angle alpha [rad]. Gives ``steering_angle_peak``,
    ``steering_angle_rms``.
``steering_rate`` : str
    Signal of the steering rate [rad/s]. Gives ``steering_rate_peak``, ``steering_rate_rms``.
    It is never derived from ``steering_angle`` by finite differences (which would amplify
    noise and the step changes of a zero-order hold): record the actuator's rate output.
``control`` : str
    Signal of the controller's command u (e.g. [V]). Gives ``control_effort``,
    ``control_peak``, ``control_rms``.
``settle_band`` : float, default 0.02
    Band [m] of the lateral error: settled once |e| stays within it (> 0).
``settle_after`` : float, optional
    Fixed start [s] of the "after settling" window, measured from the first sample. When
    absent the window starts at the settling time.
``saturation`` : table
    ``{signal = "<signal>", limit = <float > 0>, tolerance = <float >= 0, optional>}``: gives
    ``saturated_fraction`` and ``saturated_time``. A sample counts as saturated when
    ``|signal| >= limit - tolerance``; the default tolerance is ``1e-9 * limit`` so that a
    signal clipped exactly at the limit counts.

Complete example::

    [metrics]
    lateral_error = "sensor.lateral_error"
    heading_error = "sensor.heading_error"
    steering_angle = "act.alpha"
    steering_rate = "act.alpha_rate"
    control = "ctrl.u"
    settle_band = 0.02
    settle_after = 5.0
    saturation = { signal = "act.alpha", limit = 0.785 }
    reference = { path = "sine:amplitude=2,wavelength=18.85", x = "vehicle.x", y = "vehicle.y" }

Definitions
-----------
Times are integrated over the recorded (possibly non-uniform) grid t_0 < ... < t_N with
signals taken as piecewise linear between samples; T = t_N - t_0; integrals use the
trapezoidal rule, except that |e| is integrated exactly for the piecewise-linear e (the
trapezoidal rule would overestimate a piece that crosses zero).

For a lateral-error signal e (prefix ``P`` = ``lateral_error`` or ``path_error``):

``P_max``
    max |e| [m].
``P_mean``
    time-weighted mean of |e|: (1/T) integral |e| dt [m].
``P_rms``
    sqrt((1/T) integral e^2 dt) [m].
``P_signed_mean``
    time-weighted mean of e: m = (1/T) integral e dt [m] (trapezoidal, exact for the
    piecewise-linear e). The sign says on which side of the path e lies on average.
``P_std``
    time-weighted (population) standard deviation of e about ``P_signed_mean``:
    sqrt((1/T) integral (e - m)^2 dt) [m], trapezoidal like ``P_rms``, so that
    ``P_rms``^2 = ``P_signed_mean``^2 + ``P_std``^2 up to rounding.
``P_settling_time``
    t_s - t_0 [s], where t_s is the first time after which |e| <= ``settle_band`` for good;
    the crossing is interpolated linearly between the last sample outside the band and
    the next one. 0 when |e| never leaves the band.
``P_settled_max``, ``P_settled_mean``, ``P_settled_rms``, ``P_settled_signed_mean``,
``P_settled_std``
    the five above (all but the settling time) over the window [t_0 + w, t_N],
    w = ``settle_after`` if given, otherwise the settling time; the window's first value
    is interpolated.
``P_overshoot``
    largest excursion past zero opposite to the sign of the initial error e(t_0):
    max(0, max(-sign(e(t_0)) e)) [m].
``P_overshoot_ratio``
    ``P_overshoot`` / |e(t_0)| [1]. For a second-order response with damping ratio zeta it
    is exp(-zeta pi / sqrt(1 - zeta^2)).

``heading_error_rms``, ``heading_error_max`` [rad]; ``steering_angle_peak`` (max |alpha|),
``steering_angle_rms`` [rad]; ``steering_rate_peak``, ``steering_rate_rms`` [rad/s];
``control_effort`` = integral u^2 dt [unit(u)^2 s], ``control_peak`` = max |u|,
``control_rms``; ``saturated_fraction`` [1] = (time with |signal| >= limit - tolerance) / T,
exact for the piecewise-linear signal; ``saturated_time`` [s] that time; ``duration`` = T [s].

Bounded memory
--------------
:func:`compute_metrics` takes whole arrays; :func:`compute_metrics_csv` (what a run uses)
computes the same result from a ``timeseries.csv`` with memory that does not grow with the
run's length. It reads the file once in chunks of ``timeseries.CHUNK_ROWS`` rows and spools
the signals the metrics use (and the path offsets of ``reference``, computed on the way
with the projection hint carried across chunks) as float64 to anonymous temporary files
on disk. Everything is then computed from chunks of that spool, each chunk with the
previous sample prepended so that every piece between two samples is the one of the whole
signal:

- maxima, the initial error, the overshoot and the last sample outside the settling band
  are order-free (one pass; the settling time is interpolated from that sample and the
  next, read back from the spool);
- every integral (mean, RMS, |e| mean, effort, saturated time) is the sum of the same
  per-piece terms in the same order as ``numpy.sum`` adds them (:class:`PairwiseSum`
  walks numpy's pairwise-summation tree, whose shape depends only on the count, known
  after the first read);
- quantities that need a value known only at the end take another pass over the spool:
  the standard deviation (about the mean), the settled window (which starts at the
  settling time; its interpolated first sample is computed with ``numpy.interp`` on the
  two samples around it), and the settled standard deviation (a third pass).

So the streamed result equals :func:`compute_metrics` bit for bit (no tolerance), which
``tests/orchestrator/report/test_metrics_streaming.py`` checks with chunk boundaries on the
settling and overshoot samples (and :class:`PairwiseSum` against ``numpy.sum``, so a numpy
that changed its summation order would be caught there). Memory: a chunk, the per-level partial sums
(about log2(n / 128)) and one pending block of at most 128 values per sum. Disk: 8 bytes
per sample per spooled signal.

Undefined values
----------------
The result never holds NaN or inf: a metric that is undefined is reported as ``None``
(JSON ``null``), namely

- every time-averaged metric (mean, signed mean, standard deviation, RMS, effort,
  fraction) of a run with T = 0;
- ``P_settling_time`` when e never settles (its last sample is outside the band);
- the ``P_settled_*`` metrics when their window is empty (``settle_after`` >= T) or, without
  ``settle_after``, when e never settles;
- ``P_overshoot`` and ``P_overshoot_ratio`` when e(t_0) = 0 (no initial sign);
- any metric of a signal that has non-finite samples.
"""

import math
import tempfile
from collections.abc import Callable, Generator, Iterable, Iterator
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import IO, Any

import numpy as np
import numpy.typing as npt

from .. import timeseries
from ..manifest import schema

#: A float64 signal, its samples or its pieces.
Floats = npt.NDArray[np.float64]
#: Metric name -> value (None where undefined).
MetricValues = dict[str, float | None]

_SIGNAL_KEYS = ("lateral_error", "heading_error", "steering_angle", "steering_rate", "control")


# --------------------------------------------------------------------------- reference

@dataclass(frozen=True)
class MetricDoc:
    """What a metric is: the reference docs/metrics.md shows (a test keeps them equal)."""

    #: the unit documented (the report uses the recorded signal's unit where it declares
    #: one: ``unit(u)`` is the control signal's)
    unit: str
    #: the definition, with its formula
    definition: str
    #: when the value is empty (``None``: JSON null, an empty cell of summary.csv)
    empty: str


_NONFINITE = "the signal has a non-finite sample"
_AVERAGE = f"T = 0 (one sample), or {_NONFINITE}"
_UNSETTLED = ("e never settles (its last sample is outside the band; the report writes "
              "\"did not settle\")")


def _lateral_docs(prefix: str, what: str) -> dict[str, MetricDoc]:
    window = ("over the settled window [t_0 + w, t_N], w = settle_after if given, else the "
              "settling time; its first value interpolated")
    settled_empty = (f"the window is empty: {_UNSETTLED} without settle_after, or "
                     f"settle_after >= T; or {_NONFINITE}")
    docs = {
        "max": ("m", f"peak |e| of {what}: max |e|", _NONFINITE),
        "mean": ("m", f"time-weighted mean of |e| of {what}: (1/T) integral |e| dt (exact "
                 "for the piecewise-linear e)", _AVERAGE),
        "rms": ("m", f"root mean square of {what}: sqrt((1/T) integral e^2 dt)", _AVERAGE),
        "signed_mean": ("m", f"time-weighted mean of {what} with its sign: m = (1/T) "
                        "integral e dt (positive: left of the path on average)", _AVERAGE),
        "std": ("m", f"time-weighted standard deviation of {what} about its signed mean: "
                "sqrt((1/T) integral (e - m)^2 dt)", _AVERAGE),
        "settling_time": ("s", "t_s - t_0, t_s the first time after which |e| <= "
                          "settle_band for good (interpolated between samples); 0 when "
                          "|e| never leaves the band", f"{_UNSETTLED}; or {_NONFINITE}"),
        "settled_max": ("m", f"max |e| {window}; without settle_after it is the band itself "
                        "whenever e settles (the window starts on the band's edge)",
                        settled_empty),
        "settled_mean": ("m", f"time-weighted mean of |e| {window}", settled_empty),
        "settled_rms": ("m", f"root mean square of e {window}", settled_empty),
        "settled_signed_mean": ("m", f"time-weighted mean of e with its sign {window}: the "
                                "steady offset", settled_empty),
        "settled_std": ("m", f"standard deviation of e about its mean {window}",
                        settled_empty),
        "overshoot": ("m", "largest excursion past zero opposite to the initial error: "
                      "max(0, max(-sign(e(t_0)) e))",
                      f"e(t_0) = 0 (no initial sign); or {_NONFINITE}"),
        "overshoot_ratio": ("1", "overshoot / |e(t_0)|; exp(-zeta pi / sqrt(1 - zeta^2)) "
                            "for a second-order response of damping ratio zeta",
                            f"e(t_0) = 0 (no initial sign); or {_NONFINITE}"),
    }
    return {f"{prefix}_{name}": MetricDoc(*text) for name, text in docs.items()}


#: Every metric :func:`compute_metrics` can produce, in the order of docs/metrics.md: name
#: -> :class:`MetricDoc`. e is the ``[metrics]`` signal, T = t_N - t_0, integrals over the
#: recorded grid with the signal piecewise linear (trapezoidal rule).
METRICS: dict[str, MetricDoc] = {
    **_lateral_docs("lateral_error", "the lateral error e (the [metrics] lateral_error "
                    "signal)"),
    **_lateral_docs("path_error", "the path error e: the recorded point's signed offset "
                    "from the [metrics] reference path"),
    "heading_error_rms": MetricDoc("rad", "root mean square of the heading error: "
                                   "sqrt((1/T) integral psi_e^2 dt)", _AVERAGE),
    "heading_error_max": MetricDoc("rad", "peak |heading error|", _NONFINITE),
    "steering_angle_peak": MetricDoc("rad", "peak |alpha| of the steering angle",
                                     _NONFINITE),
    "steering_angle_rms": MetricDoc("rad", "root mean square of the steering angle",
                                    _AVERAGE),
    "steering_rate_peak": MetricDoc("rad/s", "peak |steering rate| (the recorded rate "
                                    "signal, never differentiated)", _NONFINITE),
    "steering_rate_rms": MetricDoc("rad/s", "root mean square of the steering rate",
                                   _AVERAGE),
    "control_effort": MetricDoc("unit(u)^2 s", "integral u^2 dt of the control signal u "
                                "(e.g. V^2 s for a voltage)", f"one sample, or {_NONFINITE}"),
    "control_peak": MetricDoc("unit(u)", "peak |u| of the control signal", _NONFINITE),
    "control_rms": MetricDoc("unit(u)", "root mean square of the control signal: "
                             "sqrt((1/T) integral u^2 dt)", _AVERAGE),
    "saturated_fraction": MetricDoc("1", "share of the time with |signal| >= limit - "
                                    "tolerance (saturated_time / T)", _AVERAGE),
    "saturated_time": MetricDoc("s", "time with |signal| >= limit - tolerance (exact for "
                                "the piecewise-linear signal)", _NONFINITE),
    "duration": MetricDoc("s", "T = t_N - t_0, the recorded span", "never empty"),
}


# --------------------------------------------------------------------------- validation

def _validate(spec: "schema.MetricsTable | dict[str, Any] | None") -> dict[str, Any]:
    """``spec`` normalised (defaults filled in): a :class:`~agv_cosim.manifest.schema.MetricsTable`
    as the manifest's schema checked it, or a plain ``[metrics]`` table checked here (a
    problem is a ValueError naming ``metrics.<key>``)."""
    if isinstance(spec, schema.MetricsTable):
        return spec.spec()
    return schema.check(schema.MetricsTable, {} if spec is None else spec, "metrics").spec()


def referenced_signals(spec: "schema.MetricsTable | dict[str, Any] | None") -> list[str]:
    """Every signal ``"component.variable"`` that the ``[metrics]`` table names.

    Parameters
    ----------
    spec : dict
        The ``[metrics]`` table (see the module docstring).

    Returns
    -------
    list of str
        The names, each once, in the order the table's keys define them.

    Raises
    ------
    ValueError
        If the table is malformed (the message names the key).
    """
    spec = _validate(spec)
    names = [spec[key] for key in _SIGNAL_KEYS if key in spec]
    if "saturation" in spec:
        names.append(spec["saturation"]["signal"])
    if "reference" in spec:
        names += [spec["reference"]["x"], spec["reference"]["y"]]
    return list(dict.fromkeys(names))


# --------------------------------------------------------------------------- numerics

def _integral(t: Floats, f: Floats) -> float:
    """Trapezoidal integral of samples ``f`` over the grid ``t``."""
    if len(t) < 2:
        return 0.0
    return float(np.sum(0.5 * (f[1:] + f[:-1]) * np.diff(t)))


def _time_mean(t: Floats, f: Floats) -> float | None:
    """(1/T) integral f dt, or None when T = 0."""
    duration = float(t[-1] - t[0])
    return _integral(t, f) / duration if duration > 0 else None


def _rms(t: Floats, f: Floats) -> float | None:
    mean_square = _time_mean(t, f * f)
    return math.sqrt(mean_square) if mean_square is not None else None


def _mean_and_std(t: Floats, f: Floats) -> tuple[float | None, float | None]:
    """Time-weighted mean of f and standard deviation about it, or (None, None) when T = 0."""
    mean = _time_mean(t, f)
    if mean is None:
        return None, None
    deviation = f - mean
    variance = _time_mean(t, deviation * deviation)
    assert variance is not None  # the same T > 0 as the mean's
    return mean, math.sqrt(max(0.0, variance))


def _abs_mean(t: Floats, f: Floats) -> float | None:
    """Time-weighted mean of |f| for piecewise-linear f (exact across sign changes)."""
    duration = float(t[-1] - t[0])
    if duration <= 0:
        return None
    area = _abs_pieces(f) * np.diff(t)
    return float(np.sum(area)) / duration


def _abs_pieces(f: Floats) -> Floats:
    """Mean of |f| over each linear piece between consecutive samples (exact)."""
    a, b = f[:-1], f[1:]
    same = a * b >= 0
    with np.errstate(divide="ignore", invalid="ignore"):
        # a linear piece through zero: two triangles, (a^2 + b^2) / (2 |a - b|) * dt
        crossing = (a * a + b * b) / (2.0 * np.abs(a - b))
    return np.where(same, 0.5 * (np.abs(a) + np.abs(b)), crossing)


def _measure_at_least(a: Floats, b: Floats, threshold: float) -> Floats:
    """Fraction of [0, 1] where the line a + (b - a) tau >= threshold (elementwise)."""
    slope = b - a
    with np.errstate(divide="ignore", invalid="ignore"):
        tau = np.clip((threshold - a) / slope, 0.0, 1.0)
    flat = np.where(a >= threshold, 1.0, 0.0)
    return np.where(slope > 0, 1.0 - tau, np.where(slope < 0, tau, flat))


def saturated_time(t: np.ndarray, f: np.ndarray, threshold: float) -> float:
    """Time [s] during which |f| >= ``threshold`` (> 0), f piecewise linear over ``t``."""
    if len(t) < 2:
        return 0.0
    return float(np.sum(_saturated_fractions(f, threshold) * np.diff(t)))


def _saturated_fractions(f: Floats, threshold: float) -> Floats:
    """Fraction of each linear piece between consecutive samples where |f| >= threshold."""
    a, b = f[:-1], f[1:]
    return _measure_at_least(a, b, threshold) + _measure_at_least(-a, -b, threshold)


def settling_time(t: np.ndarray, e: np.ndarray, band: float) -> float | None:
    """First time after which |e| <= band for good, or None if the last sample is outside.

    The crossing is interpolated linearly between the last sample outside the band and
    the next one. Returns ``t[0]`` when no sample is outside the band.
    """
    outside = np.flatnonzero(np.abs(e) > band)
    if outside.size == 0:
        return float(t[0])
    k = int(outside[-1])
    if k == len(e) - 1:
        return None
    target = math.copysign(band, e[k])
    tau = (target - e[k]) / (e[k + 1] - e[k])
    return float(t[k] + tau * (t[k + 1] - t[k]))


def _window(t: Floats, f: Floats, start: float) -> tuple[Floats, Floats] | None:
    """Samples of f over [start, t[-1]], with an interpolated first sample at ``start``."""
    if start >= t[-1]:
        return None
    k = int(np.searchsorted(t, start, side="right"))
    value = float(np.interp(start, t, f))
    return np.concatenate(([start], t[k:])), np.concatenate(([value], f[k:]))


def _lateral_metrics(prefix: str, t: Floats, e: Floats, band: float,
                     settle_after: float | None) -> MetricValues:
    out: MetricValues = {
        f"{prefix}_max": float(np.max(np.abs(e))),
        f"{prefix}_mean": _abs_mean(t, e),
        f"{prefix}_rms": _rms(t, e),
    }
    out[f"{prefix}_signed_mean"], out[f"{prefix}_std"] = _mean_and_std(t, e)
    t_settle = settling_time(t, e, band)
    out[f"{prefix}_settling_time"] = None if t_settle is None else t_settle - float(t[0])
    start = float(t[0]) + settle_after if settle_after is not None else t_settle
    window = None if start is None else _window(t, e, start)
    if window is None:
        out.update({f"{prefix}_settled_{name}": None
                    for name in ("max", "mean", "rms", "signed_mean", "std")})
    else:
        tw, ew = window
        out[f"{prefix}_settled_max"] = float(np.max(np.abs(ew)))
        out[f"{prefix}_settled_mean"] = _abs_mean(tw, ew)
        out[f"{prefix}_settled_rms"] = _rms(tw, ew)
        out[f"{prefix}_settled_signed_mean"], out[f"{prefix}_settled_std"] = \
            _mean_and_std(tw, ew)
    e0 = float(e[0])
    if e0 == 0.0:
        out[f"{prefix}_overshoot"] = out[f"{prefix}_overshoot_ratio"] = None
    else:
        overshoot = max(0.0, float(np.max(-math.copysign(1.0, e0) * e)))
        out[f"{prefix}_overshoot"] = overshoot
        out[f"{prefix}_overshoot_ratio"] = overshoot / abs(e0)
    return out


def load_path(path: str, key: str, base_dir: str | Path | None = None) -> Any:
    """``agv_core.numerics.paths.parse_path(path)``, with a bad path string as ValueError
    naming ``key``.

    Parameters
    ----------
    path : str
        Path string.
    key : str
        Spec key the string came from, for the message.
    base_dir : str or pathlib.Path, optional
        Folder that relative file names in the path string (waypoints) are relative to.
    """
    from agv_core.errors import ParameterError
    from agv_core.numerics.paths import parse_path

    try:
        return parse_path(path, base_dir=base_dir)
    except ParameterError as error:
        raise ValueError(f"{key}: {error}") from None


def path_offsets(path: Any, x: np.ndarray, y: np.ndarray,
                 base_dir: str | Path | None = None) -> np.ndarray:
    """Signed offsets [m] of the points (x, y) from ``path`` (positive left of it).

    Each point is projected with the previous point's arc length as the hint, so a path
    that comes close to itself is followed continuously.

    Parameters
    ----------
    path : str
        Path string understood by ``agv_core.numerics.paths.parse_path``.
    x, y : numpy.ndarray
        Coordinates [m] of the tracked point.
    base_dir : str or pathlib.Path, optional
        Folder that relative file names in ``path`` are relative to.
    """
    geometry = load_path(path, "metrics.reference.path", base_dir)
    return _offsets(geometry, x, y, None)[0]


def _offsets(geometry: Any, x: Floats, y: Floats,
             s_hint: float | None) -> tuple[Floats, float | None]:
    """Offsets of (x, y) from ``geometry`` and the last point's arc length (next hint)."""
    from agv_core.numerics.paths import project_trajectory

    offsets, arcs = project_trajectory(geometry, x, y, s_hint)
    return offsets, (float(arcs[-1]) if len(arcs) else s_hint)


def _clean(metrics: dict[str, Any]) -> MetricValues:
    return {key: (None if value is None or not math.isfinite(value) else float(value))
            for key, value in metrics.items()}


def _get(signals: dict[str, np.ndarray], name: str, key: str, n: int) -> Floats:
    if name not in signals:
        raise ValueError(f"metrics.{key}: signal {name!r} is not in the results")
    values = np.asarray(signals[name], dtype=float)
    if values.shape != (n,):
        raise ValueError(f"metrics.{key}: signal {name!r} has shape {values.shape}, "
                         f"the time grid ({n},)")
    return values


#: The metrics of ``lateral_error`` and ``reference`` (prefixed ``lateral_error_``,
#: ``path_error_``), in the order a result holds them.
_LATERAL_NAMES = ("max", "mean", "rms", "signed_mean", "std", "settling_time",
                  "settled_max", "settled_mean", "settled_rms", "settled_signed_mean",
                  "settled_std", "overshoot", "overshoot_ratio")


def _time_grid(time: np.ndarray) -> Floats:
    """``time`` as a float array, checked: non-empty, 1-D, finite, strictly increasing."""
    t = np.asarray(time, dtype=float)
    if t.ndim != 1 or t.size == 0:
        raise ValueError("metrics: time must be a non-empty 1-D array")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise ValueError("metrics: time must be finite and strictly increasing")
    return t


def _measured(ok: bool, names: Iterable[str],
              measure: Callable[[], dict[str, Any]]) -> dict[str, Any]:
    """``measure()`` if ``ok``, else every metric of ``names`` None (a signal with a
    non-finite sample has no metrics)."""
    return measure() if ok else {name: None for name in names}


def _if_finite(values: np.ndarray, names: Iterable[str],
               measure: Callable[[], dict[str, Any]]) -> dict[str, Any]:
    """``measure()``, or every metric of ``names`` None when ``values`` has a
    non-finite sample."""
    return _measured(bool(np.all(np.isfinite(values))), names, measure)


def _heading_metrics(t: Floats, h: Floats) -> dict[str, Any]:
    return {"heading_error_rms": _rms(t, h), "heading_error_max": float(np.max(np.abs(h)))}


def _steering_angle_metrics(t: Floats, alpha: Floats) -> dict[str, Any]:
    return {"steering_angle_peak": float(np.max(np.abs(alpha))),
            "steering_angle_rms": _rms(t, alpha)}


def _steering_rate_metrics(t: Floats, rate: Floats) -> dict[str, Any]:
    return {"steering_rate_peak": float(np.max(np.abs(rate))),
            "steering_rate_rms": _rms(t, rate)}


def _control_metrics(t: Floats, u: Floats) -> dict[str, Any]:
    return {"control_effort": _integral(t, u * u) if t.size >= 2 else None,
            "control_peak": float(np.max(np.abs(u))), "control_rms": _rms(t, u)}


#: Each ``[metrics]`` key naming one signal whose metrics come from it alone -> those
#: metrics, in the order a result holds them.
_SIGNAL_METRICS = {"heading_error": ("heading_error_rms", "heading_error_max"),
                   "steering_angle": ("steering_angle_peak", "steering_angle_rms"),
                   "steering_rate": ("steering_rate_peak", "steering_rate_rms"),
                   "control": ("control_effort", "control_peak", "control_rms")}
#: Each key of :data:`_SIGNAL_METRICS` -> its metrics from (t, values).
_MEASURES: dict[str, Callable[[Floats, Floats], dict[str, Any]]] = {
    "heading_error": _heading_metrics, "steering_angle": _steering_angle_metrics,
    "steering_rate": _steering_rate_metrics, "control": _control_metrics}


def _path_metrics(ref: dict[str, Any], t: Floats, signals: dict[str, np.ndarray],
                  band: float, settle_after: float | None,
                  base_dir: str | Path | None) -> dict[str, Any]:
    """The ``path_error_*`` metrics of ``reference``: the offsets of (x, y) from its
    path; all None when x, y or the offsets have a non-finite sample."""
    x = _get(signals, ref["x"], "reference.x", t.size)
    y = _get(signals, ref["y"], "reference.y", t.size)
    names = [f"path_error_{name}" for name in _LATERAL_NAMES]

    def from_offsets() -> dict[str, Any]:
        e = path_offsets(ref["path"], x, y, base_dir)
        return _if_finite(e, names, lambda: _lateral_metrics("path_error", t, e, band,
                                                             settle_after))

    return _if_finite(np.concatenate((x, y)), names, from_offsets)


def _saturation_metrics(sat: dict[str, Any], t: Floats, signals: dict[str, np.ndarray],
                        duration: float) -> dict[str, Any]:
    """``saturated_time`` and ``saturated_fraction`` of ``saturation``."""
    s = _get(signals, sat["signal"], "saturation.signal", t.size)

    def measure() -> dict[str, Any]:
        seconds = saturated_time(t, s, sat["limit"] - sat["tolerance"])
        return {"saturated_time": seconds,
                "saturated_fraction": seconds / duration if duration > 0 else None}

    return _if_finite(s, ["saturated_fraction", "saturated_time"], measure)


def compute_metrics(time: np.ndarray, signals: dict[str, np.ndarray],
                    spec: "schema.MetricsTable | dict[str, Any] | None", *,
                    base_dir: str | Path | None = None) -> dict[str, Any]:
    """Path-tracking metrics of one run.

    Parameters
    ----------
    time : numpy.ndarray
        Strictly increasing sample times [s], shape (n,), n >= 1.
    signals : dict of str to numpy.ndarray
        Recorded signals by name ``"component.variable"``, each of shape (n,).
    spec : dict
        The ``[metrics]`` table (see the module docstring for keys and definitions).
    base_dir : str or pathlib.Path, optional
        Folder that relative file names in ``reference.path`` are relative to (the
        manifest's folder); the working directory when None.

    Returns
    -------
    dict of str to float or None
        Metric name -> value in the units of the module docstring; ``None`` where the
        metric is undefined (never NaN). Always holds ``duration``.

    Raises
    ------
    ValueError
        If the table is malformed, a signal it names is missing or has the wrong length,
        or ``time`` is not a strictly increasing 1-D array.
    """
    spec = _validate(spec)
    t = _time_grid(time)
    band = spec["settle_band"]
    settle_after = spec.get("settle_after")
    result: dict[str, Any] = {"duration": float(t[-1] - t[0])}
    if "lateral_error" in spec:
        e = _get(signals, spec["lateral_error"], "lateral_error", t.size)
        result.update(_if_finite(e, [f"lateral_error_{name}" for name in _LATERAL_NAMES],
                                 lambda: _lateral_metrics("lateral_error", t, e, band,
                                                          settle_after)))
    if "reference" in spec:
        result.update(_path_metrics(spec["reference"], t, signals, band, settle_after,
                                    base_dir))
    for key, names in _SIGNAL_METRICS.items():
        if key in spec:
            values = _get(signals, spec[key], key, t.size)
            result.update(_if_finite(values, names, partial(_MEASURES[key], t, values)))
    if "saturation" in spec:
        result.update(_saturation_metrics(spec["saturation"], t, signals,
                                          result["duration"]))
    return _clean(result)


# --------------------------------------------------------------------------- streaming

class PairwiseSum:
    """Sum of ``n`` doubles fed in pieces, bit-identical to ``numpy.sum`` of all of them.

    numpy sums a contiguous float64 array pairwise: an array of more than 128 values is
    split in two at half its length rounded down to a multiple of 8, each half summed the
    same way, and a block of at most 128 values is summed by a fixed loop. The split
    points depend only on ``n``, so with ``n`` known in advance the same tree can be
    walked while the values arrive: each block is summed by ``numpy.sum`` itself when it is
    complete, and the partial sums are added in the tree's order. State: one pending block
    (<= 128 values) and one partial sum per tree level (about log2(n / 128)).

    Parameters
    ----------
    n : int
        Number of values that will be fed (>= 0).
    """

    _BLOCK = 128

    def __init__(self, n: int) -> None:
        self.n = n
        self.result = 0.0 if n == 0 else None
        self._tree = self._walk(n)
        self._need = next(self._tree) if n else None
        self._parts: list[np.ndarray] = []
        self._have = 0

    @classmethod
    def _walk(cls, n: int) -> Generator[int, Floats, Any]:
        if n <= cls._BLOCK:
            block = yield n
            return np.sum(block)
        half = n // 2
        half -= half % 8
        left = yield from cls._walk(half)
        right = yield from cls._walk(n - half)
        return left + right

    def add(self, values: np.ndarray) -> None:
        """Feed the next values (1-D array); more than ``n`` in all is an error."""
        values = np.asarray(values, dtype=float)
        pos, size = 0, values.size
        while pos < size:
            if self._need is None:
                raise ValueError(f"PairwiseSum: more than {self.n} values")
            take = min(self._need - self._have, size - pos)
            self._parts.append(values[pos:pos + take])
            self._have += take
            pos += take
            if self._have == self._need:
                block = self._parts[0] if len(self._parts) == 1 else np.concatenate(self._parts)
                self._parts, self._have = [], 0
                try:
                    self._need = self._tree.send(block)
                except StopIteration as done:
                    self.result, self._need = float(done.value), None

    def total(self) -> float:
        """The sum; an error if fewer than ``n`` values were fed."""
        if self.result is None:
            raise ValueError(f"PairwiseSum: fewer than {self.n} values fed")
        return self.result


class _Spool:
    """Columns of float64 kept on disk (anonymous temporary files), read back in chunks."""

    def __init__(self, chunk_rows: int) -> None:
        self.chunk_rows = chunk_rows
        self.files: dict[str, IO[bytes]] = {}
        self.rows = 0
        self.first_time: Any = None
        self.last_time: Any = None

    def append(self, name: str, values: np.ndarray) -> None:
        if name not in self.files:
            self.files[name] = tempfile.TemporaryFile()
        np.ascontiguousarray(values, dtype=float).tofile(self.files[name])

    def close(self) -> None:
        for stream in self.files.values():
            stream.close()

    def chunks(self, name: str, first: int = 0) -> Iterator[np.ndarray]:
        """Arrays of at most ``chunk_rows`` values of column ``name`` from row ``first``."""
        stream = self.files[name]
        stream.flush()
        stream.seek(8 * first)
        while True:
            values = np.fromfile(stream, dtype=float, count=self.chunk_rows)
            if values.size == 0:
                return
            yield values

    def rows_at(self, name: str, first: int, count: int) -> Floats:
        """``count`` values of column ``name`` from row ``first``."""
        stream = self.files[name]
        stream.flush()
        stream.seek(8 * first)
        return np.fromfile(stream, dtype=float, count=count)


def _pieces(spool: "_Spool", name: str, first_row: int,
            lead: tuple[float, float] | None = None) -> Iterator[tuple[Floats, Floats]]:
    """Chunks of (t, f) with the previous sample prepended, so that the pieces between
    consecutive samples (``f[1:]``, ``f[:-1]``, ``np.diff(t)``) of each chunk are exactly
    those of the whole signal; ``lead`` = (t, f) is an extra first sample (a window's
    interpolated start), rows start at ``first_row``."""
    previous = lead
    for t, f in zip(spool.chunks("time", first_row), spool.chunks(name, first_row)):
        if previous is not None:
            t = np.concatenate(([previous[0]], t))
            f = np.concatenate(([previous[1]], f))
        yield t, f
        previous = (t[-1], f[-1])


def _sums(spool: "_Spool", name: str, first_row: int = 0,
          lead: tuple[float, float] | None = None, *,
          mean: float | None = None, squares: bool = True, absolute: bool = False,
          threshold: float | None = None) -> dict[str, Any]:
    """One pass over a signal (rows from ``first_row``, after the sample ``lead``).

    Returns the piecewise sums that the in-memory functions compute with ``np.sum``, each
    bit-identical: ``"f"`` (trapezoid of f), ``"f2"`` (of f^2), ``"abs"`` (exact |f|),
    ``"dev2"`` (trapezoid of (f - mean)^2), ``"sat"`` (time at or past ``threshold``), and
    ``"max_abs"``; ``"duration"`` = last time - first time.
    """
    count = spool.rows - first_row + (lead is not None)
    names = ["f"] + ["f2"] * squares + ["abs"] * absolute + ["dev2"] * (mean is not None) \
        + ["sat"] * (threshold is not None)
    sums = {key: PairwiseSum(max(0, count - 1)) for key in names}
    out: dict[str, Any] = {"max_abs": 0.0 if lead is None else abs(float(lead[1])),
                           "first": None, "last": None}
    for t, f in _pieces(spool, name, first_row, lead):
        if out["first"] is None:
            out["first"] = float(t[0])
        out["last"] = float(t[-1])
        dt = np.diff(t)
        sums["f"].add(0.5 * (f[1:] + f[:-1]) * dt)
        if squares:
            g = f * f
            sums["f2"].add(0.5 * (g[1:] + g[:-1]) * dt)
        if absolute:
            sums["abs"].add(_abs_pieces(f) * dt)
        if mean is not None:
            d = f - mean
            g = d * d
            sums["dev2"].add(0.5 * (g[1:] + g[:-1]) * dt)
        if threshold is not None:
            sums["sat"].add(_saturated_fractions(f, threshold) * dt)
        out["max_abs"] = max(out["max_abs"], float(np.max(np.abs(f))))
    out.update({key: total.total() for key, total in sums.items()})
    return out


def _time_average(total: float, duration: float) -> float | None:
    return total / duration if duration > 0 else None


def _std(dev2: float, duration: float) -> float:
    """The standard deviation from the integral ``dev2`` of (f - mean)^2 over
    ``duration`` (> 0: the mean it is about exists)."""
    return math.sqrt(max(0.0, dev2 / duration))


def _sqrt_or_none(value: float | None) -> float | None:
    return math.sqrt(value) if value is not None else None


def _first_after(spool: "_Spool", start: float) -> int:
    """Index of the first sample with time > ``start`` (``np.searchsorted(side='right')``)."""
    row = 0
    for t in spool.chunks("time"):
        k = int(np.searchsorted(t, start, side="right"))
        if k < t.size:
            return row + k
        row += t.size
    return row


def _window_stats(spool: "_Spool", column: str,
                  start: float | None) -> MetricValues | None:
    """Mean/RMS/std sums of the signal over [start, t_N], its first value interpolated as
    :func:`_window` does; None when the window is empty."""
    if start is None or start >= spool.last_time:
        return None
    k = _first_after(spool, start)
    t_pair = spool.rows_at("time", k - 1, 2)
    f_pair = spool.rows_at(column, k - 1, 2)
    lead = (start, float(np.interp(start, t_pair, f_pair)))
    first = _sums(spool, column, k, lead, absolute=True)
    span = first["last"] - first["first"]
    mean = _time_average(first["f"], span)
    std = None
    if mean is not None:
        second = _sums(spool, column, k, lead, mean=mean, squares=False)
        std = _std(second["dev2"], span)
    return {"max": first["max_abs"], "mean": _time_average(first["abs"], span),
            "rms": _sqrt_or_none(_time_average(first["f2"], span)),
            "signed_mean": mean, "std": std}


def _lateral_stream(prefix: str, spool: "_Spool", column: str, band: float,
                    settle_after: float | None) -> MetricValues:
    """:func:`_lateral_metrics` of a spooled signal, bit for bit."""
    first = _sums(spool, column, absolute=True)
    duration = spool.last_time - spool.first_time
    out = {f"{prefix}_max": first["max_abs"],
           f"{prefix}_mean": _time_average(first["abs"], duration),
           f"{prefix}_rms": _sqrt_or_none(_time_average(first["f2"], duration))}
    mean = _time_average(first["f"], duration)
    std = None
    if mean is not None:
        second = _sums(spool, column, mean=mean, squares=False)
        std = _std(second["dev2"], duration)
    out[f"{prefix}_signed_mean"], out[f"{prefix}_std"] = mean, std
    # settling: the last sample outside the band, and the one after it
    e0 = float(spool.rows_at(column, 0, 1)[0])
    sign = -math.copysign(1.0, e0)
    last_outside, overshoot, row = -1, -math.inf, 0
    for f in spool.chunks(column):
        outside = np.flatnonzero(np.abs(f) > band)
        if outside.size:
            last_outside = row + int(outside[-1])
        overshoot = max(overshoot, float(np.max(sign * f)))
        row += f.size
    if last_outside < 0:
        t_settle = spool.first_time
    elif last_outside == spool.rows - 1:
        t_settle = None
    else:
        t = spool.rows_at("time", last_outside, 2)
        e = spool.rows_at(column, last_outside, 2)
        target = math.copysign(band, e[0])
        tau = (target - e[0]) / (e[1] - e[0])
        t_settle = float(t[0] + tau * (t[1] - t[0]))
    out[f"{prefix}_settling_time"] = None if t_settle is None else t_settle - spool.first_time
    start = spool.first_time + settle_after if settle_after is not None else t_settle
    window = _window_stats(spool, column, start)
    for name in ("max", "mean", "rms", "signed_mean", "std"):
        out[f"{prefix}_settled_{name}"] = None if window is None else window[name]
    if e0 == 0.0:
        out[f"{prefix}_overshoot"] = out[f"{prefix}_overshoot_ratio"] = None
    else:
        out[f"{prefix}_overshoot"] = max(0.0, overshoot)
        out[f"{prefix}_overshoot_ratio"] = out[f"{prefix}_overshoot"] / abs(e0)
    return out


def compute_metrics_csv(path: str | Path, spec: "schema.MetricsTable | dict[str, Any] | None",
                        *, base_dir: str | Path | None = None,
                        chunk_rows: int | None = None) -> dict[str, Any]:
    """:func:`compute_metrics` of a ``timeseries.csv``, in memory bounded by the chunk.

    The file is read once, ``chunk_rows`` rows at a time; the signals the metrics use (and
    the path offsets of ``reference``) are spooled as float64 to anonymous temporary files
    and read back in chunks for the passes that need a value known only at the end (see
    "Bounded memory" in the module docstring). The result equals :func:`compute_metrics` of
    the whole arrays bit for bit, keys in the same order.

    Parameters
    ----------
    path : str or pathlib.Path
        A ``timeseries.csv`` as written by ``results.CsvSink``.
    spec, base_dir
        As for :func:`compute_metrics`.
    chunk_rows : int, optional
        Rows per chunk (default ``timeseries.CHUNK_ROWS``).

    Raises
    ------
    ValueError
        As :func:`compute_metrics`.
    """

    spec = _validate(spec)
    chunk_rows = chunk_rows or timeseries.CHUNK_ROWS
    present = set(timeseries.timeseries_columns(path))
    used = {key: spec[key] for key in _SIGNAL_KEYS if key in spec}
    checks = [(key, name) for key, name in used.items() if key == "lateral_error"]
    if "reference" in spec:
        checks += [("reference.x", spec["reference"]["x"]),
                   ("reference.y", spec["reference"]["y"])]
    checks += [(key, name) for key, name in used.items() if key != "lateral_error"]
    if "saturation" in spec:
        checks.append(("saturation.signal", spec["saturation"]["signal"]))
    for key, name in checks:
        if name not in present:
            raise ValueError(f"metrics.{key}: signal {name!r} is not in the results")
    names = list(dict.fromkeys(name for _, name in checks))
    geometry = None
    if "reference" in spec:
        geometry = load_path(spec["reference"]["path"], "metrics.reference.path", base_dir)
    spool = _Spool(chunk_rows)
    try:
        finite = dict.fromkeys(names, True)
        path_finite = {"xy": True, "e": True}
        s_hint: Any = None
        previous: Any = None
        for t, signals in timeseries.iter_timeseries(path, names, chunk_rows):
            if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0) \
                    or (previous is not None and t[0] <= previous):
                raise ValueError("metrics: time must be finite and strictly increasing")
            if previous is None:
                spool.first_time = float(t[0])
            previous = t[-1]
            spool.append("time", t)
            for name in names:
                spool.append(name, signals[name])
                finite[name] = finite[name] and bool(np.all(np.isfinite(signals[name])))
            if geometry is not None and path_finite["xy"] and path_finite["e"]:
                x, y = signals[spec["reference"]["x"]], signals[spec["reference"]["y"]]
                if np.all(np.isfinite(x)) and np.all(np.isfinite(y)):
                    e, s_hint = _offsets(geometry, x, y, s_hint)
                    spool.append("path_error", e)
                    path_finite["e"] = bool(np.all(np.isfinite(e)))
                else:
                    path_finite["xy"] = False
            spool.rows += t.size
        if spool.rows == 0:
            raise ValueError("metrics: time must be a non-empty 1-D array")
        spool.last_time = float(previous)
        return _clean(_stream_metrics(spool, spec, finite, path_finite))
    finally:
        spool.close()


def _rms_and_peak(spool: "_Spool", name: str) -> tuple[float | None, float]:
    """The RMS and the peak |f| of the spooled signal ``name``."""
    sums = _sums(spool, name)
    return _sqrt_or_none(_time_average(sums["f2"], spool.last_time - spool.first_time)), \
        sums["max_abs"]


def _heading_stream(spool: "_Spool", name: str) -> dict[str, Any]:
    rms, peak = _rms_and_peak(spool, name)
    return {"heading_error_rms": rms, "heading_error_max": peak}


def _steering_angle_stream(spool: "_Spool", name: str) -> dict[str, Any]:
    rms, peak = _rms_and_peak(spool, name)
    return {"steering_angle_peak": peak, "steering_angle_rms": rms}


def _steering_rate_stream(spool: "_Spool", name: str) -> dict[str, Any]:
    rms, peak = _rms_and_peak(spool, name)
    return {"steering_rate_peak": peak, "steering_rate_rms": rms}


def _control_stream(spool: "_Spool", name: str) -> dict[str, Any]:
    sums = _sums(spool, name)
    duration = spool.last_time - spool.first_time
    return {"control_effort": sums["f2"] if spool.rows >= 2 else None,
            "control_peak": sums["max_abs"],
            "control_rms": _sqrt_or_none(_time_average(sums["f2"], duration))}


#: :data:`_MEASURES` of a spooled signal (the spool, the signal's column).
_STREAM_MEASURES: dict[str, Callable[["_Spool", str], dict[str, Any]]] = {
    "heading_error": _heading_stream, "steering_angle": _steering_angle_stream,
    "steering_rate": _steering_rate_stream, "control": _control_stream}


def _saturation_stream(spool: "_Spool", sat: dict[str, Any]) -> dict[str, Any]:
    sums = _sums(spool, sat["signal"], squares=False,
                 threshold=sat["limit"] - sat["tolerance"])
    return {"saturated_time": sums["sat"],
            "saturated_fraction": _time_average(sums["sat"],
                                                spool.last_time - spool.first_time)}


def _stream_metrics(spool: "_Spool", spec: dict[str, Any], finite: dict[str, bool],
                    path_finite: dict[str, bool]) -> dict[str, Any]:
    band = spec["settle_band"]
    settle_after = spec.get("settle_after")
    result: dict[str, Any] = {"duration": spool.last_time - spool.first_time}
    if "lateral_error" in spec:
        name = spec["lateral_error"]
        result.update(_measured(finite[name], [f"lateral_error_{m}" for m in _LATERAL_NAMES],
                                lambda: _lateral_stream("lateral_error", spool, name, band,
                                                        settle_after)))
    if "reference" in spec:
        result.update(_measured(path_finite["xy"] and path_finite["e"],
                                [f"path_error_{m}" for m in _LATERAL_NAMES],
                                lambda: _lateral_stream("path_error", spool, "path_error",
                                                        band, settle_after)))
    for key, names in _SIGNAL_METRICS.items():
        if key in spec:
            result.update(_measured(finite[spec[key]], names,
                                    partial(_STREAM_MEASURES[key], spool, spec[key])))
    if "saturation" in spec:
        sat = spec["saturation"]
        result.update(_measured(finite[sat["signal"]], ["saturated_fraction", "saturated_time"],
                                partial(_saturation_stream, spool, sat)))
    return result
