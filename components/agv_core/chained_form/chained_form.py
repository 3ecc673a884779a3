"""Chained-form (Samson) path-following steering law (seed 002, eqs 10-24).

Path-relative kinematics of the rear-axle centre R of a kinematic bicycle (wheelbase
``l``, speed ``v > 0``, front-wheel angle ``delta``), relative to a path with curvature
``c(s)``; signs as in components/README.md (``y`` positive left of the path, ``theta`` =
vehicle heading minus path heading, ``c`` positive for a left turn):

    s'     = v cos(theta) / (1 - y c)
    y'     = v sin(theta)
    theta' = v tan(delta) / l - c v cos(theta) / (1 - y c)

Chained transform (seed 002 eq 19): a1 = s, a2 = y, a3 = (1 - y c(s)) tan(theta). With
derivatives taken with respect to a1 = s (written ``d/ds``) the system becomes the chained
system  da2/ds = a3,  da3/ds = m3, and the virtual control (eq 21)

    m3 = -Kd a3 - Kp a2

gives the linear distance-domain error dynamics (eq 22) a2'' + Kd a2' + Kp a2 = 0, which
does not contain the speed. Solving da3/ds = m3 for the steering angle (eq 23, derived in
components/README.md) gives, with ``dc = dc/ds``:

    tan(delta) = l [ cos(theta)^3 / (1 - y c)^2 * ( m3 + dc y tan(theta)
                                                    + c (1 - y c) tan(theta)^2 )
                     + c cos(theta) / (1 - y c) ]

valid for |theta| < pi/2 and y c < 1. The steering angle is then saturated at
``+/- delta_max``.
"""

import math
from pathlib import Path
from typing import Any, cast

from ..errors import ParameterError
from ..numerics import paths
from ..numerics.angles import wrap_angle
from ..numerics.finite import finite as _finite
from ..numerics.sampling import SampleHold

#: Sources of the path-relative state understood by :class:`ChainedFormController`.
SOURCES = ("sensor", "pose")


def chained_coordinates(lateral_error: float, heading_error: float, curvature: float
                        ) -> tuple[float, float]:
    """Chained-form states a2 [m] and a3 [1] (seed 002 eq 19).

    Parameters
    ----------
    lateral_error : float
        y [m], positive left of the path.
    heading_error : float
        theta [rad], vehicle heading minus path heading.
    curvature : float
        c(s) [1/m] of the path at the projection point, positive turning left.

    Returns
    -------
    tuple of float
        (a2, a3) = (y, (1 - y c) tan(theta)) [m], [1].
    """
    return lateral_error, (1.0 - lateral_error * curvature) * math.tan(heading_error)


def distance_derivatives(lateral_error: float, heading_error: float, curvature: float,
                         delta: float, wheelbase: float) -> tuple[float, float]:
    """Path-arc-length derivatives of the path-relative state (model divided by s').

    Parameters
    ----------
    lateral_error, heading_error, curvature : float
        y [m], theta [rad], c [1/m].
    delta : float
        Front-wheel angle [rad].
    wheelbase : float
        l [m].

    Returns
    -------
    tuple of float
        (dy/ds [1], dtheta/ds [1/m]) for |theta| < pi/2 and y c < 1.
    """
    scale = 1.0 - lateral_error * curvature
    dy = scale * math.tan(heading_error)
    dtheta = math.tan(delta) * scale / (wheelbase * math.cos(heading_error)) - curvature
    return dy, dtheta


def steering_law(lateral_error: float, heading_error: float, curvature: float,
                 curvature_rate: float, Kd: float, Kp: float, wheelbase: float,
                 delta_max: float) -> tuple[float, float, bool]:
    """Unsaturated chained-form steering angle (seed 002 eq 23), with its domain check.

    Parameters
    ----------
    lateral_error : float
        y [m], positive left of the path.
    heading_error : float
        theta [rad], vehicle heading minus path heading, in (-pi, pi].
    curvature : float
        c [1/m] at the projection point.
    curvature_rate : float
        dc/ds [1/m2] at the projection point.
    Kd : float
        Derivative gain per unit distance [1/m].
    Kp : float
        Proportional gain per unit distance squared [1/m2].
    wheelbase : float
        l [m].
    delta_max : float
        Saturation [rad]; used only for the out-of-domain command.

    Returns
    -------
    tuple
        (delta_law [rad] in (-pi/2, pi/2), m3 [1/m], in_domain [bool]). Outside the
        domain (|theta| >= pi/2 or y c >= 1) the law is undefined and ``delta_law`` is
        full lock towards the path direction: -sign(theta) delta_max when |theta| >=
        pi/2, else -sign(y) delta_max; m3 is then NaN-free but meaningless (0).
    """
    y, theta, c, dc = lateral_error, heading_error, curvature, curvature_rate
    cos_t = math.cos(theta)
    scale = 1.0 - y * c
    if not cos_t > 0.0:
        return -math.copysign(delta_max, theta), 0.0, False
    if not scale > 0.0:
        return -math.copysign(delta_max, y), 0.0, False
    tan_t = math.tan(theta)
    a3 = scale * tan_t
    m3 = -Kd * a3 - Kp * y
    tan_delta = wheelbase * (cos_t ** 3 / scale ** 2 * (m3 + dc * y * tan_t
                                                        + c * scale * tan_t ** 2)
                             + c * cos_t / scale)
    return math.atan(tan_delta), m3, True


class ChainedFormController:
    """Chained-form path-following controller with saturation and sample-and-hold.

    Parameters
    ----------
    Kd : float
        Gain on a3 per unit distance [1/m] (> 0). Seed 002: 0.6.
    Kp : float
        Gain on a2 per unit distance squared [1/m2] (> 0). Seed 002: 0.09.
    wheelbase : float
        l [m], rear-axle centre to front-wheel centre (> 0).
    delta_max : float
        Steering saturation [rad], 0 < delta_max < pi/2. Seed 002: 45 deg.
    sample_period : float
        Controller sample period [s]; 0 computes on every call (every step). Samples at
        multiples of it, by the rule of :mod:`agv_core.numerics.sampling` (an instant inside a
        communication step is sampled from the inputs held over it, committed by
        :meth:`step` / :meth:`step_from_pose`).
    path : object, optional
        For :meth:`update_from_pose`: a reference path with ``project(x, y, s_hint)``
        returning an object with ``s, heading, curvature, curvature_rate, offset``
        (agv_core.numerics.paths.ReferencePath).
    """

    def __init__(self, Kd: float = 0.6, Kp: float = 0.09, wheelbase: float = 2.0,
                 delta_max: float = math.pi / 4, sample_period: float = 0.0,
                 path: paths.ReferencePath | None = None) -> None:
        for name, value in (("Kd", Kd), ("Kp", Kp), ("wheelbase", wheelbase),
                            ("delta_max", delta_max), ("sample_period", sample_period)):
            _finite(name, value)
        if not Kd > 0.0:
            raise ParameterError("Kd", f"must be > 0 for a stable a2 loop, got {Kd}")
        if not Kp > 0.0:
            raise ParameterError("Kp", f"must be > 0 for a stable a2 loop, got {Kp}")
        if not wheelbase > 0.0:
            raise ParameterError("wheelbase", f"must be a positive length in m, got {wheelbase}")
        if not 0.0 < delta_max < math.pi / 2:
            raise ParameterError("delta_max", f"must be in (0, pi/2) rad, got {delta_max}")
        if not sample_period >= 0.0:
            raise ParameterError("sample_period", f"must be >= 0 s, got {sample_period}")
        self.Kd = float(Kd)
        self.Kp = float(Kp)
        self.wheelbase = float(wheelbase)
        self.delta_max = float(delta_max)
        self.sample_period = float(sample_period)
        self.path = path
        self._hold = SampleHold(self.sample_period)
        self._s_hint: float | None = None
        self.outputs: dict[str, float] = self._evaluate(0.0, 0.0, 0.0, 0.0)

    # ------------------------------------------------------------------ law
    def _evaluate(self, lateral_error: float, heading_error: float, curvature: float,
                  curvature_rate: float, s: float = 0.0) -> dict[str, float]:
        delta_law, m3, in_domain = steering_law(
            lateral_error, heading_error, curvature, curvature_rate, self.Kd, self.Kp,
            self.wheelbase, self.delta_max)
        delta = min(max(delta_law, -self.delta_max), self.delta_max)
        a2, a3 = chained_coordinates(lateral_error, heading_error, curvature)
        if not in_domain:
            a3 = 0.0
        return {"delta": delta, "delta_law": delta_law, "m3": m3, "a2": a2, "a3": a3,
                "s": s, "lateral_error": lateral_error, "heading_error": heading_error,
                "saturated": delta != delta_law, "in_domain": in_domain}

    def update(self, t: float, lateral_error: float, heading_error: float, curvature: float,
               curvature_rate: float) -> float:
        """Steering angle [rad] at time ``t`` [s] from the path-relative state.

        Parameters
        ----------
        t : float
            Time [s] (selects the sample instant when ``sample_period > 0``).
        lateral_error : float
            y [m], positive left of the path.
        heading_error : float
            theta [rad]; wrapped to (-pi, pi] here.
        curvature : float
            c [1/m] at the projection point.
        curvature_rate : float
            dc/ds [1/m2] at the projection point.

        Returns
        -------
        float
            Saturated steering angle delta [rad]; all outputs are in ``self.outputs``.
        """
        self.outputs = self._hold.output(t, self._state_inputs(
            lateral_error, heading_error, curvature, curvature_rate), self._evaluate)
        return self.outputs["delta"]

    @staticmethod
    def _state_inputs(lateral_error: float, heading_error: float, curvature: float,
                      curvature_rate: float) -> tuple[float, float, float, float]:
        return (float(lateral_error), wrap_angle(heading_error), float(curvature),
                float(curvature_rate))

    def step(self, t: float, h: float, lateral_error: float, heading_error: float,
             curvature: float, curvature_rate: float) -> None:
        """Commit the samples of the step from ``t`` to ``t + h`` [s] (inputs held).

        The sampling rule is :mod:`agv_core.numerics.sampling`'s: an instant inside the step is
        sampled from these held inputs.
        """
        self._hold.step(t, h, self._state_inputs(lateral_error, heading_error, curvature,
                                                  curvature_rate), self._evaluate)
        self.outputs = self._hold.value if self._hold.value is not None else self.outputs

    def _from_pose(self, x: float, y: float, heading: float) -> dict[str, float]:
        path = cast(paths.ReferencePath, self.path)  # checked by the caller
        p = path.project(x, y, s_hint=self._s_hint)
        self._s_hint = float(p.s)
        return self._evaluate(float(p.offset), paths.heading_error(heading, float(p.heading)),
                              float(p.curvature), float(p.curvature_rate), s=float(p.s))

    def update_from_pose(self, t: float, x: float, y: float, heading: float) -> float:
        """Steering angle [rad] from the rear-axle-centre pose, projected on ``path``.

        Parameters
        ----------
        t : float
            Time [s].
        x, y : float
            Rear-axle centre [m].
        heading : float
            Vehicle heading [rad], counter-clockwise from +x.

        Returns
        -------
        float
            Saturated steering angle delta [rad].
        """
        if self.path is None:
            raise ValueError("update_from_pose needs a path")
        self.outputs = self._hold.output(t, (float(x), float(y), float(heading)),
                                         self._from_pose)
        return self.outputs["delta"]

    def step_from_pose(self, t: float, h: float, x: float, y: float, heading: float
                       ) -> None:
        """:meth:`step` for the pose inputs (rear-axle centre [m], heading [rad])."""
        if self.path is None:
            raise ValueError("step_from_pose needs a path")
        self._hold.step(t, h, (float(x), float(y), float(heading)), self._from_pose)
        self.outputs = self._hold.value if self._hold.value is not None else self.outputs

    # ------------------------------------------------------------------ state
    def get_state(self) -> dict[str, Any]:
        """JSON-safe snapshot: the held sample, its outputs and the projection hint."""
        return {"hold": self._hold.get_state(), "s_hint": self._s_hint,
                "outputs": dict(self.outputs)}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a snapshot from :meth:`get_state`."""
        self._hold.set_state(state["hold"])
        self._s_hint = state["s_hint"]
        self.outputs = dict(state["outputs"])


def path_from_spec(spec: str, base_dir: str | Path | None = None) -> paths.ReferencePath:
    """Parse a path string with :func:`agv_core.numerics.paths.parse_path`.

    Parameters
    ----------
    spec : str
        Path string, e.g. ``"sine:amplitude=3,wavelength=30"``.
    base_dir : str or pathlib.Path, optional
        Folder for relative file names in ``spec``.

    Returns
    -------
    agv_core.numerics.paths.ReferencePath
    """
    return paths.parse_path(spec, base_dir=base_dir)


def make_controller(Kd: float = 0.6, Kp: float = 0.09, wheelbase: float = 2.0,
                    delta_max: float = math.pi / 4, sample_period: float = 0.0,
                    source: str = "sensor", path: str = "",
                    base_dir: str | Path | None = None) -> ChainedFormController:
    """Build a :class:`ChainedFormController` from FMU-style parameters.

    Parameters
    ----------
    Kd, Kp, wheelbase, delta_max, sample_period : float
        As for :class:`ChainedFormController` ([1/m], [1/m2], [m], [rad], [s]).
    source : str
        ``"sensor"`` (path-relative state given directly) or ``"pose"`` (rear-axle pose
        projected on ``path``).
    path : str
        Path string for ``source="pose"`` (ignored for ``"sensor"``).
    base_dir : str or pathlib.Path, optional
        Folder for relative file names in ``path``.

    Returns
    -------
    ChainedFormController

    Raises
    ------
    ParameterError
        For a bad gain, length, angle, period, source or path.
    """
    if source not in SOURCES:
        raise ParameterError("source", f"must be one of {SOURCES}, got '{source}'")
    reference = None
    if source == "pose":
        if not path:
            raise ParameterError("path", "source 'pose' needs a path string")
        try:
            reference = path_from_spec(path, base_dir=base_dir)
        except ParameterError:
            raise
        except Exception as error:  # noqa: BLE001 - any parse failure is a bad parameter
            raise ParameterError("path", f"cannot parse '{path}': {error}") from error
    return ChainedFormController(Kd, Kp, wheelbase, delta_max, sample_period, reference)
