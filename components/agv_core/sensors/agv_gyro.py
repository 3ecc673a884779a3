"""FMU slave: fibre-optic gyro heading (agv_core.sensors.InstantSensor)."""

from math import isfinite
from typing import Any

from agv_boot import load_core

core: Any = load_core("fmi.fmi_slave", "sensors.sensors")


class AgvGyro(core.fmi.fmi_slave.AgvSlave):
    """Fibre-optic gyro heading of seed 004: drift, resolution, optional noise."""

    #: publish reads the core (reads do not change what it shows) and sets outputs only
    lazy_publish = True

    description = ("Fibre-optic gyro heading: drift 0.5 deg/h, resolution 0.01 deg, "
                   "optional white noise, sampled at every communication point")

    #: Reference: a constant heading of 0.5 rad for an hour: the drift of 0.5 deg/h,
    #: quantised to 0.01 deg.
    default_experiment = core.fmi.fmi_slave.DefaultExperiment(start_time=0.0, stop_time=3600.0,
                                                              step_size=1.0)
    reference_inputs = {"heading": ((0.0, 0.5),)}

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.input("heading", 0.0, "rad", "True heading, counter-clockwise from x")
        self.parameter("drift", core.sensors.sensors.GYRO_DRIFT, "rad/s",
                       "Heading drift rate (0.5 deg/h)")
        self.parameter("resolution", core.sensors.sensors.GYRO_RESOLUTION, "rad",
                       "Quantisation step of the reading (0.01 deg); 0 for none")
        self.parameter("noise", 0.0, "rad", "Std. dev. of white noise per sample")
        self.parameter("seed", 0, None, "Random seed (>= 0)", kind=core.fmi.fmi_slave.Integer)
        self.output("heading_meas", "rad", "Measured heading", depends_on=("heading",))

    def make_core(self) -> Any:
        return core.sensors.sensors.InstantSensor(self.drift, self.noise, self.resolution,
                                                  self.seed, self.time)

    def advance(self, t: float, h: float) -> None:
        self.core.step(t, h)

    def publish(self) -> None:
        self.heading_meas = self.core.measure(self.time, self.heading)
        if not isfinite(self.heading_meas):
            self.finite_or_fail(heading_meas=self.heading_meas)
