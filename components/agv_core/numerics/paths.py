"""Reference paths: closest-point projection, arc length, heading and curvature.

Every path kind derives from :class:`ReferencePath` and is built from a path string by
:func:`parse_path` (``kind:key=value,key=value``, numbers in SI units):

``line:x0=0,y0=0,heading=0,step_at=<m>,step=<m>``
    Straight line from ``(x0, y0)`` along ``heading`` [rad], unbounded both ways (s < 0
    behind the start). With ``step_at`` the reference jumps sideways by ``step`` [m]
    (positive left) at arc length ``step_at`` (seed 002's 2 m lateral step).
``circle:radius=R,cx=..,cy=..,direction=ccw,heading=0``
    Circle of radius R [m]. Without a centre it starts at the origin with tangent
    ``heading`` (default +x), so the default ccw centre is (0, R): seed 004's
    x^2 + (y - r)^2 = r^2. With a centre it starts at the circle point where the tangent
    is ``heading``. ``direction`` is ``ccw`` or ``cw``. Laps continue: s grows without
    bound.
``sine:amplitude=A,wavelength=W,x0=0,y0=0``
    y = y0 + A sin(2 pi (x - x0) / W) for x >= x0; before x0 the start tangent is
    extended as a straight line (s < 0). Seed 004: A = 2, W = 6 pi; seed 002: A = 3, W = 30.
``scurve:straight=L0,amplitude=A,wavelength=W``
    y = 0 for 0 <= x < L0, then y = A sin(2 pi (x - L0) / W) (seed 001's S-curve). The
    heading jumps by atan(2 pi A / W) at x = L0 (the sine starts with that slope); the
    curvature is continuous there (0 on both sides).
``waypoints:file=path.csv``
    Polyline through the vertices of a CSV file with header ``x,y`` (relative to
    ``base_dir``; :func:`path_files` names it, :func:`rebase_path` makes it absolute),
    extended straight beyond both end vertices.

Arc length of the sine pieces is closed form: with u = x - x0, k = 2 pi / W, m = A k,
s(u) = sqrt(1 + m^2) / k * E(k u | m^2 / (1 + m^2)), E the incomplete elliptic integral
of the second kind (``scipy.special.ellipeinc``); x(s) is its Newton inverse.
The closest point is found by a vectorised dense sampling of the squared distance over
a window that must contain it, then safeguarded Newton refinement of
g(x) = (x - px) + (f(x) - py) f'(x) = 0 inside the bracket of the best sample, to
rounding (better than 1e-12 m).
"""

import csv
import math
import os
from collections.abc import Collection, Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import ParameterError
from .angles import TWO_PI
from .angles import heading_error as heading_error  # part of this API
from .finite import finite


class PathProjection(NamedTuple):
    """A path point, and the signed offset of a query point from it.

    Attributes
    ----------
    s : float
        Arc length of the path point [m].
    x, y : float
        The path point [m].
    heading : float
        Path tangent heading at s [rad].
    curvature : float
        c(s) [1/m], positive turning left.
    curvature_rate : float
        dc/ds [1/m^2].
    offset : float
        Signed lateral offset of the query point [m], positive left of the path.
    """

    s: float
    x: float
    y: float
    heading: float
    curvature: float
    curvature_rate: float
    offset: float


class ReferencePath:
    """Base class of every path kind.

    Attributes
    ----------
    length : float
        Path length [m], ``math.inf`` when unbounded.
    """

    length = math.inf

    def project(self, x: float, y: float, s_hint: float | None = None) -> PathProjection:
        """Closest path point to (x, y) [m].

        Parameters
        ----------
        x, y : float
            Query point [m].
        s_hint : float, optional
            Arc length [m] of the previous projection. The search is then local around
            it (fast, and unambiguous where several path points are about as close, e.g.
            the lap of a circle).

        Returns
        -------
        PathProjection
        """
        raise NotImplementedError

    def point(self, s: float) -> PathProjection:
        """The path point at arc length ``s`` [m] (offset 0)."""
        raise NotImplementedError

    def polyline(self, s0: float, s1: float, ds: float
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Points from ``s0`` to ``s1`` [m] every ``ds`` [m] (end included), for plots.

        Returns
        -------
        tuple of numpy.ndarray
            x, y [m].
        """
        if not ds > 0:
            raise ValueError(f"ds must be positive, got {ds}")
        n = max(int(math.ceil((s1 - s0) / ds - 1e-9)), 1)
        points = [self.point(s) for s in np.linspace(s0, s1, n + 1)]
        return np.array([p.x for p in points]), np.array([p.y for p in points])


# ---------------------------------------------------------------------- line
class LinePath(ReferencePath):
    """Straight line with an optional lateral step (see the module docstring).

    Parameters
    ----------
    x0, y0 : float
        Start point [m].
    heading : float
        Direction [rad].
    step_at : float or None
        Arc length [m] where the reference jumps sideways; None for no step.
    step : float
        Lateral jump [m], positive left.

    Notes
    -----
    With a step the projection uses the branch at the along-track coordinate of the
    query point: the reference jumps when the vehicle passes ``step_at``.
    """

    def __init__(self, x0: float = 0.0, y0: float = 0.0, heading: float = 0.0,
                 step_at: float | None = None, step: float = 0.0) -> None:
        self.x0, self.y0, self.heading = float(x0), float(y0), float(heading)
        self.step_at = None if step_at is None else float(step_at)
        self.step = float(step)
        self._c, self._s = math.cos(self.heading), math.sin(self.heading)

    def _lateral(self, s: float) -> float:
        return self.step if self.step_at is not None and s >= self.step_at else 0.0

    def point(self, s: float) -> PathProjection:
        s = float(s)
        lat = self._lateral(s)
        return PathProjection(s, self.x0 + s * self._c - lat * self._s,
                              self.y0 + s * self._s + lat * self._c, self.heading, 0.0, 0.0,
                              0.0)

    def project(self, x: float, y: float, s_hint: float | None = None) -> PathProjection:
        dx, dy = float(x) - self.x0, float(y) - self.y0
        s = dx * self._c + dy * self._s
        n = -dx * self._s + dy * self._c
        lat = self._lateral(s)
        # point(s) with the offset, built once (the same arithmetic as point)
        return PathProjection(s, self.x0 + s * self._c - lat * self._s,
                              self.y0 + s * self._s + lat * self._c, self.heading, 0.0, 0.0,
                              n - lat)


# ---------------------------------------------------------------------- circle
class CirclePath(ReferencePath):
    """Circle, travelled ccw or cw from a start point (see the module docstring).

    Parameters
    ----------
    radius : float
        R [m], > 0.
    cx, cy : float or None
        Centre [m]; None for the circle through the origin with tangent ``heading``.
    direction : {"ccw", "cw"}
    heading : float
        Tangent heading at the start point [rad].
    """

    def __init__(self, radius: float, cx: float | None = None, cy: float | None = None,
                 direction: str = "ccw", heading: float = 0.0) -> None:
        if not (radius > 0 and math.isfinite(radius)):
            raise ParameterError("path", f"circle radius must be positive, got {radius}")
        if direction not in ("ccw", "cw"):
            raise ParameterError("path", f"circle direction must be ccw or cw, got "
                                         f"'{direction}'")
        if (cx is None) != (cy is None):
            raise ParameterError("path", "circle needs both cx and cy, or neither")
        self.radius = float(radius)
        self.sign = 1.0 if direction == "ccw" else -1.0
        h = float(heading)
        nx, ny = -math.sin(h), math.cos(h)   # left normal at the start
        if cx is None:
            cx, cy = self.sign * self.radius * nx, self.sign * self.radius * ny
        self.cx, self.cy = float(cx), float(cast(float, cy))  # cy is given with cx
        # polar angle of the start point seen from the centre
        self.phi0 = math.atan2(-self.sign * ny, -self.sign * nx)

    def _at(self, s: float, offset: float) -> PathProjection:
        phi = self.phi0 + self.sign * s / self.radius
        heading = phi + self.sign * math.pi / 2
        return PathProjection(s, self.cx + self.radius * math.cos(phi),
                              self.cy + self.radius * math.sin(phi), heading,
                              self.sign / self.radius, 0.0, offset)

    def point(self, s: float) -> PathProjection:
        return self._at(float(s), 0.0)

    def project(self, x: float, y: float, s_hint: float | None = None) -> PathProjection:
        dx, dy = float(x) - self.cx, float(y) - self.cy
        r = math.hypot(dx, dy)
        phi = math.atan2(dy, dx)
        if s_hint is None:
            s = (self.sign * (phi - self.phi0)) % TWO_PI * self.radius
        else:
            phi_h = self.phi0 + self.sign * float(s_hint) / self.radius
            s = float(s_hint) + self.sign * heading_error(phi - phi_h, 0.0) * self.radius
        # ccw: the centre is on the left, a point inside (r < R) is left of the path
        return self._at(s, self.sign * (self.radius - r))


# ---------------------------------------------------------------------- graph paths
#: (f, f', f'', f''') of a graph piece at x (arrays of x's shape).
_Derivatives = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                     NDArray[np.float64]]

class _LinePiece:
    """y = yr + m (x - xr) on [a, b] in x; arc length sr at the anchor x = xr."""

    def __init__(self, a: float, b: float, xr: float, yr: float, slope: float, sr: float
                 ) -> None:
        self.a, self.b, self.xr, self.yr, self.m, self.sr = a, b, xr, yr, slope, sr
        self.q = math.sqrt(1.0 + slope * slope)

    def derivs(self, x: ArrayLike) -> _Derivatives:
        x = np.asarray(x, dtype=float)
        z = np.zeros_like(x)
        return self.yr + self.m * (x - self.xr), z + self.m, z, z

    def s_of_x(self, x: float) -> float:
        return self.sr + (x - self.xr) * self.q

    def x_of_s(self, s: float) -> float:
        return self.xr + (s - self.sr) / self.q

    def closest(self, px: float, py: float, lo: float, hi: float) -> float:
        t = ((px - self.xr) + self.m * (py - self.yr)) / (1.0 + self.m * self.m)
        return min(max(self.xr + t, lo), hi)


class _SinePiece:
    """y = y0 + A sin(k (x - a)) on [a, inf); arc length sa at x = a."""

    def __init__(self, a: float, y0: float, amplitude: float, wavelength: float, sa: float
                 ) -> None:
        self.a, self.b, self.y0, self.amp, self.sa = a, math.inf, y0, amplitude, sa
        self.wavelength = wavelength
        self.k = TWO_PI / wavelength
        mk = amplitude * self.k
        self.q = math.sqrt(1.0 + mk * mk)
        self.par = mk * mk / (1.0 + mk * mk)

    def derivs(self, x: ArrayLike) -> _Derivatives:
        ph = self.k * (np.asarray(x, dtype=float) - self.a)
        sn, cs = np.sin(ph), np.cos(ph)
        ak = self.amp * self.k
        return (self.y0 + self.amp * sn, ak * cs, -ak * self.k * sn,
                -ak * self.k * self.k * cs)

    def s_of_x(self, x: float) -> float:
        from scipy.special import ellipeinc  # only sine paths need scipy

        return self.sa + self.q / self.k * float(ellipeinc(self.k * (x - self.a), self.par))

    def x_of_s(self, s: float) -> float:
        target = s - self.sa
        x = self.a + target / self.q * (self.q + 1.0) / 2.0   # mean slope guess
        for _ in range(60):
            _, fp, _, _ = self.derivs(x)
            dx = (self.s_of_x(x) - s) / math.sqrt(1.0 + float(fp) ** 2)
            x -= dx
            if abs(dx) <= 1e-14 * max(1.0, abs(x)):
                break
        return x

    def closest(self, px: float, py: float, lo: float, hi: float) -> float:
        span = hi - lo
        spacing = self.wavelength / 128.0
        n = int(min(max(math.ceil(span / spacing), 8), 4096))
        xs = np.linspace(lo, hi, n + 1)
        f, _, _, _ = self.derivs(xs)
        i = int(np.argmin((xs - px) ** 2 + (f - py) ** 2))
        a, b = xs[max(i - 1, 0)], xs[min(i + 1, n)]
        return _refine(self, px, py, a, b, xs[i])


#: A piece of a :class:`GraphPath`.
_Piece = _LinePiece | _SinePiece


def _g(piece: _Piece, px: float, py: float, x: float) -> tuple[float, float]:
    fa, fpa, fppa, _ = piece.derivs(x)
    f, fp, fpp = float(fa), float(fpa), float(fppa)
    return (x - px) + (f - py) * fp, 1.0 + fp * fp + (f - py) * fpp


def _dist2(piece: _Piece, px: float, py: float, x: float) -> float:
    f = float(piece.derivs(x)[0])
    return (x - px) ** 2 + (f - py) ** 2


def _refine(piece: _Piece, px: float, py: float, a: float, b: float, x: float) -> float:
    """Minimise the distance on [a, b] from x: Newton on g with a bisection safeguard."""
    ga, _ = _g(piece, px, py, a)
    gb, _ = _g(piece, px, py, b)
    if not (ga <= 0.0 <= gb):
        # no interior minimum bracketed: best of the sample and the ends
        return min((a, x, b), key=lambda c: _dist2(piece, px, py, c))
    lo, hi = a, b
    for _ in range(100):
        g, dg = _g(piece, px, py, x)
        if g == 0.0:
            break
        if g < 0.0:
            lo = x
        else:
            hi = x
        step = g / dg if dg > 0.0 else math.inf
        new = x - step
        if not (lo < new < hi):
            new = 0.5 * (lo + hi)
        if abs(new - x) <= 1e-15 * max(1.0, abs(x)) or hi - lo <= 1e-15 * max(1.0, abs(x)):
            x = new
            break
        x = new
    return x


class GraphPath(ReferencePath):
    """Path y = F(x) travelled towards +x, made of line and sine pieces.

    Parameters
    ----------
    pieces : list
        Consecutive pieces covering (-inf, inf) in x, with continuous arc length.
    wavelength : float
        Typical feature length [m] setting the search window with a hint.
    """

    def __init__(self, pieces: Sequence[_Piece], wavelength: float) -> None:
        self.pieces = pieces
        self.wavelength = float(wavelength)

    def _piece_x(self, x: float) -> _Piece:
        for piece in self.pieces:
            if x <= piece.b:
                return piece
        return self.pieces[-1]

    def _piece_s(self, s: float) -> _Piece:
        for piece in self.pieces:
            if piece.b == math.inf or s <= piece.s_of_x(piece.b):
                return piece
        return self.pieces[-1]

    def x_of_s(self, s: float) -> float:
        """x [m] of the path point at arc length s [m]."""
        return self._piece_s(float(s)).x_of_s(float(s))

    def _at_x(self, x: float, piece: _Piece | None = None, px: float | None = None,
              py: float | None = None) -> PathProjection:
        piece = piece or self._piece_x(x)
        f, fp, fpp, fppp = (float(v) for v in piece.derivs(x))
        q2 = 1.0 + fp * fp
        curvature = fpp / q2 ** 1.5
        dc_dx = fppp / q2 ** 1.5 - 3.0 * fp * fpp * fpp / q2 ** 2.5
        heading = math.atan(fp)
        offset = 0.0
        if px is not None:
            py = cast(float, py)  # given with px
            normal = -(px - x) * math.sin(heading) + (py - f) * math.cos(heading)
            offset = math.copysign(math.hypot(px - x, py - f), normal)
        x = float(x)
        return PathProjection(float(piece.s_of_x(x)), x, f, heading, curvature,
                              dc_dx / math.sqrt(q2), offset)

    def point(self, s: float) -> PathProjection:
        x = self.x_of_s(s)
        p = self._at_x(x)
        return p._replace(s=float(s))

    def project(self, x: float, y: float, s_hint: float | None = None) -> PathProjection:
        px, py = float(x), float(y)
        if s_hint is None:
            d0 = abs(py - float(self._piece_x(px).derivs(px)[0]))
            xa, xb = px - d0 - 1e-9, px + d0 + 1e-9
        else:
            hint = self.point(s_hint)
            w = 2.0 * math.hypot(px - hint.x, py - hint.y) + self.wavelength / 4.0
            xa, xb = self.x_of_s(s_hint - w), self.x_of_s(s_hint + w)
        best: tuple[float, float, _Piece] | None = None
        for piece in self.pieces:
            lo, hi = max(piece.a, xa), min(piece.b, xb)
            if lo > hi:
                continue
            c = piece.closest(px, py, lo, hi)
            d2 = _dist2(piece, px, py, c)
            if best is None or d2 < best[0]:
                best = (d2, c, piece)
        best = cast(tuple[float, float, _Piece], best)  # the pieces cover every x
        return self._at_x(best[1], best[2], px, py)


def sine_path(amplitude: float, wavelength: float, x0: float = 0.0, y0: float = 0.0
              ) -> GraphPath:
    """:class:`GraphPath` y = y0 + A sin(2 pi (x - x0) / W), x >= x0, tangent before."""
    _check_wave(amplitude, wavelength)
    x0, y0 = finite("x0", x0, "path"), finite("y0", y0, "path")
    slope = amplitude * TWO_PI / wavelength
    return GraphPath([_LinePiece(-math.inf, x0, x0, y0, slope, 0.0),
                      _SinePiece(x0, y0, amplitude, wavelength, 0.0)], wavelength)


def scurve_path(straight: float, amplitude: float, wavelength: float) -> GraphPath:
    """:class:`GraphPath` y = 0 for x < L0, then y = A sin(2 pi (x - L0) / W)."""
    _check_wave(amplitude, wavelength)
    if not (straight >= 0 and math.isfinite(straight)):
        raise ParameterError("path", f"scurve straight must be >= 0 m, got {straight}")
    return GraphPath([_LinePiece(-math.inf, straight, 0.0, 0.0, 0.0, 0.0),
                      _SinePiece(straight, 0.0, amplitude, wavelength, straight)], wavelength)


def _check_wave(amplitude: float, wavelength: float) -> None:
    if not (wavelength > 0 and math.isfinite(wavelength)):
        raise ParameterError("path", f"wavelength must be positive, got {wavelength}")
    if not math.isfinite(amplitude):
        raise ParameterError("path", f"amplitude must be finite, got {amplitude}")


# ---------------------------------------------------------------------- waypoints
class WaypointPath(ReferencePath):
    """Polyline through vertices, extended straight beyond both ends.

    Parameters
    ----------
    x, y : array_like
        Vertices [m], at least two, consecutive vertices distinct.

    Notes
    -----
    Heading is the direction of the segment. Curvature at an inner vertex is that of
    the circle through it and its two neighbours (signed, positive left); the end
    vertices take their neighbour's value; between vertices it is interpolated linearly
    in s (so curvature_rate is the slope of that interpolation), and held constant on
    the straight extensions.
    """

    def __init__(self, x: ArrayLike, y: ArrayLike) -> None:
        self.vx, self.vy = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        if self.vx.shape != self.vy.shape or self.vx.ndim != 1 or self.vx.size < 2:
            raise ParameterError("path", "waypoints need at least two vertices (x, y)")
        if not (np.all(np.isfinite(self.vx)) and np.all(np.isfinite(self.vy))):
            raise ParameterError("path", "waypoints must be finite numbers")
        dx, dy = np.diff(self.vx), np.diff(self.vy)
        seg = np.hypot(dx, dy)
        if np.any(seg <= 0.0):
            raise ParameterError("path", "waypoints: consecutive vertices must differ "
                                         f"(vertex {int(np.argmin(seg)) + 1} repeats)")
        self.dx, self.dy, self.seg = dx, dy, seg
        self.sv = np.concatenate(([0.0], np.cumsum(seg)))
        self.length = float(self.sv[-1])
        self.headings = np.arctan2(dy, dx)
        n = self.vx.size
        kappa = np.zeros(n)
        if n >= 3:
            cross = dx[:-1] * dy[1:] - dy[:-1] * dx[1:]
            chord = np.hypot(self.vx[2:] - self.vx[:-2], self.vy[2:] - self.vy[:-2])
            kappa[1:-1] = 2.0 * cross / (seg[:-1] * seg[1:] * chord)
            kappa[0], kappa[-1] = kappa[1], kappa[-2]
        self.kappa = kappa

    def _at(self, i: int, t: float, px: float | None = None, py: float | None = None
            ) -> PathProjection:
        """Point on segment i (extended) at distance t [m] from its start vertex."""
        i = int(i)
        h = float(self.headings[i])
        ch, sh = math.cos(h), math.sin(h)
        x, y = self.vx[i] + t * ch, self.vy[i] + t * sh
        s = float(self.sv[i]) + t
        u = min(max(t, 0.0), float(self.seg[i]))
        rate = (self.kappa[i + 1] - self.kappa[i]) / self.seg[i]
        if t != u:
            rate = 0.0
        c = float(self.kappa[i] + rate * u)
        offset = 0.0
        if px is not None:
            py = cast(float, py)  # given with px
            normal = -(px - x) * sh + (py - y) * ch
            offset = math.copysign(math.hypot(px - x, py - y), normal)
        return PathProjection(s, float(x), float(y), h, c, float(rate), offset)

    def point(self, s: float) -> PathProjection:
        s = float(s)
        i = int(np.clip(np.searchsorted(self.sv, s, side="right") - 1, 0, self.seg.size - 1))
        return self._at(i, s - float(self.sv[i]))

    def project(self, x: float, y: float, s_hint: float | None = None) -> PathProjection:
        px, py = float(x), float(y)
        idx = np.arange(self.seg.size)
        if s_hint is not None:
            hint = self.point(s_hint)
            w = 2.0 * math.hypot(px - hint.x, py - hint.y) + float(self.seg.max())
            keep = (self.sv[1:] >= s_hint - w) & (self.sv[:-1] <= s_hint + w)
            if keep.any():
                idx = idx[keep]
        ux, uy = self.dx[idx] / self.seg[idx], self.dy[idx] / self.seg[idx]
        t = (px - self.vx[idx]) * ux + (py - self.vy[idx]) * uy
        lo = np.where(idx == 0, -np.inf, 0.0)
        hi = np.where(idx == self.seg.size - 1, np.inf, self.seg[idx])
        t = np.clip(t, lo, hi)
        d2 = (self.vx[idx] + t * ux - px) ** 2 + (self.vy[idx] + t * uy - py) ** 2
        j = int(np.argmin(d2))
        return self._at(idx[j], float(t[j]), px, py)


def load_waypoints(file: str | os.PathLike[str], base_dir: str | os.PathLike[str] | None = None
                   ) -> WaypointPath:
    """Read a CSV with header ``x,y`` into a :class:`WaypointPath`."""
    path = Path(file)
    if base_dir is not None and not path.is_absolute():
        path = Path(base_dir) / path
    try:
        with open(path, newline="") as handle:
            rows = list(csv.reader(handle))
    except OSError as error:
        raise ParameterError("path", f"waypoint file '{path}' cannot be read: "
                                     f"{error.strerror or error}") from None
    rows = [r for r in rows if any(cell.strip() for cell in r)]
    if not rows or [c.strip().lower() for c in rows[0]] != ["x", "y"]:
        raise ParameterError("path", f"waypoint file '{path}' must start with the header x,y")
    xs, ys = [], []
    for number, row in enumerate(rows[1:], start=2):
        try:
            if len(row) != 2:
                raise ValueError
            xs.append(float(row[0]))
            ys.append(float(row[1]))
        except ValueError:
            raise ParameterError("path", f"waypoint file '{path}' line {number}: expected two "
                                         f"numbers, got {','.join(row)!r}") from None
    return WaypointPath(xs, ys)


# ---------------------------------------------------------------------- parsing
#: kind -> (required keys, optional keys with defaults)
_KINDS: dict[str, tuple[tuple[str, ...], dict[str, Any]]] = {
    "line": ((), {"x0": 0.0, "y0": 0.0, "heading": 0.0, "step_at": None, "step": None}),
    "circle": (("radius",), {"cx": None, "cy": None, "direction": "ccw", "heading": 0.0}),
    "sine": (("amplitude", "wavelength"), {"x0": 0.0, "y0": 0.0}),
    "scurve": (("straight", "amplitude", "wavelength"), {}),
    "waypoints": (("file",), {}),
}
_TEXT_KEYS = {"direction", "file"}
#: kind -> the keys whose value names a file, read relative to ``base_dir``
FILE_KEYS = {"waypoints": ("file",)}


def _file_items(spec: object) -> tuple[str, list[str], tuple[str, ...]] | None:
    """``(head, items, keys)`` of a path string naming files: the text before its ``:``,
    its ``key=value`` items as written, the keys of its kind that name a file; None for
    any other value. Nothing is read."""
    if not isinstance(spec, str):
        return None
    head, colon, body = spec.strip().partition(":")
    keys = FILE_KEYS.get(head.strip().lower())
    if not colon or not keys:
        return None
    return head, body.split(","), keys


def path_files(spec: object) -> list[str]:
    """The file names the path string ``spec`` names (a ``waypoints`` file), as written,
    in order; empty for a path string of another kind or any other value. Nothing is
    read: :func:`parse_path` reads them (relative to its ``base_dir``)."""
    found = _file_items(spec)
    if found is None:
        return []
    names = []
    for item in found[1]:
        key, eq, text = item.partition("=")
        if eq and key.strip() in found[2] and text.strip():
            names.append(text.strip())
    return names


def rebase_path(spec: str, base_dir: str | os.PathLike[str]) -> str:
    """``spec`` with each relative file name it names (:func:`path_files`) joined to
    ``base_dir``, its other items as written: ``parse_path(rebase_path(spec, d))``
    reads the files ``parse_path(spec, d)`` reads, from any working folder. A value that
    names no file is returned as it is. Raises ParameterError("path", ...) when a joined
    name holds a ``,``, which a path string cannot carry."""
    found = _file_items(spec)
    if found is None:
        return spec
    head, items, keys = found
    out = []
    for item in items:
        key, eq, text = item.partition("=")
        if eq and key.strip() in keys and text.strip():
            name = str(Path(base_dir) / text.strip())
            if "," in name:
                raise ParameterError("path", f"file '{name}': a ',' in the folder's name "
                                             "cannot be written in a path string")
            item = f"{key.strip()}={name}"
        out.append(item)
    return f"{head}:{','.join(out)}"


def parse_items(spec: str, kind: str, body: str, required: Sequence[str],
                optional: Mapping[str, Any], text_keys: Collection[str] = _TEXT_KEYS
                ) -> dict[str, Any]:
    """The ``key=value,...`` ``body`` of the path string ``spec`` of ``kind``, as a dict.

    ``required`` names the keys that must be given, ``optional`` maps the others to their
    defaults (merged into the result); values are floats but for ``text_keys``. Raises
    ParameterError("path", ...) naming the culprit. Path kinds defined elsewhere (seed
    003's ``curve:``, axle_pd/track_path.py) parse with it too.
    """
    values: dict[str, Any] = {}
    for item in (body.split(",") if body.strip() else []):
        key, eq, text = item.partition("=")
        key, text = key.strip(), text.strip()
        if not eq or not key or not text:
            raise ParameterError("path", f"malformed item '{item.strip()}' in '{spec}'; "
                                         "expected key=value")
        if key not in required and key not in optional:
            raise ParameterError("path", f"unknown key '{key}' for {kind}; allowed: "
                                         f"{', '.join(tuple(required) + tuple(optional))}")
        if key in values:
            raise ParameterError("path", f"key '{key}' given twice in '{spec}'")
        if key in text_keys:
            values[key] = text
        else:
            try:
                values[key] = float(text)
            except ValueError:
                raise ParameterError("path", f"{kind} {key}: '{text}' is not a number") \
                    from None
            if not math.isfinite(values[key]):
                raise ParameterError("path", f"{kind} {key} must be finite, got {text}")
    missing = [k for k in required if k not in values]
    if missing:
        raise ParameterError("path", f"{kind} needs {', '.join(missing)}")
    return dict(optional, **values)


def parse_path(spec: str, base_dir: str | os.PathLike[str] | None = None) -> ReferencePath:
    """Build a :class:`ReferencePath` from ``kind:key=value,...`` (see module docstring).

    Parameters
    ----------
    spec : str
        Path string, numbers in SI units.
    base_dir : str or Path, optional
        Folder that relative waypoint files are relative to (default: working folder).

    Raises
    ------
    ParameterError
        Named ``path``, for any malformed string or invalid value.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise ParameterError("path", "empty path string; expected 'kind:key=value,...'")
    kind, _, body = spec.strip().partition(":")
    kind = kind.strip().lower()
    if kind not in _KINDS:
        raise ParameterError("path", f"unknown path kind '{kind}'; expected one of "
                                     f"{', '.join(_KINDS)}")
    required, optional = _KINDS[kind]
    args = parse_items(spec, kind, body, required, optional)
    if kind == "line":
        if (args["step"] is None) != (args["step_at"] is None):
            raise ParameterError("path", "line: step and step_at go together")
        return LinePath(args["x0"], args["y0"], args["heading"], args["step_at"],
                        args["step"] or 0.0)
    if kind == "circle":
        return CirclePath(args["radius"], args["cx"], args["cy"], args["direction"].lower(),
                          args["heading"])
    if kind == "sine":
        return sine_path(args["amplitude"], args["wavelength"], args["x0"], args["y0"])
    if kind == "scurve":
        return scurve_path(args["straight"], args["amplitude"], args["wavelength"])
    return load_waypoints(args["file"], base_dir)


def project_trajectory(path: ReferencePath, xs: Sequence[float] | NDArray[np.float64],
                       ys: Sequence[float] | NDArray[np.float64], s_hint: float | None = None
                       ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Project a trajectory onto ``path``, point by point, in order.

    Each point is projected with the previous point's arc length as the hint (the first
    with ``s_hint``), so a path that comes close to itself is followed continuously.

    Parameters
    ----------
    path : ReferencePath
    xs, ys : sequence of float
        Coordinates [m] of the trajectory's points.
    s_hint : float, optional
        Arc length [m] to start the search from (e.g. the last one of a previous chunk).

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        Signed offsets [m] (positive left of the path) and arc lengths [m] of the
        projections, one per point.
    """
    offsets = np.empty(len(xs))
    arcs = np.empty(len(xs))
    for i, (x, y) in enumerate(zip(xs, ys)):
        projection = path.project(float(x), float(y), s_hint)
        offsets[i] = projection.offset
        arcs[i] = s_hint = projection.s
    return offsets, arcs
