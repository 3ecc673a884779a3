"""Unit tests of the kinematic vehicle core (agv_core.vehicle)."""

import json
import math

import pytest

from agv_core.errors import ParameterError
from agv_core.vehicle.vehicle import Vehicle


@pytest.mark.parametrize("reference_point", ["front", "rear"])
@pytest.mark.parametrize("alpha", [0.3, -0.05])
def test_constant_steering_drives_a_circle(reference_point, alpha):
    # rear-axle centre on a circle of radius R = L / tan(alpha) about (0, R) (start at the
    # origin heading +x with the rear axle), front wheel on radius L / sin(alpha);
    # 1e-6 relative per the brief (the arc is exact: observed ~1e-14)
    L, v, h = 1.5, 2.0, 0.05
    R = L / math.tan(alpha)
    start = (L, 0.0) if reference_point == "front" else (0.0, 0.0)
    car = Vehicle(L, *start, heading0=0.0, reference_point=reference_point)
    for _ in range(400):  # 40 m: more than a full turn for alpha = 0.3 (R = 4.83 m)
        car.step(alpha, v, h)
        xr, yr = car.rear()
        xf, yf = car.front()
        assert math.hypot(xr, yr - R) == pytest.approx(abs(R), rel=1e-6)
        assert math.hypot(xf, yf - R) == pytest.approx(abs(L / math.sin(alpha)), rel=1e-6)
    assert car.heading == pytest.approx(400 * h * v * math.tan(alpha) / L, rel=1e-12)
    assert car.distance == pytest.approx(40.0, rel=1e-12)


@pytest.mark.parametrize("reference_point", ["front", "rear"])
def test_linear_model_closed_form(reference_point):
    # small-angle model for held alpha: beta = b0 + (v alpha / L) t,
    # y_P = y0 + v (a + b0) t + v^2 alpha t^2 / (2 L), a = alpha at F, 0 at R; 1e-12 rounding
    L, v, alpha, b0, h = 1.2, 1.5, 0.02, -0.01, 0.01
    car = Vehicle(L, 0.3, 0.1, heading0=b0, reference_point=reference_point, linear=True)
    a = alpha if reference_point == "front" else 0.0
    for n in range(1, 301):
        car.step(alpha, v, h)
        t = n * h
        assert car.heading == pytest.approx(b0 + v * alpha * t / L, abs=1e-12)
        assert car.y == pytest.approx(0.1 + v * (a + b0) * t + v * v * alpha * t * t / (2 * L),
                                      abs=1e-12)
        assert car.x == pytest.approx(0.3 + v * t, abs=1e-12)


@pytest.mark.parametrize("linear", [False, True])
@pytest.mark.parametrize("reference_point", ["front", "rear"])
def test_two_half_steps_equal_one_step(linear, reference_point):
    # exact integration: splitting a step changes only rounding; bound 1e-12 m / rad for
    # positions of order 1 m (a few ulps accumulated over the two paths)
    one = Vehicle(1.0, 0.2, -0.4, heading0=0.7, reference_point=reference_point, linear=linear)
    two = Vehicle(1.0, 0.2, -0.4, heading0=0.7, reference_point=reference_point, linear=linear)
    for alpha, v in [(0.4, 1.0), (-0.2, 3.0), (0.0, 2.0), (1.2, 0.5)]:
        one.step(alpha, v, 0.2)
        two.step(alpha, v, 0.1)
        two.step(alpha, v, 0.1)
        for key in ("x", "y", "heading", "distance"):
            assert getattr(two, key) == pytest.approx(getattr(one, key), abs=1e-12)


def test_straight_line_and_small_angle_sinc_branch():
    # alpha = 0 (and 1e-9, inside the series branch of sinc) moves straight along heading
    car = Vehicle(1.0, 0.0, 0.0, heading0=math.pi / 6, reference_point="rear")
    car.step(1e-9, 2.0, 0.5)
    assert car.x == pytest.approx(math.cos(math.pi / 6), abs=1e-9)
    assert car.y == pytest.approx(math.sin(math.pi / 6), abs=1e-9)


def test_state_round_trip():
    car = Vehicle(1.0)
    car.step(0.2, 1.0, 0.3)
    saved = json.loads(json.dumps(car.get_state()))
    car.step(0.1, 1.0, 0.3)
    other = Vehicle(1.0)
    other.set_state(saved)
    other.step(0.1, 1.0, 0.3)
    assert other.get_state() == car.get_state()


@pytest.mark.parametrize("kwargs, name", [
    ({"wheelbase": 0.0}, "wheelbase"), ({"wheelbase": -1.0}, "wheelbase"),
    ({"wheelbase": float("nan")}, "wheelbase"), ({"wheelbase": float("inf")}, "wheelbase"),
    ({"wheelbase": 1.0, "reference_point": "middle"}, "reference_point"),
    ({"wheelbase": 1.0, "x0": float("inf")}, "x0"),
    ({"wheelbase": 1.0, "heading0": float("nan")}, "heading0"),
])
def test_bad_parameters(kwargs, name):
    with pytest.raises(ParameterError) as info:
        Vehicle(**kwargs)
    assert info.value.name == name


def test_steering_beyond_ninety_degrees_fails():
    with pytest.raises(FloatingPointError):
        Vehicle(1.0).step(math.pi / 2, 1.0, 0.1)


@pytest.mark.parametrize("linear", [False, True])
def test_halving_the_internal_step_over_20_s(linear):
    """A 20 s drive with the steering angle and speed changing every 10 ms (held over each
    communication step, as a master delivers them): integrating each step whole or as two
    5 ms halves gives the same trajectory to 1e-9 m. The integration is exact for held
    inputs, so only rounding differs: ~1e-16 relative per step over 2000 steps on
    positions up to ~30 m is ~1e-11 m, and 1e-9 leaves room."""
    whole = Vehicle(1.4944, 0.0, 0.1, reference_point="front", linear=linear)
    halves = Vehicle(1.4944, 0.0, 0.1, reference_point="front", linear=linear)
    h = 0.01
    worst = 0.0
    for k in range(2000):
        t = k * h
        alpha = 0.3 * math.sin(0.8 * t) + 0.05 * math.sin(5.0 * t)
        v = 1.5 + 0.5 * math.sin(0.3 * t)
        whole.step(alpha, v, h)
        halves.step(alpha, v, h / 2)
        halves.step(alpha, v, h / 2)
        worst = max(worst, abs(whole.x - halves.x), abs(whole.y - halves.y))
    assert worst < 1e-9
    assert whole.distance > 25.0  # the drive really covered ground (about 30 m)
