"""FMU slave: seed-004 preview + LQ path-tracking controller (agv_core.preview_lq)."""

from typing import Any

from agv_boot import load_core

core: Any = load_core("fmi.fmi_slave", "preview_lq.preview_lq", "numerics.paths", "fmi.defaults")
DEFAULTS = core.fmi.defaults.defaults_of(  # the core's defaults (written once)
    core.preview_lq.preview_lq.PreviewLQ)


class AgvPreviewLq(core.fmi.fmi_slave.AgvSlave):
    """Preview (future point, eq 5) + LQ (eqs 6-12) steering controller of seed 004."""

    description = ("Seed-004 preview + LQ tracking controller: measured pose and steering "
                   "angle in, steering-angle command (actuator angle mode) out")

    #: Reference: the measured pose held 0.1 m left of the default sine path's start with
    #: the path's heading there (atan(2 pi 2 / 18.85) = 0.588 rad), turned 0.1 rad left
    #: at 1 s; 2 s.
    default_experiment = core.fmi.fmi_slave.DefaultExperiment(start_time=0.0, stop_time=2.0,
                                                              step_size=0.01)
    reference_inputs = {"y_meas": ((0.0, 0.1),), "heading_meas": ((0.0, 0.588), (1.0, 0.688))}

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        inputs = ("x_meas", "y_meas", "fix_age", "heading_meas", "alpha_meas")
        self.input("x_meas", 0.0, "m", "Measured x of the rear-axle centre (total station)")
        self.input("y_meas", 0.0, "m", "Measured y of the rear-axle centre (total station)")
        self.input("fix_age", 0.0, "s",
                   "Age of the position fix; used only with dead_reckoning")
        self.input("heading_meas", 0.0, "rad", "Measured heading (gyro), continuous")
        self.input("alpha_meas", 0.0, "rad",
                   "Measured steering angle; used when alpha_fixed_point is false")
        self.parameter("path", core.preview_lq.preview_lq.DEFAULT_PATH, None,
                       "Reference path string (agv_core.numerics.paths.parse_path)",
                       kind=core.fmi.fmi_slave.String)
        self.parameter("wheelbase", DEFAULTS["wheelbase"], "m",
                       "Wheelbase L (Mitsubishi 2501D class tractor)")
        self.parameter("speed", DEFAULTS["speed"], "m/s", "Nominal speed V of the rear-axle centre")
        self.parameter("tau", DEFAULTS["tau"], "s", "Preview time (total station mean sample time)")
        self.parameter("ds", DEFAULTS["ds"], "m", "Polyline vertex spacing along the path")
        self.parameter("q_x", 10.0, "1", "LQ state weight on dx")
        self.parameter("q_y", 10.0, "1", "LQ state weight on dy")
        self.parameter("q_theta", 10.0, "1", "LQ state weight on dtheta")
        self.parameter("q_alpha", 1.0, "1", "LQ state weight on dalpha")
        self.parameter("r_v", 10000.0, "1", "LQ input weight on the speed variation dV")
        self.parameter("r_u", 1.0, "1", "LQ input weight on the steering rate du")
        self.parameter("alpha_max", DEFAULTS["alpha_max"], "rad",
                       "Steering-angle command limit (35 deg)")
        self.parameter("sample_period", DEFAULTS["sample_period"], "s",
                       "Controller sample period; 0 = every communication step")
        self.parameter("dead_reckoning", DEFAULTS["dead_reckoning"], None,
                       "Propagate the fix by fix_age along the kinematic arc (not in the "
                       "paper)", kind=core.fmi.fmi_slave.Boolean)
        self.parameter("alpha_fixed_point", DEFAULTS["alpha_fixed_point"], None,
                       "Use the command itself as steering angle in eq 12 (fixed point, "
                       "stable with a fast actuator); false = measured angle, eq 12 "
                       "literally", kind=core.fmi.fmi_slave.Boolean)
        # fix_age matters only with dead_reckoning, alpha_meas only without
        # alpha_fixed_point; both are declared as direct dependencies (a safe superset).
        self.output("alpha_ref", "rad", "Steering-angle command for the actuator's angle mode",
                    depends_on=inputs)
        self.output("target_x", "m", "x of the target point on the discretised path",
                    depends_on=inputs)
        self.output("target_y", "m", "y of the target point on the discretised path",
                    depends_on=inputs)
        self.output("preview_error", "m",
                    "Lateral deviation of the future point, positive left of the path",
                    depends_on=inputs)

    def make_core(self) -> Any:
        path = core.numerics.paths.parse_path(self.path)
        return core.preview_lq.preview_lq.PreviewLQ(
            path, wheelbase=self.wheelbase, speed=self.speed, tau=self.tau, ds=self.ds,
            q=(self.q_x, self.q_y, self.q_theta, self.q_alpha), r=(self.r_v, self.r_u),
            alpha_max=self.alpha_max, sample_period=self.sample_period,
            dead_reckoning=self.dead_reckoning, alpha_fixed_point=self.alpha_fixed_point)

    def advance(self, t: float, h: float) -> None:
        # the law is static; a sample instant inside this step uses the held inputs
        self.core.step(t, h, self.x_meas, self.y_meas, self.heading_meas, self.alpha_meas,
                       self.fix_age)

    def publish(self) -> None:
        out = self.core.update(self.time, self.x_meas, self.y_meas, self.heading_meas,
                               self.alpha_meas, self.fix_age)
        self.alpha_ref = out["alpha_ref"]
        self.target_x, self.target_y = out["target_x"], out["target_y"]
        self.preview_error = out["preview_error"]
        self.finite_or_fail(alpha_ref=self.alpha_ref, preview_error=self.preview_error)
