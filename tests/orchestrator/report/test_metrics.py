"""Tests of agv_cosim.metrics: closed forms first, then hand-computed grids, then an FMU run."""

import math

import numpy as np
import pytest

from agv_cosim.report.metrics import (
    compute_metrics,
    referenced_signals,
    saturated_time,
    settling_time,
)

FULL_SPEC = {
    "lateral_error": "sensor.lateral_error",
    "heading_error": "sensor.heading_error",
    "steering_angle": "act.alpha",
    "steering_rate": "act.alpha_rate",
    "control": "ctrl.u",
    "settle_band": 0.02,
    "settle_after": 5.0,
    "saturation": {"signal": "act.alpha", "limit": 0.785},
    "reference": {"path": "line:x0=0,y0=0,heading=0", "x": "vehicle.x", "y": "vehicle.y"},
}



# --------------------------------------------------------------------------- closed forms

def _exponential(t, e0=0.5, tau=2.0):
    return e0 * np.exp(-t / tau)


@pytest.mark.parametrize("grid", ["uniform", "nonuniform"])
def test_exponential_decay_closed_forms(grid):
    e0, tau, band, duration = 0.5, 2.0, 0.02, 20.0
    u = np.linspace(0.0, 1.0, 20001)
    # the non-uniform grid is dense where e changes fastest (t = D u^2), max step 2e-3 s
    t = duration * (u if grid == "uniform" else u * u)
    m = compute_metrics(t, {"s.e": _exponential(t, e0, tau)},
                        {"lateral_error": "s.e", "settle_band": band})
    # closed forms of e0 exp(-t/tau) over [0, D]
    mean = e0 * tau / duration * (1 - math.exp(-duration / tau))
    rms = e0 * math.sqrt(tau / (2 * duration) * (1 - math.exp(-2 * duration / tau)))
    t_settle = tau * math.log(e0 / band)
    rest = duration - t_settle
    settled_rms = band * math.sqrt(tau / (2 * rest) * (1 - math.exp(-2 * rest / tau)))
    settled_mean = band * tau / rest * (1 - math.exp(-rest / tau))
    # trapezoidal error ~ (h/tau)^2 / 12 relative with h <= 2e-3 s, tau = 2 s: ~1e-7
    assert m["lateral_error_mean"] == pytest.approx(mean, rel=1e-6)
    assert m["lateral_error_rms"] == pytest.approx(rms, rel=1e-6)
    assert m["lateral_error_settled_mean"] == pytest.approx(settled_mean, rel=1e-6)
    assert m["lateral_error_settled_rms"] == pytest.approx(settled_rms, rel=1e-6)
    # linear interpolation of the band crossing: error ~ h^2 / (8 tau) < 1e-6 s
    assert m["lateral_error_settling_time"] == pytest.approx(t_settle, abs=1e-6)
    # the settled window starts on the band (interpolated value, same 1e-6 s error)
    assert m["lateral_error_settled_max"] == pytest.approx(band, rel=1e-6)
    assert m["lateral_error_max"] == e0           # first sample, exact
    assert m["lateral_error_overshoot"] == 0.0    # monotone: no excursion past zero
    assert m["lateral_error_overshoot_ratio"] == 0.0
    assert m["duration"] == duration


@pytest.mark.parametrize("zeta", [0.2, 0.5, 0.7])
def test_damped_response_overshoot(zeta):
    # e(t) of a second-order system released from e0 at rest: first undershoot at
    # t = pi / wd with e = -e0 exp(-zeta pi / sqrt(1 - zeta^2))
    e0, wn = -0.3, 2.0
    wd = wn * math.sqrt(1 - zeta * zeta)
    t = np.linspace(0.0, 15.0, 15001)
    e = e0 * np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta * wn / wd * np.sin(wd * t))
    m = compute_metrics(t, {"s.e": e}, {"lateral_error": "s.e"})
    ratio = math.exp(-zeta * math.pi / math.sqrt(1 - zeta * zeta))
    # sampling a smooth peak misses it by <= |e''| h^2 / 8 ~ wn^2 e0 1.25e-7 ~ 2e-7 m
    assert m["lateral_error_overshoot_ratio"] == pytest.approx(ratio, abs=1e-6)
    assert m["lateral_error_overshoot"] == pytest.approx(abs(e0) * ratio, abs=1e-6)


def test_signed_mean_and_std_of_an_offset_sine():
    # e = a + b sin(t) over whole periods: time mean a, population std b / sqrt(2) (the
    # trapezoid over whole periods of a sinusoid is exact to rounding); the settled window
    # [2 pi, 6 pi] is again two whole periods and starts on a sample
    a, b = -0.3, 0.2
    t = np.linspace(0.0, 6 * math.pi, 60001)
    m = compute_metrics(t, {"s.e": a + b * np.sin(t)},
                        {"lateral_error": "s.e", "settle_after": 2 * math.pi})
    for window in ("", "settled_"):
        assert m[f"lateral_error_{window}signed_mean"] == pytest.approx(a, abs=1e-12)
        assert m[f"lateral_error_{window}std"] == pytest.approx(b / math.sqrt(2), rel=1e-9)
        # rms^2 = mean^2 + std^2 (same trapezoid, rounding only)
        assert m[f"lateral_error_{window}rms"] ** 2 == pytest.approx(
            m[f"lateral_error_{window}signed_mean"] ** 2 + m[f"lateral_error_{window}std"] ** 2,
            rel=1e-12)


def test_signed_mean_and_std_of_a_ramp_on_a_settled_window():
    # e = c t on a non-uniform grid, window [w, D] starting between samples (interpolated):
    # mean c (w + D) / 2 (exact for a linear e), std c (D - w) / sqrt(12) (trapezoid of a
    # quadratic: relative error h^2 / (D - w)^2 ~ 1e-8 with h <= 1e-3 s)
    c, w, duration = -0.05, 3.3333, 10.0
    u = np.linspace(0.0, 1.0, 10001)
    t = duration * u * (2 - u)          # denser towards the end, max step 2e-3 s
    m = compute_metrics(t, {"s.e": c * t}, {"lateral_error": "s.e", "settle_after": w})
    assert m["lateral_error_signed_mean"] == pytest.approx(c * duration / 2, rel=1e-12)
    assert m["lateral_error_std"] == pytest.approx(abs(c) * duration / math.sqrt(12), rel=1e-6)
    assert m["lateral_error_settled_signed_mean"] == pytest.approx(c * (w + duration) / 2,
                                                                   rel=1e-12)
    assert m["lateral_error_settled_std"] == pytest.approx(
        abs(c) * (duration - w) / math.sqrt(12), rel=1e-6)


def test_piecewise_linear_grid_by_hand():
    # non-uniform grid, values chosen so every metric is a hand calculation (exact to
    # rounding: 1e-12)
    t = np.array([0.0, 1.0, 3.0, 6.0])
    e = np.array([2.0, -2.0, 0.0, 1.0])
    m = compute_metrics(t, {"s.e": e}, {"lateral_error": "s.e", "settle_band": 1.5})
    # |e| exactly for the piecewise-linear e: 1 (zero crossing at 0.5) + 2 + 1.5 over 6 s
    assert m["lateral_error_mean"] == pytest.approx(4.5 / 6, abs=1e-12)
    # trapezoidal e^2: (4 + 4)/2*1 + (4 + 0)/2*2 + (0 + 1)/2*3 = 9.5 over 6 s
    assert m["lateral_error_rms"] == pytest.approx(math.sqrt(9.5 / 6), abs=1e-12)
    # last outside the band: sample 1 (e = -2); e = -1.5 a quarter of the way to t = 3
    assert m["lateral_error_settling_time"] == pytest.approx(1.5, abs=1e-12)
    assert m["lateral_error_overshoot"] == pytest.approx(2.0, abs=1e-12)
    assert m["lateral_error_overshoot_ratio"] == pytest.approx(1.0, abs=1e-12)
    # settled window [1.5, 6]: e = -1.5 -> 0 over 1.5 s, then 0 -> 1 over 3 s
    assert m["lateral_error_settled_max"] == pytest.approx(1.5, abs=1e-12)
    assert m["lateral_error_settled_mean"] == pytest.approx((1.125 + 1.5) / 4.5, abs=1e-12)
    # trapezoidal e: (2 - 2)/2*1 + (-2 + 0)/2*2 + (0 + 1)/2*3 = -0.5 over 6 s; the std is
    # the trapezoid of (e - mean)^2, = 9.5/6 - mean^2 since the trapezoid is linear
    assert m["lateral_error_signed_mean"] == pytest.approx(-0.5 / 6, abs=1e-12)
    assert m["lateral_error_std"] == pytest.approx(math.sqrt(9.5 / 6 - (0.5 / 6) ** 2),
                                                   abs=1e-12)
    # settled window [1.5, 6]: integral of e = -1.125 + 1.5 over 4.5 s; e^2 by trapezoid:
    # (2.25 + 0)/2*1.5 + (0 + 1)/2*3 = 3.1875
    settled_mean = 0.375 / 4.5
    assert m["lateral_error_settled_signed_mean"] == pytest.approx(settled_mean, abs=1e-12)
    assert m["lateral_error_settled_std"] == pytest.approx(
        math.sqrt(3.1875 / 4.5 - settled_mean ** 2), abs=1e-12)


def test_settling_time_with_time_offset_and_settle_after():
    # times are measured from the first sample; settle_after fixes the window
    t = np.linspace(10.0, 30.0, 2001)
    e = _exponential(t - 10.0)
    m = compute_metrics(t, {"s.e": e},
                        {"lateral_error": "s.e", "settle_after": 10.0})
    assert m["lateral_error_settling_time"] == pytest.approx(2 * math.log(25), abs=1e-4)
    # window [20, 30] s: starts at e = 0.5 exp(-5); 1e-9 is rounding on an exact sample
    assert m["lateral_error_settled_max"] == pytest.approx(0.5 * math.exp(-5), rel=1e-9)


def test_saturation_fraction_of_a_sine():
    # |A sin(w t)| >= L for a fraction 1 - (2/pi) asin(L/A) of whole periods
    amplitude, limit = 1.0, 0.6
    t = np.linspace(0.0, 4 * math.pi, 40001)
    spec = {"saturation": {"signal": "a.alpha", "limit": limit}}
    m = compute_metrics(t, {"a.alpha": amplitude * np.sin(t)}, spec)
    fraction = 1 - 2 / math.pi * math.asin(limit / amplitude)
    # crossings interpolated linearly: error ~ h^2 per crossing, h = 3e-4: << 1e-6
    assert m["saturated_fraction"] == pytest.approx(fraction, abs=1e-6)
    assert m["saturated_time"] == pytest.approx(fraction * 4 * math.pi, abs=1e-5)


def test_saturation_fraction_of_a_clipped_signal():
    # held exactly at +limit for 3 s, then at -limit for 2 s, then 0 for 5 s: 50 %
    # saturated. A step between samples counts only tolerance/limit (1e-9) of its interval.
    limit = 0.785
    t = np.array([0.0, 1.0, 3.0, 3.0 + 1e-9, 5.0, 5.0 + 1e-9, 7.0, 10.0])
    s = np.array([limit, limit, limit, -limit, -limit, 0.0, 0.0, 0.0])
    m = compute_metrics(t, {"a.alpha": s}, {"saturation": {"signal": "a.alpha",
                                                            "limit": limit}})
    assert m["saturated_fraction"] == pytest.approx(0.5, abs=1e-9)
    # just below the limit (beyond the tolerance) is not saturated at all
    m = compute_metrics(t, {"a.alpha": 0.999 * s},
                        {"saturation": {"signal": "a.alpha", "limit": limit}})
    assert m["saturated_fraction"] == 0.0


def test_steering_heading_and_control():
    # alpha = A sin(w t), u = U cos(w t) over whole periods: RMS = amplitude / sqrt(2),
    # effort = U^2 T / 2; heading error a ramp -0.1 .. 0.3 rad: max 0.3, RMS^2 = mean of a^2
    t = np.linspace(0.0, 2 * math.pi, 20001)
    signals = {"a.alpha": 0.4 * np.sin(t), "a.rate": 0.4 * np.cos(t),
               "c.u": 3.0 * np.cos(t), "s.h": -0.1 + 0.4 * t / (2 * math.pi)}
    m = compute_metrics(t, signals, {"steering_angle": "a.alpha", "steering_rate": "a.rate",
                                     "control": "c.u", "heading_error": "s.h"})
    # trapezoid over whole periods of a sinusoid is exact to rounding; peaks sampled at
    # pi/2 within 1e-8 relative
    assert m["steering_angle_rms"] == pytest.approx(0.4 / math.sqrt(2), rel=1e-9)
    assert m["steering_angle_peak"] == pytest.approx(0.4, rel=1e-8)
    assert m["steering_rate_peak"] == pytest.approx(0.4, rel=1e-12)
    assert m["steering_rate_rms"] == pytest.approx(0.4 / math.sqrt(2), rel=1e-9)
    assert m["control_effort"] == pytest.approx(9.0 * math.pi, rel=1e-9)
    assert m["control_peak"] == pytest.approx(3.0, rel=1e-12)
    assert m["control_rms"] == pytest.approx(3.0 / math.sqrt(2), rel=1e-9)
    # ramp a + b s, s in [0, 1]: mean square a^2 + a b + b^2 / 3; trapezoid error h^2 b^2/6
    a, b = -0.1, 0.4
    assert m["heading_error_rms"] == pytest.approx(math.sqrt(a * a + a * b + b * b / 3),
                                                   rel=1e-8)
    assert m["heading_error_max"] == pytest.approx(0.3, rel=1e-12)


# --------------------------------------------------------------------------- undefined values

def test_undefined_metrics_are_none_never_nan():
    t = np.linspace(0.0, 1.0, 11)
    # never settles (ends outside the band), starts at zero (no overshoot direction)
    m = compute_metrics(t, {"s.e": t}, {"lateral_error": "s.e"})
    assert m["lateral_error_settling_time"] is None
    assert m["lateral_error_settled_rms"] is None
    assert m["lateral_error_overshoot"] is None and m["lateral_error_overshoot_ratio"] is None
    assert m["lateral_error_max"] == 1.0
    # a NaN in a signal makes that signal's metrics None, the others still count
    e = np.exp(-t)
    u = np.ones_like(t)
    u[3] = np.nan
    m = compute_metrics(t, {"s.e": e, "c.u": u}, {"lateral_error": "s.e", "control": "c.u"})
    assert m["control_effort"] is None and m["control_peak"] is None
    assert m["lateral_error_max"] == 1.0
    # a single sample: no duration, so no averages
    m = compute_metrics(np.array([0.0]), {"s.e": np.array([0.01])},
                        {"lateral_error": "s.e", "control": "s.e"})
    assert m["duration"] == 0.0 and m["lateral_error_rms"] is None
    assert m["lateral_error_signed_mean"] is None and m["lateral_error_std"] is None
    assert m["control_effort"] is None and m["lateral_error_settling_time"] == 0.0
    # settle_after past the end: empty window
    m = compute_metrics(t, {"s.e": e}, {"lateral_error": "s.e", "settle_after": 2.0})
    assert m["lateral_error_settled_rms"] is None
    assert m["lateral_error_settled_signed_mean"] is None
    assert m["lateral_error_settled_std"] is None
    for value in m.values():
        assert value is None or math.isfinite(value)


def test_low_level_helpers():
    t = np.array([0.0, 1.0, 2.0])
    assert settling_time(t, np.array([0.0, 0.01, 0.0]), 0.02) == 0.0
    # triangle 0 -> 1 -> 0 above 0.5 for half of each piece: 1 s in all
    assert saturated_time(t, np.array([0.0, 1.0, 0.0]), 0.5) == pytest.approx(1.0, abs=1e-15)


# --------------------------------------------------------------------------- the spec

def test_referenced_signals_lists_every_name_once():
    assert referenced_signals(FULL_SPEC) == [
        "sensor.lateral_error", "sensor.heading_error", "act.alpha", "act.alpha_rate",
        "ctrl.u", "vehicle.x", "vehicle.y"]
    assert referenced_signals({}) == []


@pytest.mark.parametrize("spec, key", [
    ({"lateral_eror": "s.e"}, "metrics.lateral_eror"),
    ({"lateral_error": "nodot"}, "metrics.lateral_error"),
    ({"control": 3}, "metrics.control"),
    ({"settle_band": 0.0}, "metrics.settle_band"),
    ({"settle_band": True}, "metrics.settle_band"),
    ({"settle_band": "0.02"}, "metrics.settle_band"),
    ({"settle_after": -1.0}, "metrics.settle_after"),
    ({"saturation": {"signal": "a.alpha"}}, "metrics.saturation.limit"),
    ({"saturation": {"signal": "a.alpha", "limit": 1, "lim": 2}}, "metrics.saturation.lim"),
    ({"saturation": {"signal": "a.alpha", "limit": 1, "tolerance": 1}},
     "metrics.saturation.tolerance"),
    ({"saturation": "a.alpha"}, "metrics.saturation"),
    ({"reference": {"path": "line:", "x": "v.x"}}, "metrics.reference.y"),
    ({"reference": {"path": "", "x": "v.x", "y": "v.y"}}, "metrics.reference.path"),
])
def test_bad_spec_names_the_key(spec, key):
    with pytest.raises(ValueError, match=key.replace(".", r"\.")):
        referenced_signals(spec)
    with pytest.raises(ValueError, match=key.replace(".", r"\.")):
        compute_metrics(np.array([0.0, 1.0]), {}, spec)


def test_missing_or_misshapen_signal_and_bad_time():
    t = np.array([0.0, 1.0])
    with pytest.raises(ValueError, match=r"metrics\.control: signal 'c\.u'"):
        compute_metrics(t, {}, {"control": "c.u"})
    with pytest.raises(ValueError, match=r"metrics\.control"):
        compute_metrics(t, {"c.u": np.zeros(3)}, {"control": "c.u"})
    with pytest.raises(ValueError, match="strictly increasing"):
        compute_metrics(np.array([0.0, 0.0]), {"c.u": np.zeros(2)}, {"control": "c.u"})


# --------------------------------------------------------------------------- reference path

def test_geometric_error_from_reference_path():
    # points at a known offset from a circle of radius 5 (centre (0, 5), counter-clockwise):
    # inside the circle is left of the path, so offset = R - r
    radius = 5.0
    t = np.linspace(0.0, 10.0, 1001)
    offset = 0.4 * np.exp(-t)
    phi = 0.3 * t - math.pi / 2
    r = radius - offset
    x, y = r * np.cos(phi), radius + r * np.sin(phi)
    spec = {"reference": {"path": f"circle:radius={radius}", "x": "v.x", "y": "v.y"},
            "lateral_error": "s.e"}
    m = compute_metrics(t, {"v.x": x, "v.y": y, "s.e": offset}, spec)
    # the projection is closed-form for a circle: same numbers as the signal to 1e-9 m
    for name in ("max", "mean", "rms", "signed_mean", "std", "settling_time", "settled_rms",
                 "settled_signed_mean", "settled_std"):
        assert m[f"path_error_{name}"] == pytest.approx(m[f"lateral_error_{name}"], abs=1e-9)
    assert m["path_error_settling_time"] == pytest.approx(math.log(0.4 / 0.02), abs=1e-4)


def test_bad_reference_path_names_the_key():
    t = np.array([0.0, 1.0])
    spec = {"reference": {"path": "spiral:r=1", "x": "v.x", "y": "v.y"}}
    with pytest.raises(ValueError, match=r"metrics\.reference\.path"):
        compute_metrics(t, {"v.x": t, "v.y": t}, spec)


# --------------------------------------------------------------------------- integration

def test_metrics_of_a_vehicle_fmu_run(component_fmus):
    """A straight drive at a heading offset, run as an FMU through fmpy.

    The front point starts at y = 0 with heading 0.1 rad at 1 m/s and alpha = 0, so
    y(t) = t sin(0.1): read as a lateral error from the line y = 0 it is a ramp with
    max = T sin(0.1), RMS = T sin(0.1) / sqrt(3) and mean = T sin(0.1) / 2.
    """
    from fmpy import simulate_fmu

    fmu = component_fmus["agv_vehicle"]
    stop, heading = 4.0, 0.1
    result = simulate_fmu(str(fmu), stop_time=stop, step_size=0.01, output_interval=0.01,
                          start_values={"heading0": heading}, output=["y", "x"])
    t = np.asarray(result["time"])
    signals = {"vehicle.y": np.asarray(result["y"]), "vehicle.x": np.asarray(result["x"])}
    spec = {"lateral_error": "vehicle.y"}
    spec["reference"] = {"path": "line:x0=0,y0=0,heading=0", "x": "vehicle.x",
                         "y": "vehicle.y"}
    m = compute_metrics(t, signals, spec)
    slope = math.sin(heading)
    # exact arc integration (1e-12) and a trapezoid of a quadratic: relative h^2/T^2 ~ 1e-5
    # over the RMS integral -> rel 1e-5
    assert t[-1] == pytest.approx(stop, abs=1e-9)
    assert m["lateral_error_max"] == pytest.approx(stop * slope, rel=1e-9)
    assert m["lateral_error_mean"] == pytest.approx(stop * slope / 2, rel=1e-9)
    assert m["lateral_error_rms"] == pytest.approx(stop * slope / math.sqrt(3), rel=1e-5)
    assert m["lateral_error_settling_time"] is None   # ends 0.4 m off a 0.02 m band
    assert m["path_error_rms"] == pytest.approx(m["lateral_error_rms"], abs=1e-9)


def test_project_trajectory_follows_a_circle_over_more_than_one_lap():
    # a point 1 m inside a ccw circle of radius 5 (so 1 m left of it), one and a half
    # laps: closed form offset 1 m and arc length 5 * angle, the arc continuing past one
    # lap because each projection starts from the previous one (1e-9 m: far above the
    # projection's rounding, far below any real error)
    from agv_core.numerics.paths import CirclePath, project_trajectory

    angles = np.linspace(0.1, 3.0 * math.pi, 200)
    xs, ys = 4.0 * np.sin(angles), 5.0 - 4.0 * np.cos(angles)
    offsets, arcs = project_trajectory(CirclePath(5.0), xs, ys)
    np.testing.assert_allclose(offsets, 1.0, atol=1e-9)
    np.testing.assert_allclose(arcs, 5.0 * angles, atol=1e-9)
    empty = project_trajectory(CirclePath(5.0), [], [], s_hint=2.0)
    assert len(empty[0]) == len(empty[1]) == 0
