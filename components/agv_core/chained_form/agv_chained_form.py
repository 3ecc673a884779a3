"""FMU slave: chained-form (Samson) path-following steering law (agv_core.chained_form)."""

from typing import Any

from agv_boot import load_core

core: Any = load_core(
    "fmi.fmi_slave", "chained_form.chained_form", "numerics.paths", "fmi.defaults")
DEFAULTS = core.fmi.defaults.defaults_of(  # the core's defaults (written once)
    core.chained_form.chained_form.make_controller)

_STATE_INPUTS = ("lateral_error", "heading_error", "curvature", "curvature_rate")
_POSE_INPUTS = ("x", "y", "heading")


class AgvChainedForm(core.fmi.fmi_slave.AgvSlave):
    """Seed 002 chained-form path following: path-relative state in, steering angle out."""

    description = ("Chained-form (Samson) path-following controller, seed 002 eq (23): "
                   "speed-independent steering angle from the path-relative state, "
                   "saturated at +/-delta_max")

    #: Reference: a 0.1 m lateral error from the start and a 0.05 rad heading error from
    #: 0.5 s (source 'sensor', straight path).
    default_experiment = core.fmi.fmi_slave.DefaultExperiment(start_time=0.0, stop_time=1.0,
                                                              step_size=0.01)
    reference_inputs = {"lateral_error": ((0.0, 0.1),),
                        "heading_error": ((0.0, 0.0), (0.5, 0.05))}

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        S = core.fmi.fmi_slave.String
        B = core.fmi.fmi_slave.Boolean
        self.input("lateral_error", 0.0, "m",
                   "Lateral deviation y of the rear-axle centre, positive left of the path "
                   "(source 'sensor')")
        self.input("heading_error", 0.0, "rad",
                   "Heading error theta = vehicle minus path heading, wrapped to (-pi, pi] "
                   "(source 'sensor')")
        self.input("curvature", 0.0, "1/m",
                   "Path curvature c(s) at the projection point, positive turning left "
                   "(source 'sensor')")
        self.input("curvature_rate", 0.0, "1/m2",
                   "Path curvature derivative dc/ds at the projection point (source 'sensor')")
        self.input("x", 0.0, "m", "x of the rear-axle centre (source 'pose')")
        self.input("y", 0.0, "m", "y of the rear-axle centre (source 'pose')")
        self.input("heading", 0.0, "rad", "Vehicle heading, counter-clockwise from x "
                   "(source 'pose')")
        self.parameter("Kd", DEFAULTS["Kd"], "1/m", "Gain on a3 per unit distance (seed 002: 0.6)")
        self.parameter("Kp", DEFAULTS["Kp"], "1/m2", "Gain on a2 per unit distance squared "
                       "(seed 002: 0.09)")
        self.parameter("wheelbase", DEFAULTS["wheelbase"], "m",
                       "Wheelbase l, rear-axle centre to front wheel")
        self.parameter("delta_max", DEFAULTS["delta_max"], "rad",
                       "Steering saturation (seed 002: 45 deg)")
        self.parameter("sample_period", DEFAULTS["sample_period"], "s",
                       "Controller sample period, output held between samples; 0 = every step")
        self.parameter("source", DEFAULTS["source"], None,
                       "Where the path-relative state comes from: 'sensor' (inputs "
                       "lateral_error, heading_error, curvature, curvature_rate) or 'pose' "
                       "(inputs x, y, heading projected on parameter path)", kind=S)
        self.parameter("path", DEFAULTS["path"], None,
                       "Reference path string for source 'pose', e.g. "
                       "'sine:amplitude=3,wavelength=30'", kind=S)
        every = _STATE_INPUTS + _POSE_INPUTS
        self.output("delta", "rad", "Steering angle command, saturated at +/-delta_max; "
                    "connect to the vehicle's alpha or an actuator's alpha_ref",
                    depends_on=every)
        self.output("delta_law", "rad", "Unsaturated steering angle of eq (23)",
                    depends_on=every)
        self.output("m3", "1/m", "Virtual control m3 = -Kd a3 - Kp a2", depends_on=every)
        self.output("a2", "m", "Chained state a2 = y", depends_on=every)
        self.output("a3", "1", "Chained state a3 = (1 - y c) tan(theta)", depends_on=every)
        self.output("theta", "rad", "Heading error used by the law", depends_on=every)
        self.output("s", "m", "Arc length of the projection point (source 'pose'; 0 for "
                    "'sensor')", depends_on=_POSE_INPUTS)
        self.output("saturated", None, "True while delta is limited by delta_max",
                    depends_on=every, kind=B, start=False)
        self.output("in_domain", None, "False when |theta| >= pi/2 or y c >= 1 (law "
                    "undefined; full-lock recovery command)", depends_on=every, kind=B,
                    start=True)

    def make_core(self) -> Any:
        return core.chained_form.chained_form.make_controller(
            self.Kd, self.Kp, self.wheelbase, self.delta_max, self.sample_period,
            self.source, self.path)

    def advance(self, t: float, h: float) -> None:
        # a static law; a sample instant inside this step is taken from the held inputs
        c = self.core
        if self.source == "pose":
            c.step_from_pose(t, h, self.x, self.y, self.heading)
        else:
            c.step(t, h, self.lateral_error, self.heading_error, self.curvature,
                   self.curvature_rate)

    def publish(self) -> None:
        c = self.core
        if self.source == "pose":
            c.update_from_pose(self.time, self.x, self.y, self.heading)
        else:
            c.update(self.time, self.lateral_error, self.heading_error, self.curvature,
                     self.curvature_rate)
        out = c.outputs
        self.delta, self.delta_law, self.m3 = out["delta"], out["delta_law"], out["m3"]
        self.a2, self.a3, self.theta, self.s = out["a2"], out["a3"], out["heading_error"], out["s"]
        self.saturated, self.in_domain = out["saturated"], out["in_domain"]
        self.finite_or_fail(delta=self.delta, a3=self.a3)
