"""Rear-wheel feedback path tracking (Samson's law, in the form PythonRobotics uses).

Path-relative kinematics of the rear-axle centre (signs of components/README.md: e the
offset, positive left; theta = vehicle minus path heading; c the path curvature at the
projection, positive turning left; v > 0 the speed):

    e'     = v sin(theta)
    theta' = omega - c v cos(theta) / (1 - c e)

With the Lyapunov function V = e^2 + theta^2 / k_e, the yaw rate

    omega = c v cos(theta) / (1 - c e) - k_theta |v| theta - k_e v e sin(theta) / theta

gives V' = -2 k_theta |v| theta^2 / k_e <= 0 (README.md). The kinematic bicycle turns at
omega = v tan(delta) / L, so for v > 0 the speed cancels:

    tan(delta) = L [ c cos(theta) / (1 - c e) - k_theta theta - k_e e sin(theta) / theta ]

(sin(theta)/theta = 1 at theta = 0). Linearised on a straight path, in the arc length s:
e'' + k_theta e' + k_e e = 0 (natural wavenumber sqrt(k_e) [1/m], damping ratio
k_theta / (2 sqrt(k_e))); in time at speed v: e'' + k_theta v e' + k_e v^2 e = 0.
Domain: 1 - c e > 0 (the rear axle on the path's side of the centre of curvature);
outside it the law is undefined and the command is full lock towards the path,
-sign(e) delta_max, with ``in_domain`` false. The law is written for forward driving (the
speed input is not used).
"""

import math
from pathlib import Path
from typing import Any

from ..numerics.path_law import PathLaw, heading_difference, parse_path_parameter, positive
from ..numerics.paths import ReferencePath


def rear_wheel_angle(lateral_error: float, heading_error: float, curvature: float,
                     k_theta: float, k_e: float, wheelbase: float) -> float:
    """The unsaturated wheel angle [rad] of the law (module docstring), for 1 - c e > 0.

    Parameters
    ----------
    lateral_error : float
        e [m], positive left of the path.
    heading_error : float
        theta [rad] in (-pi, pi].
    curvature : float
        c [1/m] at the projection point.
    k_theta : float
        Heading gain [1/m].
    k_e : float
        Lateral gain [1/m2].
    wheelbase : float
        L [m].
    """
    e, theta, c = lateral_error, heading_error, curvature
    sinc = math.sin(theta) / theta if theta != 0.0 else 1.0
    per_length = c * math.cos(theta) / (1.0 - c * e) - k_theta * theta - k_e * e * sinc
    return math.atan(wheelbase * per_length)


def distance_poles(k_theta: float, k_e: float) -> tuple[complex, complex]:
    """Roots [1/m] of the linearised distance-domain error dynamics s^2 + k_theta s + k_e."""
    disc = complex(k_theta * k_theta - 4.0 * k_e) ** 0.5
    return (-k_theta + disc) / 2.0, (-k_theta - disc) / 2.0


class RearWheelFeedback(PathLaw):
    """Samson's rear-wheel feedback law (see the module docstring).

    Parameters
    ----------
    path : agv_core.numerics.paths.ReferencePath
        Reference path.
    k_theta : float
        Heading gain per unit distance [1/m] (> 0).
    k_e : float
        Lateral gain per unit distance squared [1/m2] (> 0).
    wheelbase, delta_max, sample_period : float
        As for :class:`agv_core.numerics.path_law.PathLaw` ([m], [rad], [s]).
    """

    def __init__(self, path: ReferencePath, k_theta: float = 1.0, k_e: float = 0.5,
                 wheelbase: float = 1.0, delta_max: float = math.pi / 4,
                 sample_period: float = 0.0) -> None:
        super().__init__(path, wheelbase, delta_max, sample_period)
        self.k_theta = positive("k_theta", k_theta, "1/m")
        self.k_e = positive("k_e", k_e, "1/m2")

    def law(self, x: float, y: float, heading: float, v: float) -> dict[str, Any]:
        p = self.project("rear", x, y)
        e, c = float(p.offset), float(p.curvature)
        theta = heading_difference(heading, p.heading)
        in_domain = 1.0 - c * e > 0.0
        if in_domain:
            delta_law = rear_wheel_angle(e, theta, c, self.k_theta, self.k_e, self.wheelbase)
        else:
            delta_law = -math.copysign(self.delta_max, e)
        return {"delta_law": delta_law, "lateral_error": e, "heading_error": theta,
                "curvature": c, "in_domain": in_domain}


def make_controller(path: str = "line", k_theta: float = 1.0, k_e: float = 0.5,
                    wheelbase: float = 1.0, delta_max: float = math.pi / 4,
                    sample_period: float = 0.0, base_dir: str | Path | None = None
                    ) -> RearWheelFeedback:
    """A :class:`RearWheelFeedback` from FMU-style parameters (``path`` a path string).

    Raises
    ------
    ParameterError
        For a bad path, gain, length, angle or period.
    """
    return RearWheelFeedback(parse_path_parameter(path, base_dir), k_theta, k_e, wheelbase,
                             delta_max, sample_period)
