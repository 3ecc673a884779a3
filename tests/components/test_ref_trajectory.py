"""Tests of the seed-001 reference trajectories (agv_core.ref_trajectory)."""

import math

import pytest

from agv_core.errors import ParameterError
from agv_core.ref_trajectory.ref_trajectory import RefTrajectory


def test_circle_closed_form():
    ref = RefTrajectory("circle", speed=0.4, omega=0.074)
    rho = 0.4 / 0.074
    for t in (0.0, 3.3, 20.0, 84.9, 200.0):
        r = ref.at(t)
        assert r["x"] == pytest.approx(rho * math.sin(0.074 * t), abs=1e-12)
        assert r["y"] == pytest.approx(rho * (1 - math.cos(0.074 * t)), abs=1e-12)
        assert r["heading"] == pytest.approx(0.074 * t, abs=1e-12)
        assert r["omega"] == pytest.approx(0.074, rel=1e-14)
        assert r["curvature"] == pytest.approx(1 / rho, rel=1e-14)
        assert r["v"] == 0.4


def test_circle_clockwise():
    r = RefTrajectory("circle", speed=0.5, omega=-0.1).at(5.0)
    assert r["omega"] == pytest.approx(-0.1)
    assert r["heading"] == pytest.approx(-0.5)


def test_scurve_geometry():
    """Straight tangent to the sine at its inflection; first crest at peak_time."""
    ref = RefTrajectory("scurve", speed=0.4, amplitude=1.5, wavelength=12.0, peak_time=33.7)
    k = 2 * math.pi / 12.0
    r0 = ref.at(0.0)
    assert (r0["x"], r0["y"]) == pytest.approx((0.0, 0.0), abs=1e-12)
    assert r0["heading"] == pytest.approx(math.atan(1.5 * k), rel=1e-14)  # 38.1 deg
    assert ref.straight == pytest.approx(10.06, abs=0.005)  # notes section 1.7
    # on the straight: heading constant, curvature 0
    r = ref.at(20.0)
    assert r["heading"] == pytest.approx(r0["heading"], abs=1e-12) and r["curvature"] == 0.0
    # at peak_time: the crest, |kappa| = A k^2, heading 0
    p = ref.at(33.7)
    assert abs(p["curvature"]) == pytest.approx(1.5 * k * k, rel=1e-9)
    assert p["heading"] == pytest.approx(0.0, abs=1e-9)
    assert abs(p["omega"]) == pytest.approx(0.4 * 1.5 * k * k, rel=1e-9)  # 0.164 rad/s
    # |kappa| is below its peak just before and after
    assert abs(ref.at(33.2)["curvature"]) < abs(p["curvature"])
    assert abs(ref.at(34.2)["curvature"]) < abs(p["curvature"])
    # speed along the path: successive points are v dt apart (to chord error)
    a, b = ref.at(40.0), ref.at(40.01)
    assert math.hypot(b["x"] - a["x"], b["y"] - a["y"]) == pytest.approx(0.004, rel=1e-5)


@pytest.mark.parametrize("kwargs,name", [
    ({"kind": "square"}, "kind"), ({"speed": 0.0}, "speed"), ({"omega": 0.0}, "omega"),
    ({"kind": "scurve", "wavelength": -1.0}, "wavelength"),
    ({"kind": "scurve", "peak_time": 1.0}, "peak_time"),
])
def test_bad_parameters_are_named(kwargs, name):
    with pytest.raises(ParameterError, match=f"'{name}'"):
        RefTrajectory(**kwargs)
