"""Kinematic single-track vehicle (seed 000 eqs 1-3, seed 004 eq 2).

Frames and signs (see components/README.md): world frame x east, y north, z up;
heading ``beta`` [rad] from the world x axis, counter-clockwise positive; steered-wheel
angle ``alpha`` [rad], positive turns left (counter-clockwise); speed ``v`` [m/s] is the
speed of the rear-axle centre (seed 000's V0), positive forward.

Nonlinear model (no tyre slip), rear-axle centre R and front-wheel centre F = R + L e(beta):

    dx_R/dt = v cos(beta),  dy_R/dt = v sin(beta),  dbeta/dt = (v / L) tan(alpha)

which is seed 000 eqs (1)-(3) written at F (there V = V0 / cos(alpha) along alpha + beta)
and seed 004 eq (2) at R. With ``alpha`` and ``v`` held over a step (zero-order hold, as a
co-simulation master delivers them) the solution is an exact circular arc, used here:

    x(t+h) = x + v h cos(beta + w h / 2) sinc(w h / 2),  w = v tan(alpha) / L
    y(t+h) = y + v h sin(beta + w h / 2) sinc(w h / 2),  sinc(u) = sin(u) / u

Linear model (seed 000 model b): the small-angle version at the reference point P,
dx_P/dt = v, dbeta/dt = (v / L) alpha, dy_P/dt = v (alpha + beta) at F or v beta at R,
also integrated exactly (a quadratic in t for held inputs). The other point follows from
the small-angle geometry (x_F = x_R + L, y_F = y_R + L beta).
"""

import math
from typing import Any

from ..errors import ParameterError
from ..numerics.arc import sinc as _sinc  # the exact arc (numerics/arc.py)

REFERENCE_POINTS = ("front", "rear")


class Vehicle:
    """Kinematic single-track vehicle integrated exactly for held inputs.

    Parameters
    ----------
    wheelbase : float
        L [m], rear-axle centre to front-wheel centre, > 0.
    x0, y0 : float
        Initial position of the reference point [m].
    heading0 : float
        Initial heading beta [rad].
    reference_point : {"front", "rear"}
        Point whose pose is reported as ``x, y`` and used as initial position.
    linear : bool
        Use the small-angle linear kinematics of seed 000 model b/c.
    """

    def __init__(self, wheelbase: float, x0: float = 0.0, y0: float = 0.0,
                 heading0: float = 0.0, reference_point: str = "front",
                 linear: bool = False) -> None:
        if not (wheelbase > 0.0 and math.isfinite(wheelbase)):
            raise ParameterError("wheelbase", f"must be a positive length in m, got {wheelbase}")
        if reference_point not in REFERENCE_POINTS:
            raise ParameterError("reference_point",
                                 f"must be one of {REFERENCE_POINTS}, got '{reference_point}'")
        for name, value in (("x0", x0), ("y0", y0), ("heading0", heading0)):
            if not math.isfinite(value):
                raise ParameterError(name, f"must be finite, got {value}")
        self.wheelbase = float(wheelbase)
        self.reference_point = reference_point
        self.linear = bool(linear)
        self.heading = float(heading0)
        self.distance = 0.0
        # state: position of the reference point
        self.x = float(x0)
        self.y = float(y0)
        self._trig = (math.nan, math.nan, math.nan)  # (heading, cos, sin) last computed

    def _cos_sin(self) -> tuple[float, float]:
        """(cos, sin) of the heading, computed once per heading value."""
        heading, c, s = self._trig
        if heading != self.heading:           # also true for a first (NaN) entry
            heading = self.heading
            c, s = math.cos(heading), math.sin(heading)
            self._trig = (heading, c, s)
        return c, s

    # ------------------------------------------------------------------ geometry
    def rear(self) -> tuple[float, float]:
        """Position of the rear-axle centre (x, y) [m]."""
        if self.reference_point == "rear":
            return self.x, self.y
        if self.linear:
            return self.x - self.wheelbase, self.y - self.wheelbase * self.heading
        c, s = self._cos_sin()
        return self.x - self.wheelbase * c, self.y - self.wheelbase * s

    def front(self) -> tuple[float, float]:
        """Position of the front-wheel centre (x, y) [m]."""
        if self.reference_point == "front":
            return self.x, self.y
        if self.linear:
            return self.x + self.wheelbase, self.y + self.wheelbase * self.heading
        c, s = self._cos_sin()
        return self.x + self.wheelbase * c, self.y + self.wheelbase * s

    def yaw_rate(self, alpha: float, v: float) -> float:
        """dbeta/dt [rad/s] for steering angle ``alpha`` [rad] and speed ``v`` [m/s]."""
        if self.linear:
            return v * alpha / self.wheelbase
        return v * math.tan(alpha) / self.wheelbase

    # ------------------------------------------------------------------ dynamics
    def step(self, alpha: float, v: float, h: float) -> None:
        """Advance by ``h`` [s] with ``alpha`` [rad] and ``v`` [m/s] held (exact)."""
        if not (abs(alpha) < math.pi / 2):
            raise FloatingPointError(f"steering angle alpha={alpha} rad is not within +/-pi/2")
        beta = self.heading
        w = self.yaw_rate(alpha, v)
        if self.linear:
            lateral = alpha if self.reference_point == "front" else 0.0
            self.x += v * h
            self.y += v * (lateral + beta) * h + 0.5 * v * w * h * h
            self.heading = beta + w * h
        else:
            half = 0.5 * w * h
            xr, yr = self.rear()
            chord = v * h * _sinc(half)
            xr += chord * math.cos(beta + half)
            yr += chord * math.sin(beta + half)
            self.heading = beta + w * h
            if self.reference_point == "rear":
                self.x, self.y = xr, yr
            else:
                c, s = self._cos_sin()
                self.x = xr + self.wheelbase * c
                self.y = yr + self.wheelbase * s
        self.distance += abs(v) * h

    # ------------------------------------------------------------------ state
    def get_state(self) -> dict[str, Any]:
        """JSON-safe snapshot of the state."""
        return {"x": self.x, "y": self.y, "heading": self.heading, "distance": self.distance}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a snapshot from :meth:`get_state`."""
        self.x = state["x"]
        self.y = state["y"]
        self.heading = state["heading"]
        self.distance = state["distance"]
