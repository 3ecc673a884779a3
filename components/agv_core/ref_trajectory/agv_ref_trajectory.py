"""FMU slave: seed-001 time-parameterised reference trajectory (agv_core.ref_trajectory)."""

from typing import Any

from agv_boot import load_core

core: Any = load_core("fmi.fmi_slave", "ref_trajectory.ref_trajectory", "fmi.defaults")
DEFAULTS = core.fmi.defaults.defaults_of(  # the core's defaults (written once)
    core.ref_trajectory.ref_trajectory.RefTrajectory)


class AgvRefTrajectory(core.fmi.fmi_slave.AgvSlave):
    """Circle or S-curve travelled at constant speed: reference pose, speed, yaw rate."""

    description = ("Reference trajectory (seed 001): circle (v, omega) or S-curve (straight "
                   "tangent to a sine, first curvature peak at peak_time) against time")

    #: Reference: the default circle (0.4 m/s, 0.074 rad/s) for one lap, 2 pi / 0.074 = 84.9 s.
    default_experiment = core.fmi.fmi_slave.DefaultExperiment(start_time=0.0, stop_time=85.0,
                                                              step_size=0.1)

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.parameter("kind", DEFAULTS["kind"], None, "'circle' or 'scurve'",
                       kind=core.fmi.fmi_slave.String)
        self.parameter("speed", DEFAULTS["speed"], "m/s", "Reference speed v_r along the path")
        self.parameter("omega", DEFAULTS["omega"], "rad/s",
                       "Circle: yaw rate omega_r (< 0: clockwise)")
        self.parameter("amplitude", DEFAULTS["amplitude"], "m", "S-curve: sine amplitude A")
        self.parameter("wavelength", DEFAULTS["wavelength"], "m", "S-curve: sine wavelength W")
        self.parameter("peak_time", DEFAULTS["peak_time"], "s",
                       "S-curve: time of the first curvature maximum (sets the straight)")
        self.output("x_ref", "m", "Reference x")
        self.output("y_ref", "m", "Reference y")
        self.output("heading_ref", "rad", "Reference heading alpha_r (path tangent)")
        self.output("v_ref", "m/s", "Reference speed v_r")
        self.output("omega_ref", "rad/s", "Reference yaw rate omega_r = kappa_r v_r")
        self.output("curvature_ref", "1/m", "Path curvature kappa_r, positive turning left")
        self.output("s_ref", "m", "Arc length travelled along the reference")

    def make_core(self) -> Any:
        return core.ref_trajectory.ref_trajectory.RefTrajectory(self.kind, self.speed, self.omega,
                                                                self.amplitude, self.wavelength,
                                                                self.peak_time)

    def advance(self, t: float, h: float) -> None:
        pass  # a function of time; publish() evaluates it at the new time

    def publish(self) -> None:
        r = self.core.at(self.time)
        self.x_ref, self.y_ref, self.heading_ref = r["x"], r["y"], r["heading"]
        self.v_ref, self.omega_ref = r["v"], r["omega"]
        self.curvature_ref, self.s_ref = r["curvature"], r["s"]
        self.finite_or_fail(x_ref=self.x_ref, y_ref=self.y_ref)
