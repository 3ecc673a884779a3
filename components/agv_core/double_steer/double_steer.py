"""Double-steering-wheel AGV of seed 001: rigid-body kinematics and inverse kinematics.

Two steered drive wheels sit on the body's longitudinal axis, the front one at body
coordinates (+L/2, 0), the rear one at (-L/2, 0); the centroid C is midway (seed 001
section 1.1, notes-001-003.md section 1.2). Body frame X' from the rear wheel to the
front wheel, Y' to the left; angles counter-clockwise positive. A wheel angle theta is
the direction of the wheel's ground velocity relative to X' (positive turns left); its
speed V is that velocity's magnitude (signed: negative drives backwards).

Forward kinematics (eqs 6-9 of the notes, exact rigid-body relations)
---------------------------------------------------------------------
The wheel contact velocities in the body frame are (V cos theta, V sin theta). A rigid
body moving with centroid velocity (u, v) [body frame] and yaw rate omega gives the
front point (u, v + omega L/2) and the rear point (u, v - omega L/2). The body twist is
the least-squares fit to the two wheel velocities::

    u     = (Vf cos(theta_f) + Vb cos(theta_b)) / 2
    v     = (Vf sin(theta_f) + Vb sin(theta_b)) / 2
    omega = (Vf sin(theta_f) - Vb sin(theta_b)) / L

It is exact (pure rolling) when the no-stretch condition Vf cos(theta_f) = Vb cos(theta_b)
holds; ``stretch`` = Vf cos(theta_f) - Vb cos(theta_b) [m/s] is reported otherwise (the
wheels would have to slip along the body axis). Symmetric steering theta_b = -theta_f,
Vf = Vb = V drives a circle of radius L / (2 sin theta_f) (each wheel; eq 3) with
omega = 2 V sin(theta_f) / L; parallel steering theta_b = theta_f, Vf = Vb translates
without yawing.

Integration: the twist is constant while the inputs are held, so the pose is advanced
exactly (motion along a circular arc, or a straight line when omega = 0)::

    psi(t+h) = psi + omega h
    [X, Y](t+h) = [X, Y] + h sinc(omega h / 2) Rot(psi + omega h / 2) [u, v]

Inverse kinematics (symmetric steering, the input stage of the 2-input MPC)
---------------------------------------------------------------------------
From a centroid speed v_c [m/s] along X' and a yaw rate omega [rad/s]::

    theta_f = atan2(omega L / 2, v_c),  theta_b = -theta_f,
    Vf = Vb = sqrt(v_c^2 + (omega L / 2)^2)

which the forward kinematics maps back to u = v_c, v = 0, omega exactly.
"""

import math
from typing import Any

from ..errors import ParameterError
from ..numerics.arc import sinc as _sinc
from ..numerics.finite import finite as _finite

TWO_PI = 2.0 * math.pi


def _positive(name: str, value: float) -> float:
    if not (math.isfinite(value) and value > 0.0):
        raise ParameterError(name, f"must be a positive number, got {value}")
    return float(value)


def body_twist(wheelbase: float, theta_f: float, v_f: float, theta_b: float, v_b: float
               ) -> tuple[float, float, float, float]:
    """Centroid velocity (u, v) [m/s] in the body frame and yaw rate [rad/s].

    Parameters
    ----------
    wheelbase : float
        L [m], distance between the two wheel contact points.
    theta_f, theta_b : float
        Front / rear wheel angle [rad], positive left of X'.
    v_f, v_b : float
        Front / rear wheel ground speed [m/s].

    Returns
    -------
    tuple of float
        (u, v, omega, stretch): u, v [m/s], omega [rad/s], stretch [m/s] (see module).
    """
    cf, sf = v_f * math.cos(theta_f), v_f * math.sin(theta_f)
    cb, sb = v_b * math.cos(theta_b), v_b * math.sin(theta_b)
    return 0.5 * (cf + cb), 0.5 * (sf + sb), (sf - sb) / wheelbase, cf - cb


def inverse_kinematics(wheelbase: float, v_c: float, omega: float
                       ) -> tuple[float, float, float, float]:
    """Symmetric-steering wheel commands for a centroid speed and a yaw rate.

    Parameters
    ----------
    wheelbase : float
        L [m].
    v_c : float
        Centroid speed along X' [m/s].
    omega : float
        Yaw rate [rad/s], positive counter-clockwise.

    Returns
    -------
    tuple of float
        (theta_f, v_f, theta_b, v_b): angles [rad], speeds [m/s] (v_f = v_b >= 0).
    """
    half = 0.5 * omega * wheelbase
    theta_f = math.atan2(half, v_c)
    speed = math.hypot(v_c, half)
    return theta_f, speed, -theta_f, speed


class InverseKinematics:
    """Stateless core of the inverse-kinematics FMU: :func:`inverse_kinematics` with a
    fixed, validated wheelbase [m]."""

    def __init__(self, wheelbase: float = 1.0) -> None:
        self.wheelbase = _positive("wheelbase", wheelbase)

    def command(self, v_c: float, omega: float) -> tuple[float, float, float, float]:
        """(theta_f, v_f, theta_b, v_b) for ``v_c`` [m/s] and ``omega`` [rad/s]."""
        return inverse_kinematics(self.wheelbase, v_c, omega)

    def get_state(self) -> dict[str, Any]:
        """No state (JSON-safe empty snapshot)."""
        return {}

    def set_state(self, state: dict[str, Any]) -> None:
        """Nothing to restore."""


def turning_radius(wheelbase: float, theta_f: float) -> float:
    """Radius [m] of the wheels' common circle under symmetric steering, L / (2 sin theta_f).

    ``math.inf`` for theta_f = 0 (straight). Seed 001 eq (3).
    """
    s = math.sin(theta_f)
    return math.inf if s == 0.0 else wheelbase / (2.0 * abs(s))


class DoubleSteerVehicle:
    """Pose of the double-steer AGV, integrated exactly for held wheel inputs.

    Parameters
    ----------
    wheelbase : float
        L [m], > 0 (seed 001 does not state it; default 1.0 m, notes section 1.6).
    x0, y0 : float
        Initial centroid position [m].
    yaw0 : float
        Initial body yaw psi [rad] (direction of X' from the global X axis).
    """

    def __init__(self, wheelbase: float = 1.0, x0: float = 0.0, y0: float = 0.0,
                 yaw0: float = 0.0) -> None:
        self.wheelbase = _positive("wheelbase", wheelbase)
        self.x = _finite("x0", x0)
        self.y = _finite("y0", y0)
        self.yaw = _finite("yaw0", yaw0)
        self.distance = 0.0

    def twist(self, theta_f: float, v_f: float, theta_b: float, v_b: float
              ) -> tuple[float, float, float, float]:
        """(u, v, omega, stretch) for these wheel inputs (see :func:`body_twist`)."""
        return body_twist(self.wheelbase, theta_f, v_f, theta_b, v_b)

    def step(self, theta_f: float, v_f: float, theta_b: float, v_b: float, h: float) -> None:
        """Advance by ``h`` [s] with the wheel inputs held (exact)."""
        u, v, w, _ = self.twist(theta_f, v_f, theta_b, v_b)
        half = 0.5 * w * h
        mid = self.yaw + half
        k = h * _sinc(half)
        cm, sm = math.cos(mid), math.sin(mid)
        self.x += k * (u * cm - v * sm)
        self.y += k * (u * sm + v * cm)
        self.yaw += w * h
        self.distance += math.hypot(u, v) * abs(h)

    def course(self, theta_f: float, v_f: float, theta_b: float, v_b: float) -> float:
        """Course alpha [rad] of the centroid: yaw plus sideslip atan2(v, u) (yaw at rest)."""
        u, v, _, _ = self.twist(theta_f, v_f, theta_b, v_b)
        if u == 0.0 and v == 0.0:
            return self.yaw
        return self.yaw + math.atan2(v, u)

    def front(self) -> tuple[float, float]:
        """Front wheel contact point (x, y) [m]."""
        r = 0.5 * self.wheelbase
        return self.x + r * math.cos(self.yaw), self.y + r * math.sin(self.yaw)

    def rear(self) -> tuple[float, float]:
        """Rear wheel contact point (x, y) [m]."""
        r = 0.5 * self.wheelbase
        return self.x - r * math.cos(self.yaw), self.y - r * math.sin(self.yaw)

    def get_state(self) -> dict[str, Any]:
        """JSON-safe snapshot of the state."""
        return {"x": self.x, "y": self.y, "yaw": self.yaw, "distance": self.distance}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a snapshot from :meth:`get_state`."""
        self.x, self.y = state["x"], state["y"]
        self.yaw, self.distance = state["yaw"], state["distance"]
