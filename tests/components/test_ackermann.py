"""Analytic tests of the per-axle Ackermann coordination (agv_core.ackermann)."""

import math

import pytest

from agv_core.ackermann.ackermann import (
    axle_angle,
    turning_curvature,
    wheel_angles,
    wheel_distances,
)

CASES = [(d, offset) for d in (0.12, -0.05, 0.3, -0.4, 1e-9)
         for offset in (8.0, 3.0, -3.0, -8.0)]


@pytest.mark.parametrize("delta,offset", CASES)
def test_wheel_angles_match_the_turning_centre_construction(delta, offset):
    """Closed form (offset: wheel_angles' axle offset l): O at lateral R = offset /
    tan(delta) on the baseline; each wheel perpendicular to its line to O: tan(delta_w) =
    offset / (R -+ d/2). 1e-14 rad: rounding."""
    d = 2.1
    R = offset / math.tan(delta)
    left, right = wheel_angles(delta, offset, d)
    assert left == pytest.approx(math.atan(offset / (R - d / 2)), abs=1e-14)
    assert right == pytest.approx(math.atan(offset / (R + d / 2)), abs=1e-14)
    assert turning_curvature(delta, offset) == pytest.approx(1.0 / R, rel=1e-14)


@pytest.mark.parametrize("delta,offset", CASES)
def test_ackermann_identity_and_exact_inverse(delta, offset):
    d = 2.1
    left, right = wheel_angles(delta, offset, d)
    R = offset / math.tan(delta)
    inner, outer = (left, right) if R > 0 else (right, left)   # inner: nearer O
    assert abs(inner) > abs(outer)
    if abs(delta) > 1e-6:   # cotangents of ~1e-9 rad lose the identity to rounding
        # both wheels steer the same way, so in magnitudes (the paper's angles are >= 0)
        cot_outer, cot_inner = 1 / abs(math.tan(outer)), 1 / abs(math.tan(inner))
        assert cot_outer - cot_inner == pytest.approx(d / abs(offset), rel=1e-12)
    # the inverse needs neither d nor offset, and is exact to rounding
    assert axle_angle(left, right) == pytest.approx(delta, rel=1e-14, abs=1e-22)


def test_straight_axle_and_rejected_geometry():
    assert wheel_angles(0.0, 3.0, 2.1) == (0.0, 0.0)
    assert axle_angle(0.0, 0.0) == 0.0
    assert wheel_distances(0.0, 3.0, 2.1) == (math.inf, math.inf)
    with pytest.raises(ValueError, match="within the track"):
        wheel_angles(math.atan(3.0 / 1.0), 3.0, 2.1)    # O at 1 m: inside the 2.1 m track
    with pytest.raises(ValueError, match="no common turning centre"):
        axle_angle(0.1, -0.1)


def test_seed003_e1_e2_readings_agree():
    """Seed 003 defines e1, e2 as the distances of axle 2's wheels to its turning centre:
    sin(gamma) = L2 / e1, sin(phi) = L2 / e2 for the inner and outer wheel."""
    L2, d, delta = 3.0, 2.1, 0.12
    left, right = wheel_angles(delta, L2, d)
    e_left, e_right = wheel_distances(delta, L2, d)
    assert math.sin(left) == pytest.approx(L2 / e_left, rel=1e-14)
    assert math.sin(right) == pytest.approx(L2 / e_right, rel=1e-14)
