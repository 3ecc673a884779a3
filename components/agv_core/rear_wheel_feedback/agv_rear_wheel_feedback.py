"""FMU slave: rear-wheel feedback (Samson) path tracking, a baseline
(agv_core.rear_wheel_feedback)."""

from typing import Any

from agv_boot import load_core

core: Any = load_core("fmi.fmi_slave", "fmi.path_law_fmi", "fmi.defaults",
                 "rear_wheel_feedback.rear_wheel_feedback")
DEFAULTS: dict[str, Any] = core.fmi.defaults.defaults_of(  # the core's defaults (written once)
    core.rear_wheel_feedback.rear_wheel_feedback.make_controller)


class AgvRearWheelFeedback(core.fmi.path_law_fmi.PathLawSlave):
    """Rear-wheel feedback (Samson): rear-axle pose in, wheel angle out."""

    description = ("Rear-wheel feedback path tracking (Samson's law) on the rear axle: "
                   "curvature feed-forward plus heading and lateral feedback, tan(delta) = "
                   "L [c cos(theta)/(1 - c e) - k_theta theta - k_e e sin(theta)/theta]")
    uses_speed = False

    def defaults(self) -> dict[str, Any]:
        return DEFAULTS

    def declare_gains(self, defaults: dict[str, Any]) -> None:
        self.parameter("k_theta", defaults["k_theta"], "1/m", "Heading gain per unit "
                       "distance (> 0)")
        self.parameter("k_e", defaults["k_e"], "1/m2", "Lateral gain per unit distance "
                       "squared (> 0)")

    def declare_extra_outputs(self) -> None:
        self.output("curvature", "1/m", "Path curvature at the rear axle's projection, "
                    "positive turning left", depends_on=self.depends)
        self.output("in_domain", None, "False when 1 - c e <= 0 (law undefined; full-lock "
                    "recovery towards the path)", depends_on=self.depends,
                    kind=core.fmi.fmi_slave.Boolean, start=True)

    def publish_extra(self, out: dict[str, Any]) -> None:
        self.curvature, self.in_domain = out["curvature"], out["in_domain"]

    def make_law(self) -> Any:
        return core.rear_wheel_feedback.rear_wheel_feedback.make_controller(
            self.path, self.k_theta, self.k_e, self.wheelbase, self.delta_max,
            self.sample_period)
