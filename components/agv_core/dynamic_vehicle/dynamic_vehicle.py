"""Dynamic single-track (bicycle) vehicle with tyre forces: a drop-in for the kinematic
:class:`~agv_core.vehicle.vehicle.Vehicle`.

Frames and signs as in components/README.md: world x east, y north; heading psi [rad]
counter-clockwise from +x, continuous; steered-wheel angle delta [rad] positive left;
lateral quantities positive left. The speed input u = v0 + dv [m/s] is the body's
longitudinal speed (the x velocity of every body point in the body frame), held by the
drive: in the kinematic model it is the rear-axle centre's speed, here the rear axle may
slide sideways as well.

Geometry: rear-axle centre R, centre of gravity G at b = ``cg_to_rear`` ahead of R, front
wheel F at a = L - b ahead of G. States: R = (X, Y), psi, the lateral velocity vy of G
and the yaw rate r (body frame), and the distance travelled by R.

Slip angles (velocity direction minus wheel angle, agv_core.dynamic_vehicle.tyres):

    alpha_f = atan2(vy + a r, u) - delta,     alpha_r = atan2(vy - b r, u)

Lateral forces F_f, F_r: the sum over each axle's two wheels of tyre(alpha) (Fiala or
linear) with the wheel's load, and the planar equations of motion with u held:

    m (vy' + u r) = F_xf sin(delta) + F_f cos(delta) + F_r
    Iz r' = a (F_xf sin(delta) + F_f cos(delta)) - b F_r + (t/2) (F_fl - F_fr) sin(delta)
    X' = u cos(psi) - (vy - b r) sin(psi)       Y' = u sin(psi) + (vy - b r) cos(psi)
    psi' = r                                    distance' = |velocity of R|

Drive force, combined slip and load transfer (README): the driven axle (``drive``)
supplies the force that holds u, m a_x = -m r vy plus the front tyres' drag
F_f sin(delta), shared equally by its wheels; each wheel's lateral limit is what its
friction circle leaves, sqrt((mu Fz)^2 - F_x^2) (the Fiala law with a derated limit,
agv_core.dynamic_vehicle.tyres.combined_limit); the wheel loads carry the longitudinal
and lateral load transfer m a_x h / L and m a_y h / t (``cg_height`` h, ``track`` t,
``layout`` four or three wheels); a_y and the loads are solved to a fixed point. A wheel
whose load falls to 0 fails the step (WheelLiftError), and so does a drive force beyond
the driven wheels' friction (DriveLimitError). ``cg_height = 0`` with ``drive =
"ideal"`` is the model without load transfer and combined slip, exactly (one tyre per
axle at its static load, F_xf = 0).

The lateral acceleration output is a_y = vy' + u r (body frame, the centre of gravity).
Not modelled: longitudinal slip, tyre lag, roll and suspension.

Integration for inputs held over a step: RK4 with step doubling to a stated tolerance
(agv_core.numerics.ode). ``linear = True`` is the linear single-track model (linear tyres
F = -C alpha, alpha_f = (vy + a r)/u - delta, alpha_r = (vy - b r)/u; small-angle pose
Y' = u psi + vy - b r, X' = u): a linear time-invariant system for held inputs, advanced
by its exact discretisation (the matrix exponential, scipy.linalg.expm, cached per speed
and step), like the kinematic model's exact linear step.

Low and zero speed: the model's time constants shrink in proportion to u (its lateral
eigenvalues grow as 1/u) and the slip angles are undefined at u = 0. Below
``kinematic_below`` [m/s] (|u| < u_k) the vehicle is the kinematic model (exact arc, the
lateral state set to its no-slip values r = u tan(delta) / L, vy = b r). At a switch from
the dynamic to the kinematic model the lateral state jumps to these values; the jump is
O(u_k^2) (the dynamic model converges to the kinematic one as u^2, README). Reverse
driving faster than u_k is refused (the slip angles as defined assume forward motion).
"""

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from scipy.linalg import expm

from ..errors import ModelLimitError, ParameterError
from ..numerics.arc import sinc
from ..numerics.ode import rk4_doubling
from .tyres import TYRES, combined_limit, fiala_force, linear_force

REFERENCE_POINTS = ("front", "rear")
LAYOUTS = ("four", "three")
DRIVES = ("rear", "front", "ideal")


class WheelLiftError(ModelLimitError):
    """A wheel's vertical load fell to zero: the vehicle starts to tip over."""


class DriveLimitError(ModelLimitError):
    """The driven wheels cannot transmit the force that holds the speed."""
G = 9.81  # [m/s^2] gravity
ITERATIONS = 100  # bound on the fixed-point iterations of load transfer and drive force

#: Four floats: one per wheel (front left, front right, rear left, rear right).
Four = tuple[float, float, float, float]
#: Exact discretisation (Phi, Gamma) of the linear model (:meth:`DynamicVehicle.discretisation`).
Discretisation = tuple[tuple[tuple[float, ...], ...], tuple[float, ...]]
#: What the load-transfer evaluation of :meth:`DynamicVehicle._tyres` finds: (loads, F_fl,
#: F_fr, F_f, F_r, F_x front, F_x rear, F_y).
_Found = tuple[Four, float, float, float, float, float, float, float]


def positive(name: str, value: float) -> float:
    """``value`` as a float if positive and finite; else ParameterError naming ``name``."""
    if not (math.isfinite(value) and value > 0.0):
        raise ParameterError(name, f"must be positive and finite, got {value}")
    return float(value)


class SingleTrackParameters:
    """Mass, inertia, geometry and tyres of the single-track model (SI units).

    Parameters
    ----------
    wheelbase : float
        L [m], rear-axle centre to front-wheel centre, > 0.
    mass : float
        m [kg], > 0.
    yaw_inertia : float
        Iz [kg m^2] about the vertical axis through G, > 0.
    cg_to_rear : float
        b [m], rear-axle centre to G, 0 < b < L.
    cornering_stiffness_front, cornering_stiffness_rear : float
        C_f, C_r [N/rad] per axle (both tyres of an axle together), > 0.
    mu : float
        Tyre-road friction coefficient [-], > 0 (Fiala tyre only).
    tyre : {"fiala", "linear"}
        Tyre law of the nonlinear model.
    cg_height : float
        h [m] >= 0, height of G above the ground (load transfer; 0: static loads).
    track : float
        t [m] > 0, distance between the left and right wheels of a two-wheel axle.
    layout : {"four", "three"}
        Wheels: two per axle, or one front wheel on the centre line and two rear wheels.
    drive : {"rear", "front", "ideal"}
        Axle whose wheels carry the drive force that holds the speed (split equally
        between its wheels: an open differential); "ideal": the drive force costs no
        friction (the model without combined slip).
    """

    def __init__(self, wheelbase: float = 1.0, mass: float = 400.0, yaw_inertia: float = 120.0,
                 cg_to_rear: float = 0.5, cornering_stiffness_front: float = 13500.0,
                 cornering_stiffness_rear: float = 13500.0, mu: float = 0.8,
                 tyre: str = "fiala", cg_height: float = 0.3, track: float = 0.8,
                 layout: str = "four", drive: str = "rear") -> None:
        self.L = positive("wheelbase", wheelbase)
        self.m = positive("mass", mass)
        self.Iz = positive("yaw_inertia", yaw_inertia)
        self.b = positive("cg_to_rear", cg_to_rear)
        if not self.b < self.L:
            raise ParameterError("cg_to_rear", f"must be less than the wheelbase {self.L} m, "
                                 f"got {cg_to_rear}")
        self.a = self.L - self.b
        self.Cf = positive("cornering_stiffness_front", cornering_stiffness_front)
        self.Cr = positive("cornering_stiffness_rear", cornering_stiffness_rear)
        self.mu = positive("mu", mu)
        if tyre not in TYRES:
            raise ParameterError("tyre", f"must be one of {TYRES}, got '{tyre}'")
        self.tyre = tyre
        #: static axle loads [N] and friction limits mu Fz [N]
        self.Fzf = self.m * G * self.b / self.L
        self.Fzr = self.m * G * self.a / self.L
        self.limit_f = self.mu * self.Fzf
        self.limit_r = self.mu * self.Fzr
        if not (math.isfinite(cg_height) and cg_height >= 0.0):
            raise ParameterError("cg_height", f"must be a finite height >= 0 m, got {cg_height}")
        self.h = float(cg_height)
        self.track = positive("track", track)
        if layout not in LAYOUTS:
            raise ParameterError("layout", f"must be one of {LAYOUTS}, got '{layout}'")
        if drive not in DRIVES:
            raise ParameterError("drive", f"must be one of {DRIVES}, got '{drive}'")
        self.layout, self.drive = layout, drive
        #: share of the roll moment m a_y h carried by each axle: in proportion to the
        #: static axle loads (four wheels), all on the rear pair (one front wheel)
        if layout == "four":
            self.share_f, self.share_r = self.b / self.L, self.a / self.L
            self.half_track_f = 0.5 * self.track
        else:
            self.share_f, self.share_r = 0.0, 1.0
            self.half_track_f = 0.0
        #: True when the loads are static and the drive free: the model without load
        #: transfer and combined slip
        self.static = self.h == 0.0 and drive == "ideal"

    def wheel_loads(self, ax: float, ay: float) -> Four:
        """Vertical loads [N] (front left, front right, rear left, rear right) for the
        accelerations ``ax``, ``ay`` [m/s^2] of G in the body frame: longitudinal transfer
        m a_x h / L from the front to the rear axle, lateral transfer share m a_y h / t
        from each axle's left to its right wheel. One front wheel (layout "three"): its
        load is split into two equal halves at the same point (its two entries)."""
        dlong = self.m * ax * self.h / self.L
        fzf, fzr = self.Fzf - dlong, self.Fzr + dlong
        lat = self.m * ay * self.h / self.track
        dyf, dyr = self.share_f * lat, self.share_r * lat
        return (0.5 * fzf - dyf, 0.5 * fzf + dyf, 0.5 * fzr - dyr, 0.5 * fzr + dyr)

    def wheel_names(self) -> tuple[str, str, str, str]:
        """Names of the four load entries of :meth:`wheel_loads` (layout "three": the
        front wheel twice)."""
        if self.layout == "three":
            return ("front", "front", "rear left", "rear right")
        return ("front left", "front right", "rear left", "rear right")

    def lateral_tip_acceleration(self) -> float:
        """Lateral acceleration [m/s^2] (a_x = 0) at which the first wheel lifts: the
        inner wheel of axle k when share_k m a_y h / t = Fz_k / 2, so g (t / 2) / h for
        four wheels and g d / h for one front wheel, d = t a / (2 L) the lateral distance
        from G's ground projection to the line from the front wheel to a rear wheel.
        Infinite for h = 0."""
        if self.h == 0.0:
            return math.inf
        limits = [0.5 * fz * self.track / (share * self.m * self.h)
                  for fz, share in ((self.Fzf, self.share_f), (self.Fzr, self.share_r))
                  if share > 0.0]
        return min(limits)

    def understeer_gradient(self) -> float:
        """K_us = (m / L) (b / C_f - a / C_r) [rad/(m/s^2)]: steady delta = L/R + K_us a_y."""
        return self.m / self.L * (self.b / self.Cf - self.a / self.Cr)

    def lateral_matrices(self, u: float) -> tuple[tuple[tuple[float, float], tuple[float, float]],
                                                  tuple[float, float]]:
        """(A, B) of the linear lateral dynamics d/dt [vy, r] = A [vy, r] + B delta at
        speed ``u`` [m/s] > 0, as nested tuples."""
        m, Iz, a, b, Cf, Cr = self.m, self.Iz, self.a, self.b, self.Cf, self.Cr
        A = ((-(Cf + Cr) / (m * u), -(a * Cf - b * Cr) / (m * u) - u),
             (-(a * Cf - b * Cr) / (Iz * u), -(a * a * Cf + b * b * Cr) / (Iz * u)))
        B = (Cf / m, a * Cf / Iz)
        return A, B


class DynamicVehicle:
    """Dynamic single-track vehicle (see the module docstring), the kinematic
    :class:`~agv_core.vehicle.vehicle.Vehicle`'s interface plus the lateral state.

    Parameters
    ----------
    params : SingleTrackParameters
    x0, y0 : float
        Initial position of the reference point [m].
    heading0 : float
        Initial heading [rad].
    reference_point : {"front", "rear"}
        Point reported as ``x, y`` (and given by x0, y0).
    linear : bool
        The linear single-track model (exact discretisation) instead of the nonlinear one.
    kinematic_below : float
        u_k [m/s] > 0: below it the kinematic model runs (module docstring).
    tolerance : float
        Bound on the estimated local error per step of every state, scaled by 1 + |state|
        (nonlinear model; agv_core.numerics.ode).
    alpha0, speed0 : float
        Inputs at the start [rad, m/s]: the lateral state starts at their kinematic
        (no-slip) values, so a vehicle started on an arc is already turning.
    """

    def __init__(self, params: SingleTrackParameters, x0: float = 0.0, y0: float = 0.0,
                 heading0: float = 0.0, reference_point: str = "front", linear: bool = False,
                 kinematic_below: float = 0.1, tolerance: float = 1e-9, alpha0: float = 0.0,
                 speed0: float = 0.0) -> None:
        if reference_point not in REFERENCE_POINTS:
            raise ParameterError("reference_point",
                                 f"must be one of {REFERENCE_POINTS}, got '{reference_point}'")
        for name, value in (("x0", x0), ("y0", y0), ("heading0", heading0)):
            if not math.isfinite(value):
                raise ParameterError(name, f"must be finite, got {value}")
        if not (math.isfinite(kinematic_below) and kinematic_below > 0.0):
            raise ParameterError("kinematic_below", f"must be a positive speed in m/s (the "
                                 f"dynamic model is singular at 0), got {kinematic_below}")
        self.p = params
        self.reference_point = reference_point
        self.linear = bool(linear)
        self.kinematic_below = float(kinematic_below)
        self.tolerance = positive("tolerance", tolerance)
        L = params.L
        self.psi = float(heading0)
        if reference_point == "rear":
            self.X, self.Y = float(x0), float(y0)
        elif self.linear:
            self.X, self.Y = x0 - L, y0 - L * self.psi
        else:
            self.X, self.Y = x0 - L * math.cos(self.psi), y0 - L * math.sin(self.psi)
        self.distance = 0.0
        self.substeps = 1
        # (u, h) -> exact discretisation of the linear model
        self._discrete: dict[tuple[float, float], Discretisation] = {}
        self.alpha, self.u = 0.0, 0.0
        self.vy, self.r = 0.0, 0.0
        self.start(alpha0, speed0)

    def start(self, alpha: float, speed: float) -> None:
        """Set the inputs held before the first step and the lateral state to their
        kinematic (no-slip) values."""
        self._check_inputs(alpha, speed)
        self.alpha, self.u = float(alpha), float(speed)
        self.r = self.kinematic_yaw_rate(alpha, speed)
        self.vy = self.p.b * self.r

    # ------------------------------------------------------------------ geometry
    @property
    def heading(self) -> float:
        return self.psi

    @property
    def x(self) -> float:
        return self.rear()[0] if self.reference_point == "rear" else self.front()[0]

    @property
    def y(self) -> float:
        return self.rear()[1] if self.reference_point == "rear" else self.front()[1]

    def rear(self) -> tuple[float, float]:
        """Position of the rear-axle centre (x, y) [m]."""
        return self.X, self.Y

    def front(self) -> tuple[float, float]:
        """Position of the front-wheel centre (x, y) [m]."""
        L = self.p.L
        if self.linear:
            return self.X + L, self.Y + L * self.psi
        return self.X + L * math.cos(self.psi), self.Y + L * math.sin(self.psi)

    def kinematic_yaw_rate(self, alpha: float, u: float) -> float:
        """The kinematic model's yaw rate [rad/s]: u tan(alpha) / L (linear: u alpha / L)."""
        if self.linear:
            return u * alpha / self.p.L
        return u * math.tan(alpha) / self.p.L

    def is_kinematic(self, u: float | None = None) -> bool:
        """True when speed ``u`` (default: the last applied) runs the kinematic model."""
        return abs(self.u if u is None else u) < self.kinematic_below

    # ------------------------------------------------------------------ tyres
    def lateral(self, alpha: float | None = None, u: float | None = None,
                vy: float | None = None, r: float | None = None
                ) -> tuple[float, float, float, float, float, float]:
        """(slip_f, slip_r [rad], F_f, F_r [N], vy' [m/s^2], r' [rad/s^2]) for the given
        inputs and lateral state (default: the last applied inputs, the current state).

        In the kinematic regime the slips and forces are 0 and (vy', r') = (0, 0)."""
        alpha = self.alpha if alpha is None else alpha
        u = self.u if u is None else u
        vy = self.vy if vy is None else vy
        r = self.r if r is None else r
        if self.is_kinematic(u):
            return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        p = self.p
        if self.linear:
            slip_f = (vy + p.a * r) / u - alpha
            slip_r = (vy - p.b * r) / u
            ff, fr = -p.Cf * slip_f, -p.Cr * slip_r
            return slip_f, slip_r, ff, fr, (ff + fr) / p.m - u * r, (p.a * ff - p.b * fr) / p.Iz
        slip_f = math.atan2(vy + p.a * r, u) - alpha
        slip_r = math.atan2(vy - p.b * r, u)
        if not p.static:
            tyres = self._tyres(alpha, u, vy, r, slip_f, slip_r)
            return slip_f, slip_r, tyres[0], tyres[1], tyres[2], tyres[3]
        if p.tyre == "fiala":
            ff = fiala_force(slip_f, p.Cf, p.limit_f)
            fr = fiala_force(slip_r, p.Cr, p.limit_r)
        else:
            ff, fr = linear_force(slip_f, p.Cf), linear_force(slip_r, p.Cr)
        ffc = ff * math.cos(alpha)
        return slip_f, slip_r, ff, fr, (ffc + fr) / p.m - u * r, (p.a * ffc - p.b * fr) / p.Iz

    def _wheel_force(self, slip: float, stiffness: float, static_load: float, load: float,
                     fx: float) -> float:
        """Lateral force [N] of one wheel with vertical ``load`` [N] and longitudinal force
        ``fx`` [N]: cornering stiffness and friction limit in proportion to the load (the
        axle's ``stiffness`` at its ``static_load``), the limit derated by ``fx``."""
        if not load > 0.0:
            return 0.0
        c = stiffness * (load / static_load)
        if self.p.tyre == "linear":
            return linear_force(slip, c)
        return fiala_force(slip, c, combined_limit(self.p.mu * load, fx))

    def _tyres(self, alpha: float, u: float, vy: float, r: float, slip_f: float, slip_r: float
               ) -> tuple[float, float, float, float, Four, float, float, float]:
        """Forces with load transfer and combined slip (module docstring): (F_f, F_r
        [N] lateral per axle, vy' [m/s^2], r' [rad/s^2], loads (4) [N], F_x front,
        F_x rear [N] per axle, a_y [m/s^2]). The lateral load transfer depends on a_y,
        which depends on the forces, and a driven front axle's F_x on its own lateral
        force: both are iterated to a fixed point (to 1e-12 relative)."""
        p = self.p
        m, mu = p.m, p.mu
        cos_d, sin_d = math.cos(alpha), math.sin(alpha)
        drag = -m * r * vy              # m a_x: the body force that holds u (u' = 0)
        scale = mu * m * G

        def evaluate(ay: float, fxf: float) -> tuple[float, _Found]:
            """Forces for the lateral acceleration ``ay`` that sets the load transfer."""
            loads = p.wheel_loads(-r * vy, ay)

            def front(fx: float) -> tuple[float, float]:
                return (self._wheel_force(slip_f, p.Cf, p.Fzf, loads[0], 0.5 * fx),
                        self._wheel_force(slip_f, p.Cf, p.Fzf, loads[1], 0.5 * fx))

            fxr = 0.0
            if p.drive == "front":
                fxf = self._front_drive(front, drag, cos_d, sin_d, fxf, scale)
            else:
                fxf = 0.0
            ffl, ffr = front(fxf)
            ff = ffl + ffr
            if p.drive == "rear":
                fxr = drag + ff * sin_d
            fr = (self._wheel_force(slip_r, p.Cr, p.Fzr, loads[2], 0.5 * fxr)
                  + self._wheel_force(slip_r, p.Cr, p.Fzr, loads[3], 0.5 * fxr))
            fy = fxf * sin_d + ff * cos_d + fr
            return fy / m, (loads, ffl, ffr, ff, fr, fxf, fxr, fy)

        ay, fxf = u * r, 0.0
        for _ in range(30):
            ay_new, found = evaluate(ay, fxf)
            done = p.h == 0.0 or abs(ay_new - ay) <= 1e-12 * (1.0 + abs(ay))
            ay, fxf = ay_new, found[5]
            if done:
                break
        else:
            ay, found = self._bisect_ay(evaluate, ay, fxf)
        loads, ffl, ffr, ff, fr, fxf, fxr, fy = found
        # the front wheels' body-x forces differ left to right by (F_fl - F_fr) sin(delta)
        mz = p.a * (fxf * sin_d + ff * cos_d) - p.b * fr + p.half_track_f * (ffl - ffr) * sin_d
        return ff, fr, fy / m - u * r, mz / p.Iz, loads, fxf, fxr, ay

    @staticmethod
    def _bisect_ay(evaluate: Callable[[float, float], tuple[float, _Found]], ay: float,
                   fxf: float) -> tuple[float, _Found]:
        """Fixed point of a_y -> evaluate(a_y)[0] by bisection when the iteration does not
        contract (a wheel near lift or drive spin switching its force on and off): the
        new a_y is bounded, so a bracket is found by widening; the forces returned are
        those at the bracket's end nearest the fixed point."""
        span = 1.0 + abs(ay)
        for _ in range(ITERATIONS):
            lo, hi = ay - span, ay + span
            if evaluate(lo, fxf)[0] >= lo and evaluate(hi, fxf)[0] <= hi:
                break
            span *= 2.0
        else:
            raise FloatingPointError("lateral load transfer found no fixed point")
        for _ in range(ITERATIONS):
            mid = 0.5 * (lo + hi)
            if evaluate(mid, fxf)[0] >= mid:
                lo = mid
            else:
                hi = mid
            if hi - lo <= 1e-12 * (1.0 + abs(mid)):
                break
        return evaluate(lo, fxf)

    @staticmethod
    def _front_drive(front: Callable[[float], tuple[float, float]], drag: float, cos_d: float,
                     sin_d: float, guess: float, scale: float) -> float:
        """The driven front axle's longitudinal force x [N] solving
        x cos(delta) = drag + F_f(x) sin(delta) (``front(x)``: the two wheels' lateral
        forces): fixed-point iteration from ``guess``, bisection when it does not
        contract (the root lies within (drag -+ |sin(delta)| mu m g) / cos(delta))."""
        x = guess
        for _ in range(20):
            left, right = front(x)
            new = (drag + (left + right) * sin_d) / cos_d
            if abs(new - x) <= 1e-12 * (scale + abs(x)):
                return new
            x = new
        spread = abs(sin_d) * scale / cos_d
        lo, hi = drag / cos_d - spread, drag / cos_d + spread
        for _ in range(ITERATIONS):
            mid = 0.5 * (lo + hi)
            left, right = front(mid)
            if mid * cos_d - drag - (left + right) * sin_d > 0.0:
                hi = mid
            else:
                lo = mid
            if hi - lo <= 1e-12 * (scale + abs(mid)):
                break
        return 0.5 * (lo + hi)

    def tyre_state(self) -> dict[str, Any]:
        """Loads, drive and friction use for the last inputs and the current state:
        dict with ``loads`` (front left, front right, rear left, rear right [N]; one front
        wheel: its two halves), ``drive_front``, ``drive_rear`` (longitudinal force of
        each axle [N]), ``friction_front``, ``friction_rear`` (the largest
        sqrt(F_x^2 + F_y^2) / (mu Fz) of the axle's wheels, 1 at the friction limit),
        ``tip_margin`` (the smallest wheel load over its static load: 1 at rest, 0 when
        a wheel lifts). Kinematic regime and the static model: static loads, no drive
        force (friction use from the lateral forces alone)."""
        p = self.p
        half = (0.5 * p.Fzf, 0.5 * p.Fzf, 0.5 * p.Fzr, 0.5 * p.Fzr)
        shares: Four | None
        if self.is_kinematic() or self.linear:
            loads, fxf, fxr = half, 0.0, 0.0
            ff = fr = 0.0
            shares = (0.5, 0.5, 0.5, 0.5)
        elif p.static:
            slip_f, slip_r, ff, fr, _, _ = self.lateral()
            loads, fxf, fxr = half, 0.0, 0.0
            shares = (0.5, 0.5, 0.5, 0.5)
        else:
            alpha, u, vy, r = self.alpha, self.u, self.vy, self.r
            slip_f = math.atan2(vy + p.a * r, u) - alpha
            slip_r = math.atan2(vy - p.b * r, u)
            _, _, _, _, loads, fxf, fxr, _ = self._tyres(alpha, u, vy, r, slip_f, slip_r)
            ff = fr = 0.0
            shares = None
        use = []
        for i, load in enumerate(loads):
            front = i < 2
            if shares is None:
                slip = slip_f if front else slip_r
                fy = self._wheel_force(slip, p.Cf if front else p.Cr,
                                       p.Fzf if front else p.Fzr, load,
                                       0.5 * (fxf if front else fxr))
            else:
                fy = shares[i] * (ff if front else fr)
            fx = 0.5 * (fxf if front else fxr)
            use.append(math.hypot(fx, fy) / (p.mu * load) if load > 0.0 else math.inf)
        return {"loads": tuple(loads), "drive_front": fxf, "drive_rear": fxr,
                "friction_front": max(use[0], use[1]), "friction_rear": max(use[2], use[3]),
                "tip_margin": min(load / static for load, static in zip(loads, half))}

    def check_contact(self) -> None:
        """Raise :class:`WheelLiftError` naming the wheel when a wheel's load is <= 0, and
        :class:`DriveLimitError` when the driven axle's force per wheel exceeds mu Fz
        (the speed cannot be held), for the last inputs and the current state."""
        p = self.p
        if p.static or self.linear or self.is_kinematic():
            return
        state = self.tyre_state()
        for name, load in zip(p.wheel_names(), state["loads"]):
            if not load > 0.0:
                raise WheelLiftError(
                    f"the {name} wheel lifts (vertical load {load:.1f} N): the vehicle "
                    f"tips over (lateral acceleration {self.lateral_acceleration():.3f} "
                    f"m/s2, tip-over limit {p.lateral_tip_acceleration():.3f} m/s2)")
        for axle, fx, loads in (("front", state["drive_front"], state["loads"][:2]),
                                ("rear", state["drive_rear"], state["loads"][2:])):
            if abs(0.5 * fx) > p.mu * min(loads):
                raise DriveLimitError(
                    f"the {axle} axle's drive needs {abs(fx):.1f} N to hold the speed "
                    f"{self.u:.3f} m/s, more than its wheels' friction "
                    f"2 x mu Fz = {2.0 * p.mu * min(loads):.1f} N")

    def lateral_acceleration(self, dvy: float | None = None) -> float:
        """a_y = vy' + u r [m/s^2] of G in the body frame (last inputs, current state;
        ``dvy``: vy' if already computed by :meth:`lateral`). Kinematic regime: u r."""
        if dvy is None:
            dvy = self.lateral()[4]
        return dvy + self.u * self.r

    def sideslip(self) -> float:
        """Sideslip angle of G [rad]: atan2(vy, u) (linear model: vy / u; 0 at rest)."""
        if self.linear:
            return self.vy / self.u if self.u != 0.0 else 0.0
        return math.atan2(self.vy, self.u) if self.u != 0.0 else 0.0

    # ------------------------------------------------------------------ dynamics
    def _check_inputs(self, alpha: float, u: float) -> None:
        if not (abs(alpha) < 0.5 * math.pi):
            raise FloatingPointError(f"steering angle alpha={alpha} rad is not within +/-pi/2")
        if not math.isfinite(u):
            raise FloatingPointError(f"speed {u} m/s is not finite")
        if u <= -self.kinematic_below:
            raise ValueError(f"speed {u} m/s: reverse driving faster than kinematic_below = "
                             f"{self.kinematic_below} m/s is not modelled")

    def step(self, alpha: float, v: float, h: float) -> None:
        """Advance by ``h`` [s] with steering ``alpha`` [rad] and speed ``v`` [m/s] held."""
        self._check_inputs(alpha, v)
        self.alpha, self.u = float(alpha), float(v)
        if h <= 0.0:
            return
        if self.is_kinematic():
            self._kinematic_step(h)
        elif self.linear:
            self._linear_step(h)
        else:
            self._nonlinear_step(h)
            self.check_contact()

    def _kinematic_step(self, h: float) -> None:
        u, alpha = self.u, self.alpha
        w = self.kinematic_yaw_rate(alpha, u)
        if self.linear:
            self.X += u * h
            self.Y += u * self.psi * h + 0.5 * u * w * h * h
        else:
            half = 0.5 * w * h
            chord = u * h * sinc(half)
            self.X += chord * math.cos(self.psi + half)
            self.Y += chord * math.sin(self.psi + half)
        self.psi += w * h
        self.r = w
        self.vy = self.p.b * w
        self.distance += abs(u) * h

    def discretisation(self, u: float, h: float) -> Discretisation:
        """Exact discretisation (Phi, Gamma) of the linear model's z = [Y, psi, vy, r] at
        speed ``u`` over ``h``: z(t+h) = Phi z(t) + Gamma delta (nested tuples)."""
        key = (u, h)
        found = self._discrete.get(key)
        if found is not None:
            return found
        ((a11, a12), (a21, a22)), (b1, b2) = self.p.lateral_matrices(u)
        M = np.zeros((5, 5))
        M[0, 1], M[0, 2], M[0, 3] = u, 1.0, -self.p.b     # Y' = u psi + vy - b r
        M[1, 3] = 1.0                                      # psi' = r
        M[2, 2], M[2, 3], M[2, 4] = a11, a12, b1
        M[3, 2], M[3, 3], M[3, 4] = a21, a22, b2
        E = expm(M * h)
        found = (tuple(tuple(float(x) for x in E[i, :4]) for i in range(4)),
                 tuple(float(E[i, 4]) for i in range(4)))
        if len(self._discrete) > 64:   # a varying speed: keep the cache bounded
            self._discrete.clear()
        self._discrete[key] = found
        return found

    def _linear_step(self, h: float) -> None:
        phi, gamma = self.discretisation(self.u, h)
        z = (self.Y, self.psi, self.vy, self.r)
        d = self.alpha
        self.Y, self.psi, self.vy, self.r = (
            row[0] * z[0] + row[1] * z[1] + row[2] * z[2] + row[3] * z[3] + g * d
            for row, g in zip(phi, gamma))
        self.X += self.u * h
        self.distance += abs(self.u) * h

    def rates(self, state: Sequence[float]) -> list[float]:
        """Right-hand side of the nonlinear model for [X, Y, psi, vy, r, distance] with
        the held inputs (self.alpha, self.u)."""
        _, _, psi, vy, r, _ = state
        u = self.u
        _, _, _, _, dvy, dr = self.lateral(self.alpha, u, vy, r)
        vr = vy - self.p.b * r
        c, s = math.cos(psi), math.sin(psi)
        return [u * c - vr * s, u * s + vr * c, r, dvy, dr, math.hypot(u, vr)]

    def _nonlinear_step(self, h: float) -> None:
        y = [self.X, self.Y, self.psi, self.vy, self.r, self.distance]
        y, self.substeps = rk4_doubling(self.rates, y, h, self.tolerance,
                                        start=max(1, self.substeps // 2))
        self.X, self.Y, self.psi, self.vy, self.r, self.distance = y

    # ------------------------------------------------------------------ state
    def get_state(self) -> dict[str, Any]:
        """JSON-safe snapshot of the state."""
        return {"X": self.X, "Y": self.Y, "psi": self.psi, "vy": self.vy, "r": self.r,
                "distance": self.distance, "alpha": self.alpha, "u": self.u,
                "substeps": self.substeps}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a snapshot from :meth:`get_state`."""
        self.X, self.Y, self.psi = state["X"], state["Y"], state["psi"]
        self.vy, self.r = state["vy"], state["r"]
        self.distance = state["distance"]
        self.alpha, self.u = state["alpha"], state["u"]
        self.substeps = int(state["substeps"])
