"""FMU slave: seed-001 linear time-varying MPC (agv_core.ltv_mpc)."""

from typing import Any

from agv_boot import load_core

core: Any = load_core("fmi.fmi_slave", "fmi.tracking_fmi", "ltv_mpc.ltv_mpc", "fmi.defaults")
DEFAULTS = core.fmi.defaults.defaults_of(  # the core's defaults (written once)
    core.ltv_mpc.ltv_mpc.LtvMpc)


class AgvLtvMpc(core.fmi.tracking_fmi.TrackingSlave):
    """LTV MPC on the unicycle error model, increments with bounds and slack, OSQP."""

    description = ("Seed-001 LTV MPC: pose and reference in, (v_c, omega) out; QP by OSQP "
                   "(warm-started), a QP that is not solved is an FMU error")
    solve_errors = (core.ltv_mpc.ltv_mpc.MpcSolveError,)

    #: Reference: a held pose 0.5 m left of a reference moving along x at 0.4 m/s, heading
    #: 0: the MPC's first 20 samples (open loop: the pose input does not move).
    default_experiment = core.fmi.fmi_slave.DefaultExperiment(start_time=0.0, stop_time=4.0,
                                                              step_size=0.2)
    reference_inputs = {"y": ((0.0, 0.5),), "v_ref": ((0.0, 0.4),)}

    def declare_parameters(self) -> None:
        p = self.parameter
        p("sample_time", DEFAULTS["sample_time"], "s",
          "Sample time T (prediction step and output update)")
        p("horizon", DEFAULTS["horizon"], None, "Prediction horizon N (samples)",
          kind=core.fmi.fmi_slave.Integer)
        p("control_horizon", DEFAULTS["control_horizon"], None,
          "Control horizon N_c (samples); 0 = N",
          kind=core.fmi.fmi_slave.Integer)
        p("q_x", 1.0, "1", "State weight on e_X (cost in SI numbers)")
        p("q_y", 1.0, "1", "State weight on e_Y")
        p("q_heading", 0.5, "1", "State weight on e_alpha")
        p("lam", DEFAULTS["lam"], "1", "Input-increment weight: R = lam I_2")
        p("rho", DEFAULTS["rho"], "1", "Slack weight")
        p("slack_max", DEFAULTS["slack_max"], "m", "Upper bound of the slack")
        p("e_max", DEFAULTS["e_max"], "m", "Soft bound on the predicted |e_X|, |e_Y| (0 = none)")
        p("v_min", 0.0, "m/s", "Lower bound of v_c")
        p("v_max", 0.8, "m/s", "Upper bound of v_c")
        p("omega_min", -0.6, "rad/s", "Lower bound of omega")
        p("omega_max", 0.6, "rad/s", "Upper bound of omega")
        p("dv_max", 0.05, "m/s", "Bound of |Delta v_c| per sample")
        p("domega_max", 0.05, "rad/s", "Bound of |Delta omega| per sample")
        p("eps", DEFAULTS["eps"], "1", "OSQP absolute and relative tolerance")
        p("max_iter", DEFAULTS["max_iter"], None, "OSQP iteration limit per sample",
          kind=core.fmi.fmi_slave.Integer)

    def declare_extra_outputs(self) -> None:
        deps = core.fmi.tracking_fmi.INPUTS
        self.output("dv_c", "m/s", "Applied increment Delta v_c", depends_on=deps)
        self.output("domega", "rad/s", "Applied increment Delta omega", depends_on=deps)
        self.output("slack", "m", "Slack gamma of the last QP", depends_on=deps)
        self.output("iterations", "1", "OSQP iterations of the last QP", depends_on=deps)

    def make_core(self) -> Any:
        return core.ltv_mpc.ltv_mpc.LtvMpc(
            sample_time=self.sample_time, horizon=self.horizon,
            control_horizon=self.control_horizon, q=(self.q_x, self.q_y, self.q_heading),
            lam=self.lam, rho=self.rho, slack_max=self.slack_max, e_max=self.e_max,
            u_min=(self.v_min, self.omega_min), u_max=(self.v_max, self.omega_max),
            du_min=(-self.dv_max, -self.domega_max), du_max=(self.dv_max, self.domega_max),
            eps=self.eps, max_iter=self.max_iter)

    def publish_extra(self, out: dict[str, Any]) -> None:
        self.dv_c, self.domega = out["dv_c"], out["domega"]
        self.slack, self.iterations = out["slack"], float(out["iterations"])
