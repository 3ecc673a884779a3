"""FMU slave: per-axle PD with fuzzy-scheduled gains (agv_core.fuzzy_pd, interface in
agv_core.axle_pd_fmi)."""

import math
from typing import Any

from agv_boot import load_core

core: Any = load_core("fmi.fmi_slave", "axle_pd.fuzzy_pd", "fmi.axle_pd_fmi", "fmi.defaults")
DEFAULTS = core.fmi.defaults.defaults_of(  # the core's defaults (written once): km/h, deg
    core.axle_pd.fuzzy_pd.FuzzySchedule)


class AgvFuzzyPd(core.fmi.axle_pd_fmi.AxlePdSlave):
    """Seed 003 section 4: lateral error and speed in, axle steering angle out."""

    description = ("Seed 003 fuzzy-scheduled PD: a Mamdani system (scikit-fuzzy) sets Kp, Kd "
                   "from the lateral error and speed; delta = -(Kp e + Kd de/dt)")

    #: Reference: a 1 cm step of the lateral error at 0.5 s at 14 km/h: with e held the
    #: filter is exact, error_rate = (e / tau_d) exp(-(t - 0.5) / tau_d) and
    #: delta = -(Kp e + Kd error_rate), Kp, Kd the schedule's gains at (1 cm, 14 km/h)
    #: (709.7 deg/m, 111.8 deg s/m).
    default_experiment = core.fmi.fmi_slave.DefaultExperiment(start_time=0.0, stop_time=1.0,
                                                              step_size=0.01)
    reference_inputs = {"lateral_error": ((0.0, 0.0), (0.5, 0.01)),
                        "speed": ((0.0, 14.0 / 3.6),)}

    def declare_gain_parameters(self) -> None:
        S, Int = core.fmi.fmi_slave.String, core.fmi.fmi_slave.Integer
        self.parameter("kp_rules", DEFAULTS["kp_rules"], None,
                       "Kp rule table: 5 rows (e NB..PB) of 3 labels (speed low, mid, high) "
                       "from NB NM NS ZE PS PM PB, rows separated by ';'", kind=S)
        self.parameter("kd_rules", DEFAULTS["kd_rules"], None,
                       "Kd rule table, same layout", kind=S)
        self.parameter("e_max", DEFAULTS["e_max"], "m", "Lateral-error universe [-e_max, e_max]")
        self.parameter("v_max", DEFAULTS["v_max"] / core.axle_pd.fuzzy_pd.KMH, "m/s",
                       "Speed universe [0, v_max] (80 km/h)")
        self.parameter("kp_max", math.radians(DEFAULTS["kp_max"]), "rad/m",
                       "Kp universe [-kp_max, kp_max] (1500 deg/m)")
        self.parameter("kd_max", math.radians(DEFAULTS["kd_max"]), "rad.s/m",
                       "Kd universe [-kd_max, kd_max] (800 deg s/m)")
        self.parameter("e_cells", DEFAULTS["e_cells"], None,
                       "Gain-grid cells across the error universe "
                       "(multiple of 4)", kind=Int)
        self.parameter("v_cells", DEFAULTS["v_cells"], None,
                       "Gain-grid cells across the speed universe "
                       "(multiple of 2)", kind=Int)

    def make_gains(self) -> Any:
        return core.axle_pd.fuzzy_pd.FuzzySchedule(
            self.kp_rules, self.kd_rules, self.e_max, self.v_max * core.axle_pd.fuzzy_pd.KMH,
            math.degrees(self.kp_max), math.degrees(self.kd_max), self.e_cells, self.v_cells)
