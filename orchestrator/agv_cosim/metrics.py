"""Path-tracking metrics computed from a run's recorded signals.

The orchestrator calls :func:`compute_metrics` with the run's time grid, its recorded
signals (named ``"component.variable"``) and the manifest's ``[metrics]`` table, and
:func:`referenced_signals` beforehand to know what it must record.

The ``[metrics]`` table
-----------------------
Every key is optional; a metric is computed only when the signals it needs are named.

``lateral_error`` : str
    Signal of the signed lateral error e [m] (e.g. ``"sensor.lateral_error"``). Gives the
    ``lateral_error_*`` metrics.
``reference`` : table
    ``{path = "<path string>", x = "<signal>", y = "<signal>"}``: the lateral error is
    computed geometrically, as the signed offset of the recorded point (x, y) [m] from the
    path ``agv_core.paths.parse_path(path)`` (positive left of the path). Gives the
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
from collections.abc import Mapping

import numpy as np

#: Default settling band of the lateral error [m].
DEFAULT_SETTLE_BAND = 0.02

_SIGNAL_KEYS = ("lateral_error", "heading_error", "steering_angle", "steering_rate", "control")
_KEYS = _SIGNAL_KEYS + ("settle_band", "settle_after", "saturation", "reference")
_SATURATION_KEYS = ("signal", "limit", "tolerance")
_REFERENCE_KEYS = ("path", "x", "y")


# --------------------------------------------------------------------------- validation

def check_signal_name(key, value, table="metrics"):
    """Return ``value`` if it is a signal name 'component.variable'; else raise
    ValueError naming ``table.key`` (also used for the ``[plots]`` table)."""
    if not isinstance(value, str):
        raise ValueError(f"{table}.{key}: expected a signal name 'component.variable', "
                         f"got {value!r}")
    component, dot, variable = value.partition(".")
    if not dot or not component or not variable:
        raise ValueError(f"{table}.{key}: signal name {value!r} is not 'component.variable'")
    return value


def _check_number(key, value, minimum=None, strict=False):
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value):
        raise ValueError(f"metrics.{key}: expected a finite number, got {value!r}")
    if minimum is not None and (value <= minimum if strict else value < minimum):
        relation = ">" if strict else ">="
        raise ValueError(f"metrics.{key}: must be {relation} {minimum}, got {value!r}")
    return float(value)


def _check_table(key, value, allowed, required):
    if not isinstance(value, Mapping):
        raise ValueError(f"metrics.{key}: expected a table, got {value!r}")
    for sub in value:
        if sub not in allowed:
            raise ValueError(f"metrics.{key}.{sub}: unknown key (allowed: "
                             f"{', '.join(allowed)})")
    for sub in required:
        if sub not in value:
            raise ValueError(f"metrics.{key}.{sub}: missing")


def _validate(spec):
    """Check ``spec`` and return it normalised (defaults filled in)."""
    if spec is None:
        spec = {}
    if not isinstance(spec, Mapping):
        raise ValueError(f"metrics: expected a table, got {type(spec).__name__}")
    for key in spec:
        if key not in _KEYS:
            raise ValueError(f"metrics.{key}: unknown key (allowed: {', '.join(_KEYS)})")
    out = {}
    for key in _SIGNAL_KEYS:
        if key in spec:
            out[key] = check_signal_name(key, spec[key])
    out["settle_band"] = _check_number("settle_band",
                                       spec.get("settle_band", DEFAULT_SETTLE_BAND),
                                       0.0, strict=True)
    if "settle_after" in spec:
        out["settle_after"] = _check_number("settle_after", spec["settle_after"], 0.0)
    if "saturation" in spec:
        sat = spec["saturation"]
        _check_table("saturation", sat, _SATURATION_KEYS, ("signal", "limit"))
        limit = _check_number("saturation.limit", sat["limit"], 0.0, strict=True)
        tolerance = _check_number("saturation.tolerance", sat.get("tolerance", 1e-9 * limit),
                                  0.0)
        if tolerance >= limit:
            raise ValueError(f"metrics.saturation.tolerance: must be < limit ({limit!r}), "
                             f"got {tolerance!r}")
        out["saturation"] = {"signal": check_signal_name("saturation.signal", sat["signal"]),
                             "limit": limit, "tolerance": tolerance}
    if "reference" in spec:
        ref = spec["reference"]
        _check_table("reference", ref, _REFERENCE_KEYS, _REFERENCE_KEYS)
        if not isinstance(ref["path"], str) or not ref["path"].strip():
            raise ValueError(f"metrics.reference.path: expected a path string, "
                             f"got {ref['path']!r}")
        out["reference"] = {"path": ref["path"],
                            "x": check_signal_name("reference.x", ref["x"]),
                            "y": check_signal_name("reference.y", ref["y"])}
    return out


def referenced_signals(spec):
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

def _integral(t, f):
    """Trapezoidal integral of samples ``f`` over the grid ``t``."""
    if len(t) < 2:
        return 0.0
    return float(np.sum(0.5 * (f[1:] + f[:-1]) * np.diff(t)))


def _time_mean(t, f):
    """(1/T) integral f dt, or None when T = 0."""
    duration = float(t[-1] - t[0])
    return _integral(t, f) / duration if duration > 0 else None


def _rms(t, f):
    mean_square = _time_mean(t, f * f)
    return math.sqrt(mean_square) if mean_square is not None else None


def _mean_and_std(t, f):
    """Time-weighted mean of f and standard deviation about it, or (None, None) when T = 0."""
    mean = _time_mean(t, f)
    if mean is None:
        return None, None
    deviation = f - mean
    return mean, math.sqrt(max(0.0, _time_mean(t, deviation * deviation)))


def _abs_mean(t, f):
    """Time-weighted mean of |f| for piecewise-linear f (exact across sign changes)."""
    duration = float(t[-1] - t[0])
    if duration <= 0:
        return None
    a, b, dt = f[:-1], f[1:], np.diff(t)
    same = a * b >= 0
    with np.errstate(divide="ignore", invalid="ignore"):
        # a linear piece through zero: two triangles, (a^2 + b^2) / (2 |a - b|) * dt
        crossing = (a * a + b * b) / (2.0 * np.abs(a - b))
    area = np.where(same, 0.5 * (np.abs(a) + np.abs(b)), crossing) * dt
    return float(np.sum(area)) / duration


def _measure_at_least(a, b, threshold):
    """Fraction of [0, 1] where the line a + (b - a) tau >= threshold (elementwise)."""
    slope = b - a
    with np.errstate(divide="ignore", invalid="ignore"):
        tau = np.clip((threshold - a) / slope, 0.0, 1.0)
    flat = np.where(a >= threshold, 1.0, 0.0)
    return np.where(slope > 0, 1.0 - tau, np.where(slope < 0, tau, flat))


def saturated_time(t, f, threshold):
    """Time [s] during which |f| >= ``threshold`` (> 0), f piecewise linear over ``t``."""
    if len(t) < 2:
        return 0.0
    a, b = f[:-1], f[1:]
    fraction = _measure_at_least(a, b, threshold) + _measure_at_least(-a, -b, threshold)
    return float(np.sum(fraction * np.diff(t)))


def settling_time(t, e, band):
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


def _window(t, f, start):
    """Samples of f over [start, t[-1]], with an interpolated first sample at ``start``."""
    if start >= t[-1]:
        return None
    k = int(np.searchsorted(t, start, side="right"))
    value = float(np.interp(start, t, f))
    return np.concatenate(([start], t[k:])), np.concatenate(([value], f[k:]))


def _lateral_metrics(prefix, t, e, band, settle_after):
    out = {
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


def load_path(path, key, base_dir=None):
    """``agv_core.paths.parse_path(path)``, with a bad path string as ValueError naming ``key``.

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
    from agv_core.paths import parse_path

    try:
        return parse_path(path, base_dir=base_dir)
    except ParameterError as error:
        raise ValueError(f"{key}: {error}") from None


def path_offsets(path, x, y, base_dir=None):
    """Signed offsets [m] of the points (x, y) from ``path`` (positive left of it).

    Each point is projected with the previous point's arc length as the hint, so a path
    that comes close to itself is followed continuously.

    Parameters
    ----------
    path : str
        Path string understood by ``agv_core.paths.parse_path``.
    x, y : numpy.ndarray
        Coordinates [m] of the tracked point.
    base_dir : str or pathlib.Path, optional
        Folder that relative file names in ``path`` are relative to.
    """
    geometry = load_path(path, "metrics.reference.path", base_dir)
    offsets = np.empty(len(x))
    s_hint = None
    for i, (xi, yi) in enumerate(zip(x, y)):
        projection = geometry.project(float(xi), float(yi), s_hint)
        offsets[i] = projection.offset
        s_hint = projection.s
    return offsets


def _clean(metrics):
    return {key: (None if value is None or not math.isfinite(value) else float(value))
            for key, value in metrics.items()}


def _get(signals, name, key, n):
    if name not in signals:
        raise ValueError(f"metrics.{key}: signal {name!r} is not in the results")
    values = np.asarray(signals[name], dtype=float)
    if values.shape != (n,):
        raise ValueError(f"metrics.{key}: signal {name!r} has shape {values.shape}, "
                         f"the time grid ({n},)")
    return values


def compute_metrics(time, signals, spec, *, base_dir=None):
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
    t = np.asarray(time, dtype=float)
    if t.ndim != 1 or t.size == 0:
        raise ValueError("metrics: time must be a non-empty 1-D array")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise ValueError("metrics: time must be finite and strictly increasing")
    n = t.size
    band = spec["settle_band"]
    settle_after = spec.get("settle_after")
    result = {"duration": float(t[-1] - t[0])}

    def finite(values, names):
        # all metrics of a signal with non-finite samples are None
        if np.all(np.isfinite(values)):
            return True
        result.update({name: None for name in names})
        return False

    lateral_names = ("max", "mean", "rms", "signed_mean", "std", "settling_time",
                     "settled_max", "settled_mean", "settled_rms", "settled_signed_mean",
                     "settled_std", "overshoot", "overshoot_ratio")
    if "lateral_error" in spec:
        e = _get(signals, spec["lateral_error"], "lateral_error", n)
        if finite(e, [f"lateral_error_{name}" for name in lateral_names]):
            result.update(_lateral_metrics("lateral_error", t, e, band, settle_after))
    if "reference" in spec:
        ref = spec["reference"]
        x = _get(signals, ref["x"], "reference.x", n)
        y = _get(signals, ref["y"], "reference.y", n)
        names = [f"path_error_{name}" for name in lateral_names]
        if finite(np.concatenate((x, y)), names):
            e = path_offsets(ref["path"], x, y, base_dir)
            if finite(e, names):
                result.update(_lateral_metrics("path_error", t, e, band, settle_after))
    if "heading_error" in spec:
        h = _get(signals, spec["heading_error"], "heading_error", n)
        if finite(h, ["heading_error_rms", "heading_error_max"]):
            result["heading_error_rms"] = _rms(t, h)
            result["heading_error_max"] = float(np.max(np.abs(h)))
    if "steering_angle" in spec:
        alpha = _get(signals, spec["steering_angle"], "steering_angle", n)
        if finite(alpha, ["steering_angle_peak", "steering_angle_rms"]):
            result["steering_angle_peak"] = float(np.max(np.abs(alpha)))
            result["steering_angle_rms"] = _rms(t, alpha)
    if "steering_rate" in spec:
        rate = _get(signals, spec["steering_rate"], "steering_rate", n)
        if finite(rate, ["steering_rate_peak", "steering_rate_rms"]):
            result["steering_rate_peak"] = float(np.max(np.abs(rate)))
            result["steering_rate_rms"] = _rms(t, rate)
    if "control" in spec:
        u = _get(signals, spec["control"], "control", n)
        if finite(u, ["control_effort", "control_peak", "control_rms"]):
            result["control_effort"] = _integral(t, u * u) if n >= 2 else None
            result["control_peak"] = float(np.max(np.abs(u)))
            result["control_rms"] = _rms(t, u)
    if "saturation" in spec:
        sat = spec["saturation"]
        s = _get(signals, sat["signal"], "saturation.signal", n)
        if finite(s, ["saturated_fraction", "saturated_time"]):
            seconds = saturated_time(t, s, sat["limit"] - sat["tolerance"])
            result["saturated_time"] = seconds
            duration = result["duration"]
            result["saturated_fraction"] = seconds / duration if duration > 0 else None
    return _clean(result)
