"""Planar kinematics of seed 003's three-car articulated train (head car, floating middle
car, tail car; four steered axles).

Topology (seed 003 section 1): two powered end cars with two steered axles each, and a
floating middle car with no running gear, hinged to both (a two-force bar). Frames and
signs as in components/README.md: world x east, y north; headings psi counter-clockwise
from +x, continuous; axle angles delta_i positive left; lateral positions positive left.

Geometry (all cars rigid, every axle centre rolls without side slip):

* head car: reference point its hinge J1; axle 1 at a1 = L1 + L2 and axle 2 at a2 = L2
  ahead of J1 on its centre line (L1 = axle spacing, L2 = rear axle to hinge);
* floating car: the bar J1 -> J2 of length Lm; J2 = J1 - Lm (cos psi2, sin psi2);
* tail car: the mirror image, reference point its hinge J2; axle 3 at a3 = -L2 and axle 4
  at a4 = -(L1 + L2) (behind J2).

Car c moves with longitudinal speed u_c (its body-frame x velocity, common to all its
points) and yaw rate omega_c. A point at body position (a, 0) has lateral body velocity
vy_ref + omega_c a; no side slip at axle i means vy_ref + omega_c a_i = u_c tan(delta_i).
Two axles per car give

    head:  omega1 = u1 (tan d1 - tan d2) / L1,    vy_J1 = u1 tan d2 - omega1 L2
    tail:  omega3 = u3 (tan d3 - tan d4) / L1,    vy_J2 = u3 tan d3 + omega3 L2 = u3 g3

The input speed v is u1. The tail car's speed u3 and the bar's rate follow from the
hinge J2 being both the bar's end and the tail car's reference point:

    u3 w + Lm psi2' n2 = v_J1,   w = Rot(psi3) [1, g3],   n2 = (-sin psi2, cos psi2)

(dot with e2 = (cos psi2, sin psi2) gives u3, dot with n2 gives psi2'; singular only at a
jack-knife, w . e2 = 0, which is reported as an error).

Integration for inputs held over a step of length h:

* the head car is exact: J1 moves on a circular arc (constant body-frame velocity, constant
  omega1): J1(h) = J1 + h Rot(psi1 + omega1 h / 2) [u1, vy_J1] sinc(omega1 h / 2);
* (psi2, psi3) solve the ODE above with v_J1(t) known in closed form; classical RK4 with
  step doubling: the step is split into 2^k equal sub-steps until the Richardson estimate
  |y_(h/2^(k+1)) - y_(h/2^k)| / 15 of the local error of the returned (finer) solution is
  below ``tolerance`` [rad] for both angles;
* J2, the tail car and the axle points are algebraic in (J1, psi1, psi2, psi3).

So the floating car's constraints |J1 - J2| = Lm and "J2 is the tail car's hinge" hold by
construction (to rounding); the only integration error is in psi2, psi3, bounded per step
by ``tolerance`` (the test checks the sum over a run against scipy's DOP853).
"""

import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Self

from ..ackermann.ackermann import wheel_angles
from ..errors import ParameterError
from ..numerics.arc import sinc as _sinc

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

AXLES = 4


def _positive(name: str, value: float) -> float:
    if not (math.isfinite(value) and value > 0.0):
        raise ParameterError(name, f"must be a positive length in m, got {value}")
    return float(value)


class TrainGeometry:
    """Dimensions of the train [m] (see the module docstring).

    Parameters
    ----------
    L1 : float
        Axle spacing of each powered car (seed 003's head-car wheelbase), > 0.
    L2 : float
        Inner axle to hinge (seed 003: rear axle to hinge), > 0.
    d : float
        Track width, >= 0.
    Lm : float
        Hinge-to-hinge length of the floating car, > 0.
    """

    def __init__(self, L1: float = 5.0, L2: float = 3.0, d: float = 2.1, Lm: float = 9.0
                 ) -> None:
        self.L1 = _positive("L1", L1)
        self.L2 = _positive("L2", L2)
        if not (math.isfinite(d) and d >= 0.0):
            raise ParameterError("d", f"must be a track width >= 0 in m, got {d}")
        self.d = float(d)
        self.Lm = _positive("Lm", Lm)
        #: body position of each axle from its car's hinge (= distance to the baseline)
        self.axle_offsets = (self.L1 + self.L2, self.L2, -self.L2, -(self.L1 + self.L2))

    def length(self) -> float:
        """Front axle to rear axle along a straight train [m]."""
        return 2.0 * (self.L1 + self.L2) + self.Lm


class Train:
    """Three-car train state and exact/error-bounded integration for held inputs.

    Parameters
    ----------
    geometry : TrainGeometry
    x1, y1 : float
        Hinge J1 [m].
    psi1, psi2, psi3 : float
        Headings [rad] of the head car, of the bar J2 -> J1 (floating car) and of the tail
        car.
    tolerance : float
        Bound on the Richardson estimate of the local error of psi2, psi3 per step [rad].
    """

    def __init__(self, geometry: TrainGeometry, x1: float = 0.0, y1: float = 0.0,
                 psi1: float = 0.0, psi2: float = 0.0, psi3: float = 0.0,
                 tolerance: float = 1e-12) -> None:
        if not (math.isfinite(tolerance) and tolerance > 0.0):
            raise ParameterError("tolerance", f"must be positive, got {tolerance}")
        for name, value in (("x1", x1), ("y1", y1), ("psi1", psi1), ("psi2", psi2),
                            ("psi3", psi3)):
            if not math.isfinite(value):
                raise ParameterError(name, f"must be finite, got {value}")
        self.g = geometry
        self.tolerance = float(tolerance)
        self.x1, self.y1 = float(x1), float(y1)
        self.psi1, self.psi2, self.psi3 = float(psi1), float(psi2), float(psi3)
        self.distance = 0.0
        self.u1 = 0.0
        self.deltas: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)
        self.wheels: tuple[tuple[float, ...], ...] | None = None
        self.substeps = 1

    @classmethod
    def straight(cls, geometry: TrainGeometry, x_front: float = 0.0, y_front: float = 0.0,
                 heading: float = 0.0, tolerance: float = 1e-12) -> Self:
        """A straight train along ``heading`` [rad] with axle 1's centre at (x_front,
        y_front) [m]."""
        a1 = geometry.axle_offsets[0]
        return cls(geometry, x_front - a1 * math.cos(heading), y_front - a1 * math.sin(heading),
                   heading, heading, heading, tolerance)

    # ------------------------------------------------------------------ kinematics
    def head_rates(self, u1: float, deltas: Sequence[float]) -> tuple[float, float]:
        """(omega1 [rad/s], vy_J1 [m/s]) of the head car."""
        t1, t2 = math.tan(deltas[0]), math.tan(deltas[1])
        omega = u1 * (t1 - t2) / self.g.L1
        return omega, u1 * t2 - omega * self.g.L2

    def tail_factors(self, deltas: Sequence[float]) -> tuple[float, float]:
        """(g3, k3): vy_J2 = u3 g3 and omega3 = u3 k3 for the tail car."""
        t3, t4 = math.tan(deltas[2]), math.tan(deltas[3])
        k3 = (t3 - t4) / self.g.L1
        return t3 + k3 * self.g.L2, k3

    def link_rates(self, vx: float, vy: float, psi2: float, psi3: float, g3: float, k3: float
                   ) -> tuple[float, float, float]:
        """(u3 [m/s], psi2' [rad/s], psi3' [rad/s]) for J1 velocity (vx, vy) [m/s]."""
        c2, s2 = math.cos(psi2), math.sin(psi2)
        c3, s3 = math.cos(psi3), math.sin(psi3)
        wx, wy = c3 - g3 * s3, s3 + g3 * c3
        we = wx * c2 + wy * s2
        if abs(we) < 1e-12:
            raise FloatingPointError("jack-knife: the tail car's hinge velocity is "
                                     "perpendicular to the floating car")
        u3 = (vx * c2 + vy * s2) / we
        rate2 = ((-vx * s2 + vy * c2) - u3 * (-wx * s2 + wy * c2)) / self.g.Lm
        return u3, rate2, u3 * k3

    def _rhs(self, t: float, psi2: float, psi3: float, u1: float, vyj: float, omega1: float,
             g3: float, k3: float) -> tuple[float, float]:
        p = self.psi1 + omega1 * t
        c, s = math.cos(p), math.sin(p)
        _, r2, r3 = self.link_rates(u1 * c - vyj * s, u1 * s + vyj * c, psi2, psi3, g3, k3)
        return r2, r3

    def _rk4(self, h: float, n: int, args: tuple[float, float, float, float, float]
             ) -> tuple[float, float]:
        p2, p3 = self.psi2, self.psi3
        dt = h / n
        f = self._rhs
        for k in range(n):
            t = k * dt
            a2, a3 = f(t, p2, p3, *args)
            b2, b3 = f(t + 0.5 * dt, p2 + 0.5 * dt * a2, p3 + 0.5 * dt * a3, *args)
            c2, c3 = f(t + 0.5 * dt, p2 + 0.5 * dt * b2, p3 + 0.5 * dt * b3, *args)
            d2, d3 = f(t + dt, p2 + dt * c2, p3 + dt * c3, *args)
            p2 += dt * (a2 + 2.0 * b2 + 2.0 * c2 + d2) / 6.0
            p3 += dt * (a3 + 2.0 * b3 + 2.0 * c3 + d3) / 6.0
        return p2, p3

    def step(self, u1: float, deltas: Sequence[float], h: float,
             wheels: Sequence[Sequence[float]] | None = None) -> None:
        """Advance by ``h`` [s] with speed ``u1`` [m/s] and axle angles ``deltas`` [rad]
        held. ``wheels`` (optional, 4 pairs of left/right angles [rad]) is recorded for
        the slip diagnostics only: the kinematics use the axle-equivalent ``deltas``."""
        deltas = tuple(float(d) for d in deltas)
        u1 = float(u1)
        self.u1, self.deltas = u1, deltas
        self.wheels = None if wheels is None else tuple(tuple(map(float, w)) for w in wheels)
        if h <= 0.0:
            return
        omega1, vyj = self.head_rates(u1, deltas)
        g3, k3 = self.tail_factors(deltas)
        args = (u1, vyj, omega1, g3, k3)
        n = 1
        coarse = self._rk4(h, n, args)
        while True:
            fine = self._rk4(h, 2 * n, args)
            err = max(abs(fine[0] - coarse[0]), abs(fine[1] - coarse[1])) / 15.0
            if err <= self.tolerance:
                break
            if n >= 1 << 16:
                raise FloatingPointError(f"RK4 step doubling did not reach tolerance "
                                         f"{self.tolerance} rad within 65536 sub-steps")
            n, coarse = 2 * n, fine
        self.substeps = 2 * n
        half = 0.5 * omega1 * h
        p = self.psi1 + half
        scale = h * _sinc(half)
        c, s = math.cos(p), math.sin(p)
        self.x1 += scale * (u1 * c - vyj * s)
        self.y1 += scale * (u1 * s + vyj * c)
        self.psi1 += omega1 * h
        self.psi2, self.psi3 = fine
        self.distance += abs(u1) * h

    # ------------------------------------------------------------------ outputs
    def hinge2(self) -> tuple[float, float]:
        """Hinge J2 [m]."""
        return (self.x1 - self.g.Lm * math.cos(self.psi2),
                self.y1 - self.g.Lm * math.sin(self.psi2))

    def axle_points(self) -> tuple[tuple[float, float], ...]:
        """Centres of axles 1-4 [m], the tracking points: ((x1, y1), ..., (x4, y4))."""
        x2, y2 = self.hinge2()
        a = self.g.axle_offsets
        c1, s1 = math.cos(self.psi1), math.sin(self.psi1)
        c3, s3 = math.cos(self.psi3), math.sin(self.psi3)
        return ((self.x1 + a[0] * c1, self.y1 + a[0] * s1),
                (self.x1 + a[1] * c1, self.y1 + a[1] * s1),
                (x2 + a[2] * c3, y2 + a[2] * s3),
                (x2 + a[3] * c3, y2 + a[3] * s3))

    def car_rates(self, u1: float | None = None, deltas: Sequence[float] | None = None
                  ) -> tuple[float, float, float, float]:
        """(u3 [m/s], omega1, psi2', omega3 [rad/s]) at the current pose, for the last
        applied inputs unless given."""
        u1 = self.u1 if u1 is None else u1
        deltas = self.deltas if deltas is None else deltas
        omega1, vyj = self.head_rates(u1, deltas)
        g3, k3 = self.tail_factors(deltas)
        c, s = math.cos(self.psi1), math.sin(self.psi1)
        u3, r2, r3 = self.link_rates(u1 * c - vyj * s, u1 * s + vyj * c, self.psi2,
                                     self.psi3, g3, k3)
        return u3, omega1, r2, r3

    def wheel_states(self) -> list[tuple[float, float]]:
        """Per wheel (axle 1 left, 1 right, ..., 4 right): (speed [m/s], slip [rad]).

        Wheel w of axle i sits at body (a_i, +-d/2); its velocity is
        (u - omega (+-d/2), u tan(delta_i)) in its car's frame. Its angle is the recorded
        wheel input, else the Ackermann angle about the car's hinge baseline
        (agv_core.ackermann). Slip = direction of the wheel's velocity minus the wheel's
        angle (forward-motion convention), 0 at standstill.
        """
        u3, omega1, _, omega3 = self.car_rates()
        out = []
        half = 0.5 * self.g.d
        for i in range(AXLES):
            u, omega = (self.u1, omega1) if i < 2 else (u3, omega3)
            delta = self.deltas[i]
            if self.wheels is not None:
                pair = self.wheels[i]
            else:
                pair = wheel_angles(delta, self.g.axle_offsets[i], self.g.d)
            vy = u * math.tan(delta)
            for w, angle in ((half, pair[0]), (-half, pair[1])):
                vx = u - omega * w
                speed = math.hypot(vx, vy)
                if speed == 0.0:
                    out.append((0.0, 0.0))
                    continue
                sign = 1.0 if vx >= 0.0 else -1.0
                out.append((speed, math.atan2(sign * vy, sign * vx) - angle))
        return out

    # ------------------------------------------------------------------ state
    def get_state(self) -> dict[str, Any]:
        return {"x1": self.x1, "y1": self.y1, "psi": [self.psi1, self.psi2, self.psi3],
                "distance": self.distance, "u1": self.u1, "deltas": list(self.deltas),
                "wheels": None if self.wheels is None else [list(w) for w in self.wheels],
                "substeps": self.substeps}

    def set_state(self, state: dict[str, Any]) -> None:
        self.x1, self.y1 = float(state["x1"]), float(state["y1"])
        self.psi1, self.psi2, self.psi3 = (float(p) for p in state["psi"])
        self.distance = float(state["distance"])
        self.u1 = float(state["u1"])
        self.deltas = tuple(float(d) for d in state["deltas"])
        w = state["wheels"]
        self.wheels = None if w is None else tuple(tuple(p) for p in w)
        self.substeps = int(state["substeps"])


def steady_axle_angles(geometry: TrainGeometry, radius: float
                       ) -> tuple[float, float, float, float]:
    """Closed-form axle angles [rad] that keep all four axle centres on a circle of
    ``radius`` [m] (positive: left turn) in steady state.

    Both axles of a car on one circle put the car's instantaneous centre on the
    perpendicular bisector of its axles, so tan(delta) = (a_i - cx) / cy gives
    +-asin(L1 / 2R): (front, rear) of the head car = (+s, -s), of the tail car (+s, -s).
    """
    s = math.asin(geometry.L1 / (2.0 * radius))
    return (s, -s, s, -s)


def steady_pose(geometry: TrainGeometry, radius: float, phi: float = 0.0
                ) -> tuple[float, float, float, float, float]:
    """The train on a circle centred at the origin (ccw for radius > 0): every axle centre
    at |radius|, J1 at polar angle ``phi`` [rad]. Returns (x1, y1, psi1, psi2, psi3)."""
    R = abs(radius)
    sgn = 1.0 if radius > 0 else -1.0
    L1, L2, Lm = geometry.L1, geometry.L2, geometry.Lm
    cy = math.sqrt(R * R - 0.25 * L1 * L1)      # |lateral body offset of the centre|
    cx = L2 + 0.5 * L1                          # body x of the centre, head car
    rj = math.hypot(cx, cy)                     # radius of both hinges
    x1, y1 = rj * math.cos(phi), rj * math.sin(phi)
    # head car: the centre sits at body (cx, sgn cy): world(C - J1) = Rot(psi1)(cx, sgn cy)
    psi1 = math.atan2(-y1, -x1) - math.atan2(sgn * cy, cx)
    # J2 on the same circle, Lm behind J1 (chord), travelling the same direction
    dphi = 2.0 * math.asin(Lm / (2.0 * rj))
    phi2 = phi - sgn * dphi
    x2, y2 = rj * math.cos(phi2), rj * math.sin(phi2)
    psi2 = math.atan2(y1 - y2, x1 - x2)
    # tail car: centre at body (-cx, sgn cy) from J2
    psi3 = math.atan2(-y2, -x2) - math.atan2(sgn * cy, -cx)

    def near(angle: float) -> float:   # the same direction, within pi of the floating car's heading
        return psi2 + math.remainder(angle - psi2, 2.0 * math.pi)

    return x1, y1, near(psi1), psi2, near(psi3)


def steady_offsets(geometry: TrainGeometry, radius: float, kp: Callable[[float], float],
                   car: str = "head") -> tuple[float, float, float, float]:
    """Steady state of one powered car on a circle under proportional axle control.

    Each axle i of the car obeys delta_i = -kp(e_i) e_i (kp in rad/m, a function of the
    error, e.g. a fuzzy schedule at fixed speed; the derivative term vanishes in steady
    state) and the car turns rigidly about the circle's centre with both axle centres at
    radii r_i = R - e_i (R > 0: left turn, e positive left = inside). With the axles at
    body positions a_i, the turning centre is at body (cx, cy),

        cx = (a_f + a_r) / 2 - (r_f^2 - r_r^2) / (2 (a_f - a_r)),   cy = sqrt(r_f^2 - (a_f - cx)^2)

    and tan(delta_i) = (a_i - cx) / cy. Solved for (e_f, e_r) by scipy.optimize.root.

    Returns
    -------
    (e_front, e_rear, delta_front, delta_rear) : floats [m, m, rad, rad]
    """
    from scipy.optimize import root

    a = geometry.axle_offsets[:2] if car == "head" else geometry.axle_offsets[2:]
    R = float(radius)
    if R <= 0.0:
        raise ValueError("steady_offsets: left turns (radius > 0) only")

    def angles(e: "Sequence[float] | NDArray[np.float64]") -> tuple[float, float]:
        r_f, r_r = R - e[0], R - e[1]
        cx = 0.5 * (a[0] + a[1]) - (r_f * r_f - r_r * r_r) / (2.0 * (a[0] - a[1]))
        cy = math.sqrt(r_f * r_f - (a[0] - cx) ** 2)
        return math.atan((a[0] - cx) / cy), math.atan((a[1] - cx) / cy)

    def residual(e: "NDArray[np.float64]") -> list[float]:
        d = angles(e)
        return [d[0] + kp(e[0]) * e[0], d[1] + kp(e[1]) * e[1]]

    s = math.asin(geometry.L1 / (2.0 * R))
    guess = [-s / kp(0.0), s / kp(0.0)]
    sol = root(residual, guess, method="hybr", tol=1e-14)
    if not sol.success:
        raise RuntimeError(f"steady_offsets: {sol.message}")
    e_f, e_r = (float(x) for x in sol.x)
    d_f, d_r = angles(sol.x)
    return e_f, e_r, d_f, d_r
