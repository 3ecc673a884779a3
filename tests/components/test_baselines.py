"""The field's baseline path trackers: pure pursuit, Stanley, rear-wheel feedback.

Tiers: (1) each law's closed forms (pure pursuit's steady circle and its chord map,
Stanley's heading and cross-track terms, rear-wheel feedback's feed-forward); (2) closed
loop with the exact kinematic vehicle core and an ideal actuator against each law's
linearised error dynamics; (3) what every core refuses (non-finite inputs, bad
parameters) and the sample-and-hold and state; (4) the FMUs give the cores' numbers and
refuse a NaN input through fmpy (slow: builds every component FMU).
"""

import math
import shutil
import sys

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave

from agv_core.errors import ParameterError
from agv_core.numerics import paths
from agv_core.pure_pursuit import pure_pursuit as pp
from agv_core.rear_wheel_feedback import rear_wheel_feedback as rw
from agv_core.stanley import stanley as st
from agv_core.vehicle.vehicle import Vehicle

L = 1.5


def _closed_loop(law, x0, y0, heading0, v, h, steps, point="rear"):
    """Ideal actuator, exact kinematic vehicle: per step the law's wheel angle from the
    rear-axle pose at the step's start, held over it. Returns arrays (t, x, y, heading,
    delta) of the tracked point (rear axle or front wheel) at every step's start and end."""
    car = Vehicle(L, x0, y0, heading0, reference_point="rear")
    rows = []
    for i in range(steps + 1):
        t = i * h
        xr, yr = car.rear()
        delta = law.update(t, xr, yr, car.heading, v)
        law.step(t, h, xr, yr, car.heading, v)
        px, py = car.front() if point == "front" else (xr, yr)
        rows.append((t, px, py, car.heading, delta))
        if i < steps:
            car.step(delta, v, h)
    return np.array(rows).T


# ---------------------------------------------------------------------------- pure pursuit
@pytest.mark.parametrize("radius, v, k_ld, L_min", [(10.0, 1.0, 0.1, 2.0),
                                                   (10.0, 4.0, 0.5, 1.0),
                                                   (4.5, 2.0, 0.3, 3.0),
                                                   (25.0, 3.0, 1.0, 2.0)])
def test_pure_pursuit_steady_circle_is_the_closed_form(radius, v, k_ld, L_min):
    """Rear axle on the circle, heading along it: the goal is the chord Ld, so
    sin(alpha) = Ld / (2R) and delta = atan(2 L sin(alpha) / Ld) = atan(L / R)."""
    for direction, sign in (("ccw", 1.0), ("cw", -1.0)):
        law = pp.make_controller(f"circle:radius={radius},direction={direction}", k_ld, L_min,
                                 wheelbase=L, delta_max=1.5)
        delta = law.update(0.0, 0.0, 0.0, 0.0, v)
        ld = k_ld * v + L_min
        assert law.outputs["lookahead"] == ld and law.outputs["on_chord"]
        assert law.outputs["goal_distance"] == ld
        assert law.outputs["alpha"] == pytest.approx(sign * math.asin(ld / (2 * radius)),
                                                     abs=1e-12)
        assert delta == pytest.approx(sign * math.atan(L / radius), abs=1e-12)


@pytest.mark.parametrize("r", [8.5, 9.7, 10.0, 10.4, 12.0])
def test_pure_pursuit_chord_map_off_the_circle(r):
    """A rear axle on the concentric circle of radius r, heading along it, is commanded
    kappa = (Ld^2 + r^2 - R^2) / (r Ld^2) (README.md): more than 1/r outside the path
    circle, less inside, so the only steady circle is r = R (no steady offset)."""
    radius, ld = 10.0, 2.4
    law = pp.make_controller(f"circle:radius={radius}", 0.2, 2.0, wheelbase=L, delta_max=1.5)
    # rear axle at (0, R - r) (centre (0, R)), heading +x: on the circle of radius r
    delta = law.update(0.0, 0.0, radius - r, 0.0, 2.0)
    kappa = math.tan(delta) / L
    expected = pp.circle_steady_curvature(radius, ld, r)
    assert kappa == pytest.approx(expected, rel=1e-10)
    assert (kappa - 1 / r) * (r - radius) >= 0.0
    assert (kappa == pytest.approx(1 / r, rel=1e-12)) == (r == radius)


def test_pure_pursuit_closed_loop_converges_onto_the_circle():
    """From 0.3 m inside the circle the rear axle settles on it: no steady offset in the
    kinematic model (the chord map's only fixed point), the wheel at atan(L / R)."""
    radius = 10.0
    law = pp.make_controller(f"circle:radius={radius}", 0.1, 2.0, wheelbase=L)
    t, x, y, heading, delta = _closed_loop(law, 0.0, 0.3, 0.0, 2.0, 0.01, 4000)
    r = np.hypot(x, y - radius)
    tail = t > 30.0
    assert abs(r[0] - (radius - 0.3)) < 1e-12
    assert np.max(np.abs(r[tail] - radius)) < 1e-6
    assert np.max(np.abs(delta[tail] - math.atan(L / radius))) < 1e-6


def test_pure_pursuit_straight_line_error_is_its_linearisation():
    """Linearised on a straight line, in arc length s: e'' + (2/Ld) e' + (2/Ld^2) e = 0,
    roots (-1 +/- i)/Ld (damping ratio 1/sqrt 2 at every Ld); from e0 parallel to the line,
    e(s) = e0 exp(-s/Ld) (cos(s/Ld) + sin(s/Ld))."""
    e0, v, k_ld, L_min = 0.01, 1.5, 0.4, 1.2
    ld = k_ld * v + L_min
    law = pp.make_controller("line", k_ld, L_min, wheelbase=L)
    t, x, y, heading, delta = _closed_loop(law, 0.0, e0, 0.0, v, 0.001, 8000)
    u = x / ld
    predicted = e0 * np.exp(-u) * (np.cos(u) + np.sin(u))
    assert np.max(np.abs(y - predicted)) < 0.005 * e0
    # the undershoot of the linearisation (exp(-pi) e0 at s = pi Ld) is there
    assert np.min(y) == pytest.approx(-e0 * math.exp(-math.pi), rel=0.02)


def test_pure_pursuit_beyond_the_look_ahead_pursues_the_closest_point():
    law = pp.make_controller("line", 0.0, 2.0, wheelbase=L)
    delta = law.update(0.0, 0.0, -3.0, 0.0, 1.0)  # 3 m right of the line, parallel
    assert not law.outputs["on_chord"]
    assert law.outputs["goal_distance"] == 3.0 and law.outputs["goal_y"] == 0.0
    assert law.outputs["alpha"] == pytest.approx(math.pi / 2)
    assert delta == pytest.approx(min(math.atan(2 * L / 3.0), math.pi / 4))


# ---------------------------------------------------------------------------- Stanley
def test_stanley_terms_are_the_heading_and_cross_track_errors():
    law = st.make_controller("line", k=2.5, k_soft=1.0, wheelbase=L, delta_max=1.5)
    # front wheel on the line, heading 0.1 rad left: steer 0.1 rad right
    assert law.update(0.0, -L * math.cos(0.1), -L * math.sin(0.1), 0.1, 3.0) == \
        pytest.approx(-0.1, abs=1e-12)
    # front wheel 0.4 m left of the line, parallel: -atan(k e / (k_soft + v))
    assert law.update(0.0, 0.0, 0.4, 0.0, 3.0) == pytest.approx(-math.atan(2.5 * 0.4 / 4.0))
    assert law.outputs["lateral_error"] == pytest.approx(0.4)
    # reversing counts as standstill
    assert law.update(0.0, 0.0, 0.4, 0.0, -2.0) == pytest.approx(-math.atan(2.5 * 0.4))


@pytest.mark.parametrize("v, k, k_soft", [(0.5, 2.5, 1.0), (1.0, 1.0, 0.5), (2.0, 2.5, 0.01)])
def test_stanley_cross_track_error_decays_at_its_linearised_rate(v, k, k_soft):
    """Front wheel e0 off a straight line, parallel: with the wheel at -theta - atan(k e /
    (k_soft + v)) it moves at atan(k e / (k_soft + v)) to the line, so de/dt = -v_f k e /
    (k_soft + v) for small e, e(t) = e0 exp(-rate t) (rate -> k for k_soft << v)."""
    e0 = 0.02
    law = st.make_controller("line", k, k_soft, wheelbase=L, delta_max=1.5)
    rate = st.straight_line_rate(k, k_soft, v)
    steps = int(round(3.0 / rate / 0.001))
    t, x, y, heading, delta = _closed_loop(law, -L, e0, 0.0, v, 0.001, steps, point="front")
    assert y[0] == pytest.approx(e0, abs=1e-15)
    predicted = e0 * np.exp(-rate * t)
    # second order: v_f = v / cos(delta) and atan(k e) vs k e: about (k e0 / (k_soft+v))^2
    bound = 1.5 * (k * e0 / (k_soft + v)) ** 2 * 3.0 + 2e-3
    assert np.max(np.abs(y / predicted - 1.0)) < bound
    if k_soft < 0.02 * v:
        assert rate == pytest.approx(k, rel=0.01)


def test_stanley_steady_circle_front_wheel_on_it_rear_axle_inside():
    """Kinematic steady state on a circle: e = 0 at the front wheel (README.md), so the
    rear axle runs on the radius sqrt(R^2 - L^2)."""
    radius = 6.0
    law = st.make_controller(f"circle:radius={radius}", 1.5, 1.0, wheelbase=L, delta_max=1.5)
    t, x, y, heading, delta = _closed_loop(law, 0.0, 0.5, 0.0, 2.0, 0.01, 3000)
    tail = t > 20.0
    rear = np.hypot(x, y - radius)
    front = np.hypot(x + L * np.cos(heading), y + L * np.sin(heading) - radius)
    assert np.max(np.abs(front[tail] - radius)) < 1e-6
    assert np.max(np.abs(rear[tail] - math.sqrt(radius ** 2 - L ** 2))) < 1e-6


def test_stanley_large_offset_heads_straight_for_the_line():
    """Far off the path the cross-track term tends to 90 deg: full lock at delta_max."""
    law = st.make_controller("line", wheelbase=L, delta_max=0.6)
    assert law.update(0.0, 0.0, 50.0, 0.0, 1.0) == -0.6
    assert law.outputs["saturated"] and law.outputs["delta_law"] < -1.5


# ---------------------------------------------------------------------------- rear wheel
def test_rear_wheel_feedback_feed_forward_on_the_circle():
    for direction, sign in (("ccw", 1.0), ("cw", -1.0)):
        law = rw.make_controller(f"circle:radius=7,direction={direction}", wheelbase=L)
        assert law.update(0.0, 0.0, 0.0, 0.0, 0.0) == pytest.approx(
            sign * math.atan(L / 7.0), abs=1e-12)
    # beyond the centre of curvature (1 - c e <= 0): full lock towards the path
    law = rw.make_controller("circle:radius=2", wheelbase=L, delta_max=1.2)
    assert law.update(0.0, 0.0, 1.0, 0.0, 1.0) == pytest.approx(
        math.atan(L * (0.5 / (1 - 0.5 * 1.0) - 0.5 * 1.0)))  # halfway in, c e = 1/2, k_e e
    assert law.outputs["in_domain"]
    assert law.update(0.0, 0.0, 2.0, 0.0, 1.0) == -1.2  # at the centre, c e = 1
    assert not law.outputs["in_domain"]


def test_rear_wheel_feedback_lyapunov_function_decreases():
    """V = e^2 + theta^2 / k_e never grows along the exact kinematic closed loop (on a
    curved path, from a large error), to within the zero-order hold's O(h) slack."""
    law = rw.make_controller("sine:amplitude=2,wavelength=25", 1.2, 0.6, wheelbase=L,
                             delta_max=1.5)
    t, x, y, heading, delta = _closed_loop(law, 0.0, 1.5, 0.6, 1.0, 0.002, 10000)
    path = paths.parse_path("sine:amplitude=2,wavelength=25")
    hint, values = None, []
    for xi, yi, hi in zip(x[::25], y[::25], heading[::25]):
        p = path.project(xi, yi, s_hint=hint)
        hint = p.s
        theta = paths.heading_error(hi, p.heading)
        values.append(p.offset ** 2 + theta ** 2 / 0.6)
    values = np.array(values)
    assert values[0] > 1.5 and values[-1] < 1e-6
    assert np.all(np.diff(values) < 1e-4)


@pytest.mark.parametrize("k_theta, k_e, v", [(1.0, 0.5, 1.0), (1.0, 0.5, 3.0), (2.0, 1.0, 2.0),
                                             (0.6, 0.25, 1.0)])
def test_rear_wheel_feedback_error_is_its_second_order_linearisation(k_theta, k_e, v):
    """Straight line, e0 off, parallel: e'' + k_theta e' + k_e e = 0 in arc length, the
    same curve at every speed (solved with the roots of distance_poles)."""
    e0 = 0.01
    law = rw.make_controller("line", k_theta, k_e, wheelbase=L, delta_max=1.5)
    steps = int(round(20.0 / v / 0.001))
    t, x, y, heading, delta = _closed_loop(law, 0.0, e0, 0.0, v, 0.001, steps)
    p1, p2 = rw.distance_poles(k_theta, k_e)
    s = x
    if abs(p1 - p2) < 1e-12:
        predicted = e0 * (1 - p1.real * s) * np.exp(p1.real * s)
    else:
        # e = A e^(p1 s) + B e^(p2 s), e(0) = e0, e'(0) = 0
        a = -p2 * e0 / (p1 - p2)
        b = p1 * e0 / (p1 - p2)
        predicted = (a * np.exp(p1 * s) + b * np.exp(p2 * s)).real
    assert np.max(np.abs(y - predicted)) < 0.005 * e0


def test_rear_wheel_feedback_poles():
    p1, p2 = rw.distance_poles(1.0, 0.5)
    assert p1 == pytest.approx(complex(-0.5, 0.5)) and p2 == pytest.approx(complex(-0.5, -0.5))
    p1, p2 = rw.distance_poles(3.0, 2.0)
    assert (p1, p2) == (-1.0, -2.0)


# ---------------------------------------------------------------------------- shared frame
LAWS = [pp.make_controller, st.make_controller, rw.make_controller]


@pytest.mark.parametrize("make", LAWS, ids=["pure_pursuit", "stanley", "rear_wheel"])
@pytest.mark.parametrize("which", range(4))
def test_a_non_finite_input_is_refused_not_turned_into_a_command(make, which):
    law = make("circle:radius=10", wheelbase=L)
    good = [0.0, 0.1, 0.05, 1.0]
    law.update(0.0, *good)
    before = dict(law.outputs)
    for bad in (math.nan, math.inf):
        values = list(good)
        values[which] = bad
        with pytest.raises(FloatingPointError, match=["'x'", "'y'", "'heading'",
                                                      "'v'"][which]):
            law.update(0.01, *values)
        with pytest.raises(FloatingPointError):
            law.step(0.01, 0.01, *values)
    assert law.outputs == before


@pytest.mark.parametrize("make, name, value", [
    (pp.make_controller, "k_ld", -0.1), (pp.make_controller, "L_min", 0.0),
    (pp.make_controller, "L_min", math.nan), (st.make_controller, "k", 0.0),
    (st.make_controller, "k_soft", 0.0), (rw.make_controller, "k_theta", -1.0),
    (rw.make_controller, "k_e", math.inf), (rw.make_controller, "wheelbase", 0.0),
    (st.make_controller, "delta_max", 1.6), (pp.make_controller, "sample_period", -1.0)])
def test_bad_parameters_are_named(make, name, value):
    with pytest.raises(ParameterError, match=f"parameter '{name}'"):
        make("line", **{name: value})


@pytest.mark.parametrize("make", LAWS, ids=["pure_pursuit", "stanley", "rear_wheel"])
def test_a_bad_path_is_a_parameter_error(make):
    for spec in ("", "circle", "spiral:radius=3"):
        with pytest.raises(ParameterError, match="parameter 'path'"):
            make(spec)


@pytest.mark.parametrize("make", LAWS, ids=["pure_pursuit", "stanley", "rear_wheel"])
def test_pose_rebuilt_from_a_path_relative_measurement(make):
    """Source 'sensor': (s, e, theta) of the rear axle give back the pose it came from."""
    spec = "sine:amplitude=2,wavelength=18.84955592153876"
    law = make(spec, wheelbase=L)
    path = paths.parse_path(spec)
    for x, y, heading in [(1.0, 0.3, 0.5), (6.0, 1.2, -0.2), (13.0, -2.5, 0.1)]:
        p = path.project(x, y)
        pose = law.pose_from_path(p.s, p.offset, paths.heading_error(heading, p.heading))
        assert pose == pytest.approx((x, y, heading), abs=1e-9)
    with pytest.raises(FloatingPointError, match="'e_meas'"):
        law.pose_from_path(1.0, math.nan, 0.0)


def test_sample_and_hold_and_state_round_trip():
    law = rw.make_controller("line", wheelbase=L, sample_period=0.1)
    first = law.update(0.0, 0.0, 0.2, 0.0, 1.0)
    law.step(0.0, 0.05, 0.0, 0.2, 0.0, 1.0)
    assert law.update(0.05, 0.0, -0.3, 0.0, 1.0) == first  # held between samples
    saved = law.get_state()
    law.step(0.05, 0.05, 0.0, -0.3, 0.0, 1.0)
    second = law.update(0.1, 0.0, -0.3, 0.0, 1.0)  # the instant 0.1 takes the new pose
    assert second > 0.0 > first
    law.set_state(saved)
    assert law.update(0.05, 0.0, -0.3, 0.0, 1.0) == first


# ---------------------------------------------------------------------------- FMUs
MODELS = {"agv_pure_pursuit": pp.make_controller, "agv_stanley": st.make_controller,
          "agv_rear_wheel_feedback": rw.make_controller}


def _forget_bundled_cores():
    """Forget the ``agv_core_<tag>`` modules an in-process build left in sys.modules (see
    tests/components/test_chained_form.py)."""
    for name in [m for m in sys.modules if m.startswith("agv_core_")]:
        del sys.modules[name]


@pytest.mark.slow
@pytest.mark.parametrize("stem", sorted(MODELS))
def test_fmu_gives_the_core_numbers_and_refuses_nan(component_fmus, stem):
    path = str(component_fmus[stem])
    _forget_bundled_cores()
    md = read_model_description(path)
    folder = extract(path)
    refs = {v.name: v.valueReference for v in md.modelVariables}
    spec = "sine:amplitude=2,wavelength=18.84955592153876"
    slave = FMU2Slave(guid=md.guid, unzipDirectory=folder,
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="b")
    core = MODELS[stem](spec, wheelbase=1.4944)
    speed = "speed" in refs
    try:
        slave.instantiate()
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        slave.setString([refs["path"]], [spec])
        slave.setReal([refs["wheelbase"]], [1.4944])
        if speed:
            slave.setReal([refs["speed"]], [2.0])
        slave.exitInitializationMode()
        t = 0.0
        for x, y, heading in [(1.0, 0.2, 0.4), (7.4, 1.3, 0.05), (12.0, -2.0, -0.3)]:
            slave.setReal([refs["x"], refs["y"], refs["heading"]], [x, y, heading])
            if speed:
                slave.setReal([refs["dv"]], [0.5])
            got = slave.getReal([refs["delta"], refs["lateral_error"]])
            expected = core.update(t, x, y, heading, 2.5)
            # the same code on the same doubles; the projection's search starts from the
            # last one's hint, which the FMU's extra publications move: equal to rounding
            assert got == pytest.approx([expected, core.outputs["lateral_error"]], abs=1e-12)
            slave.doStep(t, 0.01)
            t += 0.01
        # a non-finite input is refused where it is set (fmi2Error), the input keeps
        # its value (components/README.md, the adapter's rules)
        with pytest.raises(FMICallException, match="status 3"):
            slave.setReal([refs["y"]], [math.nan])
    finally:
        slave.freeInstance()
        shutil.rmtree(folder, ignore_errors=True)
