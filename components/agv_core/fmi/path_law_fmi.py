"""The FMI adapter shared by the baseline path-tracking laws (pure pursuit, Stanley,
rear-wheel feedback; cores on :class:`agv_core.numerics.path_law.PathLaw`).

The three FMUs have the same inputs (the rear-axle pose ``x``, ``y``, ``heading``, and
where the law uses the speed, ``dv`` added to the parameter ``speed`` as in the vehicles'
``v0 + dv``), the same parameters ``path``, ``wheelbase``, ``delta_max``,
``sample_period``, and the same common outputs (``delta`` for the steering actuator's
angle mode or the vehicle's ``alpha``, ``delta_law``, ``lateral_error``,
``heading_error``, ``saturated``), so a manifest swaps one for another. A slave script
subclasses :class:`PathLawSlave`, sets ``uses_speed``, declares its gains in
``declare_gains``, builds its core in ``make_core`` and may add outputs in
``declare_extra_outputs`` / ``publish_extra``. With ``source = "sensor"`` the pose is
rebuilt from a path-relative measurement of the rear axle (``s_meas``, ``e_meas``,
``theta_meas``, e.g. AgvVisionSensor's outputs, latency and all) on the same path.
"""

from typing import Any

from ..errors import ParameterError
from .fmi_slave import AgvSlave, Boolean, DefaultExperiment, String

#: where the pose comes from: the inputs x, y, heading, or a path-relative measurement
SOURCES = ("pose", "sensor")

#: A reference experiment for every law: default path 'line' (the x axis), the rear axle
#: held 0.1 m left of it from the start and turned 0.05 rad left at 0.5 s; 1 s at 10 ms.
REFERENCE_EXPERIMENT = DefaultExperiment(start_time=0.0, stop_time=1.0, step_size=0.01)
REFERENCE_INPUTS = {"y": ((0.0, 0.1),), "heading": ((0.0, 0.0), (0.5, 0.05))}


class PathLawSlave(AgvSlave):
    """Common FMU interface of the baseline path-tracking laws."""

    #: True when the law reads the speed (then ``speed`` and ``dv`` are declared)
    uses_speed = True
    default_experiment = REFERENCE_EXPERIMENT
    reference_inputs = REFERENCE_INPUTS

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.input("x", 0.0, "m", "x of the rear-axle centre")
        self.input("y", 0.0, "m", "y of the rear-axle centre")
        self.input("heading", 0.0, "rad", "Vehicle heading, counter-clockwise from x, "
                   "continuous")
        self.input("s_meas", 0.0, "m", "Arc length of the rear axle's projection (source "
                   "'sensor', e.g. AgvVisionSensor.s)")
        self.input("e_meas", 0.0, "m", "Lateral deviation of the rear-axle centre, positive "
                   "left (source 'sensor', e.g. AgvVisionSensor.lateral_error)")
        self.input("theta_meas", 0.0, "rad", "Heading error of the vehicle, vehicle minus path "
                   "(source 'sensor', e.g. AgvVisionSensor.heading_error)")
        inputs: tuple[str, ...] = ("x", "y", "heading", "s_meas", "e_meas", "theta_meas")
        if self.uses_speed:
            self.input("dv", 0.0, "m/s", "Speed added to the parameter speed (the "
                       "vehicle's v0 + dv)")
            inputs += ("dv",)
        self.depends = inputs
        defaults = self.defaults()
        self.parameter("path", defaults["path"], None,
                       "Reference path string (agv_core.numerics.paths.parse_path), e.g. "
                       "'sine:amplitude=2,wavelength=18.84955592153876'", kind=String)
        self.parameter("wheelbase", defaults["wheelbase"], "m",
                       "Wheelbase L, rear-axle centre to front-wheel centre")
        self.parameter("delta_max", defaults["delta_max"], "rad",
                       "Steering saturation of delta (45 deg)")
        self.parameter("sample_period", defaults["sample_period"], "s",
                       "Controller sample period, output held between samples; 0 = every "
                       "step")
        self.parameter("source", "pose", None,
                       "'pose': inputs x, y, heading; 'sensor': the pose rebuilt from s_meas, "
                       "e_meas, theta_meas on the same path (a sensor's latency then delays "
                       "it)", kind=String)
        if self.uses_speed:
            self.parameter("speed", 1.0, "m/s", "Constant part of the rear-axle speed the law "
                           "uses (set it to the vehicle's v0)")
        self.declare_gains(defaults)
        self.output("delta", "rad", "Steered-wheel angle command, saturated at "
                    "+/-delta_max, positive left; for the actuator's alpha_ref (angle mode) "
                    "or the vehicle's alpha", depends_on=inputs)
        self.output("delta_law", "rad", "Unsaturated wheel angle of the law",
                    depends_on=inputs)
        self.output("lateral_error", "m", "Offset of the point the law regulates from the "
                    "path, positive left", depends_on=inputs)
        self.output("heading_error", "rad", "Vehicle minus path heading at that point's "
                    "projection, wrapped to (-pi, pi]", depends_on=inputs)
        self.output("saturated", None, "True while delta is limited by delta_max",
                    depends_on=inputs, kind=Boolean, start=False)
        self.declare_extra_outputs()

    # ------------------------------------------------------------------ hooks
    def defaults(self) -> dict[str, Any]:
        """The core's parameter defaults by name (override)."""
        raise NotImplementedError

    def make_core(self) -> Any:
        if self.source not in SOURCES:
            raise ParameterError("source", f"must be one of {SOURCES}, got '{self.source}'")
        return self.make_law()

    def make_law(self) -> Any:
        """Build the core from the parameters (override)."""
        raise NotImplementedError

    def declare_gains(self, defaults: dict[str, Any]) -> None:
        """Declare the law's own parameters (override)."""

    def declare_extra_outputs(self) -> None:
        """Declare outputs only this law has (override)."""

    def publish_extra(self, out: dict[str, Any]) -> None:
        """Copy the extra outputs from the core's result ``out`` (override)."""

    # ------------------------------------------------------------------ FMI
    def _speed(self) -> float:
        return self.speed + self.dv if self.uses_speed else 0.0

    def _pose(self) -> tuple[float, float, float]:
        if self.source == "sensor":
            pose: tuple[float, float, float] = self.core.pose_from_path(
                self.s_meas, self.e_meas, self.theta_meas)
            return pose
        return self.x, self.y, self.heading

    def advance(self, t: float, h: float) -> None:
        # a static law; a sample instant inside this step is taken from the held inputs
        self.core.step(t, h, *self._pose(), self._speed())

    def publish(self) -> None:
        self.core.update(self.time, *self._pose(), self._speed())
        out = self.core.outputs
        self.delta, self.delta_law = out["delta"], out["delta_law"]
        self.lateral_error, self.heading_error = out["lateral_error"], out["heading_error"]
        self.saturated = out["saturated"]
        self.publish_extra(out)
        self.finite_or_fail(delta=self.delta, delta_law=self.delta_law)
