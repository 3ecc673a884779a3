"""The shared frame of the pose-driven path-tracking laws (pure pursuit, Stanley,
rear-wheel feedback): rear-axle pose and speed in, steered-wheel angle out.

A law subclasses :class:`PathLaw` and implements :meth:`PathLaw.law`, a static map from
the rear-axle pose ``(x, y, heading)`` and the speed ``v`` to a dict holding at least
``delta_law`` (the unsaturated wheel angle [rad]) and ``lateral_error`` /
``heading_error`` (the errors the law regulates). This frame adds what every law shares:
the refusal of non-finite inputs (a NaN pose must not become a wheel angle, least of all
full lock), the saturation at ``+/- delta_max``, the sample-and-hold of
:mod:`agv_core.numerics.sampling` and a JSON-safe state (the held sample and the
projection hints).

Signs as in components/README.md: lateral deviation positive left of the path, heading
error = vehicle minus path heading, wheel angle positive left.
"""

import math
from pathlib import Path
from typing import Any

from ..errors import ParameterError
from . import paths
from .angles import wrap_angle
from .finite import finite
from .sampling import SampleHold

#: the inputs of every law, in order: rear-axle centre [m], heading [rad], speed [m/s]
INPUTS = ("x", "y", "heading", "v")


def refuse_non_finite(x: float, y: float, heading: float, v: float) -> None:
    """Raise FloatingPointError naming the first non-finite input; else nothing.

    The laws take atan, sin and comparisons of their inputs, each of which turns a NaN
    into a plausible-looking number or a saturated command; the input is refused instead.
    """
    if not math.isfinite(x + y + heading + v):  # finite iff every term is (or overflow)
        for name, value in zip(INPUTS, (x, y, heading, v)):
            if not math.isfinite(value):
                raise FloatingPointError(f"input '{name}' is {value}: a path-tracking law "
                                         "needs a finite pose and speed")
        raise FloatingPointError(f"inputs x={x}, y={y}, heading={heading}, v={v} overflow")


class PathLaw:
    """A static steering law on a reference path, saturated and sampled.

    Parameters
    ----------
    path : agv_core.numerics.paths.ReferencePath
        The reference path (``project``, ``point``).
    wheelbase : float
        L [m], rear-axle centre to front-wheel centre (> 0).
    delta_max : float
        Steering saturation [rad], 0 < delta_max < pi/2.
    sample_period : float
        Controller sample period [s] (>= 0; 0: every call), the rule of
        :mod:`agv_core.numerics.sampling`.
    """

    def __init__(self, path: paths.ReferencePath, wheelbase: float = 1.0,
                 delta_max: float = math.pi / 4, sample_period: float = 0.0) -> None:
        for name, value in (("wheelbase", wheelbase), ("delta_max", delta_max),
                            ("sample_period", sample_period)):
            finite(name, value)
        if not wheelbase > 0.0:
            raise ParameterError("wheelbase", f"must be a positive length in m, got {wheelbase}")
        if not 0.0 < delta_max < math.pi / 2:
            raise ParameterError("delta_max", f"must be in (0, pi/2) rad, got {delta_max}")
        if not sample_period >= 0.0:
            raise ParameterError("sample_period", f"must be >= 0 s, got {sample_period}")
        self.path = path
        self.wheelbase = float(wheelbase)
        self.delta_max = float(delta_max)
        self.sample_period = float(sample_period)
        self._hold = SampleHold(self.sample_period)
        self._hints: dict[str, float] = {}
        self.outputs: dict[str, float] | None = None  # the numbers of the last sample

    # ------------------------------------------------------------------ to implement
    def law(self, x: float, y: float, heading: float, v: float) -> dict[str, Any]:
        """The unsaturated law: a dict with ``delta_law``, ``lateral_error``,
        ``heading_error`` and any diagnostics (override)."""
        raise NotImplementedError

    # ------------------------------------------------------------------ helpers
    def project(self, key: str, x: float, y: float) -> paths.PathProjection:
        """The projection of (x, y) [m] on the path, searched near the last one of ``key``
        (one hint per tracked point: the rear axle and the front wheel differ)."""
        p = self.path.project(x, y, s_hint=self._hints.get(key))
        self._hints[key] = float(p.s)
        return p

    def _evaluate(self, x: float, y: float, heading: float, v: float) -> dict[str, Any]:
        out = self.law(x, y, heading, v)
        delta_law = out["delta_law"]
        delta = min(max(delta_law, -self.delta_max), self.delta_max)
        out["delta"] = delta
        out["saturated"] = delta != delta_law
        return out

    @staticmethod
    def _inputs(x: float, y: float, heading: float, v: float
                ) -> tuple[float, float, float, float]:
        x, y, heading, v = float(x), float(y), float(heading), float(v)
        refuse_non_finite(x, y, heading, v)
        return x, y, heading, v

    def pose_from_path(self, s: float, lateral_error: float, heading_error: float
                       ) -> tuple[float, float, float]:
        """The rear-axle pose (x, y [m], heading [rad]) that a path-relative measurement
        describes: the path point at arc length ``s`` [m], ``lateral_error`` [m] to its
        left, heading = path heading + ``heading_error`` [rad] (a sensor's s, e, theta of
        the rear-axle centre, e.g. AgvVisionSensor's with its latency).

        Raises
        ------
        FloatingPointError
            For a non-finite input (named s_meas, e_meas, theta_meas as in the FMUs).
        """
        s, e, theta = float(s), float(lateral_error), float(heading_error)
        for name, value in (("s_meas", s), ("e_meas", e), ("theta_meas", theta)):
            if not math.isfinite(value):
                raise FloatingPointError(f"input '{name}' is {value}: a path-tracking law "
                                         "needs a finite measurement")
        p = self.path.point(s)
        heading = float(p.heading)
        return (float(p.x) - e * math.sin(heading), float(p.y) + e * math.cos(heading),
                heading + theta)

    # ------------------------------------------------------------------ interface
    def update(self, t: float, x: float, y: float, heading: float, v: float) -> float:
        """Saturated wheel angle [rad] at time ``t`` [s] from the rear-axle pose (x, y [m],
        heading [rad]) and the speed ``v`` [m/s]; every output in ``self.outputs``.

        Raises
        ------
        FloatingPointError
            For a non-finite input.
        """
        self.outputs = self._hold.output(t, self._inputs(x, y, heading, v), self._evaluate)
        return self.outputs["delta"]

    def step(self, t: float, h: float, x: float, y: float, heading: float, v: float
             ) -> None:
        """Commit the samples of the step from ``t`` to ``t + h`` [s], inputs held."""
        self._hold.step(t, h, self._inputs(x, y, heading, v), self._evaluate)
        if self._hold.value is not None:
            self.outputs = self._hold.value

    def get_state(self) -> dict[str, Any]:
        """JSON-safe snapshot: the held sample, its outputs and the projection hints."""
        return {"hold": self._hold.get_state(), "hints": dict(self._hints),
                "outputs": None if self.outputs is None else dict(self.outputs)}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a snapshot from :meth:`get_state`."""
        self._hold.set_state(state["hold"])
        self._hints = dict(state["hints"])
        self.outputs = None if state["outputs"] is None else dict(state["outputs"])


def heading_difference(vehicle_heading: float, path_heading: float) -> float:
    """Vehicle minus path heading [rad], wrapped exactly to (-pi, pi]."""
    return wrap_angle(vehicle_heading - path_heading)


def positive(name: str, value: float, unit: str) -> float:
    """``value`` as a float if finite and > 0; else ParameterError naming ``name``."""
    finite(name, value)
    if not value > 0.0:
        raise ParameterError(name, f"must be > 0 {unit}, got {value}")
    return float(value)


def non_negative(name: str, value: float, unit: str) -> float:
    """``value`` as a float if finite and >= 0; else ParameterError naming ``name``."""
    finite(name, value)
    if not value >= 0.0:
        raise ParameterError(name, f"must be >= 0 {unit}, got {value}")
    return float(value)


def parse_path_parameter(spec: str, base_dir: str | Path | None = None
                         ) -> paths.ReferencePath:
    """The path of an FMU's ``path`` parameter, every parse failure a ParameterError."""
    if not spec:
        raise ParameterError("path", "a path string is needed, e.g. 'line' or "
                             "'circle:radius=10'")
    try:
        return paths.parse_path(spec, base_dir=base_dir)
    except ParameterError:
        raise
    except Exception as error:  # noqa: BLE001 - any parse failure is a bad parameter
        raise ParameterError("path", f"cannot parse '{spec}': {error}") from error
