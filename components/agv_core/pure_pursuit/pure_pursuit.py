"""Pure-pursuit path tracking (Coulter 1992), with a speed-scheduled look-ahead.

Rear-axle centre R = (x, y), heading psi, speed v, wheelbase L. The goal point G is the
first path point ahead of R's projection whose distance from R is the look-ahead

    Ld = k_ld max(v, 0) + L_min.

The circular arc that leaves R tangent to the heading and passes through G has the
curvature (chord Ld, angle alpha between the heading and the chord RG)

    kappa = 2 sin(alpha) / Ld,

and the kinematic bicycle drives it with the wheel angle

    delta = atan(L kappa) = atan(2 L sin(alpha) / Ld).

Derivation and the closed forms (steady circle, straight-line error dynamics) in README.md.
When the path is farther than Ld from R (|lateral error| >= Ld) no path point lies at
Ld: the goal is then the closest path point and its distance d replaces Ld (the vehicle
turns towards the path). A path that comes no farther than Ld within 10 Ld of arc length
ahead (a circle of diameter < Ld) takes the farthest point found, again with its distance.
"""

import math
from pathlib import Path
from typing import Any

from scipy.optimize import brentq

from ..numerics.path_law import (
    PathLaw,
    heading_difference,
    non_negative,
    parse_path_parameter,
    positive,
)
from ..numerics.paths import PathProjection, ReferencePath

#: arc-length step of the forward search, as a fraction of Ld
SEARCH_STEP = 0.25
#: the forward search ends this many Ld of arc length ahead
SEARCH_SPAN = 10.0


def pursuit_angle(wheelbase: float, alpha: float, lookahead: float) -> float:
    """The pure-pursuit wheel angle atan(2 L sin(alpha) / Ld) [rad].

    Parameters
    ----------
    wheelbase : float
        L [m].
    alpha : float
        Angle from the heading to the chord towards the goal [rad], positive left.
    lookahead : float
        Chord length Ld [m] (> 0).
    """
    return math.atan(2.0 * wheelbase * math.sin(alpha) / lookahead)


def circle_steady_curvature(radius: float, lookahead: float, r: float) -> float:
    """Commanded curvature [1/m] of the chord law for a rear axle on the circle of radius
    ``r`` [m] concentric with a path circle of radius ``radius`` [m], heading along it
    (left turn), goal on the path at chord ``lookahead`` [m]:
    kappa = (Ld^2 + r^2 - R^2) / (r Ld^2) (README.md); 1/r only at r = R."""
    return (lookahead ** 2 + r ** 2 - radius ** 2) / (r * lookahead ** 2)


class PurePursuit(PathLaw):
    """Pure pursuit on the rear axle (see the module docstring).

    Parameters
    ----------
    path : agv_core.numerics.paths.ReferencePath
        Reference path.
    k_ld : float
        Look-ahead gain [s] (>= 0): Ld grows by k_ld per m/s.
    L_min : float
        Look-ahead at standstill [m] (> 0).
    wheelbase, delta_max, sample_period : float
        As for :class:`agv_core.numerics.path_law.PathLaw` ([m], [rad], [s]).
    """

    def __init__(self, path: ReferencePath, k_ld: float = 0.1, L_min: float = 2.0,
                 wheelbase: float = 1.0, delta_max: float = math.pi / 4,
                 sample_period: float = 0.0) -> None:
        super().__init__(path, wheelbase, delta_max, sample_period)
        self.k_ld = non_negative("k_ld", k_ld, "s")
        self.L_min = positive("L_min", L_min, "m")

    def lookahead(self, v: float) -> float:
        """Ld [m] at speed ``v`` [m/s] (reversing counts as standstill)."""
        return self.k_ld * max(v, 0.0) + self.L_min

    def goal(self, p: PathProjection, x: float, y: float, v: float
             ) -> tuple[tuple[float, float], float, float, float, bool]:
        """The goal point of the rear axle (x, y) [m] at speed ``v`` [m/s], whose projection
        on the path is ``p``: ((gx, gy) [m], its arc length [m], its distance d [m], Ld [m],
        on_chord), ``on_chord`` true when d = Ld."""
        ld = self.lookahead(v)
        if abs(p.offset) >= ld:
            return (p.x, p.y), p.s, abs(p.offset), ld, False

        def excess(s: float) -> float:
            q = self.path.point(s)
            return math.hypot(q.x - x, q.y - y) - ld

        step = SEARCH_STEP * ld
        a, fa = p.s, abs(p.offset) - ld
        far = (fa, a)
        for _ in range(int(SEARCH_SPAN / SEARCH_STEP)):
            b = a + step
            fb = excess(b)
            if fb >= 0.0:
                s = b if fb == 0.0 else brentq(excess, a, b, xtol=1e-12, rtol=4 * 2.3e-16)
                q = self.path.point(s)
                return (q.x, q.y), s, ld, ld, True
            far = max(far, (fb, b))
            a, fa = b, fb
        q = self.path.point(far[1])
        return (q.x, q.y), far[1], far[0] + ld, ld, False

    def law(self, x: float, y: float, heading: float, v: float) -> dict[str, Any]:
        rear = self.project("rear", x, y)
        (gx, gy), s_goal, d, ld, on_chord = self.goal(rear, x, y, v)
        alpha = heading_difference(math.atan2(gy - y, gx - x), heading)
        delta_law = pursuit_angle(self.wheelbase, alpha, d) if d > 0.0 else 0.0
        return {"delta_law": delta_law, "lateral_error": float(rear.offset),
                "heading_error": heading_difference(heading, rear.heading),
                "alpha": alpha, "lookahead": ld, "goal_distance": d, "goal_x": gx,
                "goal_y": gy, "goal_s": s_goal, "on_chord": on_chord}


def make_controller(path: str = "line", k_ld: float = 0.1, L_min: float = 2.0,
                    wheelbase: float = 1.0, delta_max: float = math.pi / 4,
                    sample_period: float = 0.0, base_dir: str | Path | None = None
                    ) -> PurePursuit:
    """A :class:`PurePursuit` from FMU-style parameters (``path`` a path string).

    Raises
    ------
    ParameterError
        For a bad path, gain, length, angle or period.
    """
    return PurePursuit(parse_path_parameter(path, base_dir), k_ld, L_min, wheelbase,
                       delta_max, sample_period)
