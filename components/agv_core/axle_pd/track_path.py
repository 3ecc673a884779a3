"""A straight - (clothoid) - arc - (clothoid) - straight reference path, and the
lateral errors of several tracking points from any reference path (seed 003).

``curve:straight=S,radius=R,angle=A,transition=T,direction=ccw,x0=0,y0=0,heading=0``
    From (x0, y0) along ``heading`` [rad]: a straight of length S [m] (also extended
    backwards, s < 0), a clothoid of length T [m] whose curvature grows linearly from 0 to
    1/R, a circular arc of radius R [m], a clothoid of length T back to 0, and a straight
    to infinity. The total heading change is A [rad] (so the arc is R A - T long; needs
    R A >= T). ``direction`` ccw turns left (curvature +1/R), cw right. T = 0 (default):
    no transition, the curvature steps from 0 to 1/R (a heading-continuous corner of
    curvature).

Heading is quadratic in s on the clothoids; positions there are the exact integral of
(cos, sin)(heading) by 24-point Gauss-Legendre quadrature (for heading changes up to
1 rad per clothoid, the quadrature error is below 1e-13 m; checked against
scipy.special.fresnel in the tests). Lines and the arc are closed form.

Projection: Newton on g(s) = (P(s) - q) . t(s) = 0 from the hint (g' = 1 - offset c(s)),
to |ds| < 1e-12 m; without a hint (or when Newton leaves the well-posed region
offset * c < 1, or does not converge) the closest candidate over every piece (line
projections, samples every 0.25 m then Newton) is taken.

Other kinds (``line``, ``circle``, ``sine``, ``scurve``, ``waypoints``) are passed to
:func:`agv_core.numerics.paths.parse_path`.
"""

import math
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any, cast

import numpy as np

from ..errors import ParameterError
from ..numerics.paths import PathProjection, ReferencePath, parse_items, parse_path

_GL_X, _GL_W = (tuple(float(v) for v in a) for a in np.polynomial.legendre.leggauss(24))


class CurvePath(ReferencePath):
    """Straight, clothoid, arc, clothoid, straight (see the module docstring)."""

    def __init__(self, straight: float, radius: float, angle: float, transition: float = 0.0,
                 direction: str = "ccw", x0: float = 0.0, y0: float = 0.0,
                 heading: float = 0.0) -> None:
        if not (math.isfinite(straight) and straight >= 0.0):
            raise ParameterError("path", f"curve straight must be >= 0 m, got {straight}")
        if not (math.isfinite(radius) and radius > 0.0):
            raise ParameterError("path", f"curve radius must be positive, got {radius}")
        if not (math.isfinite(angle) and 0.0 < angle < 2.0 * math.pi):
            raise ParameterError("path", f"curve angle must be in (0, 2 pi) rad, got {angle}")
        if not (math.isfinite(transition) and transition >= 0.0):
            raise ParameterError("path", f"curve transition must be >= 0 m, got {transition}")
        if radius * angle < transition:
            raise ParameterError("path", f"curve: radius * angle = {radius * angle} m is "
                                         f"shorter than the transition {transition} m")
        if direction not in ("ccw", "cw"):
            raise ParameterError("path", f"curve direction must be ccw or cw, got "
                                         f"'{direction}'")
        self.radius = float(radius)
        self.sign = 1.0 if direction == "ccw" else -1.0
        self.kappa = self.sign / self.radius
        self.T = float(transition)
        self.angle = float(angle)
        arc = self.radius * self.angle - self.T
        # breakpoints in s: end of straight, end of clothoid in, end of arc, end of out
        self.s1 = float(straight)
        self.s2 = self.s1 + self.T
        self.s3 = self.s2 + arc
        self.s4 = self.s3 + self.T
        self.h0 = float(heading)
        # start pose of every piece
        self.p0 = (float(x0), float(y0))
        self.p1 = (self.p0[0] + self.s1 * math.cos(self.h0),
                   self.p0[1] + self.s1 * math.sin(self.h0))
        self.th1 = self.h0
        self.p2 = self._clothoid_pos(self.p1, self.th1, 0.0, self.kappa, self.T)
        self.th2 = self.h0 + 0.5 * self.kappa * self.T
        cx = self.p2[0] - math.sin(self.th2) / self.kappa
        cy = self.p2[1] + math.cos(self.th2) / self.kappa
        self.centre = (cx, cy)
        self.th3 = self.th2 + self.kappa * arc
        self.p3 = (cx + math.sin(self.th3) / self.kappa, cy - math.cos(self.th3) / self.kappa)
        self.p4 = self._clothoid_pos(self.p3, self.th3, self.kappa, -self.kappa, self.T)
        self.th4 = self.h0 + self.sign * self.angle

    @staticmethod
    def _clothoid_pos(p: tuple[float, float], th: float, k0: float, dk: float, length: float,
                      u: float | None = None) -> tuple[float, float]:
        """Position after ``u`` (default: all of ``length``) [m] along a clothoid from
        pose (p, th) whose curvature goes k0 -> k0 + dk over ``length``."""
        u = length if u is None else u
        if u == 0.0:
            return p
        rate = dk / length
        x, y = p
        half = 0.5 * u
        for xi, wi in zip(_GL_X, _GL_W):
            w = half * (xi + 1.0)
            a = th + k0 * w + 0.5 * rate * w * w
            x += half * wi * math.cos(a)
            y += half * wi * math.sin(a)
        return (x, y)

    def _pose(self, s: float) -> tuple[float, float, float, float, float]:
        """(x, y, heading, curvature, curvature_rate) at arc length s."""
        if s <= self.s1:
            return (self.p0[0] + s * math.cos(self.h0), self.p0[1] + s * math.sin(self.h0),
                    self.h0, 0.0, 0.0)
        if s < self.s2:
            u = s - self.s1
            rate = self.kappa / self.T
            x, y = self._clothoid_pos(self.p1, self.th1, 0.0, self.kappa, self.T, u)
            return x, y, self.th1 + 0.5 * rate * u * u, rate * u, rate
        if s <= self.s3:
            th = self.th2 + self.kappa * (s - self.s2)
            cx, cy = self.centre
            return (cx + math.sin(th) / self.kappa, cy - math.cos(th) / self.kappa, th,
                    self.kappa, 0.0)
        if s < self.s4:
            u = s - self.s3
            rate = -self.kappa / self.T
            x, y = self._clothoid_pos(self.p3, self.th3, self.kappa, -self.kappa, self.T, u)
            return x, y, self.th3 + self.kappa * u + 0.5 * rate * u * u, self.kappa + rate * u, \
                rate
        u = s - self.s4
        return (self.p4[0] + u * math.cos(self.th4), self.p4[1] + u * math.sin(self.th4),
                self.th4, 0.0, 0.0)

    def point(self, s: float) -> PathProjection:
        x, y, th, c, dc = self._pose(float(s))
        return PathProjection(float(s), x, y, th, c, dc, 0.0)

    def _at(self, s: float, qx: float, qy: float) -> PathProjection:
        x, y, th, c, dc = self._pose(s)
        off = -(qx - x) * math.sin(th) + (qy - y) * math.cos(th)
        return PathProjection(s, x, y, th, c, dc, off)

    def _newton(self, qx: float, qy: float, s: float) -> float | None:
        for _ in range(30):
            x, y, th, c, _ = self._pose(s)
            dx, dy = x - qx, y - qy
            g = dx * math.cos(th) + dy * math.sin(th)
            off = -(qx - x) * math.sin(th) + (qy - y) * math.cos(th)
            dg = 1.0 - off * c
            if dg <= 0.1:
                return None
            step = g / dg
            s -= step
            if abs(step) < 1e-12:
                return s
        return None

    def _global(self, qx: float, qy: float) -> float:
        best: tuple[float, float] | None = None
        candidates = []
        # straight before: closest point of the infinite line, clamped to s <= s1
        c0, s0 = math.cos(self.h0), math.sin(self.h0)
        candidates.append(min((qx - self.p0[0]) * c0 + (qy - self.p0[1]) * s0, self.s1))
        c4, s4 = math.cos(self.th4), math.sin(self.th4)
        candidates.append(self.s4 + max((qx - self.p4[0]) * c4 + (qy - self.p4[1]) * s4, 0.0))
        n = max(int(math.ceil((self.s4 - self.s1) / 0.25)), 1)
        samples = [self.s1 + (self.s4 - self.s1) * k / n for k in range(n + 1)]
        d2 = [(p.x - qx) ** 2 + (p.y - qy) ** 2 for p in map(self.point, samples)]
        k = min(range(len(samples)), key=d2.__getitem__)
        refined = self._newton(qx, qy, samples[k])
        candidates.append(samples[k] if refined is None else refined)
        for s in candidates:
            p = self.point(s)
            dist = (p.x - qx) ** 2 + (p.y - qy) ** 2
            if best is None or dist < best[0]:
                best = (dist, s)
        return cast(tuple[float, float], best)[1]  # three candidates: never None

    def project(self, x: float, y: float, s_hint: float | None = None) -> PathProjection:
        qx, qy = float(x), float(y)
        s: float | None = None
        if s_hint is not None:
            s = self._newton(qx, qy, float(s_hint))
        if s is None:
            s = self._global(qx, qy)
        return self._at(s, qx, qy)


_CURVE_REQUIRED = ("straight", "radius", "angle")
_CURVE_OPTIONAL = {"transition": 0.0, "direction": "ccw", "x0": 0.0, "y0": 0.0, "heading": 0.0}


def parse_track_path(spec: str, base_dir: str | Path | None = None) -> ReferencePath:
    """``curve:...`` (this module) or any kind of :func:`agv_core.numerics.paths.parse_path`.

    Raises ParameterError("path", ...) for a malformed string.
    """
    if not isinstance(spec, str) or spec.strip().partition(":")[0].strip().lower() != "curve":
        return parse_path(spec, base_dir)
    body = spec.strip().partition(":")[2]
    args = parse_items(spec, "curve", body, _CURVE_REQUIRED, _CURVE_OPTIONAL,
                       text_keys=("direction",))
    return CurvePath(args["straight"], args["radius"], args["angle"], args["transition"],
                     args["direction"].lower(), args["x0"], args["y0"], args["heading"])


class PointErrors:
    """Signed lateral errors of n tracking points from one path (noise-free probe).

    Each point keeps its previous arc length as the projection hint (local, unambiguous).

    Parameters
    ----------
    path : ReferencePath
    n : int
        Number of points.
    """

    def __init__(self, path: ReferencePath, n: int = 4) -> None:
        self.path = path
        self.hints: list[float | None] = [None] * int(n)
        self.last: Sequence[PathProjection | None] = [None] * int(n)

    def measure(self, points: Iterable[tuple[float, float]], commit: bool = False
                ) -> list[PathProjection]:
        """Projections of ``points`` [(x, y), ...] [m]; ``commit`` stores the hints."""
        out = [self.path.project(x, y, h) for (x, y), h in zip(points, self.hints)]
        if commit:
            self.hints = [p.s for p in out]
        self.last = out
        return out

    def get_state(self) -> dict[str, Any]:
        return {"hints": list(self.hints)}

    def set_state(self, state: dict[str, Any]) -> None:
        self.hints = [None if h is None else float(h) for h in state["hints"]]
