"""Analytic tests of the seed-001 double-steer kinematics (agv_core.double_steer)."""

import math

import pytest

from agv_core.double_steer.double_steer import (
    DoubleSteerVehicle,
    body_twist,
    inverse_kinematics,
    turning_radius,
)
from agv_core.errors import ParameterError


@pytest.mark.parametrize("theta", [0.1, 0.4, math.pi / 4, 1.2, math.pi / 2])
def test_symmetric_steering_drives_circle_of_radius_L_over_2sin(theta):
    """001-G1: symmetric steering puts both wheels on one circle of radius L/(2 sin theta)."""
    L, V, h = 1.3, 0.5, 0.05
    veh = DoubleSteerVehicle(L, 0.0, 0.0, 0.0)
    R = turning_radius(L, theta)
    assert R == pytest.approx(L / (2.0 * math.sin(theta)), rel=1e-15)
    # instantaneous centre: on the body's lateral axis through C, at R cos(theta) left
    centre = (0.0, R * math.cos(theta))
    worst_front = worst_centroid = 0.0
    for _ in range(200):
        veh.step(theta, V, -theta, V, h)
        fx, fy = veh.front()
        worst_front = max(worst_front, abs(math.hypot(fx - centre[0], fy - centre[1]) - R))
        worst_centroid = max(worst_centroid, abs(math.hypot(veh.x - centre[0],
                                                            veh.y - centre[1])
                                                 - R * math.cos(theta)))
    # exact arc integration: only rounding remains (200 steps)
    assert worst_front < 1e-12
    assert worst_centroid < 1e-12


def test_double_steer_radius_smaller_than_single_steer():
    """001-G1: L/(2 sin theta) < L/sin theta on (0, pi/2], minimum L/2 at 90 deg."""
    L = 1.0
    for i in range(1, 91):
        theta = math.radians(i)
        assert turning_radius(L, theta) < L / math.sin(theta)
    assert turning_radius(L, math.pi / 2) == pytest.approx(L / 2, rel=1e-15)
    assert turning_radius(L, 0.0) == math.inf


@pytest.mark.parametrize("theta", [0.05, 0.3, 0.9])
def test_body_rotation_two_theta_in_t1(theta):
    """001-G2: the body turns by 2 theta_f while the front wheel covers the arc 2 R theta_f."""
    L, V = 1.0, 0.4
    R = turning_radius(L, theta)
    t1 = 2.0 * R * theta / V
    veh = DoubleSteerVehicle(L)
    n = 37
    for _ in range(n):
        veh.step(theta, V, -theta, V, t1 / n)
    assert veh.yaw == pytest.approx(2.0 * theta, rel=1e-13)
    # and proportional to time: half the time, half the rotation
    veh2 = DoubleSteerVehicle(L)
    veh2.step(theta, V, -theta, V, t1 / 2)
    assert veh2.yaw == pytest.approx(theta, rel=1e-13)


def test_parallel_steering_translates_without_yaw():
    veh = DoubleSteerVehicle(1.0, 1.0, 2.0, 0.3)
    theta, V, h = 0.7, 0.6, 0.1
    for _ in range(50):
        veh.step(theta, V, theta, V, h)
    assert veh.yaw == 0.3
    d = V * h * 50
    assert veh.x == pytest.approx(1.0 + d * math.cos(0.3 + theta), abs=1e-12)
    assert veh.y == pytest.approx(2.0 + d * math.sin(0.3 + theta), abs=1e-12)
    assert veh.course(theta, V, theta, V) == pytest.approx(0.3 + theta, abs=1e-15)


@pytest.mark.parametrize("v_c,omega", [(0.4, 0.074), (0.3, -0.5), (0.0, 0.2), (0.8, 0.0),
                                       (0.1, 1.5)])
def test_inverse_kinematics_round_trip(v_c, omega):
    L = 1.2
    tf, vf, tb, vb = inverse_kinematics(L, v_c, omega)
    assert tb == -tf and vf == vb >= 0.0
    u, v, w, stretch = body_twist(L, tf, vf, tb, vb)
    assert u == pytest.approx(v_c, abs=1e-15)
    assert v == pytest.approx(0.0, abs=1e-15)
    assert w == pytest.approx(omega, abs=1e-15)
    assert stretch == pytest.approx(0.0, abs=1e-15)


def test_stretch_reports_inconsistent_wheel_speeds():
    u, v, w, stretch = body_twist(1.0, 0.0, 0.5, 0.0, 0.3)
    assert (u, v, w, stretch) == pytest.approx((0.4, 0.0, 0.0, 0.2))


def test_exact_for_held_inputs_against_fine_rk4():
    """Exact integration vs an independent RK4 of the rigid-body ODE (1e4 sub-steps)."""
    L, tf, vf, tb, vb = 1.0, 0.5, 0.7, -0.2, 0.65
    veh = DoubleSteerVehicle(L, 0.0, 0.0, 0.1)
    veh.step(tf, vf, tb, vb, 3.0)
    u, v, w, _ = body_twist(L, tf, vf, tb, vb)

    def f(s):
        return (u * math.cos(s[2]) - v * math.sin(s[2]),
                u * math.sin(s[2]) + v * math.cos(s[2]), w)

    s, n = (0.0, 0.0, 0.1), 10000
    h = 3.0 / n
    for _ in range(n):
        k1 = f(s)
        k2 = f([a + h / 2 * b for a, b in zip(s, k1)])
        k3 = f([a + h / 2 * b for a, b in zip(s, k2)])
        k4 = f([a + h * b for a, b in zip(s, k3)])
        s = [a + h / 6 * (b + 2 * c + 2 * d + e) for a, b, c, d, e in zip(s, k1, k2, k3, k4)]
    # RK4 global error ~ (h w)^4: far below 1e-12 at h = 3e-4 s
    assert (veh.x, veh.y, veh.yaw) == pytest.approx(tuple(s), abs=1e-12)


def test_state_round_trip_and_validation():
    veh = DoubleSteerVehicle(1.0)
    veh.step(0.3, 0.4, -0.3, 0.4, 1.0)
    snap = veh.get_state()
    veh.step(0.3, 0.4, -0.3, 0.4, 1.0)
    after = (veh.x, veh.y, veh.yaw)
    veh.set_state(snap)
    veh.step(0.3, 0.4, -0.3, 0.4, 1.0)
    assert (veh.x, veh.y, veh.yaw) == after
    with pytest.raises(ParameterError, match="wheelbase"):
        DoubleSteerVehicle(0.0)
    with pytest.raises(ParameterError, match="yaw0"):
        DoubleSteerVehicle(1.0, yaw0=math.nan)
