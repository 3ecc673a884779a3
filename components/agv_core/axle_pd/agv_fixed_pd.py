"""FMU slave: per-axle PD with fixed gains, the baseline of the fuzzy-scheduled PD
(agv_core.fuzzy_pd, interface in agv_core.axle_pd_fmi)."""

import math
from typing import Any

from agv_boot import load_core

core: Any = load_core("fmi.fmi_slave", "axle_pd.fuzzy_pd", "fmi.axle_pd_fmi", "fmi.defaults")
DEFAULTS = core.fmi.defaults.defaults_of(  # the core's defaults (written once), deg
    core.axle_pd.fuzzy_pd.FixedGains)


class AgvFixedPd(core.fmi.axle_pd_fmi.AxlePdSlave):
    """Same interface as AgvFuzzyPd, constant gains."""

    description = ("Fixed-gain PD steering law for one axle: delta = -(Kp e + Kd de/dt), "
                   "the baseline for seed 003's fuzzy-scheduled PD")
    speed_description = "Vehicle speed (not used; same interface as AgvFuzzyPd)"
    kp_description = "Proportional gain in use"
    kd_description = "Derivative gain in use"
    gain_depends_on = ()

    #: Reference: a 1 cm step of the lateral error at 0.5 s: with e held the filter is
    #: exact, error_rate = (e / tau_d) exp(-(t - 0.5) / tau_d), delta = -(Kp e + Kd
    #: error_rate) (0.52 rad peak, below delta_max).
    default_experiment = core.fmi.fmi_slave.DefaultExperiment(start_time=0.0, stop_time=1.0,
                                                              step_size=0.01)
    reference_inputs = {"lateral_error": ((0.0, 0.0), (0.5, 0.01)),
                        "speed": ((0.0, 14.0 / 3.6),)}

    def declare_gain_parameters(self) -> None:
        self.parameter("Kp", math.radians(DEFAULTS["kp_deg"]), "rad/m",
                       "Proportional gain (default: the fuzzy Kp at e = 1 cm, 14 km/h)")
        self.parameter("Kd", math.radians(DEFAULTS["kd_deg"]), "rad.s/m",
                       "Derivative gain (default: the fuzzy Kd at e = 1 cm, 14 km/h)")

    def make_gains(self) -> Any:
        return core.axle_pd.fuzzy_pd.FixedGains(math.degrees(self.Kp), math.degrees(self.Kd))
