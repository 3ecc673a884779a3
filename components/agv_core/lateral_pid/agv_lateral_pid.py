"""FMU slave: seed-001 comparison PID on the lateral error (agv_core.pid)."""

from typing import Any

from agv_boot import load_core

core: Any = load_core("fmi.fmi_slave", "fmi.tracking_fmi", "lateral_pid.pid", "fmi.defaults")
DEFAULTS = core.fmi.defaults.defaults_of(  # the core's defaults (written once)
    core.lateral_pid.pid.LateralPid)


class AgvLateralPid(core.fmi.tracking_fmi.TrackingSlave):
    """Sampled PID on the lateral error, constant speed v_r (swap-in for AgvLtvMpc)."""

    description = ("Seed-001 comparison PID: pose and reference in, (v_c = v_r, omega) out; "
                   "omega = -(Kp e + Ki int e + Kd de/dt) on the lateral error")

    #: Reference: a held pose 0.1 m left of a reference moving along x at 0.4 m/s, heading
    #: 0: the PID's first 20 samples (open loop: the integral grows, omega saturates).
    default_experiment = core.fmi.fmi_slave.DefaultExperiment(start_time=0.0, stop_time=4.0,
                                                              step_size=0.2)
    reference_inputs = {"y": ((0.0, 0.1),), "v_ref": ((0.0, 0.4),)}

    def declare_parameters(self) -> None:
        p = self.parameter
        p("sample_time", DEFAULTS["sample_time"], "s", "Sample time T")
        p("kp", DEFAULTS["kp"], "rad/(s.m)",
          "Proportional gain (seed 001 gives none; calibrated to its 19 cm overshoot)")
        p("ki", DEFAULTS["ki"], "rad/(s2.m)", "Integral gain")
        p("kd", DEFAULTS["kd"], "rad/m", "Derivative gain")
        p("omega_max", DEFAULTS["omega_max"], "rad/s", "Yaw-rate limit")

    def declare_extra_outputs(self) -> None:
        self.output("integral", "m.s", "Integral of e_lat (held while omega saturates)",
                    depends_on=core.fmi.tracking_fmi.INPUTS)

    def make_core(self) -> Any:
        return core.lateral_pid.pid.LateralPid(self.kp, self.ki, self.kd, self.sample_time,
                                               self.omega_max)

    def publish_extra(self, out: dict[str, Any]) -> None:
        self.integral = out["integral"]
