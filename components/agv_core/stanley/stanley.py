"""Stanley path tracking (Hoffmann, Thrun et al. 2007), on the front-wheel centre.

Front-wheel centre F = R + L (cos psi, sin psi) of the rear-axle centre R, heading psi,
wheelbase L, speed v. With F's signed offset e from the path (positive left), the heading
error theta = psi - psi_path at F's projection (positive when pointing left of the path),
the law in this project's signs (components/README.md: a positive wheel angle steers left)
is

    delta = -theta - atan(k e / (k_soft + max(v, 0))),

saturated at +/- delta_max. The first term turns the wheel onto the path direction, the
second steers it towards the path at an angle that tends to 90 deg for large e. For the
front wheel, which moves along its own plane at speed v_f, de/dt = v_f sin(theta + delta)
= -v_f sin(atan(k e / (k_soft + v))): for small e, de/dt = -(v_f k / (k_soft + v)) e, an
exponential decay of rate k when k_soft << v (README.md has the derivation and the test).
The speed in the law is the rear-axle speed v of this project's vehicles (v_f = v /
cos(delta); the two differ by 1 % at delta = 8 deg).
"""

import math
from pathlib import Path
from typing import Any

from ..numerics.path_law import PathLaw, heading_difference, parse_path_parameter, positive
from ..numerics.paths import ReferencePath


def stanley_angle(lateral_error: float, heading_error: float, k: float, k_soft: float,
                  v: float) -> float:
    """The unsaturated Stanley wheel angle [rad] (module docstring).

    Parameters
    ----------
    lateral_error : float
        e [m] of the front-wheel centre, positive left of the path.
    heading_error : float
        theta [rad], vehicle minus path heading, in (-pi, pi].
    k : float
        Cross-track gain [1/s].
    k_soft : float
        Softening speed [m/s] (> 0).
    v : float
        Speed [m/s]; reversing counts as standstill.
    """
    return -heading_error - math.atan(k * lateral_error / (k_soft + max(v, 0.0)))


def straight_line_rate(k: float, k_soft: float, v: float) -> float:
    """Decay rate [1/s] of a small front-wheel offset on a straight path,
    v k / (k_soft + v) (README.md)."""
    return v * k / (k_soft + v)


class Stanley(PathLaw):
    """Stanley's law (see the module docstring).

    Parameters
    ----------
    path : agv_core.numerics.paths.ReferencePath
        Reference path.
    k : float
        Cross-track gain [1/s] (> 0).
    k_soft : float
        Softening speed [m/s] (> 0): keeps the law finite at standstill.
    wheelbase, delta_max, sample_period : float
        As for :class:`agv_core.numerics.path_law.PathLaw` ([m], [rad], [s]).
    """

    def __init__(self, path: ReferencePath, k: float = 2.5, k_soft: float = 1.0,
                 wheelbase: float = 1.0, delta_max: float = math.pi / 4,
                 sample_period: float = 0.0) -> None:
        super().__init__(path, wheelbase, delta_max, sample_period)
        self.k = positive("k", k, "1/s")
        self.k_soft = positive("k_soft", k_soft, "m/s")

    def law(self, x: float, y: float, heading: float, v: float) -> dict[str, Any]:
        xf = x + self.wheelbase * math.cos(heading)
        yf = y + self.wheelbase * math.sin(heading)
        p = self.project("front", xf, yf)
        e = float(p.offset)
        theta = heading_difference(heading, p.heading)
        return {"delta_law": stanley_angle(e, theta, self.k, self.k_soft, v),
                "lateral_error": e, "heading_error": theta, "x_front": xf, "y_front": yf}


def make_controller(path: str = "line", k: float = 2.5, k_soft: float = 1.0,
                    wheelbase: float = 1.0, delta_max: float = math.pi / 4,
                    sample_period: float = 0.0, base_dir: str | Path | None = None
                    ) -> Stanley:
    """A :class:`Stanley` from FMU-style parameters (``path`` a path string).

    Raises
    ------
    ParameterError
        For a bad path, gain, speed, length, angle or period.
    """
    return Stanley(parse_path_parameter(path, base_dir), k, k_soft, wheelbase, delta_max,
                   sample_period)
