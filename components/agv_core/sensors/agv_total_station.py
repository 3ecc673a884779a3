"""FMU slave: robotic total station (agv_core.sensors.TotalStation)."""

from math import isfinite
from typing import Any

from agv_boot import load_core

core: Any = load_core("fmi.fmi_slave", "sensors.sensors", "fmi.defaults")
DEFAULTS = core.fmi.defaults.defaults_of(  # the core's defaults (written once)
    core.sensors.sensors.TotalStation)


class AgvTotalStation(core.fmi.fmi_slave.AgvSlave):
    """Robotic total station of seed 004: jittered position fixes sent by radio modem."""

    #: publish reads the core (reads do not change what it shows) and sets outputs; the
    #: availability it passes on is passed again by advance
    lazy_publish = True

    description = ("Robotic total station: position fixes every 0.65 s on average with "
                   "jitter, radio latency and mm-level noise")

    #: Reference: a prism standing at (1, 2) m; fixes every 0.65 s on average, delayed and
    #: noisy (seed 0).
    default_experiment = core.fmi.fmi_slave.DefaultExperiment(start_time=0.0, stop_time=10.0,
                                                              step_size=0.01)
    reference_inputs = {"x": ((0.0, 1.0),), "y": ((0.0, 2.0),)}

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.input("x", 0.0, "m", "x of the prism (tracked point)")
        self.input("y", 0.0, "m", "y of the prism (tracked point)")
        self.parameter("mean_interval", DEFAULTS["mean_interval"], "s", "Mean time between fixes")
        self.parameter("jitter", DEFAULTS["jitter"], "s",
                       "Half-width of the uniform spread of each interval (< mean_interval)")
        self.parameter("latency", DEFAULTS["latency"], "s", "Radio-modem transmission delay")
        self.parameter("noise", DEFAULTS["noise"], "m", "Std. dev. of the noise of each coordinate")
        self.parameter("seed", DEFAULTS["seed"], None, "Random seed (>= 0)",
                       kind=core.fmi.fmi_slave.Integer)
        self.parameter("available", True, None, "Fixes reach the vehicle (false: a radio "
                       "or line-of-sight dropout; fixes due then are lost)",
                       kind=core.fmi.fmi_slave.Boolean, tunable=True)
        self.output("x_meas", "m", "Measured x of the newest fix", depends_on=("x",))
        self.output("y_meas", "m", "Measured y of the newest fix", depends_on=("y",))
        self.output("fix_age", "s", "Time since the shown fix was measured")

    def make_core(self) -> Any:
        return core.sensors.sensors.TotalStation(self.mean_interval, self.jitter, self.latency,
                                                 self.noise, self.seed, self.time)

    def advance(self, t: float, h: float) -> None:
        self.core.available = bool(self.available)
        self.core.step(t, h, self.x, self.y)

    def publish(self) -> None:
        self.core.available = bool(self.available)
        self.x_meas, self.y_meas, self.fix_age = self.core.measure(self.time, self.x, self.y)
        if not isfinite(self.x_meas + self.y_meas):  # finite iff every term is
            self.finite_or_fail(x_meas=self.x_meas, y_meas=self.y_meas)
