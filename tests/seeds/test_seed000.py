"""Seed 000 reproduction: the experiments/seed000_*.toml manifests run through the
orchestrator, checked against the paper's claims and against the linear closed loop.

The manifests are copied into tmp_path with their FMU paths pointed at the session-built
FMUs (``component_fmus``); the speed study is trimmed to 1-4 m/s and 10 s to keep the file
under a minute. All runs use the manifests' 1 ms step.
"""

import csv
import re

import control
import numpy as np
import pytest
import scipy.linalg

from agv_core.state_feedback.state_feedback import PAPER_GAINS, closed_loop, model_b
from agv_cosim.pipeline import run_manifest

from manifests import assert_complete, localise

pytestmark = pytest.mark.seed

EXPERIMENTS = __import__("pathlib").Path(__file__).resolve().parents[2] / "experiments"
WHEELBASE = 1.4944   # [m], find_wheelbase(), as in the manifests
K_ACT = 0.6          # [rad/(V.s)]
E0 = 0.1             # [m] initial lateral offset of the front wheel (the step)
STEP = 0.001         # [s] the manifests' communication step

def _localise(name, tmp_path, fmus, resub=()):
    """Copy manifest ``name`` into tmp_path with fmu paths pointing at ``fmus``."""
    text = (EXPERIMENTS / name).read_text()
    assert re.search(r"^step = 0\.001$", text, re.M), "the manifests use a 1 ms step"
    return localise(EXPERIMENTS / name, tmp_path, fmus, resub=resub)


def _series(out, run):
    with open(out / run / "timeseries.csv", newline="") as handle:
        rows = list(csv.reader(handle))
    head, data = rows[0], np.array(rows[1:], dtype=float)
    return {name: data[:, i] for i, name in enumerate(head)}


@pytest.fixture(scope="module")
def abc(component_fmus, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("seed000_abc")
    out, results, _ = run_manifest(_localise("seed000_models_abc.toml", tmp, component_fmus),
                                   out_dir=tmp / "out", quiet=True)
    assert_complete(results, 3)
    return {m: _series(out, m) for m in "abc"}


@pytest.fixture(scope="module")
def speed(component_fmus, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("seed000_speed")
    trim = [(r'^"vehicle\.v0" = \[.*\]', '"vehicle.v0" = [1.0, 2.0, 3.0, 4.0]'),
            (r"^stop = 15\.0$", "stop = 10.0")]
    out, results, _ = run_manifest(_localise("seed000_speed.toml", tmp, component_fmus, trim),
                                   out_dir=tmp / "out", quiet=True)
    assert_complete(results, 8)
    with open(out / "summary.csv", newline="") as handle:
        summary = {row["run"]: row for row in csv.DictReader(handle)}
    runs = {}
    for m in "ab":
        for v in (1.0, 2.0, 3.0, 4.0):
            label = f"{m}__vehicle.v0={v}"
            runs[m, v] = (_series(out, label), summary[label])
    return runs


# ------------------------------------------------------------------ linear references
def _linear_response(V0, t, delay=0.0):
    """e(t) [m] of model b's continuous closed loop from e(0) = E0, optionally with a
    loop delay [s] on u (7th-order Pade, exact enough below 0.07 s at these frequencies)."""
    A, B = model_b(V0, WHEELBASE, K_ACT)
    plant = control.ss(A, B, np.eye(3), np.zeros((3, 1)))
    if delay > 0.0:
        num, den = control.pade(delay, 7)
        plant = control.series(control.ss(control.tf(num, den)), plant)
    gain = control.ss(np.zeros((0, 0)), np.zeros((0, 3)), np.zeros((1, 0)),
                      np.atleast_2d(PAPER_GAINS))
    loop = control.feedback(plant, gain)
    x0 = np.zeros(loop.nstates)
    x0[-1] = E0   # the plant's states come last: (alpha, beta, e)
    return np.asarray(control.initial_response(loop, T=t, X0=x0).outputs[2])


def _exact_b(V0, t):
    """e(t) [m] of model b's continuous closed loop, by the matrix exponential."""
    A, B = model_b(V0, WHEELBASE, K_ACT)
    acl = A - B @ np.atleast_2d(PAPER_GAINS)
    return np.array([(scipy.linalg.expm(acl * s) @ [0.0, 0.0, E0])[2] for s in t])


def _prony_damping(t, e, order=3, t_max=8.0):
    """Damping ratio of the oscillatory pole pair of a fitted ``order`` recurrence.

    e sampled uniformly is fitted by least squares with e[k] = sum a_i e[k-i]; for a
    noise-free response of an order-n LTI system the roots are its discrete poles exactly.
    """
    e = e[t <= t_max]
    ts = t[1] - t[0]
    n = len(e)
    lhs = np.column_stack([e[order - 1 - i:n - 1 - i] for i in range(order)])
    coeffs = np.linalg.lstsq(lhs, e[order:], rcond=None)[0]
    poles = np.log(np.roots(np.r_[1.0, -coeffs]).astype(complex)) / ts
    pair = poles[np.argmax(poles.imag)]
    assert pair.imag > 0.1
    return -pair.real / abs(pair)


def _zero_crossings(e):
    return int(np.sum(np.signbit(e[1:]) != np.signbit(e[:-1])))


# ------------------------------------------------------------------ Fig. 4: models a, b, c
def test_deviations_coincide_as_the_actuator_delay_predicts(abc):
    eb = abc["b"]["sensor.lateral_error"]
    t = abc["b"]["time"]
    d_a = np.max(np.abs(abc["a"]["sensor.lateral_error"] - eb)) / E0
    d_c = np.max(np.abs(abc["c"]["sensor.lateral_error"] - eb)) / E0
    # prediction: a = b with a 0.05 s loop delay (linear, continuous) -> 0.0184 e0.
    pred_a = np.max(np.abs(_linear_response(1.0, t, 0.05) - _linear_response(1.0, t))) / E0
    assert pred_a == pytest.approx(0.0184, abs=5e-4)
    # measured 0.0184: the nonlinear kinematics (|alpha| <= 0.07 rad, error O(alpha^2)
    # ~ 0.5 %) and the 1 ms holds move it little: 10 % tolerance.
    assert d_a == pytest.approx(pred_a, rel=0.10)
    # c: eq 7's rate lag has the low-frequency equivalent delay (group delay at 0)
    # 15.7926/195.23 - 8.91/506.3 = 0.0633 s -> 0.0241 e0; its second-order transient
    # is not a pure delay (measured 0.0291): within a factor 1.5 either way.
    tau_c = 15.7926 / 195.23 - 8.91 / 506.3
    pred_c = np.max(np.abs(_linear_response(1.0, t, tau_c) - _linear_response(1.0, t))) / E0
    assert pred_c / 1.5 < d_c < 1.5 * pred_c
    # "nearly coincide": all below 4 % of the step
    assert max(d_a, d_c) < 0.04


def test_control_signals_differ_more_than_deviations(abc):
    ub = abc["b"]["ctrl.u"]
    eb = abc["b"]["sensor.lateral_error"]
    for m in "ac":
        d_e = np.max(np.abs(abc[m]["sensor.lateral_error"] - eb)) / np.max(np.abs(eb))
        d_u = np.max(np.abs(abc[m]["ctrl.u"] - ub)) / np.max(np.abs(ub))
        # u feeds alpha back directly (Ka), which the actuator lag shifts by ~tau while e
        # integrates alpha twice and smooths it: measured d_u/d_e = 7.6 (a), 6.3 (c).
        # A factor 3 states "differ more" with margin.
        assert d_u > 3.0 * d_e, m
        assert d_u > 0.10   # measured 0.140 (a), 0.184 (c) of the peak |u| = 0.447 V


def test_model_b_matches_the_continuous_closed_loop(abc, speed):
    # Model b is linear and every FMU is exact for held inputs, so the only difference
    # to the continuous loop is the hold of u and alpha over a step: about h/2 each of
    # loop delay, h in all (the master reads act.alpha at the start of each pass, so no
    # FMU gets it a step late). A hold is a delay only at low frequency: measured, the
    # error is that of a 1.1-1.6 h delay. Tolerance: the effect of a 3 h loop delay on
    # the linear response (3 x the h the holds add, ~2 x the largest measured).
    for V0, series in [(1.0, abc["b"])] + [(v, speed["b", v][0]) for v in (2.0, 3.0, 4.0)]:
        t, e = series["time"], series["sensor.lateral_error"]
        err = np.max(np.abs(e - _exact_b(V0, t)))
        bound = np.max(np.abs(_linear_response(V0, t, 3 * STEP) - _linear_response(V0, t)))
        assert err < bound, (V0, err, bound)
        # and the bound itself is small: < 1.5 % of e0 even at 4 m/s
        assert bound < 0.015 * E0


def test_model_b_damping_matches_closed_loop_poles(speed):
    # zeta of the fitted 3rd-order recurrence vs the dominant pair of closed_loop().
    # Expected 0.678, 0.351, 0.209, 0.126; measured 0.678, 0.350, 0.208, 0.124. The extra
    # loop delay of the holds (~h) shifts zeta by <~ 0.01 (a 1 ms delay at 4 m/s lowers
    # it by 0.0014); 0.015 absolute.
    for v in (1.0, 2.0, 3.0, 4.0):
        series = speed["b", v][0]
        zeta = _prony_damping(series["time"], series["sensor.lateral_error"])
        expected = closed_loop(PAPER_GAINS, v, WHEELBASE, K_ACT)["min_damping"]
        assert zeta == pytest.approx(expected, abs=0.015), v


# ------------------------------------------------------------------ Fig. 5: speed
def test_overshoot_grows_with_speed(speed):
    for m in "ab":
        ratios = [float(speed[m, v][1]["lateral_error_overshoot_ratio"])
                  for v in (1.0, 2.0, 3.0, 4.0)]
        assert all(b > a for a, b in zip(ratios, ratios[1:])), (m, ratios)
    # model b: a second-order pair alone would give exp(-zeta pi / sqrt(1 - zeta^2)) =
    # 0.05, 0.31, 0.51, 0.67 at 1-4 m/s; the real pole and the zero (s + V0/L) lower it:
    # measured 0.050, 0.215, 0.354, 0.467 (the continuous closed loop: 0.050, 0.214,
    # 0.352, 0.464). Check within 0.05 of those and below the pure second-order value.
    for v, measured in zip((1.0, 2.0, 3.0, 4.0), (0.050, 0.215, 0.354, 0.467)):
        ratio = float(speed["b", v][1]["lateral_error_overshoot_ratio"])
        zeta = closed_loop(PAPER_GAINS, v, WHEELBASE, K_ACT)["min_damping"]
        assert ratio == pytest.approx(measured, abs=0.05)
        assert ratio < np.exp(-zeta * np.pi / np.sqrt(1 - zeta ** 2)) + 0.01


def test_strong_oscillation_above_3_m_per_s(speed):
    # Model a at 4 m/s: the 0.05 s delay brings the pair to zeta ~ 0.05 (Pade analysis)
    # -> overshoot > 0.5 e0 (measured 0.637), >= 12 zero crossings in 10 s (period
    # 2 pi / 4.1 = 1.5 s -> 13), fitted zeta < 0.1 (measured 0.06).
    a4, s4 = speed["a", 4.0]
    assert float(s4["lateral_error_overshoot_ratio"]) > 0.5
    assert _zero_crossings(a4["sensor.lateral_error"]) >= 12
    assert _prony_damping(a4["time"], a4["sensor.lateral_error"]) < 0.1
    # and it is still ringing at the end: with sigma ~ 0.19-0.25 1/s the first peak
    # (0.64 e0 at ~1 s) decays to 0.09-0.14 e0 by 9 s (measured 0.173 e0 over the last
    # 2 s); model b at 4 m/s (sigma 0.48 1/s) is down to ~0.01 e0 there (measured 0.015).
    last = a4["time"] >= a4["time"][-1] - 2.0
    assert np.max(np.abs(a4["sensor.lateral_error"][last])) > 0.08 * E0
    b4, _ = speed["b", 4.0]
    assert np.max(np.abs(b4["sensor.lateral_error"][last])) < 0.03 * E0
    # at 1 m/s, by contrast, |e| is below 0.5 % of e0 after 5 s (settled)
    a1, _ = speed["a", 1.0]
    assert np.max(np.abs(a1["sensor.lateral_error"][a1["time"] >= 5.0])) < 0.005 * E0
