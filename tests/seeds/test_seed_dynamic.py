"""Kinematic against dynamic plants in the seed experiments (experiments/seed000_dynamic.toml,
seed003_dynamic_speed.toml, seed004_dynamic.toml), shortened, through the orchestrator and
the FMUs; the numbers the results pages quote, with stated bounds.

Shortened runs: seed 000 at 1 and 4 m/s for 10 s (models a and b); seed 003 at 14 km/h
until axle 4 has left the 20 m curve (29 s), and the faster speeds on the same cores in a
plain-Python loop that the first seed-003 test shows equal to the FMU run; seed 004 the
2.77 m circle for 25 s.
"""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from agv_core.axle_pd.fuzzy_pd import AxlePD, FixedGains, FuzzySchedule
from agv_core.axle_pd.track_path import PointErrors, parse_track_path
from agv_core.dynamic_train.dynamic_train import DynamicTrain, TrainDynamics
from agv_core.dynamic_vehicle.dynamic_vehicle import SingleTrackParameters, WheelLiftError
from agv_core.state_feedback.state_feedback import PAPER_GAINS, loop_poles
from agv_core.train.train import TrainGeometry
from agv_cosim.pipeline import run_manifest
from agv_cosim.timeseries import read_timeseries

from manifests import assert_complete, localise

pytestmark = pytest.mark.seed

EXPERIMENTS = Path(__file__).resolve().parents[2] / "experiments"
E0 = 0.1
WHEELBASE = 1.4944
GEOM = TrainGeometry(5.0, 3.0, 2.1, 9.0)
QUARTER = math.pi / 2


def _load(out, run):
    return read_timeseries(out / run / "timeseries.csv")


def _prony_damping(t, e, order, t_max=8.0):
    e = e[t <= t_max]
    ts = t[1] - t[0]
    n = len(e)
    lhs = np.column_stack([e[order - 1 - i:n - 1 - i] for i in range(order)])
    coeffs = np.linalg.lstsq(lhs, e[order:], rcond=None)[0]
    poles = np.log(np.roots(np.r_[1.0, -coeffs]).astype(complex)) / ts
    pairs = poles[poles.imag > 0.1]
    pair = pairs[np.argmax(pairs.real)]
    return -pair.real / abs(pair)


def _seed000_plant():
    """The manifest's AGV with linear tyres (0.12 per degree of 1962 N per axle)."""
    c = 13489.0
    return SingleTrackParameters(WHEELBASE, 400.0, 167.0, 0.7472, c, c, 0.8, "linear")


# ---------------------------------------------------------------------------- seed 000
@pytest.fixture(scope="module")
def seed000(component_fmus, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("seed000_dynamic")
    manifest = localise(EXPERIMENTS / "seed000_dynamic.toml", tmp, component_fmus,
                        replace=[("stop = 15.0", "stop = 10.0")],
                        resub=[(r'^"vehicle\.v0" = \[.*\]', '"vehicle.v0" = [1.0, 4.0]')])
    out, results, _ = run_manifest(manifest, tmp / "out", quiet=True, workers=2,
                                   variants=["a_kin", "a_dyn", "b_kin", "b_dyn"])
    assert_complete(results, 8)
    return {(r, v): _load(out, f"{r}__vehicle.v0={v}")
            for r in ("a_kin", "a_dyn", "b_kin", "b_dyn") for v in (1.0, 4.0)}


@pytest.mark.parametrize("model", ["a", "b"])
def test_seed000_at_1_m_per_s_slip_does_not_matter(seed000, model):
    """The paper neglects tyre slip because the AGV is slow: at 1 m/s the dynamic
    vehicle's deviation is within 2 % of the step of the kinematic one's (measured 1.1 %
    for a, 1.0 % for b: the size of the a/b difference itself, 1.8 %)."""
    (tk, sk), (td, sd) = seed000[f"{model}_kin", 1.0], seed000[f"{model}_dyn", 1.0]
    assert np.array_equal(tk, td)
    diff = np.max(np.abs(sk["sensor.lateral_error"] - sd["sensor.lateral_error"]))
    assert 0.002 * E0 < diff < 0.02 * E0


def test_seed000_linear_dynamic_loop_has_the_analysed_damping(seed000):
    """Model b on the linear single-track model is a linear loop: the damping of its
    dominant pair fitted to the simulation (5th-order recurrence) equals the closed-loop
    poles (state_feedback.loop_poles with the single-track plant) within 0.015 at 1 m/s
    (0.663) and at 4 m/s (0.019), as for the kinematic model b."""
    plant = _seed000_plant()
    for v in (1.0, 4.0):
        t, s = seed000["b_dyn", v]
        fitted = _prony_damping(t, s["sensor.lateral_error"], 5)
        expected = loop_poles(PAPER_GAINS, v, WHEELBASE, 0.6, plant)["dominant_damping"]
        assert fitted == pytest.approx(expected, abs=0.015)


def test_seed000_at_4_m_per_s_slip_makes_model_a_unstable(seed000):
    """Model a at 4 m/s: the kinematic loop is poorly damped but stable (its stability
    limit is 4.59 m/s by the Pade analysis), the dynamic one is unstable (limit 3.54 m/s):
    its deviation grows into a limit cycle at the 35 deg end stop (> e0 in the last 2 s)
    while the kinematic one decays (0.17 e0 in the last 2 s, below its 0.64 e0 overshoot)."""
    (tk, sk), (td, sd) = seed000["a_kin", 4.0], seed000["a_dyn", 4.0]
    late_kin = np.max(np.abs(sk["sensor.lateral_error"][tk >= 8.0]))
    late_dyn = np.max(np.abs(sd["sensor.lateral_error"][td >= 8.0]))
    assert late_kin < 0.25 * E0 < E0 < late_dyn
    assert np.max(np.abs(sd["act.alpha"])) == pytest.approx(0.61, abs=1e-9)
    plant = _seed000_plant()
    assert loop_poles(PAPER_GAINS, 4.0, WHEELBASE, 0.6, delay=0.05)["stable"]
    assert not loop_poles(PAPER_GAINS, 4.0, WHEELBASE, 0.6, plant, delay=0.05)["stable"]
    assert loop_poles(PAPER_GAINS, 3.0, WHEELBASE, 0.6, plant, delay=0.05)["stable"]


# ---------------------------------------------------------------------------- seed 003
def closed_loop_003(v_kmh, fuzzy, h=0.002, past=5.0, stop=None, every=1):
    """seed003_dynamic_speed.toml's loop on the pure cores with the dynamic train
    (Gauss-Seidel order: train outputs -> errors -> PD -> train step); the maximum
    |offset| [m] of each axle over every ``every``-th step (10: the manifest's 20 ms
    record)."""
    path = parse_track_path(f"curve:straight=60,radius=20,angle={QUARTER}")
    v = v_kmh / 3.6
    train = DynamicTrain.straight(TrainDynamics(GEOM), 8.0, 0.0, 0.0)
    train.start(v, (0.0,) * 4)
    probe = PointErrors(path, 4)
    gains = FuzzySchedule() if fuzzy else FixedGains(710.0, 112.0)
    pds = [AxlePD(gains) for _ in range(4)]
    steps = int(round(stop / h)) if stop else int(math.ceil((path.s4 + past + 17.0) / v / h))
    worst = [0.0] * 4
    for k in range(steps):
        points = train.axle_points()
        errors = [p.offset for p in probe.measure(points)]
        u3 = train.car_speeds()[3]
        deltas = [pd.evaluate(e, v if i < 2 else u3)["delta"]
                  for i, (pd, e) in enumerate(zip(pds, errors))]
        if k % every == 0:
            worst = [max(w, abs(e)) for w, e in zip(worst, errors)]
        train.step(v, deltas, h)
        probe.measure(points, commit=True)
        for pd, e in zip(pds, errors):
            pd.advance(e, h)
    return worst


@pytest.fixture(scope="module")
def seed003(component_fmus, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("seed003_dynamic")
    manifest = localise(EXPERIMENTS / "seed003_dynamic_speed.toml", tmp, component_fmus,
                        replace=[("stop = 47.0", "stop = 29.0")],
                        resub=[(r'^"train\.v0" = \[.*\]', '"train.v0" = [3.888888888888889]')])
    out, results, _ = run_manifest(manifest, tmp / "out", quiet=True, workers=2,
                                   variants=["dyn_fuzzy", "dyn_fixed"])
    assert_complete(results, 2)
    return {v: _load(out, f"{v}__train.v0=3.888888888888889")[1]
            for v in ("dyn_fuzzy", "dyn_fixed")}


def test_seed003_fmu_run_equals_the_pure_core_loop(seed003):
    """Same cores and order, wheel angles through the Ackermann FMU and back by the exact
    inverse: the per-axle maxima over the 20 ms record agree to 1e-12 m (rounding of the
    inverse: ~1e-15 m measured). The maxima are transient peaks here, so both sides take
    them over the same instants."""
    for variant, fuzzy in (("dyn_fuzzy", True), ("dyn_fixed", False)):
        fmu = [float(np.max(np.abs(seed003[variant][f"err.e{i}"]))) for i in range(1, 5)]
        assert closed_loop_003(14.0, fuzzy, stop=29.0, every=10) == pytest.approx(fmu,
                                                                                 abs=1e-12)


def test_seed003_dynamic_train_keeps_the_paper_bound_at_14_km_per_h(seed003):
    """Claim 003-A1 on the dynamic train (two tyres per axle, cg height 1.2 m): at
    14 km/h every axle stays within 2.5 cm (measured 1.15 / 0.97 / 1.14 / 0.92 cm fuzzy,
    1.19 / 0.96 / 1.17 / 0.91 fixed; the kinematic train 1.04 / 0.98 / 1.04 / 0.98): the
    tyres' slip (axle centres 0.65-0.71 deg at 0.76 m/s^2) moves the front axles out by
    ~1 mm."""
    for variant in ("dyn_fuzzy", "dyn_fixed"):
        worst = [float(np.max(np.abs(seed003[variant][f"err.e{i}"]))) for i in range(1, 5)]
        assert max(worst) < 0.025
        assert 0.0105 < worst[0] < 0.0125


def test_seed003_speed_where_the_dynamic_train_loses_the_curve():
    """Pure-core loop (equal to the FMUs, above) on the dynamic train with two tyres per
    axle and lateral load transfer (cg height 1.2 m): at 30 km/h the fixed PD keeps every
    axle within the paper's 2.5 cm (measured 2.19 cm) and the fuzzy schedule does not
    (3.71 cm, axle 1): the fixed gains win by > 1 mm (1.5 cm). At 35 km/h neither law
    holds the curve: the fixed loop's axle 1 is 53 cm off, and under the fuzzy schedule
    the tail car's axle 3 left wheel lifts at 8.18 s (the step fails with
    WheelLiftError), whereas the kinematic train stays within 1.04 cm at every speed.
    (With one lumped tyre per axle: 1.95 cm fuzzy, 2.11 cm fixed at 30 km/h; 45 / 39 cm
    at 35 km/h.)"""
    fuzzy30, fixed30 = max(closed_loop_003(30.0, True)), max(closed_loop_003(30.0, False))
    assert fixed30 < 0.025 < fuzzy30
    assert fuzzy30 - fixed30 > 0.001
    assert max(closed_loop_003(35.0, False)) > 0.1
    with pytest.raises(WheelLiftError, match="axle 3's left wheel lifts"):
        closed_loop_003(35.0, True)


# ---------------------------------------------------------------------------- seed 004
@pytest.fixture(scope="module")
def seed004(component_fmus, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("seed004_dynamic")
    manifest = localise(EXPERIMENTS / "seed004_dynamic.toml", tmp, component_fmus,
                        replace=[("stop = 45.0", "stop = 25.0")])
    out, results, _ = run_manifest(manifest, tmp / "out", quiet=True, workers=2,
                                   variants=["r277_kin", "r277_dyn"])
    assert_complete(results, 4)
    return {(v, dr): json.loads((out / f"{v}__ctrl.dead_reckoning={dr}" / "metrics.json")
                                .read_text())
            for v in ("r277_kin", "r277_dyn") for dr in ("False", "True")}


def test_seed004_slip_moves_the_tractor_outwards_on_the_tight_circle(seed004):
    """On the 2.77 m circle (0.81 m/s^2) the rear axle slides outwards: with dead
    reckoning (where the kinematic loop is within 1.5 cm) the settled mean offset moves
    outwards (more negative) by more than 1 cm on the dynamic tractor; with the paper's
    law it moves outwards too. Stats over 10-25 s."""
    for dr in ("False", "True"):
        kin = seed004["r277_kin", dr]["lateral_error_settled_signed_mean"]
        dyn = seed004["r277_dyn", dr]["lateral_error_settled_signed_mean"]
        assert dyn < kin - 0.01
