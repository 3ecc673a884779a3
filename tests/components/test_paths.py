"""Tests of agv_core.numerics.paths: closed forms first, then brute force, then properties."""

import math

import numpy as np
import pytest
from scipy.integrate import quad

from agv_core.errors import ParameterError
from agv_core.numerics.paths import heading_error, parse_path

RNG = np.random.default_rng(12345)


# ---------------------------------------------------------------------- closed forms
def test_heading_error_wraps_to_half_open_interval():
    # exact binary fractions of pi: results are exact to one rounding (1e-15 rad)
    assert heading_error(math.pi, 0.0) == pytest.approx(math.pi, abs=1e-15)
    assert heading_error(-math.pi, 0.0) == pytest.approx(math.pi, abs=1e-15)
    assert heading_error(1.5 * math.pi, 0.0) == pytest.approx(-0.5 * math.pi, abs=1e-15)
    assert heading_error(0.1, 4 * math.pi + 0.3) == pytest.approx(-0.2, abs=1e-14)


def test_line_projection_closed_form():
    path = parse_path("line:x0=1,y0=2,heading=0.3")
    c, s = math.cos(0.3), math.sin(0.3)
    p = path.project(4.0, 1.0)
    # s = (p - p0) . t, offset = (p - p0) . n_left: arithmetic identity, 1e-12 m
    assert p.s == pytest.approx(3.0 * c - 1.0 * s, abs=1e-12)
    assert p.offset == pytest.approx(-3.0 * s - 1.0 * c, abs=1e-12)
    assert (p.heading, p.curvature, p.curvature_rate) == (0.3, 0.0, 0.0)


def test_line_step_jumps_at_step_at():
    path = parse_path("line:step_at=5,step=2")
    assert path.project(4.999, 0.5).offset == pytest.approx(0.5, abs=1e-12)
    assert path.project(5.001, 0.5).offset == pytest.approx(-1.5, abs=1e-12)
    assert path.point(6.0).y == 2.0 and path.point(4.0).y == 0.0


@pytest.mark.parametrize("direction, sign", [("ccw", 1.0), ("cw", -1.0)])
def test_circle_closed_form(direction, sign):
    radius = 4.4
    path = parse_path(f"circle:radius={radius},direction={direction}")
    start = path.point(0.0)
    assert (start.x, start.y, start.heading % (2 * math.pi)) == pytest.approx((0, 0, 0),
                                                                            abs=1e-12)
    centre = (0.0, sign * radius)
    for r, angle in [(3.0, 0.4), (6.0, 2.0), (4.4, -1.0)]:
        x, y = centre[0] + r * math.cos(angle), centre[1] + r * math.sin(angle)
        p = path.project(x, y)
        # offset = (R - r) on the left for ccw, (r - R) for cw; exact to rounding
        assert p.offset == pytest.approx(sign * (radius - r), abs=1e-12)
        assert p.curvature == pytest.approx(sign / radius, rel=1e-15)
        # arc length from the start point (angle -pi/2 for ccw, +pi/2 for cw)
        expected = ((sign * (angle + sign * math.pi / 2)) % (2 * math.pi)) * radius
        assert p.s == pytest.approx(expected, abs=1e-12)


def test_circle_hint_keeps_lap():
    path = parse_path("circle:radius=2")
    lap = 2 * math.pi * 2
    p = path.project(2.0, 2.0, s_hint=3 * lap + math.pi - 0.1)
    assert p.s == pytest.approx(3 * lap + math.pi, abs=1e-12)   # one quarter = pi m


def test_sine_arc_length_matches_quadrature():
    amp, wl = 3.0, 30.0
    path = parse_path(f"sine:amplitude={amp},wavelength={wl}")
    k = 2 * math.pi / wl
    for x in (0.3, 7.5, 29.0, 95.0):
        ref, err = quad(lambda u: math.sqrt(1 + (amp * k * math.cos(k * u)) ** 2), 0, x,
                        epsabs=1e-13, epsrel=1e-13, limit=200)
        p = path.project(x, amp * math.sin(k * x))
        # elliptic-integral closed form vs adaptive quadrature: both ~1e-13, allow 1e-9
        assert p.s == pytest.approx(ref, abs=1e-9)
        assert path.point(ref).x == pytest.approx(x, abs=1e-9)


def test_sine_curvature_closed_form():
    # seed 004 path y = 2 sin(x / 3): curvature -A k^2 at the crest x = 3 pi / 2
    path = parse_path(f"sine:amplitude=2,wavelength={6 * math.pi}")
    p = path.project(1.5 * math.pi, 2.5)
    assert p.curvature == pytest.approx(-2.0 / 9.0, rel=1e-12)
    assert p.offset == pytest.approx(0.5, abs=1e-12)
    assert p.heading == pytest.approx(0.0, abs=1e-12)
    # dc/ds against a central difference of c(s) (step 1e-4 m: truncation ~1e-9)
    q = path.point(2.0)
    dc = (path.point(2.0 + 1e-4).curvature - path.point(2.0 - 1e-4).curvature) / 2e-4
    assert q.curvature_rate == pytest.approx(dc, rel=1e-6)


# ---------------------------------------------------------------------- brute force
def _sine(amp, wl, x0=0.0, y0=0.0):
    def f(x):
        return y0 + amp * np.sin(2 * np.pi * (x - x0) / wl)
    return f


def _scurve(straight, amp, wl):
    def f(x):
        return np.where(x < straight, 0.0, amp * np.sin(2 * np.pi * (x - straight) / wl))
    return f


@pytest.mark.parametrize("spec, f, corner", [
    ("sine:amplitude=3,wavelength=30", _sine(3, 30), None),
    (f"sine:amplitude=2,wavelength={6 * math.pi},x0=1,y0=-1", _sine(2, 6 * math.pi, 1, -1),
     None),
    ("scurve:straight=10,amplitude=1.5,wavelength=12", _scurve(10, 1.5, 12), 10.0)])
def test_graph_projection_matches_brute_force(spec, f, corner):
    path = parse_path(spec)
    for _ in range(15):
        px, py = RNG.uniform(1, 40), RNG.uniform(-4, 4)
        p = path.project(px, py)
        # dense grid in x (spacing 2e-5 m) over every x that can be closer than
        # |py - f(px)|: grid min distance exceeds the true one by <= ~1e-9 m
        reach = abs(py - f(px)) + 1e-3
        x = np.arange(px - reach, px + reach, 2e-5)
        if corner is not None:
            x = np.append(x, corner)   # at a kink the grid error would be first order
        d = np.hypot(x - px, f(x) - py)
        assert abs(p.offset) == pytest.approx(d.min(), abs=2e-9)
        assert abs(p.offset) <= d.min() + 1e-12
        if corner is not None and abs(p.x - corner) < 1e-9:
            continue   # closest point at the S-curve's corner: not perpendicular
        # closest point is a critical point: (p - c) . tangent = 0 to rounding
        along = (px - p.x) * math.cos(p.heading) + (py - p.y) * math.sin(p.heading)
        assert abs(along) < 1e-10


def test_sine_global_minimum_far_from_path():
    # far above a crest several branches compete; compare with a dense global search
    path = parse_path("sine:amplitude=3,wavelength=10")
    px, py = 12.0, 9.0
    x = np.linspace(-5, 40, 450001)
    d = np.hypot(x - px, 3 * np.sin(2 * np.pi * x / 10) - py)
    p = path.project(px, py)
    # grid 1e-4 m: distance error <= ~1e-8 m
    assert abs(p.offset) == pytest.approx(d.min(), abs=1e-7)
    assert p.x == pytest.approx(x[np.argmin(d)], abs=2e-4)


# ---------------------------------------------------------------------- properties
SPECS = ["line:x0=1,y0=-2,heading=0.7", "circle:radius=9.07", "circle:radius=3,cx=1,cy=2,"
         "direction=cw,heading=0.5", "sine:amplitude=3,wavelength=30",
         "scurve:straight=5,amplitude=2,wavelength=20"]


@pytest.mark.parametrize("spec", SPECS)
def test_point_of_projection_is_consistent(spec):
    path = parse_path(spec)
    for _ in range(20):
        s = RNG.uniform(0.5, 30.0)
        q = path.point(s)
        lateral = RNG.uniform(-0.8, 0.8)
        px, py = q.x - lateral * math.sin(q.heading), q.y + lateral * math.cos(q.heading)
        p = path.project(px, py, s_hint=s + 0.3)
        # near a smooth path the projection of a normal offset returns s and offset;
        # arc-length round trips are Newton-exact: 1e-9 m
        assert p.s == pytest.approx(s, abs=1e-9)
        assert p.offset == pytest.approx(lateral, abs=1e-9)
        r = path.point(p.s)
        assert (r.x, r.y) == pytest.approx((p.x, p.y), abs=1e-9)
        assert heading_error(r.heading, p.heading) == pytest.approx(0.0, abs=1e-9)


def test_waypoints_on_circle(tmp_path):
    radius = 5.0
    angles = np.linspace(-math.pi / 2, math.pi / 2, 41)
    (tmp_path / "arc.csv").write_text(
        "x,y\n" + "".join(f"{radius * math.cos(a)!r},{radius + radius * math.sin(a)!r}\n"
                          for a in angles))
    path = parse_path("waypoints:file=arc.csv", base_dir=tmp_path)
    chord = 2 * radius * math.sin((angles[1] - angles[0]) / 2)
    assert path.length == pytest.approx(40 * chord, rel=1e-12)
    p = path.project(3.0, 5.0)
    # vertices lie on the circle: circle through 3 vertices is the circle itself
    assert p.curvature == pytest.approx(1 / radius, rel=1e-9)  # runs counter-clockwise
    # (3, 5) is inside the arc, left of it: distance to the chords near the vertex
    # (5, 5), between R cos(pi / 80) - 3 and 2
    assert 1.99 < p.offset <= 2.0
    q = path.point(path.length + 1.0)   # straight extension past the last vertex (0, 10)
    heading = math.pi - (angles[-1] - angles[-2]) / 2    # direction of the last chord
    assert (q.x, q.y) == pytest.approx((math.cos(heading), 10.0 + math.sin(heading)),
                                       abs=1e-12)   # 1 m along it: exact to rounding


@pytest.mark.parametrize("spec, words", [
    ("spiral:a=1", "unknown path kind"),
    ("circle:radius", "malformed"),
    ("circle:", "needs radius"),
    ("circle:radius=0", "positive"),
    ("circle:radius=-2", "positive"),
    ("circle:radius=abc", "not a number"),
    ("circle:radius=2,colour=3", "unknown key"),
    ("sine:amplitude=1,wavelength=0", "wavelength"),
    ("sine:amplitude=1", "needs wavelength"),
    ("line:step_at=3", "go together"),
    ("", "empty"),
    ("waypoints:file=missing.csv", "cannot be read"),
])
def test_bad_specs_raise_parameter_error(spec, words, tmp_path):
    with pytest.raises(ParameterError, match=words) as info:
        parse_path(spec, base_dir=tmp_path)
    assert info.value.name == "path"


def test_malformed_waypoint_file(tmp_path):
    (tmp_path / "bad.csv").write_text("x,y\n0,0\n1,oops\n")
    with pytest.raises(ParameterError, match="line 3"):
        parse_path("waypoints:file=bad.csv", base_dir=tmp_path)
    (tmp_path / "nohead.csv").write_text("0,0\n1,1\n")
    with pytest.raises(ParameterError, match="header"):
        parse_path("waypoints:file=nohead.csv", base_dir=tmp_path)


def test_path_files_and_rebase_path(tmp_path, monkeypatch):
    """The file a path string names, and the string with it made absolute: parsed from
    any working folder, it reads the file parse_path(spec, base_dir) reads."""
    from agv_core.numerics.paths import path_files, rebase_path

    assert path_files(" Waypoints: file = wp.csv ") == ["wp.csv"]
    assert path_files("waypoints:file=/abs/wp.csv") == ["/abs/wp.csv"]
    assert path_files("line:x0=1") == path_files("file=wp.csv") == path_files(3.0) == []
    assert rebase_path("line:x0=1,y0=2", tmp_path) == "line:x0=1,y0=2"
    assert rebase_path("waypoints:file=/abs/wp.csv", tmp_path) == "waypoints:file=/abs/wp.csv"
    spec = rebase_path("waypoints: file = sub/wp.csv", tmp_path)
    assert spec == f"waypoints:file={tmp_path / 'sub/wp.csv'}"
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "wp.csv").write_text("x,y\n0,0\n1,0\n3,1\n")
    elsewhere = tmp_path / "elsewhere"
    (elsewhere / "sub").mkdir(parents=True)
    (elsewhere / "sub" / "wp.csv").write_text("x,y\n0,5\n1,5\n")
    monkeypatch.chdir(elsewhere)
    ours = parse_path("waypoints:file=sub/wp.csv", base_dir=tmp_path).project(2.0, 0.0)
    assert parse_path(spec).project(2.0, 0.0) == ours
    assert parse_path("waypoints:file=sub/wp.csv").project(2.0, 0.0) != ours
    with pytest.raises(ParameterError, match="cannot be written in a path string"):
        rebase_path("waypoints:file=wp.csv", tmp_path / "a,b")
