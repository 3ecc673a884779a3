"""FMU slave: per-axle PD with fuzzy-scheduled gains (agv_core.fuzzy_pd)."""

import math

from agv_boot import load_core

core = load_core("fmi_slave", "fuzzy_pd")

_INPUTS = ("lateral_error", "speed")


class AgvFuzzyPd(core.fmi_slave.AgvSlave):
    """Seed 003 section 4: lateral error and speed in, axle steering angle out."""

    description = ("Seed 003 fuzzy-scheduled PD: a Mamdani system (scikit-fuzzy) sets Kp, Kd "
                   "from the lateral error and speed; delta = -(Kp e + Kd de/dt)")

    #: Reference: a 1 cm step of the lateral error at 0.5 s at 14 km/h: with e held the
    #: filter is exact, error_rate = (e / tau_d) exp(-(t - 0.5) / tau_d) and
    #: delta = -(Kp e + Kd error_rate), Kp, Kd the schedule's gains at (1 cm, 14 km/h)
    #: (709.7 deg/m, 111.8 deg s/m).
    default_experiment = core.fmi_slave.DefaultExperiment(start_time=0.0, stop_time=1.0,
                                                          step_size=0.01)
    reference_inputs = {"lateral_error": ((0.0, 0.0), (0.5, 0.01)),
                        "speed": ((0.0, 14.0 / 3.6),)}

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        S, I = core.fmi_slave.String, core.fmi_slave.Integer
        self.input("lateral_error", 0.0, "m", "Lateral error e of the axle's tracking point, "
                   "positive left of the path")
        self.input("speed", 0.0, "m/s", "Vehicle speed (scheduling variable)")
        self.parameter("kp_rules", core.fuzzy_pd.DEFAULT_KP_RULES, None,
                       "Kp rule table: 5 rows (e NB..PB) of 3 labels (speed low, mid, high) "
                       "from NB NM NS ZE PS PM PB, rows separated by ';'", kind=S)
        self.parameter("kd_rules", core.fuzzy_pd.DEFAULT_KD_RULES, None,
                       "Kd rule table, same layout", kind=S)
        self.parameter("e_max", 0.05, "m", "Lateral-error universe [-e_max, e_max]")
        self.parameter("v_max", 80.0 / 3.6, "m/s", "Speed universe [0, v_max] (80 km/h)")
        self.parameter("kp_max", math.radians(1500.0), "rad/m",
                       "Kp universe [-kp_max, kp_max] (1500 deg/m)")
        self.parameter("kd_max", math.radians(800.0), "rad.s/m",
                       "Kd universe [-kd_max, kd_max] (800 deg s/m)")
        self.parameter("e_cells", 100, None, "Gain-grid cells across the error universe "
                       "(multiple of 4)", kind=I)
        self.parameter("v_cells", 40, None, "Gain-grid cells across the speed universe "
                       "(multiple of 2)", kind=I)
        self.parameter("tau_d", 0.05, "s", "Derivative filter time constant")
        self.parameter("delta_max", math.radians(35.0), "rad", "Steering saturation")
        _outputs(self)

    def make_core(self):
        schedule = core.fuzzy_pd.FuzzySchedule(
            self.kp_rules, self.kd_rules, self.e_max, self.v_max * core.fuzzy_pd.KMH,
            math.degrees(self.kp_max), math.degrees(self.kd_max), self.e_cells, self.v_cells)
        return core.fuzzy_pd.AxlePD(schedule, self.tau_d, self.delta_max)

    def advance(self, t, h):
        self.core.advance(self.lateral_error, h)

    def publish(self):
        _publish(self)


def _outputs(slave):
    slave.output("delta", "rad", "Axle-equivalent steering angle, positive left, saturated",
                 depends_on=_INPUTS)
    slave.output("Kp_used", "rad/m", "Scheduled proportional gain in use", depends_on=_INPUTS)
    slave.output("Kd_used", "rad.s/m", "Scheduled derivative gain in use", depends_on=_INPUTS)
    slave.output("error_rate", "m/s", "Filtered rate of the lateral error",
                 depends_on=("lateral_error",))
    slave.output("saturated", None, "True while delta is limited by delta_max",
                 depends_on=_INPUTS, kind=core.fmi_slave.Boolean, start=False)


def _publish(slave):
    out = slave.core.evaluate(slave.lateral_error, slave.speed)
    slave.delta, slave.Kp_used, slave.Kd_used = out["delta"], out["Kp"], out["Kd"]
    slave.error_rate, slave.saturated = out["error_rate"], out["saturated"]
    slave.finite_or_fail(delta=slave.delta)
