"""FMU slave: steering-angle sensor (agv_core.sensors.InstantSensor)."""

from math import isfinite
from typing import Any

from agv_boot import load_core

core: Any = load_core("fmi.fmi_slave", "sensors.sensors")


class AgvSteerSensor(core.fmi.fmi_slave.AgvSlave):
    """Steered-wheel angle displacement sensor (seeds 000 and 004): noise, resolution."""

    #: publish reads the core (reads do not change what it shows) and sets outputs only
    lazy_publish = True

    description = ("Steering-angle sensor: white noise and quantisation, sampled at every "
                   "communication point")

    #: Reference: a 0.1 rad step of the wheel angle at 0.5 s, seen with noise and
    #: quantisation (seed 0).
    default_experiment = core.fmi.fmi_slave.DefaultExperiment(start_time=0.0, stop_time=2.0,
                                                              step_size=0.01)
    reference_inputs = {"alpha": ((0.0, 0.0), (0.5, 0.1))}

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.input("alpha", 0.0, "rad", "True steered-wheel angle, positive left")
        self.parameter("noise", core.sensors.sensors.STEER_NOISE, "rad",
                       "Std. dev. of white noise per sample")
        self.parameter("resolution", core.sensors.sensors.STEER_RESOLUTION, "rad",
                       "Quantisation step of the reading (0.1 deg); 0 for none")
        self.parameter("seed", 0, None, "Random seed (>= 0)", kind=core.fmi.fmi_slave.Integer)
        self.output("alpha_meas", "rad", "Measured steered-wheel angle",
                    depends_on=("alpha",))

    def make_core(self) -> Any:
        return core.sensors.sensors.InstantSensor(0.0, self.noise, self.resolution, self.seed,
                                                  self.time)

    def advance(self, t: float, h: float) -> None:
        self.core.step(t, h)

    def publish(self) -> None:
        self.alpha_meas = self.core.measure(self.time, self.alpha)
        if not isfinite(self.alpha_meas):
            self.finite_or_fail(alpha_meas=self.alpha_meas)
