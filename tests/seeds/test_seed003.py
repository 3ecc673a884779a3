"""Seed 003 (issue 14): the paper's claims as numbers, through the orchestrator and the FMUs.

The shipped manifest experiments/seed003_curve.toml runs in tmp_path with its FMU paths
pointed at the session-built FMUs, shortened from 36 s to 29 s (axle 4 leaves the 20 m
arc after 27.9 s) and limited to the fuzzy and fixed variants without transition. The
speed and radius comparisons use the same cores in a plain-Python closed loop
(:func:`closed_loop`), which the first test shows equal to the FMU run to rounding, so a
sweep costs ~1 s per run instead of ~10 s.
"""

import math
from pathlib import Path

import numpy as np
import pytest

from agv_core.axle_pd.fuzzy_pd import AxlePD, FixedGains, FuzzySchedule
from agv_core.axle_pd.track_path import PointErrors, parse_track_path
from agv_core.train.train import Train, TrainGeometry, steady_offsets
from agv_cosim.pipeline import run_manifest
from agv_cosim.timeseries import read_timeseries

from manifests import assert_complete, localise

pytestmark = pytest.mark.seed

EXPERIMENTS = Path(__file__).resolve().parents[2] / "experiments"
GEOM = TrainGeometry(5.0, 3.0, 2.1, 9.0)
QUARTER = math.pi / 2
V14 = 14 / 3.6
STOP = 29.0
FIXED = (710.0, 112.0)      # deg/m, deg s/m: AgvFixedPd's defaults


@pytest.fixture(scope="module")
def curve_runs(component_fmus, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("seed003")
    manifest = localise(EXPERIMENTS / "seed003_curve.toml", tmp, component_fmus,
                        replace=[("stop = 36.0", f"stop = {STOP}")])
    out, results, _ = run_manifest(manifest, tmp / "out", variants=["fuzzy", "fixed"],
                                   workers=2, quiet=True)
    assert_complete(results, 2)
    return {name: read_timeseries(out / name / "timeseries.csv")[1]
            for name in ("fuzzy", "fixed")}


def closed_loop(v_kmh=14.0, radius=20.0, fuzzy=True, h=0.002, past=5.0, schedule=None):
    """The manifest's loop on the pure cores (Gauss-Seidel order: train outputs -> errors
    -> PD -> train step), until axle 4 is ``past`` m beyond the arc. Returns the maximum
    |offset| [m] of each axle and the time series of offsets."""
    path = parse_track_path(f"curve:straight=60,radius={radius},angle={QUARTER}")
    train = Train.straight(GEOM, 8.0, 0.0, 0.0)
    train.u1 = v_kmh / 3.6
    probe = PointErrors(path, 4)
    gains = (schedule or FuzzySchedule()) if fuzzy else FixedGains(*FIXED)
    pds = [AxlePD(gains) for _ in range(4)]
    v = v_kmh / 3.6
    steps = int(math.ceil((path.s4 + past + 17.0) / v / h))
    worst = [0.0] * 4
    for _ in range(steps):
        points = train.axle_points()
        errors = [p.offset for p in probe.measure(points)]
        u3 = train.car_rates()[0]
        deltas = [pd.evaluate(e, v if i < 2 else u3)["delta"]
                  for i, (pd, e) in enumerate(zip(pds, errors))]
        worst = [max(w, abs(e)) for w, e in zip(worst, errors)]
        train.step(v, deltas, h)
        probe.measure(points, commit=True)
        for pd, e in zip(pds, errors):
            pd.advance(e, h)
    return worst


def test_fmu_run_equals_the_pure_core_loop(curve_runs):
    """Same cores, same order, wheel angles through the Ackermann FMU and back by the
    exact inverse: the per-axle maxima agree to 1e-12 m (rounding of the inverse)."""
    fmu = [float(np.max(np.abs(curve_runs["fuzzy"][f"err.e{i}"]))) for i in range(1, 5)]
    assert closed_loop() == pytest.approx(fmu, abs=1e-12)


@pytest.mark.parametrize("variant", ["fuzzy", "fixed"])
def test_every_axle_stays_within_2_5_cm(curve_runs, variant):
    """Claim 003-A1/A5: at 14 km/h through the 20 m curve every axle's maximum lateral
    offset is below 2.5 cm (paper). Ours: 1.04 / 0.98 / 1.04 / 0.98 cm (fuzzy), so the
    claim holds with a factor 2.4 to spare; the margin is the kinematic plant (below)."""
    s = curve_runs[variant]
    worst = [float(np.max(np.abs(s[f"err.e{i}"]))) for i in range(1, 5)]
    assert max(worst) < 0.025
    assert min(worst) > 0.009      # the curve is felt on every axle: not a vacuous pass


@pytest.mark.parametrize("variant", ["fuzzy", "fixed"])
def test_steady_state_matches_the_closed_form_and_settles(curve_runs, variant):
    """In the steady window of each powered car (its rear axle >= 10 m into the arc,
    its front axle still on it: ~16 m of travel) the offsets equal the closed-form steady
    state of the P part (agv_core.train.steady_offsets: delta_i = -Kp(e_i) e_i with the
    car rotating about the arc centre) within 1e-7 m, the axle angles within 1e-6 rad,
    and every axle and wheel angle varies by less than 0.001 deg peak to peak (claim
    003-A3, 'small variation of the steady wheel angles'). Measured: 2e-9 m and 1e-7 deg
    (fuzzy), 2e-8 m and 1.2e-6 deg (fixed, whose Kd = 112 deg s/m leaves a slower
    filter mode); the P loop's time constant 1 / (Kp v) is ~20 ms, 10 m of arc ~130 of
    them, so the bounds are far from the transient and far above rounding."""
    s = curve_runs[variant]
    schedule = FuzzySchedule()
    kp = ((lambda e: math.radians(schedule.gains(e, 14.0)[0])) if variant == "fuzzy"
          else (lambda e: math.radians(FIXED[0])))
    e_f, e_r, d_f, d_r = steady_offsets(GEOM, 20.0, kp)
    arc_end = 60.0 + 20.0 * QUARTER
    for front, rear in ((1, 2), (3, 4)):
        window = (s[f"err.s{rear}"] >= 70.0) & (s[f"err.s{front}"] <= arc_end)
        assert np.ptp(s["train.distance"][window]) > 15.0
        for axle, e_ss, d_ss in ((front, e_f, d_f), (rear, e_r, d_r)):
            assert s[f"err.e{axle}"][window] == pytest.approx(e_ss, abs=1e-7)
            assert s[f"pd{axle}.delta"][window] == pytest.approx(d_ss, abs=1e-6)
            for name in (f"pd{axle}.delta", f"ack.delta{axle}_left",
                         f"ack.delta{axle}_right"):
                assert math.degrees(np.ptp(s[name][window])) < 1e-3
        # claim 003-A2: per axle, the inner wheel (nearer the axle's own turning centre on
        # its car's hinge baseline, left when delta l > 0) turns more than the outer one.
        # Axles 1 and 3 steer left (+), 2 and 4 right (-); axle 3 lies behind J2 (l < 0),
        # so its centre is on the right although it steers left.
        k = np.flatnonzero(window)[len(np.flatnonzero(window)) // 2]
        for axle in (front, rear):
            delta = s[f"pd{axle}.delta"][k]
            left, right = s[f"ack.delta{axle}_left"][k], s[f"ack.delta{axle}_right"][k]
            centre_left = delta * GEOM.axle_offsets[axle - 1] > 0
            inner, outer = (left, right) if centre_left else (right, left)
            assert abs(inner) > abs(delta) > abs(outer) > 0
            assert np.sign(inner) == np.sign(outer) == np.sign(delta)


@pytest.mark.parametrize("variant", ["fuzzy", "fixed"])
def test_steady_wheel_speeds_match_the_rotation_about_the_arc_centre(curve_runs, variant):
    """Claim 003-A2, wheel speeds: in steady curving the head car turns about the arc
    centre C; from the closed-form offsets, C is at body (cx, cy) from J1 with
    cx = (a1 + a2)/2 - (r1^2 - r2^2) / (2 L1), cy = sqrt(r1^2 - (a1 - cx)^2), the yaw rate
    is u1 / cy and each wheel's speed is the yaw rate times its distance from C: axle 1's
    inner (left) wheel 3.718 m/s, outer 4.126 m/s at 3.889 m/s. Within 1e-6 relative
    (the offsets match the closed form to 1e-7 m)."""
    s = curve_runs[variant]
    schedule = FuzzySchedule()
    kp = ((lambda e: math.radians(schedule.gains(e, 14.0)[0])) if variant == "fuzzy"
          else (lambda e: math.radians(FIXED[0])))
    e_f, e_r, _, _ = steady_offsets(GEOM, 20.0, kp)
    a1, a2 = GEOM.axle_offsets[:2]
    r1, r2 = 20.0 - e_f, 20.0 - e_r
    cx = 0.5 * (a1 + a2) - (r1 ** 2 - r2 ** 2) / (2 * GEOM.L1)
    cy = math.sqrt(r1 ** 2 - (a1 - cx) ** 2)
    rate = V14 / cy
    window = (s["err.s2"] >= 70.0) & (s["err.s1"] <= 60.0 + 20.0 * QUARTER)
    for side, w in (("left", GEOM.d / 2), ("right", -GEOM.d / 2)):
        expected = rate * math.hypot(a1 - cx, w - cy)
        assert s[f"train.speed1_{side}"][window] == pytest.approx(expected, rel=1e-6)
    assert np.all(s["train.speed1_left"][window] < V14 / np.cos(s["pd1.delta"][window]))
    assert np.all(s["train.speed1_right"][window] > V14 / np.cos(s["pd1.delta"][window]))


def test_wheels_slip_a_little(curve_runs):
    """Claim 003-A4: single-axle coordination cannot give pure rolling of every wheel.
    With O1 != O2 the wheels slip: max |slip| is > 0.1 deg and < 2 deg here (0.73 deg)."""
    s = curve_runs["fuzzy"]
    slip = max(float(np.max(np.abs(s[f"train.slip{k}_{side}"])))
               for k in range(1, 5) for side in ("left", "right"))
    assert math.radians(0.1) < slip < math.radians(2.0)


@pytest.fixture(scope="module")
def sweep():
    schedule = FuzzySchedule()
    out = {}
    # 5 km/h with 5 ms steps (the loop is 2.8 times slower in time there; the manifest's
    # 2 ms would cost 46 000 steps)
    for key, kwargs in (("v5", {"v_kmh": 5.0, "h": 0.005}), ("v40", {"v_kmh": 40.0}),
                        ("r15", {"radius": 15.0}), ("r50", {"radius": 50.0})):
        for fuzzy in (True, False):
            out[key, fuzzy] = max(closed_loop(fuzzy=fuzzy, schedule=schedule, **kwargs))
    return out


def test_speed_sweep_fuzzy_no_worse_and_speed_barely_matters(sweep, curve_runs):
    """Speed sweep (20 m curve): the fuzzy PD is no worse than the fixed PD at 5, 14 and
    40 km/h (by 0.08 mm: its Kp at e ~ 1 cm is just above 710 deg/m), and the maximum
    offset changes by < 0.1 mm between 5 and 40 km/h for either law. Why: with ideal
    steering the kinematic loop is first order in distance, the maximum is the steady
    P offset delta_ss / Kp, which does not depend on speed; the speed-scheduled gains
    change nothing that matters here."""
    at14 = {f: max(float(np.max(np.abs(curve_runs[f][f"err.e{i}"]))) for i in range(1, 5))
            for f in ("fuzzy", "fixed")}
    for key in ("v5", "v40"):
        assert sweep[key, True] <= sweep[key, False]
        assert sweep[key, True] == pytest.approx(at14["fuzzy"], abs=1e-4)
        assert sweep[key, False] == pytest.approx(at14["fixed"], abs=1e-4)
    assert at14["fuzzy"] <= at14["fixed"]


def test_radius_sweep_fuzzy_is_worse_on_wide_curves(sweep):
    """Radius sweep at 14 km/h: the fuzzy PD beats the fixed one on the tight 15 m curve
    (larger errors -> larger scheduled Kp) but is WORSE on the 50 m curve (errors of
    ~4 mm, where the proposed table's Kp falls towards 500 deg/m < 710): 0.48 vs 0.42 cm.
    So 'fuzzy no worse than fixed' does not hold across the radius sweep."""
    assert sweep["r15", True] < sweep["r15", False] - 5e-4
    assert sweep["r50", True] > sweep["r50", False] + 4e-4
    for key in ("r15", "r50"):
        assert sweep[key, True] < 0.025 and sweep[key, False] < 0.025
