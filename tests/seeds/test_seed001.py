"""Seed 001 experiments (issue 13): the claims 001-R1 ... 001-P3 as numbers.

The shipped manifests experiments/seed001_circle_lambda.toml, seed001_circle_horizon.toml
and seed001_scurve.toml (and seed001_rate_limit.toml, shortened) are copied into tmp_path
with their FMU paths pointed at the session-built FMUs and run in full through the
orchestrator (step 0.2 s: about 4 s per manifest), once per module. Runs are deterministic
(no noise), so every bound below holds with the margin stated beside it on every machine;
the margins absorb changes of the solver's rounding (OSQP tolerance 1e-7, polished), not
randomness.

Definitions (as experiments/figures/seed001_figures.py, which makes the results page):
first-10-s error = time mean of e_pos over [0, 10] s; late error = time mean of e_pos over
[60, 80] s; v_c overshoot = max v_c - 0.4 m/s; steering rate = |theta_f(k) - theta_f(k-1)|/T
of the commanded (ideal) front-wheel angle.
"""

import json
import math
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy.fmi1 import FMICallException

from agv_core.double_steer.seed001_loop import run_loop
from agv_core.lateral_pid.pid import LateralPid
from agv_core.ltv_mpc.ltv_mpc import LtvMpc
from agv_core.ref_trajectory.ref_trajectory import RefTrajectory
from agv_cosim.pipeline import run_manifest
from agv_cosim.timeseries import read_timeseries

from manifests import assert_complete, localise

pytestmark = pytest.mark.seed

EXPERIMENTS = Path(__file__).resolve().parents[2] / "experiments"
T = 0.2
LAMBDAS = ("0.05", "0.1", "1.0", "5.0", "10.0")
HORIZONS = ("5", "6", "7", "8")


def _run(name, component_fmus, tmp_path_factory):
    tmp = tmp_path_factory.mktemp(name)
    manifest = localise(EXPERIMENTS / f"{name}.toml", tmp, component_fmus)
    out, results, _ = run_manifest(manifest, tmp / "out", workers=2, quiet=True)
    assert_complete(results, len(results))
    runs = {}
    for r in results:
        t, sig = read_timeseries(out / r["label"] / "timeseries.csv")
        metrics = json.loads((out / r["label"] / "metrics.json").read_text(encoding="utf-8"))
        runs[r["label"].split("=")[-1]] = (t, sig, metrics)
    return runs


@pytest.fixture(scope="module")
def lam_runs(component_fmus, tmp_path_factory):
    return _run("seed001_circle_lambda", component_fmus, tmp_path_factory)


@pytest.fixture(scope="module")
def horizon_runs(component_fmus, tmp_path_factory):
    return _run("seed001_circle_horizon", component_fmus, tmp_path_factory)


@pytest.fixture(scope="module")
def scurve_runs(component_fmus, tmp_path_factory):
    return _run("seed001_scurve", component_fmus, tmp_path_factory)


def _mean(t, x, t0, t1):
    m = (t >= t0 - 1e-9) & (t <= t1 + 1e-9)
    return float(np.trapezoid(x[m], t[m]) / (t[m][-1] - t[m][0]))


def _first10(run):
    t, sig, _ = run
    return _mean(t, sig["ctrl.e_pos"], 0.0, 10.0)


def _late(run):
    t, sig, _ = run
    return _mean(t, sig["ctrl.e_pos"], 60.0, 80.0)


def test_fmu_runs_equal_the_plain_core_loop(scurve_runs):
    """The FMU loop (orchestrator, Gauss-Seidel, step = T) is the plain loop of the cores:
    the same floats in the same order, so only CSV round-trips could differ (repr: none)."""
    ref = RefTrajectory("scurve", speed=0.4, amplitude=1.5, wavelength=12.0, peak_time=33.7)
    h = ref.at(0.0)["heading"]
    pose0 = (0.5 * math.sin(h), -0.5 * math.cos(h), h)
    for name, ctrl in (("mpc", LtvMpc(horizon=7, lam=0.1)), ("pid", LateralPid())):
        rows = run_loop(ctrl, ref, pose0, 70.0)
        t, sig, _ = scurve_runs[name]
        assert len(rows) == len(t)
        e = np.array([r["e_lat"] for r in rows])
        assert np.max(np.abs(e - sig["ctrl.e_lat"])) < 1e-12, name


def test_r1_every_lambda_tracks(lam_runs):
    """001-R1: all lambda track well: the late error is < 1 % of the first-10-s error
    (measured: at most 0.3 %, lambda = 10)."""
    for lam in LAMBDAS:
        assert _late(lam_runs[lam]) < 0.01 * _first10(lam_runs[lam]), lam


def test_r2_smaller_lambda_smaller_initial_error(lam_runs):
    """001-R2: the first-10-s error grows with lambda (measured 27.8 / 28.1 / 31.6 / 33.4 /
    33.6 cm; every step larger by >= 0.1 cm, the claim is the ordering)."""
    errors = [_first10(lam_runs[lam]) for lam in LAMBDAS]
    assert all(b > a + 0.001 for a, b in zip(errors, errors[1:])), errors


def test_r3_late_errors_similar_lambda_acts_on_the_initial_phase(lam_runs):
    """001-R3: late (60-80 s) errors all < 0.2 cm (the notes' bound; measured <= 0.1 cm),
    and their spread is < 1/20 of the spread of the first-10-s errors (measured 0.1 vs
    5.7 cm): R acts on the initial phase."""
    late = [_late(lam_runs[lam]) for lam in LAMBDAS]
    first = [_first10(lam_runs[lam]) for lam in LAMBDAS]
    assert max(late) < 0.002, late
    assert max(late) - min(late) < (max(first) - min(first)) / 20, (late, first)


def test_n1_longer_horizon_smaller_steady_error(horizon_runs):
    """001-N1: the error after the transient falls with N. Measured on [30, 50] s, where
    it is far above the solver tolerance (mean e_pos 0.99 / 0.16 / 0.032 / 0.0083 mm for
    N = 5 / 6 / 7 / 8); each step of N at least halves it (measured: / 6.2, / 4.9, / 3.9)."""
    errs = [_mean(horizon_runs[n][0], horizon_runs[n][1]["ctrl.e_pos"], 30.0, 50.0)
            for n in HORIZONS]
    assert all(b < 0.5 * a for a, b in zip(errs, errs[1:])), errs


def test_n2_longer_horizon_larger_vc_overshoot(horizon_runs):
    """001-N2: the overshoot of the v_c command grows with N (measured 3.89 / 3.93 / 3.98 /
    4.08 cm/s; each step >= 0.02 cm/s, the claim is the ordering)."""
    over = [horizon_runs[n][1]["ctrl.v_c"].max() - 0.4 for n in HORIZONS]
    assert all(b > a + 2e-4 for a, b in zip(over, over[1:])), over


def test_n3_not_reproduced_rate_set_by_the_increment_bound(horizon_runs):
    """001-N3 says the steering rate stays within 0.2 rad/s for N < 7 and exceeds it
    otherwise, yet the paper picks N = 7: a conflict we report, not force. With our (lost,
    chosen) bound |Delta omega| <= 0.05 rad/s per sample every N exceeds 0.2 rad/s, in the
    first second, while omega climbs at that bound: the peak rate is set by the bound, not
    by N (peaks within 0.001 rad/s of each other)."""
    peaks = []
    for n in HORIZONS:
        t, sig, _ = horizon_runs[n]
        rate = np.abs(np.diff(sig["ik.theta_f"])) / T
        k = int(np.argmax(rate))
        assert rate[k] > 0.2 and t[k + 1] <= 1.0, (n, rate[k], t[k + 1])
        domega = np.diff(sig["ctrl.omega"])
        assert domega[k] == pytest.approx(0.05, abs=1e-6), (n, domega[k])
        peaks.append(rate[k])
    assert max(peaks) - min(peaks) < 1e-3, peaks


def test_p1_pid_overshoots_about_19_cm_after_the_first_curvature_peak(scurve_runs):
    """001-P1 (a calibration check, not a reproduction: Kp was chosen for 19 cm): the PID's
    lateral error peaks at 19 +- 4 cm within [33.7, 40] s, one-sided (the same sign over
    [30, 40] s), after the 33.7 s curvature maximum (it lags it by 1-4 s; measured 2.5 s)."""
    t, sig, _ = scurve_runs["pid"]
    e = sig["ctrl.e_lat"]
    w = (t >= 33.7) & (t <= 40.0)
    k = int(np.argmax(np.where(w, np.abs(e), 0.0)))
    assert 0.15 <= abs(e[k]) <= 0.23, e[k]
    assert 34.7 <= t[k] <= 37.7, t[k]
    side = e[(t >= 30.0) & (t <= 40.0)]
    assert np.all(side > 0) or np.all(side < 0)
    # the curvature maximum of the reference is at 33.7 s
    kap = np.abs(sig["ref.curvature_ref"])
    assert t[int(np.argmax(np.where(t < 40, kap, 0.0)))] == pytest.approx(33.7, abs=T)


def test_p2_mpc_within_minus1_1p1_cm_after_18_s(scurve_runs):
    """001-P2: the MPC's lateral error stays within [-1, 1.1] cm for t >= 18 s (measured
    [-0.56, 0.30] cm: the bound holds with 0.4 cm to spare)."""
    t, sig, _ = scurve_runs["mpc"]
    e = sig["ctrl.e_lat"][t >= 18.0 - 1e-9]
    assert -0.010 <= e.min() and e.max() <= 0.011, (e.min(), e.max())


def test_p3_pid_settles_later_with_larger_error(scurve_runs):
    """001-P3: the PID takes longer to settle (1 cm band: the MPC at 15.8 s, the PID never
    within 70 s) and its error after 18 s is larger (RMS 11 cm against 0.2 cm: > 10x)."""
    mpc, pid = scurve_runs["mpc"][2], scurve_runs["pid"][2]
    assert mpc["lateral_error_settling_time"] is not None
    assert mpc["lateral_error_settling_time"] < 18.0
    assert (pid["lateral_error_settling_time"] is None
            or pid["lateral_error_settling_time"] > mpc["lateral_error_settling_time"])
    assert pid["lateral_error_settled_rms"] > 10 * mpc["lateral_error_settled_rms"]


def test_failed_qp_is_an_fmu_error_naming_the_status(component_fmus):
    """A QP that OSQP does not solve (here: iteration limit 1) fails the FMU call with the
    solver status in the log, never a silent zero command."""
    messages = []

    def logger(component, instance, status, category, message):
        messages.append(message.decode())

    with pytest.raises(FMICallException):
        fmpy.simulate_fmu(str(component_fmus["agv_ltv_mpc"]), stop_time=0.4,
                          start_values={"max_iter": 1, "v_ref": 0.4, "y": -0.5},
                          debug_logging=True, logger=logger)
    assert any("QP not solved" in m and "maximum iterations reached" in m
               for m in messages), messages


def test_n3_steering_activity_after_the_transient_grows_with_n(horizon_runs):
    """What of 001-N3 does hold: after the first 2 s the commanded wheel-angle rate grows
    with N (measured max 0.023 / 0.039 / 0.059 / 0.089 rad/s for N = 5-8, each step
    >= 1.3x): a longer horizon steers more actively once the start transient is over."""
    peaks = []
    for n in HORIZONS:
        t, sig, _ = horizon_runs[n]
        rate = np.abs(np.diff(sig["ik.theta_f"])) / T
        peaks.append(rate[t[1:] > 2.0].max())
    assert all(b > 1.3 * a for a, b in zip(peaks, peaks[1:])), peaks


@pytest.fixture(scope="module")
def rate_limit_runs(component_fmus, tmp_path_factory):
    """experiments/seed001_rate_limit.toml shortened to 8 s and N in {6, 7} (4 runs at a
    10 ms step: the post-transient peaks fall at 3.5-5 s)."""
    tmp = tmp_path_factory.mktemp("seed001_rate_limit")
    manifest = localise(EXPERIMENTS / "seed001_rate_limit.toml", tmp, component_fmus,
                        replace=[("stop = 80.0", "stop = 8.0"),
                                 ("settle_after = 60.0", "settle_after = 6.0"),
                                 ('"ctrl.horizon" = [5, 6, 7, 8]', '"ctrl.horizon" = [6, 7]')])
    out, results, _ = run_manifest(manifest, tmp / "out", workers=2, quiet=True)
    assert_complete(results, len(results))
    return {r["label"]: read_timeseries(out / r["label"] / "timeseries.csv") for r in results}


def test_n3_with_actuators(rate_limit_runs):
    """With the set's steering actuator in angle mode (30 rad/s servo) the wheel follows each
    0.2 s command step quickly: after the start transient (t > 3 s) its peak rate is below
    0.2 rad/s at N = 6 and above at N = 7 (measured 0.12 / 0.28 rad/s), the paper's
    ordering; the crossing depends on our (chosen) servo bandwidth. With rate_max = 0.2 the
    wheel never exceeds it, and symmetric commands keep the body rigid (stretch 0)."""
    peak = {}
    for label, (t, sig) in rate_limit_runs.items():
        rate = np.abs(sig["act_f.alpha_rate"])
        assert np.all(sig["vehicle.stretch"] == 0.0), label
        if label.startswith("limited"):
            assert rate.max() <= 0.2 + 1e-12, label
        peak[label] = rate[t > 3.0].max()
    assert peak["fast__ctrl.horizon=6"] < 0.2 < peak["fast__ctrl.horizon=7"], peak
