"""Seed 002 (issue 6) reproduced as orchestrator experiments, and the results page figures.

The experiments are the manifests ``experiments/seed002_step.toml``,
``experiments/seed002_sine.toml`` and ``experiments/cross_seed_controllers.toml``. The
tests copy them into ``tmp_path`` pointed at the session-built FMUs (``component_fmus``),
run a subset of their runs through :func:`agv_cosim.pipeline.run_manifest`, and check the
numbers quoted on ``experiments/seed002.md``.

The figures and tables of the results page are made from every run of the three
manifests by ``sh experiments/figures/make_seed002.sh`` (experiments/figures/seed002_figures.py
imports the analysis helpers below, so the page and the tests use the same definitions).

The Gauss-Seidel master refreshes the outputs that close a loop backwards before each
pass, so a controller reads the pose at the current communication point: the only time
lag the co-simulation adds to a loop is the zero-order hold of the command over the step
(half a step, 5 ms, on average).
"""

import math
from pathlib import Path

import numpy as np
import pytest

from agv_core.numerics.paths import parse_path, project_trajectory
from agv_cosim.pipeline import run_manifest
from agv_cosim.timeseries import read_timeseries

from manifests import assert_complete, localise

pytestmark = pytest.mark.seed

ROOT = Path(__file__).resolve().parents[2]
EXPERIMENTS = ROOT / "experiments"
KMH = (2, 4, 6, 8, 10, 12, 14)
STEP = 0.01            # [s] communication step of the three manifests
KP, KD = 0.09, 0.6     # seed 002 gains [1/m2], [1/m]
SINE = "sine:amplitude=3,wavelength=30"
LOOPS = {"i": "ideal actuator, exact pose", "d": "delayed actuator, exact pose",
         "ic": "ideal actuator, camera", "dc": "delayed actuator, camera"}


# --------------------------------------------------------------------------- helpers

def step_closed_form(s, step=2.0):
    """Eq (22) response to a lateral step ``step`` [m] at arc length ``s`` [m].

    Kd = 0.6, Kp = 0.09 give a double root -0.3 1/m: with a2(0) = -step, a3(0) = 0 the
    offset is a2(s) = -step (1 + 0.3 s) e^(-0.3 s), so the rear-axle y is step + a2.
    """
    s = np.asarray(s, float)
    return step - step * (1.0 + 0.3 * s) * np.exp(-0.3 * s)


def load(out_dir, label):
    """(time [s], signals) of one run."""
    t, signals = read_timeseries(Path(out_dir) / label / "timeseries.csv")
    return t, signals


def on_grid(distance, values, grid):
    """``values`` interpolated onto the distance ``grid`` [m] (distance is increasing)."""
    return np.interp(grid, distance, values)


def spread(curves):
    """Largest difference between the curves at one grid point, and that point's index."""
    curves = np.asarray(curves)
    gap = curves.max(axis=0) - curves.min(axis=0)
    return float(gap.max()), int(gap.argmax())


def settle_distance(grid, y, target, band=0.02):
    """First distance [m] after which |y - target| <= band for good."""
    outside = np.nonzero(np.abs(np.asarray(y) - target) > band)[0]
    if len(outside) == 0:
        return 0.0
    if outside[-1] + 1 >= len(grid):
        return math.inf
    return float(grid[outside[-1] + 1])


def path_offset(path, x, y):
    """True signed offset [m] of the points (x, y) from ``path`` and their arc lengths."""
    return project_trajectory(path, x, y)


def sine_peaks(x, offset, x_from=40.0, wavelength=30.0, amplitude_sign=None):
    """Peaks of |offset| after ``x_from`` [m]: per half period, (x of the peak, |peak|).

    Half periods are [x_c - W/4, x_c + W/4] around each crest/trough x_c = W/4 + k W/2,
    so the peak's distance from the nearest crest or trough is x_peak - x_c.
    """
    out = []
    k = 0
    while True:
        xc = wavelength / 4 + k * wavelength / 2
        lo, hi = xc - wavelength / 4, xc + wavelength / 4
        k += 1
        if lo < x_from:
            continue
        if hi > x[-1]:
            break
        sel = (x >= lo) & (x < hi)
        j = int(np.argmax(np.abs(offset[sel])))
        out.append((float(x[sel][j] - xc), float(abs(offset[sel][j]))))
    return out


def sf_linear_response(v0, wheelbase=1.4944, K=0.6, tau=0.05, step=STEP, stop=30.0,
                       e0=-0.5):
    """Linear prediction of the cross-seed state-feedback loop at speed ``v0`` [m/s].

    Seed 000 model b (states alpha, beta, e of the front wheel) driven by
    u = -(Ka alpha + Kb beta + Ke e) at the paper's gains, evaluated at every
    communication point and held over the step, reaching the wheel ``tau`` later
    (actuator model a; tau a whole number of steps), discretised exactly. The rear-axle
    offset is e - L beta. Returns the front-wheel overshoot [m] and the distance [m]
    after which the rear-axle offset stays inside 2 cm.
    """
    import scipy.linalg

    from agv_core.state_feedback.state_feedback import PAPER_GAINS, model_b

    A, B = model_b(v0, wheelbase, K)
    m = np.zeros((4, 4))
    m[:3, :3], m[:3, 3:] = A * step, B * step
    phi = scipy.linalg.expm(m)
    ad, bd = phi[:3, :3], phi[:3, 3]
    gains = np.asarray(PAPER_GAINS)
    queue = [0.0] * int(round(tau / step))
    x = np.array([0.0, 0.0, e0])
    front, rear = [x[2]], [x[2] - wheelbase * x[1]]
    for _ in range(int(round(stop / step))):
        queue.append(-float(gains @ x))
        x = ad @ x + bd * queue.pop(0)
        front.append(x[2])
        rear.append(x[2] - wheelbase * x[1])
    dist = v0 * step * np.arange(len(rear))
    return {"front_overshoot": max(0.0, float(np.max(-np.sign(e0) * np.array(front)))),
            "rear_settle_distance": settle_distance(dist, rear, 0.0)}


# --------------------------------------------------------------------------- fixtures

@pytest.fixture(scope="module")
def step_runs(component_fmus, tmp_path_factory):
    """The step manifest at 2, 8 and 14 km/h (the extremes and one in between)."""
    tmp = tmp_path_factory.mktemp("seed002_step")
    manifest = localise(EXPERIMENTS / "seed002_step.toml", tmp, component_fmus,
                        name="step.toml")
    out, results, _ = run_manifest(manifest, tmp / "out", variants=["v02kmh", "v08kmh",
                                                                   "v14kmh"], quiet=True)
    assert_complete(results, 3)
    return out


@pytest.fixture(scope="module")
def sine_runs(component_fmus, tmp_path_factory):
    """The sine manifest, exact pose, over 70 m (2.3 periods)."""
    tmp = tmp_path_factory.mktemp("seed002_sine")
    manifest = localise(EXPERIMENTS / "seed002_sine.toml", tmp, component_fmus,
                        name="sine.toml", replace=[("stop = 60.0 ", "stop = 42.0 ")])
    out, results, _ = run_manifest(manifest, tmp / "out", variants=["pose"], quiet=True)
    assert_complete(results, 1)
    return out


@pytest.fixture(scope="module")
def cross_runs(component_fmus, tmp_path_factory):
    """The cross-seed manifest at 1 and 4 m/s over 30 s."""
    tmp = tmp_path_factory.mktemp("cross_seed")
    manifest = localise(EXPERIMENTS / "cross_seed_controllers.toml", tmp, component_fmus,
                        name="cross.toml",
                        replace=[("stop = 60.0 ", "stop = 30.0 "),
                                 ('"vehicle.v0" = [0.5, 1.0, 2.0, 3.0, 4.0]',
                                  '"vehicle.v0" = [1.0, 4.0]')])
    out, results, _ = run_manifest(manifest, tmp / "out", quiet=True)
    assert_complete(results, 4)
    return out, {r["label"]: r["metrics"] for r in results}


# --------------------------------------------------------------------------- tests

def test_step_closed_form_numbers():
    # eq (22) with the double root -0.3 1/m: 2 cm band reached at s = 22.13 m (README: "a
    # 2 m step is down to 2 cm after about 22 m"); largest slope 0.18 s e^(-0.3 s) at
    # s = 1/0.3 m is 0.6 / e = 0.2207. Tolerances are rounding of the quoted digits.
    s = np.linspace(0, 40, 400001)
    y = step_closed_form(s)
    assert settle_distance(s, y, 2.0) == pytest.approx(22.128, abs=0.001)
    assert np.gradient(y, s).max() == pytest.approx(0.6 / math.e, abs=1e-6)


def test_step_ideal_follows_closed_form(step_runs):
    # With an ideal actuator the only departure from eq (22) is the time lag of the
    # loop: half a step of zero-order hold (see the module docstring), 0.5 h in time =
    # 0.5 v h in distance; times the largest slope 0.2207 that is 0.110 v h. Bound
    # 0.133 v h (20 % margin for the loop's own reaction to it). Measured 0.116 v h.
    for kmh in (2, 8, 14):
        v = kmh / 3.6
        _, sig = load(step_runs, f"v{kmh:02d}kmh")
        err = np.abs(sig["veh_i.y_rear"] - step_closed_form(sig["veh_i.x_rear"])).max()
        assert err <= 0.133 * v * STEP, (kmh, err)
        assert err >= 0.05 * v * STEP, (kmh, err)   # the lag is there: not a vacuous run


def test_step_ideal_coincides_across_speeds(step_runs):
    # Against distance travelled the ideal-actuator runs coincide up to the speed
    # dependent lag 0.110 v h: spread <= 0.133 (v_14 - v_2) h = 4.4 mm, a sixth of the
    # paper's 2.7 cm. Measured 3.7 mm.
    grid = np.linspace(0, 40, 4001)
    curves = []
    for kmh in (2, 8, 14):
        _, sig = load(step_runs, f"v{kmh:02d}kmh")
        curves.append(on_grid(sig["veh_i.distance"], sig["veh_i.y_rear"], grid))
    gap, _ = spread(curves)
    assert gap <= 0.133 * (14 - 2) / 3.6 * STEP
    # and all settle into the 2 cm band at the same distance, within 0.1 m: 22.3 m, eq
    # (22)'s 22.13 m of path plus the 0.15 m by which the distance travelled exceeds s
    dists = [settle_distance(grid, c, 2.0) for c in curves]
    assert max(dists) - min(dists) <= 0.1
    assert dists[0] == pytest.approx(22.3, abs=0.15)


def test_step_delayed_actuator_drifts_apart(step_runs):
    # The servo (crossover K g = 6 rad/s) plus tau = 0.05 s lag the wheel by about
    # tau + 1/(K g) = 0.217 s, i.e. 0.12 m at 2 km/h but 0.84 m at 14 km/h of path: the
    # response is no longer speed independent. Measured spread 7.4 cm (at 2 m travelled),
    # the 14 km/h run 8.3 cm from eq (22). Bounds 6.4-9.6 cm and 7.4-11.1 cm (about
    # +-20 %, a lag estimate, not a closed form).
    grid = np.linspace(0, 40, 4001)
    curves, devs = [], []
    for kmh in (2, 8, 14):
        _, sig = load(step_runs, f"v{kmh:02d}kmh")
        curves.append(on_grid(sig["veh_i.distance"], sig["veh_d.y_rear"], grid))
        devs.append(np.abs(sig["veh_d.y_rear"] - step_closed_form(sig["veh_i.x_rear"])).max())
    gap, where = spread(curves)
    assert 0.064 <= gap <= 0.096
    assert 1.0 <= grid[where] <= 3.0
    assert devs[0] < devs[1] < devs[2]
    assert 0.074 <= devs[2] <= 0.111
    # the lag delays the response without overshoot beyond 1 mm, and settles (2 cm)
    # within 1.5 m of the ideal 22.3 m at every speed
    for c in curves:
        assert c.max() <= 2.001
        assert settle_distance(grid, c, 2.0) <= 23.8


def test_sine_exact_pose(sine_runs):
    # Exact pose, 6 km/h. Ideal actuator: the loop has the same half-step hold as the
    # core-level test of the law (tests/components/test_chained_form.py, 1.45 mm), so |y| after 40 m
    # <= 2 mm (measured 1.45 mm). Delayed actuator: measured 5.2 cm, bound 4-7 cm.
    # Both far below the paper's 25 cm.
    path = parse_path(SINE)
    _, sig = load(sine_runs, "pose")
    x = sig["veh_i.x_rear"]
    yi, _ = path_offset(path, sig["veh_i.x_rear"], sig["veh_i.y_rear"])
    yd, _ = path_offset(path, sig["veh_d.x_rear"], sig["veh_d.y_rear"])
    late = x >= 40.0
    assert late.sum() > 100
    assert np.abs(yi[late]).max() <= 0.002
    assert 0.04 <= np.abs(yd[late]).max() <= 0.07
    # the controller sees the pose of the current communication point: its a2 is the
    # true offset sample by sample (no stale step, see the module docstring)
    assert np.abs(sig["ctl_i.a2"] - yi).max() <= 1e-9
    # initial offset 0.5 m (start on the normal), right of the path
    assert yi[0] == pytest.approx(-0.5, abs=1e-9)


def test_cross_seed_speed_dependence(cross_runs):
    out, metrics = cross_runs
    sf1 = metrics["state_feedback__vehicle.v0=1.0"]
    sf4 = metrics["state_feedback__vehicle.v0=4.0"]
    cf1 = metrics["chained_form__vehicle.v0=1.0"]
    cf4 = metrics["chained_form__vehicle.v0=4.0"]
    # chained form on the same delayed actuator: settling distance (rear axle, 2 cm band)
    # 16.8 m at 1 m/s, 17.0 m at 4 m/s (the actuator lag, 0.22 s, costs v * 0.22 s of
    # path): within 0.5 m; no overshoot at either speed (< 1 mm).
    assert cf1["path_error_settling_time"] * 1.0 == pytest.approx(16.8, abs=0.3)
    assert abs(cf4["path_error_settling_time"] * 4.0
               - cf1["path_error_settling_time"] * 1.0) <= 0.5
    assert cf1["path_error_overshoot"] < 1e-3 and cf4["path_error_overshoot"] < 1e-3
    # state feedback (gains fixed at 1 m/s): the linear prediction is seed 000 model b
    # (agv_core.state_feedback.model_b, L = 1.4944 m, K = 0.6) with the actuator's
    # tau = 0.05 s = 5 steps and the command held over each 10 ms step, discretised
    # exactly (sf_linear_response below). At 1 m/s it gives a front-wheel overshoot of
    # 2.27 cm, at 4 m/s 32.8 cm (dominant pair -0.15 +- 4.12j 1/s, damping 0.036; model
    # b alone, closed_loop(): -0.49 +- 3.83j), and rear-axle settling (2 cm) after 5.6 m
    # and 62.7 m. The kinematics the linear model drops (front-wheel speed v / cos(alpha),
    # tan(alpha) in the yaw rate) only raise the loop gain, by about 5 % at the peak
    # |alpha| = 0.33 rad; with that 5 % the same model gives 2.67 cm / 34.0 cm and 79 m.
    # Bounds: +-0.5 cm and +-3 cm around the linear overshoots (covers the 5 % gain and
    # the rounding), settling at 4 m/s no earlier than the linear 60 m (more than ten
    # times the 1 m/s distance), rear overshoot at 4 m/s >= 15 cm (linear 14.6 cm,
    # 15.1 cm with 2 % more gain). Measured 2.4 / 34.0 cm, 5.6 / 93.1 m, 16.6 cm.
    lin1, lin4 = sf_linear_response(1.0), sf_linear_response(4.0)
    assert lin1["front_overshoot"] == pytest.approx(0.0227, abs=5e-4)
    assert lin4["front_overshoot"] == pytest.approx(0.328, abs=5e-3)
    assert lin4["rear_settle_distance"] >= 60.0
    assert sf1["lateral_error_overshoot"] == pytest.approx(0.023, abs=0.005)
    assert sf4["lateral_error_overshoot"] == pytest.approx(0.33, abs=0.03)
    assert sf1["path_error_settling_time"] * 1.0 == pytest.approx(5.6, abs=0.3)
    assert sf4["path_error_settling_time"] is None or sf4["path_error_settling_time"] * 4.0 >= 60
    assert sf4["path_error_overshoot"] >= 0.15
