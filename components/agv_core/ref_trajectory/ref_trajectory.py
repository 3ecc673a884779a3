"""Time-parameterised reference trajectories of seed 001 (circle and S-curve).

A trajectory is a path of :mod:`agv_core.numerics.paths` travelled at constant speed v_r [m/s]:
s(t) = s_start + v_r t. At every time it gives the reference pose (X_r, Y_r, heading
alpha_r), the speed v_r, the curvature kappa_r(s) [1/m] (positive turning left) and
the yaw rate omega_r = kappa_r v_r [rad/s].

``circle``
    Seed 001 section 3.1: v_r = 0.4 m/s, omega_r = 0.074 rad/s, so radius
    rho = v_r / omega_r = 5.405 m, counter-clockwise from (0, 0) with heading 0:
    X_r = rho sin(omega_r t), Y_r = rho (1 - cos(omega_r t)), alpha_r = omega_r t
    (notes-001-003.md section 1.7). A negative omega_r turns clockwise.
``scurve``
    Seed 001 section 3.2: "a straight line combined with a large-curvature sine"; the
    sine's formula is lost. Our choice (notes section 1.7): the straight starts at
    (0, 0) and is tangent to y = A sin(2 pi (x - x0) / W) at its inflection point x0,
    so heading and curvature are continuous; the straight's length is set so that the
    first crest of the sine (first curvature maximum, |kappa| = A (2 pi / W)^2) is
    reached at ``peak_time`` (33.7 s in the paper). Defaults A = 1.5 m, W = 12 m,
    v_r = 0.4 m/s: straight 10.06 m at 38.1 deg, kappa_max = 0.411 1/m. The sine and its
    straight tangent are :func:`agv_core.numerics.paths.sine_path`.
"""

import math
from typing import TYPE_CHECKING, Any, cast

from ..errors import ParameterError
from ..numerics.paths import CirclePath, GraphPath, sine_path

if TYPE_CHECKING:
    from ..numerics.paths import _SinePiece

KINDS = ("circle", "scurve")


class RefSample(dict[str, float]):
    """One reference sample: keys x, y, heading [m, m, rad], v [m/s], omega [rad/s],
    curvature [1/m], s [m] (arc length from the trajectory's start)."""


class RefTrajectory:
    """Reference trajectory (see the module docstring).

    Parameters
    ----------
    kind : {"circle", "scurve"}
    speed : float
        v_r [m/s], > 0.
    omega : float
        omega_r [rad/s] of the circle, != 0 (circle only).
    amplitude, wavelength : float
        A [m] (!= 0) and W [m] (> 0) of the S-curve's sine.
    peak_time : float
        Time [s] at which the S-curve reaches its first curvature maximum, > 0; the
        straight length v_r peak_time - s_crest must be >= 0.
    """

    def __init__(self, kind: str = "circle", speed: float = 0.4, omega: float = 0.074,
                 amplitude: float = 1.5, wavelength: float = 12.0, peak_time: float = 33.7
                 ) -> None:
        if kind not in KINDS:
            raise ParameterError("kind", f"must be one of {KINDS}, got '{kind}'")
        if not (math.isfinite(speed) and speed > 0.0):
            raise ParameterError("speed", f"must be > 0 m/s, got {speed}")
        self.kind = kind
        self.speed = float(speed)
        if kind == "circle":
            if not (math.isfinite(omega) and omega != 0.0):
                raise ParameterError("omega", f"must be finite and non-zero, got {omega}")
            self.omega = float(omega)
            radius = self.speed / abs(self.omega)
            self.path: CirclePath | GraphPath = CirclePath(
                radius, direction="ccw" if omega > 0 else "cw")
            self.s_start = 0.0
            self.straight = 0.0
        else:
            if not (math.isfinite(amplitude) and amplitude != 0.0):
                raise ParameterError("amplitude", f"must be finite and non-zero, got "
                                                  f"{amplitude}")
            if not (math.isfinite(wavelength) and wavelength > 0.0):
                raise ParameterError("wavelength", f"must be > 0 m, got {wavelength}")
            if not (math.isfinite(peak_time) and peak_time > 0.0):
                raise ParameterError("peak_time", f"must be > 0 s, got {peak_time}")
            k = 2.0 * math.pi / wavelength
            heading = math.atan(amplitude * k)
            crest = sine_path(amplitude, wavelength).pieces[1].s_of_x(wavelength / 4.0)
            straight = self.speed * peak_time - crest
            if straight < 0.0:
                raise ParameterError("peak_time", f"{peak_time} s at {speed} m/s is shorter "
                                                  f"than the sine's rise to its crest "
                                                  f"({crest:.3f} m)")
            self.straight = straight
            self.path = sine_path(amplitude, wavelength, x0=straight * math.cos(heading),
                                  y0=straight * math.sin(heading))
            self.s_start = -straight
            self.omega = 0.0

    def at(self, t: float) -> RefSample:
        """The reference at time ``t`` [s] (a :class:`RefSample`)."""
        s = self.s_start + self.speed * float(t)
        p = self.path.point(s)
        return RefSample(x=p.x, y=p.y, heading=p.heading, v=self.speed,
                         omega=p.curvature * self.speed, curvature=p.curvature,
                         s=s - self.s_start)

    def peak_time(self) -> float | None:
        """Time [s] of the first curvature maximum (S-curve), None for the circle."""
        if self.kind == "circle":
            return None
        sine = cast("_SinePiece", cast(GraphPath, self.path).pieces[1])  # the S-curve's sine
        crest = sine.s_of_x(sine.a + sine.wavelength / 4.0)
        return (crest - self.s_start) / self.speed

    def get_state(self) -> dict[str, Any]:
        """No state: the reference is a function of time (JSON-safe empty snapshot)."""
        return {}

    def set_state(self, state: dict[str, Any]) -> None:
        """Nothing to restore."""
