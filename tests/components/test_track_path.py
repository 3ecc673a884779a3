"""The straight-clothoid-arc-clothoid-straight path and the per-point error probe."""

import math

import numpy as np
import pytest
from scipy.special import fresnel

from agv_core.axle_pd.track_path import PointErrors, parse_track_path
from agv_core.errors import ParameterError

QUARTER = math.pi / 2


def test_clothoid_matches_fresnel_integrals():
    """Clothoid entry after the 60 m straight: x = 60 + a C(T/a), y = a S(T/a),
    a = sqrt(pi R T) (scipy.special.fresnel returns S, C). 1e-12 m: quadrature error."""
    R, T = 20.0, 10.0
    path = parse_track_path(f"curve:straight=60,radius={R},angle={QUARTER},transition={T}")
    a = math.sqrt(math.pi * R * T)
    S, C = fresnel(T / a)
    end = path.point(60.0 + T)
    assert (end.x, end.y) == pytest.approx((60.0 + a * C, a * S), abs=1e-12)
    assert end.heading == pytest.approx(T / (2 * R), rel=1e-15)
    assert end.curvature == pytest.approx(1 / R, rel=1e-15)


@pytest.mark.parametrize("transition", [0.0, 10.0])
@pytest.mark.parametrize("direction", ["ccw", "cw"])
def test_geometry_is_continuous_and_turns_by_the_angle(transition, direction):
    path = parse_track_path(f"curve:straight=60,radius=20,angle={QUARTER},"
                            f"transition={transition},direction={direction}")
    sign = 1 if direction == "ccw" else -1
    for s in (path.s1, path.s2, path.s3, path.s4):
        a, b = path.point(s - 1e-9), path.point(s + 1e-9)
        assert math.hypot(a.x - b.x, a.y - b.y) == pytest.approx(2e-9, rel=1e-3)
        assert a.heading == pytest.approx(b.heading, abs=1e-9)
    assert path.point(path.s4 + 5).heading == pytest.approx(sign * QUARTER, abs=1e-15)
    mid = path.point(0.5 * (path.s2 + path.s3))
    assert mid.curvature == sign / 20.0
    # without a transition the exit straight starts at (60 + R, R) for a quarter turn
    if transition == 0.0:
        end = path.point(path.s4)
        assert (end.x, end.y) == pytest.approx((80.0, sign * 20.0), abs=1e-12)


@pytest.mark.parametrize("transition", [0.0, 10.0])
def test_projection_recovers_offset_and_arc_length(transition):
    """Points placed at a known offset along the normal project back to (s, offset) to
    1e-9, with and without a hint (the offsets stay inside the radius of curvature)."""
    path = parse_track_path(f"curve:straight=60,radius=20,angle={QUARTER},"
                            f"transition={transition}")
    for s in np.linspace(-10.0, 130.0, 57):
        p = path.point(s)
        for off in (0.03, -0.5, 2.0):
            x, y = p.x - off * math.sin(p.heading), p.y + off * math.cos(p.heading)
            for hint in (None, s + 0.4):
                q = path.project(x, y, hint)
                assert (q.s, q.offset) == pytest.approx((s, off), abs=1e-9)


def test_other_kinds_and_errors():
    line = parse_track_path("line:heading=0")
    assert line.project(1.0, 0.25).offset == 0.25
    with pytest.raises(ParameterError, match="curve needs radius, angle"):
        parse_track_path("curve:straight=5")
    with pytest.raises(ParameterError, match="shorter than the transition"):
        parse_track_path("curve:straight=5,radius=2,angle=1,transition=3")
    with pytest.raises(ParameterError, match="unknown key 'radiuss'"):
        parse_track_path("curve:straight=5,radiuss=2,angle=1")


def test_point_errors_keep_hints():
    path = parse_track_path(f"curve:straight=60,radius=20,angle={QUARTER}")
    probe = PointErrors(path, 2)
    out = probe.measure([(70.0, 3.0), (10.0, -0.2)], commit=True)
    assert [p.offset for p in out][1] == pytest.approx(-0.2)
    assert probe.get_state()["hints"] == [out[0].s, out[1].s]
