"""Analytic tests of the dynamic single-track vehicle (agv_core.dynamic_vehicle).

Closed forms of the linear single-track model (Rajamani, Vehicle Dynamics and Control,
2nd ed. 2012, ch. 2-3; Pacejka 2012 ch. 1), with a = L - b:

- understeer gradient K_us = (m / L) (b / C_f - a / C_r); steady yaw-rate gain
  r / delta = u / (L + K_us u^2);
- lateral eigenvalues: trace T = -(C_f + C_r)/(m u) - (a^2 C_f + b^2 C_r)/(Iz u),
  determinant D = C_f C_r L^2 / (m Iz u^2) (1 + K_us u^2 / L), lambda = T/2 +- sqrt(T^2/4 - D);
- low-speed limit (README): driven by the same steering delta(s) as a function of the
  distance s, the dynamic model's heading and rear-axle offset differ from the kinematic
  model's by u^2 times the first-order terms below, plus O(u^4).
"""

import json
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from agv_core.dynamic_vehicle.dynamic_vehicle import (G, DynamicVehicle,
                                                      SingleTrackParameters)
from agv_core.dynamic_vehicle.tyres import fiala_force, linear_force, sliding_slip
from agv_core.errors import ParameterError
from agv_core.vehicle.vehicle import Vehicle

#: understeering (K_us > 0) and oversteering (K_us < 0, critical speed sqrt(-L/K_us))
UNDER = SingleTrackParameters(1.5, 400.0, 120.0, 0.9, 11000.0, 16000.0, 0.8, "linear")
OVER = SingleTrackParameters(1.5, 400.0, 120.0, 0.5, 16000.0, 9000.0, 0.8, "linear")


def closed_form_eigenvalues(p, u):
    T = -(p.Cf + p.Cr) / (p.m * u) - (p.a ** 2 * p.Cf + p.b ** 2 * p.Cr) / (p.Iz * u)
    K = p.m / p.L * (p.b / p.Cf - p.a / p.Cr)
    D = p.Cf * p.Cr * p.L ** 2 / (p.m * p.Iz * u * u) * (1.0 + K * u * u / p.L)
    root = np.sqrt(complex(T * T / 4.0 - D))
    return sorted([T / 2 + root, T / 2 - root], key=lambda z: (z.real, z.imag))


def test_understeer_gradient_is_the_closed_form():
    for p in (UNDER, OVER):
        assert p.understeer_gradient() == pytest.approx(
            p.m / p.L * (p.b / p.Cf - p.a / p.Cr), rel=1e-15)
    assert UNDER.understeer_gradient() > 0 > OVER.understeer_gradient()


@pytest.mark.parametrize("p", [UNDER, OVER], ids=["understeer", "oversteer"])
@pytest.mark.parametrize("u", [0.5, 2.0, 5.0, 10.0, 20.0])
def test_linear_eigenvalues_equal_the_closed_form(p, u):
    """The model's lateral matrix and its exact discretisation have the closed-form
    eigenvalues (1e-9 relative: eigvals of a 2x2 and expm are accurate to rounding; the
    oversteering vehicle above its critical speed sqrt(-L/K_us) = 8.39 m/s has one
    positive real eigenvalue, also as the closed form says)."""
    A, _ = p.lateral_matrices(u)
    expected = closed_form_eigenvalues(p, u)
    got = sorted(np.linalg.eigvals(np.array(A)), key=lambda z: (z.real, z.imag))
    assert got == pytest.approx(expected, rel=1e-9)
    h = 0.01
    car = DynamicVehicle(p, linear=True)
    phi, _ = car.discretisation(u, h)
    mu = sorted(np.linalg.eigvals(np.array(phi)), key=lambda z: (abs(z), z.imag))
    want = sorted([1.0, 1.0] + [np.exp(lam * h) for lam in expected],
                  key=lambda z: (abs(z), z.imag))
    assert mu == pytest.approx(want, rel=1e-9, abs=1e-12)
    if p is OVER and u > math.sqrt(-p.L / p.understeer_gradient()):
        assert max(z.real for z in expected) > 0


@pytest.mark.parametrize("p", [UNDER, OVER], ids=["understeer", "oversteer"])
@pytest.mark.parametrize("u", [1.0, 3.0, 6.0, 8.0])
def test_steady_state_yaw_rate_gain_and_understeer_gradient(p, u):
    """Held steering: the linear model settles to r / delta = u / (L + K_us u^2) and
    a_y = u r, so the steering in excess of the kinematic L / R is K_us a_y. Run until
    the slowest mode has decayed below 1e-13; 1e-9 relative (exact discretisation).
    8 m/s is just below the oversteering vehicle's critical speed 8.39 m/s."""
    delta = 0.02
    slowest = max(z.real for z in closed_form_eigenvalues(p, u))
    duration = 30.0 / -slowest
    h = 0.01
    car = DynamicVehicle(p, linear=True, reference_point="rear")
    for _ in range(int(duration / h) + 1):
        car.step(delta, u, h)
    K = p.understeer_gradient()
    assert car.r / delta == pytest.approx(u / (p.L + K * u * u), rel=1e-9)
    a_y = car.lateral_acceleration()
    assert a_y == pytest.approx(u * car.r, rel=1e-9)
    curvature = car.r / u  # of the centre of gravity's path (1 / R)
    assert (delta - p.L * curvature) / a_y == pytest.approx(K, rel=1e-7, abs=1e-12)
    # slips and forces: F_f + F_r = m a_y, a F_f = b F_r (no yaw acceleration)
    _, _, ff, fr, _, _ = car.lateral()
    assert ff + fr == pytest.approx(p.m * a_y, rel=1e-9)
    assert p.a * ff == pytest.approx(p.b * fr, rel=1e-9)


@pytest.mark.parametrize("tyre", ["linear", "fiala"])
def test_nonlinear_model_has_the_linear_gain_at_small_steering(tyre):
    """The nonlinear model (atan slips, trigonometric pose, Fiala or linear tyre) at
    delta = 1e-5 rad: the steady yaw-rate gain equals the closed form within 1e-6
    relative. The geometric nonlinearities are O(delta^2) relative; Fiala's is first
    order in the slip, theta |tan(alpha)| with theta = C / (3 mu Fz) ~ 2 /rad here, i.e.
    ~5e-7 relative at these slips (~2e-7 rad)."""
    p = SingleTrackParameters(1.5, 400.0, 120.0, 0.9, 11000.0, 16000.0, 0.8, tyre)
    u, delta = 4.0, 1e-5
    car = DynamicVehicle(p, linear=False)
    for _ in range(2000):
        car.step(delta, u, 0.01)
    K = p.understeer_gradient()
    assert car.r / delta == pytest.approx(u / (p.L + K * u * u), rel=1e-6)


def test_fiala_tyre_law():
    """Slope -C at 0, odd, monotone, saturates at mu Fz with zero slope at
    tan(alpha) = 3 mu Fz / C, continuous there (closed forms of the brush model)."""
    C, limit = 20000.0, 3000.0
    eps = 1e-9   # the central difference is off by theta eps = C eps / (3 mu Fz) relative
    assert (fiala_force(eps, C, limit) - fiala_force(-eps, C, limit)) / (2 * eps) == \
        pytest.approx(-C, rel=1e-7)
    slips = np.linspace(-1.2, 1.2, 2401)
    forces = np.array([fiala_force(s, C, limit) for s in slips])
    assert np.all(np.diff(forces) <= 0.0)
    assert forces == pytest.approx(-forces[::-1], abs=1e-9)
    sl = sliding_slip(C, limit)
    assert math.tan(sl) == pytest.approx(3 * limit / C, rel=1e-15)
    for s in (sl * (1 - 1e-9), sl, sl * 1.5, 1.5):
        assert fiala_force(s, C, limit) == pytest.approx(-limit, rel=1e-12)
    assert fiala_force(2.0, C, limit) == -limit   # beyond 90 deg: sliding
    # within the linear range the brush model is below the linear law in magnitude
    assert abs(fiala_force(0.05, C, limit)) < abs(linear_force(0.05, C))


def test_front_saturation_limits_the_lateral_acceleration():
    """The model without load transfer and with a free drive force (cg_height = 0,
    drive = 'ideal'). Fiala tyres at 6 m/s, held steering: the steady lateral acceleration
    never exceeds mu g; once the front axle slides (delta = 0.8, 1.0 rad here) its force
    is mu Fz_f = m g mu b / L, which carries the share b / L of m a_y through cos(delta),
    so the closed form is a_y = mu g cos(delta) (1e-9 relative). The tyre loads are
    static and proportional to b and a, so both axles reach their limits at a_y = mu g
    together: below the front's sliding the rear is short of its limit by cos(delta)."""
    p = SingleTrackParameters(1.5, 400.0, 120.0, 0.9, 11000.0, 16000.0, 0.8, "fiala",
                              cg_height=0.0, drive="ideal")
    for delta in (0.1, 0.3, 0.5, 0.8, 1.0):
        car = DynamicVehicle(p)
        for _ in range(3000):
            car.step(delta, 6.0, 0.01)
        a_y = car.lateral_acceleration()
        assert 0.0 < a_y < p.mu * G
        slip_f, slip_r, ff, fr, _, _ = car.lateral()
        if delta >= 0.8:
            assert a_y == pytest.approx(p.mu * G * math.cos(delta), rel=1e-9)
            assert ff == pytest.approx(p.limit_f, rel=1e-12)
            assert abs(slip_f) > sliding_slip(p.Cf, p.limit_f) > abs(slip_r)
        else:
            assert abs(slip_f) < sliding_slip(p.Cf, p.limit_f)


def _first_order(p, delta0, k, s):
    """Closed-form first-order (coefficient of u^2) deviation of heading and rear-axle
    offset, dynamic minus kinematic (linear models), for delta(s) = delta0 (1 - cos ks)/2."""
    K = p.understeer_gradient()
    d = delta0 * (1 - math.cos(k * s)) / 2
    int_d = delta0 * (s - math.sin(k * s) / k) / 2
    int2_d = delta0 * (s * s / 2 - (1 - math.cos(k * s)) / k ** 2) / 2
    compliance = p.Iz * (1 / p.Cf + 1 / p.Cr) / p.L ** 3
    dpsi = -K / p.L ** 2 * (int_d + p.b * d) - compliance * d
    int_dpsi = -K / p.L ** 2 * (int2_d + p.b * int_d) - compliance * int_d
    int_beta_r = -(p.m * p.a * (int_d + p.b * d) - p.Iz * d) / (p.L ** 2 * p.Cr)
    return dpsi, int_dpsi + int_beta_r


@pytest.mark.parametrize("p", [UNDER, OVER], ids=["understeer", "oversteer"])
def test_low_speed_limit_is_the_kinematic_model_with_a_u_squared_bound(p):
    """Both linear models driven by delta(s) = 0.1 (1 - cos(2 pi s / 2 m)) / 2 over 2 m:
    the deviation (heading, rear-axle y) equals u^2 times the closed-form first-order
    term. The relative error of that prediction is O(u^2): < 2 % at 0.2 m/s, < 0.5 % at
    0.1 m/s, and it falls by > 3.5x when u halves."""
    delta0, S = 0.1, 2.0
    k = 2 * math.pi / S
    errors = []
    for u in (0.2, 0.1, 0.05):
        h = 0.005 / u  # 5 mm of travel per step, the input held (same for both models)
        dyn = DynamicVehicle(p, reference_point="rear", linear=True, kinematic_below=0.01)
        kin = Vehicle(p.L, reference_point="rear", linear=True)
        n = int(round(S / (u * h)))
        for j in range(n):
            delta = delta0 * (1 - math.cos(k * (j + 0.5) * u * h)) / 2
            dyn.step(delta, u, h)
            kin.step(delta, u, h)
        dpsi, dy = _first_order(p, delta0, k, S)
        got_psi, got_y = (dyn.psi - kin.heading) / u ** 2, (dyn.Y - kin.y) / u ** 2
        errors.append(max(abs(got_psi / dpsi - 1), abs(got_y / dy - 1)))
    assert errors[0] < 0.02 and errors[1] < 0.005
    assert errors[0] / errors[1] > 3.5 and errors[1] / errors[2] > 3.5


def test_nonlinear_model_converges_to_the_kinematic_one_as_u_squared():
    """Fiala tyres, exact geometry: the same distance-domain steering as above at 0.4,
    0.2, 0.1 m/s; the largest rear-axle position difference from the nonlinear kinematic
    model falls by 4 +- 0.4 each time u halves (the u^2 law), and at 0.1 m/s it is below
    1e-4 m over the 2 m (measured 7.1e-5 m)."""
    p = SingleTrackParameters(1.5, 400.0, 120.0, 0.9, 11000.0, 16000.0, 0.8, "fiala")
    delta0, S = 0.3, 2.0
    k = 2 * math.pi / S
    worst = []
    for u in (0.4, 0.2, 0.1):
        h = 0.005 / u
        dyn = DynamicVehicle(p, reference_point="rear", kinematic_below=0.01)
        kin = Vehicle(p.L, reference_point="rear")
        far = 0.0
        for j in range(int(round(S / (u * h)))):
            delta = delta0 * (1 - math.cos(k * (j + 0.5) * u * h)) / 2
            dyn.step(delta, u, h)
            kin.step(delta, u, h)
            far = max(far, math.hypot(dyn.X - kin.x, dyn.Y - kin.y))
        worst.append(far)
    assert 3.6 < worst[0] / worst[1] < 4.4 and 3.6 < worst[1] / worst[2] < 4.4
    assert worst[2] < 1e-4


def test_below_the_switch_speed_it_is_the_kinematic_model():
    """|u| < kinematic_below: the pose is the kinematic Vehicle's exact arc (to rounding)
    and the lateral state its no-slip values; at the switch upwards the dynamic model
    starts from them (no jump in the pose)."""
    p = SingleTrackParameters(1.5, 400.0, 120.0, 0.9, 11000.0, 16000.0, 0.8, "fiala")
    for linear in (False, True):
        dyn = DynamicVehicle(p, 0.2, -0.3, 0.4, "front", linear, kinematic_below=0.5)
        kin = Vehicle(p.L, 0.2, -0.3, 0.4, "front", linear)
        for j in range(300):
            alpha, v = 0.3 * math.sin(0.05 * j), 0.45 * math.cos(0.01 * j)
            dyn.step(alpha, v, 0.02)
            kin.step(alpha, v, 0.02)
            assert (dyn.x, dyn.y, dyn.heading) == pytest.approx((kin.x, kin.y, kin.heading),
                                                                abs=1e-12)
            assert dyn.r == pytest.approx(kin.yaw_rate(alpha, v), abs=1e-15)
            assert dyn.lateral()[:4] == (0.0, 0.0, 0.0, 0.0)
        vy, r = dyn.vy, dyn.r
        dyn.step(0.1, 0.6, 1e-9)     # a tiny dynamic step: continuous lateral state
        assert (dyn.vy, dyn.r) == pytest.approx((vy, r), abs=1e-6)


def test_integration_error_bound_against_dop853():
    """Random piecewise-constant inputs for 10 s (1000 steps of 10 ms, 1-8 m/s, up to
    0.25 rad, the tyres partly saturated): the step-doubling RK4 state equals scipy's
    DOP853 (rtol 1e-12, atol 1e-12, the same right-hand side, step by step) within 1e-7
    (the per-step tolerance 1e-9 x 1000 steps, relative to 1 + |state|, bounds the
    accumulated error at ~1e-6 for states of order 10; measured ~1e-10)."""
    rng = np.random.default_rng(11)
    p = SingleTrackParameters(1.5, 400.0, 120.0, 0.9, 11000.0, 16000.0, 0.8, "fiala")
    car = DynamicVehicle(p, reference_point="rear", tolerance=1e-9)
    ref = DynamicVehicle(p, reference_point="rear")
    y = np.array([car.X, car.Y, car.psi, car.vy, car.r, car.distance])
    for _ in range(1000):
        alpha, u = rng.uniform(-0.25, 0.25), rng.uniform(1.0, 8.0)
        car.step(alpha, u, 0.01)
        ref.alpha, ref.u = alpha, u
        y = solve_ivp(lambda t, s: ref.rates(s), (0, 0.01), y, method="DOP853", rtol=1e-12,
                      atol=1e-12).y[:, -1]
    got = [car.X, car.Y, car.psi, car.vy, car.r, car.distance]
    assert got == pytest.approx(list(y), abs=1e-7)
    assert car.distance > 30.0


def test_starts_in_the_kinematic_motion_of_its_initial_inputs():
    p = SingleTrackParameters()
    car = DynamicVehicle(p, alpha0=0.2, speed0=2.0)
    assert car.r == pytest.approx(2.0 * math.tan(0.2) / p.L, rel=1e-15)
    assert car.vy == pytest.approx(p.b * car.r, rel=1e-15)
    assert car.lateral()[:2] == pytest.approx((0.0, 0.0), abs=1e-15)


def test_state_round_trip():
    car = DynamicVehicle(SingleTrackParameters())
    car.step(0.2, 2.0, 0.3)
    saved = json.loads(json.dumps(car.get_state()))
    car.step(0.1, 2.5, 0.3)
    other = DynamicVehicle(SingleTrackParameters())
    other.set_state(saved)
    other.step(0.1, 2.5, 0.3)
    assert other.get_state() == car.get_state()


def test_reverse_faster_than_the_switch_speed_is_refused():
    car = DynamicVehicle(SingleTrackParameters(), kinematic_below=0.1)
    car.step(0.1, -0.05, 0.1)   # slow reverse: kinematic
    with pytest.raises(ValueError, match="reverse"):
        car.step(0.1, -0.5, 0.1)
    with pytest.raises(FloatingPointError):
        car.step(math.pi / 2, 1.0, 0.1)


@pytest.mark.parametrize("kwargs, name", [
    ({"wheelbase": 0.0}, "wheelbase"), ({"mass": -1.0}, "mass"),
    ({"yaw_inertia": float("nan")}, "yaw_inertia"), ({"cg_to_rear": 1.0}, "cg_to_rear"),
    ({"cg_to_rear": 0.0}, "cg_to_rear"), ({"cornering_stiffness_front": 0.0},
                                          "cornering_stiffness_front"),
    ({"cornering_stiffness_rear": float("inf")}, "cornering_stiffness_rear"),
    ({"mu": 0.0}, "mu"), ({"tyre": "magic"}, "tyre"),
    ({"cg_height": -0.1}, "cg_height"), ({"cg_height": float("nan")}, "cg_height"),
    ({"track": 0.0}, "track"), ({"layout": "two"}, "layout"), ({"drive": "all"}, "drive"),
])
def test_bad_parameters(kwargs, name):
    with pytest.raises(ParameterError) as info:
        SingleTrackParameters(**kwargs)
    assert info.value.name == name


@pytest.mark.parametrize("kwargs, name", [
    ({"reference_point": "middle"}, "reference_point"), ({"x0": float("inf")}, "x0"),
    ({"kinematic_below": 0.0}, "kinematic_below"), ({"tolerance": 0.0}, "tolerance"),
])
def test_bad_vehicle_parameters(kwargs, name):
    with pytest.raises(ParameterError) as info:
        DynamicVehicle(SingleTrackParameters(), **kwargs)
    assert info.value.name == name


def test_seed000_loop_poles_with_the_single_track_plant():
    """state_feedback.loop_poles: with the kinematic plant its poles are closed_loop()'s
    (1e-9); with the single-track plant and ever stiffer tyres the loop's dominant pair
    tends to the kinematic one (the extra lateral poles move out as 1/C): the damping
    difference at 3 m/s shrinks by ~10x per 10x stiffness."""
    from agv_core.state_feedback.state_feedback import PAPER_GAINS, closed_loop, loop_poles

    L = 1.4944
    for v in (1.0, 3.0):
        got = loop_poles(PAPER_GAINS, v, L, 0.6)["poles"]
        want = closed_loop(PAPER_GAINS, v, L, 0.6)["poles"]
        assert sorted(got, key=lambda z: (z.real, z.imag)) == pytest.approx(
            sorted(want, key=lambda z: (z.real, z.imag)), rel=1e-9)
    kin = loop_poles(PAPER_GAINS, 3.0, L, 0.6)["dominant_damping"]
    gaps = []
    for c in (1e4, 1e5, 1e6):
        p = SingleTrackParameters(L, 400.0, 167.0, L / 2, c, c, 0.8, "linear")
        gaps.append(kin - loop_poles(PAPER_GAINS, 3.0, L, 0.6, p)["dominant_damping"])
    assert gaps[0] > 0 and 7 < gaps[0] / gaps[1] < 13 and 7 < gaps[1] / gaps[2] < 13


# ------------------------------------------------------------------ combined slip, load transfer
def _old_lateral(p, alpha, u, vy, r):
    """The model without load transfer and combined slip, written out: static axle loads,
    one Fiala tyre per axle, the drive force free."""
    slip_f = math.atan2(vy + p.a * r, u) - alpha
    slip_r = math.atan2(vy - p.b * r, u)
    ff = fiala_force(slip_f, p.Cf, p.mu * (p.m * G * p.b / p.L))
    fr = fiala_force(slip_r, p.Cr, p.mu * (p.m * G * p.a / p.L))
    ffc = ff * math.cos(alpha)
    return slip_f, slip_r, ff, fr, (ffc + fr) / p.m - u * r, (p.a * ffc - p.b * fr) / p.Iz


@pytest.mark.parametrize("layout", ["four", "three"])
def test_old_model_is_recovered_exactly_with_cg_height_0_and_the_ideal_drive(layout):
    """cg_height = 0 and drive = 'ideal' (the documented defaults of the old model): the
    tyre forces and accelerations equal the old equations bit for bit at 200 random
    states, and the general path (load transfer, per-wheel forces) gives them within
    1e-12 relative (each wheel carries exactly half its axle's load and stiffness)."""
    rng = np.random.default_rng(5)
    p = SingleTrackParameters(1.5, 400.0, 120.0, 0.9, 11000.0, 16000.0, 0.8, "fiala",
                              cg_height=0.0, drive="ideal", layout=layout)
    assert p.static
    car = DynamicVehicle(p)
    for _ in range(200):
        alpha, u = rng.uniform(-0.5, 0.5), rng.uniform(0.5, 15.0)
        vy, r = rng.uniform(-2.0, 2.0), rng.uniform(-2.0, 2.0)
        old = _old_lateral(p, alpha, u, vy, r)
        assert car.lateral(alpha, u, vy, r) == old
        general = car._tyres(alpha, u, vy, r, old[0], old[1])
        assert general[:4] == pytest.approx(old[2:], rel=1e-12, abs=1e-9)


def test_wheel_loads_sum_to_the_weight_and_transfer_m_ay_h_over_track():
    """Static and dynamic loads: the four loads sum to m g for any accelerations; the
    longitudinal transfer is m a_x h / L from front to rear; the lateral transfer (each
    right wheel's gain, summed over the axles) is m a_y h / t, split between the axles in
    proportion to their static loads (four wheels) or all on the rear pair (three)."""
    for layout in ("four", "three"):
        p = SingleTrackParameters(1.5, 400.0, 120.0, 0.9, 11000.0, 16000.0, 0.8, "fiala",
                                  cg_height=0.45, track=0.9, layout=layout)
        for ax, ay in ((0.0, 0.0), (1.3, 0.0), (0.0, 2.7), (-0.8, -3.1)):
            fl, fr, rl, rr = p.wheel_loads(ax, ay)
            assert fl + fr + rl + rr == pytest.approx(p.m * G, rel=1e-14)
            assert fl + fr == pytest.approx(p.m * G * p.b / p.L - p.m * ax * p.h / p.L,
                                            rel=1e-14)
            transfer = 0.5 * ((fr - fl) + (rr - rl))
            assert transfer == pytest.approx(p.m * ay * p.h / p.track, rel=1e-14, abs=1e-12)
            if layout == "four":
                assert 0.5 * (fr - fl) == pytest.approx(p.b / p.L * p.m * ay * p.h / p.track,
                                                        rel=1e-14, abs=1e-12)
            else:
                assert fr == fl


def test_lateral_load_transfer_in_a_steady_turn_is_m_ay_h_over_track():
    """Simulated steady turn (rear drive, h = 0.3 m, t = 0.8 m, 5 m/s, delta = 0.1 rad):
    the loads the model uses transfer m a_y h / t with the model's own a_y (the fixed
    point of load transfer and forces, 1e-9 relative), sum to m g, and the tip margin is
    1 - a_y / (g (t/2) / h) up to the longitudinal term (a_x = -r vy)."""
    p = SingleTrackParameters()
    car = DynamicVehicle(p, reference_point="rear", alpha0=0.1, speed0=5.0)
    for _ in range(1000):
        car.step(0.1, 5.0, 0.005)
    ay = car.lateral_acceleration()
    loads = car.tyre_state()["loads"]
    assert sum(loads) == pytest.approx(p.m * G, rel=1e-14)
    transfer = 0.5 * ((loads[1] - loads[0]) + (loads[3] - loads[2]))
    assert ay > 2.0
    assert transfer == pytest.approx(p.m * ay * p.h / p.track, rel=1e-9)
    ax = -car.r * car.vy
    fzr = p.Fzr + p.m * ax * p.h / p.L
    margin = (0.5 * fzr - p.share_r * p.m * ay * p.h / p.track) / (0.5 * p.Fzr)
    assert car.tyre_state()["tip_margin"] == pytest.approx(margin, rel=1e-12)


def test_tip_over_acceleration_symmetric_and_three_wheel():
    """Four wheels: the inner wheels lift at a_y = g (t/2) / h. Three wheels (one front
    wheel at (a, 0) from G, rear wheels at (-b, +-t/2)): the triangle's edge from the
    front wheel to the outer rear wheel is the tipping axis; G's ground projection lies
    d = (t/2) a / sqrt(L^2 + t^2/4) from it, and the inner rear wheel's load is zero when
    the acceleration component normal to that axis is g d / h (any direction of the
    acceleration; 1e-12). For a purely lateral acceleration the limit is g d_y / h with
    d_y = t a / (2 L) the lateral distance from G to the axis."""
    h, t = 0.5, 0.9
    four = SingleTrackParameters(1.5, 400.0, 120.0, 0.9, cg_height=h, track=t)
    assert four.lateral_tip_acceleration() == pytest.approx(G * 0.5 * t / h, rel=1e-14)
    fl, fr, rl, rr = four.wheel_loads(0.0, G * 0.5 * t / h)
    assert (fl, rl) == pytest.approx((0.0, 0.0), abs=1e-9)
    three = SingleTrackParameters(1.5, 400.0, 120.0, 0.9, cg_height=h, track=t,
                                  layout="three")
    a, L = three.a, three.L
    d_y = t * a / (2.0 * L)
    assert three.lateral_tip_acceleration() == pytest.approx(G * d_y / h, rel=1e-14)
    assert three.wheel_loads(0.0, G * d_y / h)[2] == pytest.approx(0.0, abs=1e-9)
    # unit normal n of the axis from the front wheel (a, 0) to the right rear wheel
    # (-b, -t/2), pointing from G towards the axis; G's distance d from the axis
    ex, ey = -L, -0.5 * t
    norm = math.hypot(ex, ey)
    nx, ny = -ey / norm, ex / norm
    assert nx * a + ny * 0.0 > 0.0            # n . (front wheel - G) > 0
    d = abs(-a * ey) / norm
    assert d == pytest.approx(0.5 * t * a / math.hypot(L, 0.5 * t), rel=1e-14)
    # the resultant of weight and inertia meets the ground at -(a_x, a_y) h / g from G:
    # on the axis when the acceleration is -(g d / h) n
    acc = G * d / h
    loads = three.wheel_loads(-acc * nx, -acc * ny)
    assert loads[2] == pytest.approx(0.0, abs=1e-9)
    assert min(loads[0], loads[3]) > 0.0
    assert G * d_y / h < G * 0.5 * t / h        # the three-wheeler tips earlier


def test_three_wheeler_fails_naming_the_lifting_wheel():
    """A three-wheel AGV (h = 0.3 m, t = 0.8 m: tip-over at g d_y / h = 6.54 m/s^2 below
    its sliding limit mu g = 7.85 m/s^2) on a tightening left turn at 4 m/s: the margin
    falls towards 0 and the step where the rear left wheel's load reaches 0 raises
    WheelLiftError naming it: the lateral acceleration crosses the closed form
    t (g a + a_x h) / (2 L h) (the triangle's limit g d_y / h moved by the longitudinal
    transfer of a_x = -r vy) between the last good step and the failing one, within 4 %
    of g d_y / h."""
    from agv_core.dynamic_vehicle.dynamic_vehicle import WheelLiftError
    p = SingleTrackParameters(layout="three", drive="front")
    limit = p.lateral_tip_acceleration()
    assert limit == pytest.approx(G * (0.4 * 0.5 / 1.0) / 0.3, rel=1e-14)
    car = DynamicVehicle(p, reference_point="rear", speed0=4.0)
    margins = []

    def crossing():
        ax = -car.r * car.vy
        return car.lateral_acceleration() - p.track * (G * p.a + ax * p.h) / (2 * p.L * p.h)

    with pytest.raises(WheelLiftError, match="rear left wheel lifts") as info:
        for k in range(4000):
            car.step(min(0.5, 0.0004 * k), 4.0, 0.002)
            margins.append((car.lateral_acceleration(), car.tyre_state()["tip_margin"],
                            crossing()))
    assert 0.0 < margins[-1][1] < 0.05
    assert margins[-1][2] < 0.0 <= crossing()
    assert margins[-1][0] == pytest.approx(limit, rel=0.04)
    assert "tip-over limit 6.540" in str(info.value)


def test_friction_circle_limit_on_a_steady_circle_with_the_drive_force_spent():
    """Steady circles at 8 m/s (h = 0, front drive, understeering vehicle), solved for
    (vy, r) with vy' = r' = 0 by fsolve: once the driven front axle slides, its force
    vector (drive along the wheel plus lateral) has the length mu Fz_f and its body-x
    component is the force that holds the speed, m a_x = -m r vy, its body-y component
    m a_y b / L; so the largest steady lateral acceleration is the closed form
    a_y = (L / b) sqrt((mu g b / L)^2 - a_x^2) (1e-9 relative), below mu g and below the
    free-drive model's mu g cos(delta) at the same steering only when a_x matters. The
    friction use of the front wheels is 1, the rear's below. fsolve converges at every
    steering angle (its step tolerance 1e-12: a relative step of 1e-14 is below what the
    residual's rounding, ~1e-15 m/s^2, lets it resolve, and it stopped "not making good
    progress" at 0.35 rad)."""
    from scipy.optimize import fsolve
    p = SingleTrackParameters(1.5, 400.0, 120.0, 0.9, 11000.0, 16000.0, 0.8, "fiala",
                              cg_height=0.0, drive="front")
    u = 8.0
    car = DynamicVehicle(p, reference_point="rear", alpha0=0.3, speed0=u)
    x = [car.vy, car.r]
    for delta in (0.3, 0.35, 0.38, 0.4, 0.45, 0.5):
        x, _, converged, message = fsolve(lambda z, d=delta: car.lateral(d, u, z[0], z[1])[4:6],
                                          x, xtol=1e-12, full_output=True)
        assert converged == 1, (delta, message)
        car.vy, car.r, car.alpha, car.u = float(x[0]), float(x[1]), delta, u
    state = car.tyre_state()
    ay, ax = car.lateral_acceleration(), -car.r * car.vy
    assert state["friction_front"] == pytest.approx(1.0, abs=1e-12)
    assert state["friction_rear"] < 1.0
    assert state["drive_front"] * math.cos(delta) - car.lateral()[2] * math.sin(delta) == \
        pytest.approx(p.m * ax, rel=1e-9)
    closed = p.L / p.b * math.sqrt((p.mu * G * p.b / p.L) ** 2 - ax * ax)
    assert ay == pytest.approx(closed, rel=1e-9)
    assert ay < p.mu * G


def test_rear_drive_cannot_hold_the_speed_beyond_the_friction_circle():
    """The held-out case of issue 37: 12 m/s, mu 0.7, a left circle tightening towards
    the friction limit, rear drive, h = 0. The drive force that holds the speed grows
    with the turn (drag of the front tyre and the sideslip); the rear wheels' friction
    use never exceeds 1 (the lateral force gets only what the drive leaves), and when the
    drive needs more than 2 mu Fz_r / 2 per wheel the step fails with DriveLimitError.
    The free-drive model at the same inputs reaches a_y > 0.95 mu g where the rear drive
    force it ignores would exceed the rear wheels' friction."""
    from agv_core.dynamic_vehicle.dynamic_vehicle import DriveLimitError
    p = SingleTrackParameters(mu=0.7, cg_height=0.0, drive="rear")
    car = DynamicVehicle(p, reference_point="rear", speed0=12.0)
    uses = []
    with pytest.raises(DriveLimitError, match="rear axle's drive needs"):
        for k in range(5000):
            car.step(min(0.08, 2e-5 * k), 12.0, 0.002)
            uses.append(car.tyre_state()["friction_rear"])
    assert max(uses) <= 1.0 + 1e-12
    assert max(uses) > 0.95


TIP = """
name = "tip"
[simulation]
stop = 5.0
step = 0.01
[components.act]
fmu = "{act}"
parameters = {{ alpha0 = 0.45 }}
[components.vehicle]
fmu = "{vehicle}"
parameters = {{ v0 = 4.0, layout = "three", drive = "front", reference_point = "rear" }}
[[connections]]
from = "act.alpha"
to = "vehicle.alpha"
"""


def test_fmu_run_fails_naming_the_lifting_wheel_and_the_time(component_fmus, tmp_path):
    """The FMU: a three-wheel AgvDynamicVehicle at 4 m/s with the wheel held at 0.45 rad
    (kinematic a_y 7.7 m/s^2 > its tip-over limit 6.54 m/s^2): fmi2DoStep returns Error
    (a modelling limit, not Fatal) and the run's one-line error names the component, the
    status, the time and the lifting wheel."""
    import json

    from agv_cosim import cli
    path = tmp_path / "tip.toml"
    path.write_text(TIP.format(act=component_fmus["agv_steering_b"],
                               vehicle=component_fmus["agv_dynamic_vehicle"]))
    cli.main(["run", str(path), "--quiet", "--out", str(tmp_path / "o")])
    error = json.loads((tmp_path / "o" / "base" / "run.json").read_text())["error"]
    assert "\n" not in error
    assert error.startswith("component 'vehicle': fmi2DoStep returned status 3 (Error)")
    assert "step at t=0.44 s failed: WheelLiftError: the rear left wheel lifts" in error
    assert "tip-over limit 6.540 m/s2" in error
