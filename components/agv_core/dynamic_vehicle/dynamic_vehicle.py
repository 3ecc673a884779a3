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

Lateral forces F_f = tyre(alpha_f), F_r = tyre(alpha_r) (Fiala or linear, static loads
Fz_f = m g b / L, Fz_r = m g a / L), and the planar equations of motion with u held:

    m (vy' + u r) = F_f cos(delta) + F_r        Iz r' = a F_f cos(delta) - b F_r
    X' = u cos(psi) - (vy - b r) sin(psi)       Y' = u sin(psi) + (vy - b r) cos(psi)
    psi' = r                                    distance' = |velocity of R|

The lateral acceleration output is a_y = vy' + u r = (F_f cos(delta) + F_r) / m (body
frame, the centre of gravity). Not modelled: the drive force that holds u (and its
lateral component at a driven steered wheel), load transfer, combined slip, tyre lag.

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

import numpy as np
from scipy.linalg import expm

from ..errors import ParameterError
from ..numerics.arc import sinc
from ..numerics.ode import rk4_doubling
from .tyres import TYRES, fiala_force, linear_force

REFERENCE_POINTS = ("front", "rear")
G = 9.81  # [m/s^2] gravity


def positive(name, value):
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
    """

    def __init__(self, wheelbase=1.0, mass=400.0, yaw_inertia=120.0, cg_to_rear=0.5,
                 cornering_stiffness_front=13500.0, cornering_stiffness_rear=13500.0,
                 mu=0.8, tyre="fiala"):
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

    def understeer_gradient(self):
        """K_us = (m / L) (b / C_f - a / C_r) [rad/(m/s^2)]: steady delta = L/R + K_us a_y."""
        return self.m / self.L * (self.b / self.Cf - self.a / self.Cr)

    def lateral_matrices(self, u):
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

    def __init__(self, params, x0=0.0, y0=0.0, heading0=0.0, reference_point="front",
                 linear=False, kinematic_below=0.1, tolerance=1e-9, alpha0=0.0, speed0=0.0):
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
        self._discrete = {}  # (u, h) -> exact discretisation of the linear model
        self.alpha, self.u = 0.0, 0.0
        self.vy, self.r = 0.0, 0.0
        self.start(alpha0, speed0)

    def start(self, alpha, speed):
        """Set the inputs held before the first step and the lateral state to their
        kinematic (no-slip) values."""
        self._check_inputs(alpha, speed)
        self.alpha, self.u = float(alpha), float(speed)
        self.r = self.kinematic_yaw_rate(alpha, speed)
        self.vy = self.p.b * self.r

    # ------------------------------------------------------------------ geometry
    @property
    def heading(self):
        return self.psi

    @property
    def x(self):
        return self.rear()[0] if self.reference_point == "rear" else self.front()[0]

    @property
    def y(self):
        return self.rear()[1] if self.reference_point == "rear" else self.front()[1]

    def rear(self):
        """Position of the rear-axle centre (x, y) [m]."""
        return self.X, self.Y

    def front(self):
        """Position of the front-wheel centre (x, y) [m]."""
        L = self.p.L
        if self.linear:
            return self.X + L, self.Y + L * self.psi
        return self.X + L * math.cos(self.psi), self.Y + L * math.sin(self.psi)

    def kinematic_yaw_rate(self, alpha, u):
        """The kinematic model's yaw rate [rad/s]: u tan(alpha) / L (linear: u alpha / L)."""
        if self.linear:
            return u * alpha / self.p.L
        return u * math.tan(alpha) / self.p.L

    def is_kinematic(self, u=None):
        """True when speed ``u`` (default: the last applied) runs the kinematic model."""
        return abs(self.u if u is None else u) < self.kinematic_below

    # ------------------------------------------------------------------ tyres
    def lateral(self, alpha=None, u=None, vy=None, r=None):
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
        if p.tyre == "fiala":
            ff = fiala_force(slip_f, p.Cf, p.limit_f)
            fr = fiala_force(slip_r, p.Cr, p.limit_r)
        else:
            ff, fr = linear_force(slip_f, p.Cf), linear_force(slip_r, p.Cr)
        ffc = ff * math.cos(alpha)
        return slip_f, slip_r, ff, fr, (ffc + fr) / p.m - u * r, (p.a * ffc - p.b * fr) / p.Iz

    def lateral_acceleration(self, dvy=None):
        """a_y = vy' + u r [m/s^2] of G in the body frame (last inputs, current state;
        ``dvy``: vy' if already computed by :meth:`lateral`). Kinematic regime: u r."""
        if dvy is None:
            dvy = self.lateral()[4]
        return dvy + self.u * self.r

    def sideslip(self):
        """Sideslip angle of G [rad]: atan2(vy, u) (linear model: vy / u; 0 at rest)."""
        if self.linear:
            return self.vy / self.u if self.u != 0.0 else 0.0
        return math.atan2(self.vy, self.u) if self.u != 0.0 else 0.0

    # ------------------------------------------------------------------ dynamics
    def _check_inputs(self, alpha, u):
        if not (abs(alpha) < 0.5 * math.pi):
            raise FloatingPointError(f"steering angle alpha={alpha} rad is not within +/-pi/2")
        if not math.isfinite(u):
            raise FloatingPointError(f"speed {u} m/s is not finite")
        if u <= -self.kinematic_below:
            raise ValueError(f"speed {u} m/s: reverse driving faster than kinematic_below = "
                             f"{self.kinematic_below} m/s is not modelled")

    def step(self, alpha, v, h):
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

    def _kinematic_step(self, h):
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

    def discretisation(self, u, h):
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

    def _linear_step(self, h):
        phi, gamma = self.discretisation(self.u, h)
        z = (self.Y, self.psi, self.vy, self.r)
        d = self.alpha
        self.Y, self.psi, self.vy, self.r = (
            row[0] * z[0] + row[1] * z[1] + row[2] * z[2] + row[3] * z[3] + g * d
            for row, g in zip(phi, gamma))
        self.X += self.u * h
        self.distance += abs(self.u) * h

    def rates(self, state):
        """Right-hand side of the nonlinear model for [X, Y, psi, vy, r, distance] with
        the held inputs (self.alpha, self.u)."""
        _, _, psi, vy, r, _ = state
        u = self.u
        _, _, _, _, dvy, dr = self.lateral(self.alpha, u, vy, r)
        vr = vy - self.p.b * r
        c, s = math.cos(psi), math.sin(psi)
        return [u * c - vr * s, u * s + vr * c, r, dvy, dr, math.hypot(u, vr)]

    def _nonlinear_step(self, h):
        y = [self.X, self.Y, self.psi, self.vy, self.r, self.distance]
        y, self.substeps = rk4_doubling(self.rates, y, h, self.tolerance,
                                        start=max(1, self.substeps // 2))
        self.X, self.Y, self.psi, self.vy, self.r, self.distance = y

    # ------------------------------------------------------------------ state
    def get_state(self):
        """JSON-safe snapshot of the state."""
        return {"X": self.X, "Y": self.Y, "psi": self.psi, "vy": self.vy, "r": self.r,
                "distance": self.distance, "alpha": self.alpha, "u": self.u,
                "substeps": self.substeps}

    def set_state(self, state):
        """Restore a snapshot from :meth:`get_state`."""
        self.X, self.Y, self.psi = state["X"], state["Y"], state["psi"]
        self.vy, self.r = state["vy"], state["r"]
        self.distance = state["distance"]
        self.alpha, self.u = state["alpha"], state["u"]
        self.substeps = int(state["substeps"])
