"""FMU slave: per-axle PD with fixed gains, the baseline of the fuzzy-scheduled PD
(agv_core.fuzzy_pd)."""

import math

from agv_boot import load_core

core = load_core("fmi_slave", "fuzzy_pd")

_INPUTS = ("lateral_error", "speed")


class AgvFixedPd(core.fmi_slave.AgvSlave):
    """Same interface as AgvFuzzyPd, constant gains."""

    description = ("Fixed-gain PD steering law for one axle: delta = -(Kp e + Kd de/dt), "
                   "the baseline for seed 003's fuzzy-scheduled PD")

    #: Reference: a 1 cm step of the lateral error at 0.5 s: with e held the filter is
    #: exact, error_rate = (e / tau_d) exp(-(t - 0.5) / tau_d), delta = -(Kp e + Kd
    #: error_rate) (0.52 rad peak, below delta_max).
    default_experiment = core.fmi_slave.DefaultExperiment(start_time=0.0, stop_time=1.0,
                                                          step_size=0.01)
    reference_inputs = {"lateral_error": ((0.0, 0.0), (0.5, 0.01)),
                        "speed": ((0.0, 14.0 / 3.6),)}

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("lateral_error", 0.0, "m", "Lateral error e of the axle's tracking point, "
                   "positive left of the path")
        self.input("speed", 0.0, "m/s", "Vehicle speed (not used; same interface as "
                   "AgvFuzzyPd)")
        self.parameter("Kp", math.radians(710.0), "rad/m",
                       "Proportional gain (default: the fuzzy Kp at e = 1 cm, 14 km/h)")
        self.parameter("Kd", math.radians(112.0), "rad.s/m",
                       "Derivative gain (default: the fuzzy Kd at e = 1 cm, 14 km/h)")
        self.parameter("tau_d", 0.05, "s", "Derivative filter time constant")
        self.parameter("delta_max", math.radians(35.0), "rad", "Steering saturation")
        self.output("delta", "rad", "Axle-equivalent steering angle, positive left, saturated",
                    depends_on=("lateral_error",))
        self.output("Kp_used", "rad/m", "Proportional gain in use")
        self.output("Kd_used", "rad.s/m", "Derivative gain in use")
        self.output("error_rate", "m/s", "Filtered rate of the lateral error",
                    depends_on=("lateral_error",))
        self.output("saturated", None, "True while delta is limited by delta_max",
                    depends_on=("lateral_error",), kind=core.fmi_slave.Boolean, start=False)

    def make_core(self):
        gains = core.fuzzy_pd.FixedGains(math.degrees(self.Kp), math.degrees(self.Kd))
        return core.fuzzy_pd.AxlePD(gains, self.tau_d, self.delta_max)

    def advance(self, t, h):
        self.core.advance(self.lateral_error, h)

    def publish(self):
        out = self.core.evaluate(self.lateral_error, self.speed)
        self.delta, self.error_rate, self.saturated = (out["delta"], out["error_rate"],
                                                       out["saturated"])
        self.Kp_used, self.Kd_used = out["Kp"], out["Kd"]
        self.finite_or_fail(delta=self.delta)
