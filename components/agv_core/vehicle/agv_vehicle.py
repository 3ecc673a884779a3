"""FMU slave: kinematic single-track vehicle (agv_core.vehicle)."""

from math import isfinite
from typing import Any

from agv_boot import load_core

core: Any = load_core("fmi.fmi_slave", "vehicle.vehicle", "fmi.defaults")
DEFAULTS = core.fmi.defaults.defaults_of(  # the core's defaults (written once)
    core.vehicle.vehicle.Vehicle)


class AgvVehicle(core.fmi.fmi_slave.AgvSlave):
    """Vehicle kinematics, seed 000 eqs (1)-(3) / seed 004 eq (2), integrated exactly."""

    description = ("Kinematic single-track AGV: steered-wheel angle and speed in, pose out "
                   "(exact arc integration for inputs held over a step)")

    #: Reference: a constant steering angle of 0.2 rad at v0 = 1 m/s for 10 s, a circular
    #: arc of radius L / tan(0.2) = 4.93 m about the turn centre.
    default_experiment = core.fmi.fmi_slave.DefaultExperiment(start_time=0.0, stop_time=10.0,
                                                              step_size=0.01)
    reference_inputs = {"alpha": ((0.0, 0.2),)}

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.input("alpha", 0.0, "rad", "Steered-wheel angle, positive turns left")
        self.input("dv", 0.0, "m/s", "Speed added to v0 (a speed profile; with v0 = 0 the "
                   "speed of the rear-axle centre)")
        self.parameter("v0", 1.0, "m/s", "Constant part of the speed of the rear-axle centre; "
                       "the speed is v0 + dv")
        self.parameter("wheelbase", 1.0, "m", "Wheelbase L, rear-axle centre to front wheel")
        self.parameter("x0", DEFAULTS["x0"], "m", "Initial x of the reference point")
        self.parameter("y0", DEFAULTS["y0"], "m", "Initial y of the reference point")
        self.parameter("heading0", DEFAULTS["heading0"], "rad",
                       "Initial heading, counter-clockwise from x")
        self.parameter("reference_point", DEFAULTS["reference_point"], None,
                       "Point reported as x, y: 'front' (wheel centre, seed 000) or 'rear' "
                       "(axle centre, seed 004)", kind=core.fmi.fmi_slave.String)
        self.parameter("linear", DEFAULTS["linear"], None,
                       "Small-angle linear kinematics (seed 000 models b and c)",
                       kind=core.fmi.fmi_slave.Boolean)
        self.output("x", "m", "x of the reference point")
        self.output("y", "m", "y of the reference point")
        self.output("heading", "rad", "Heading beta, counter-clockwise from the x axis")
        self.output("x_rear", "m", "x of the rear-axle centre")
        self.output("y_rear", "m", "y of the rear-axle centre")
        self.output("x_front", "m", "x of the front-wheel centre")
        self.output("y_front", "m", "y of the front-wheel centre")
        self.output("distance", "m", "Distance travelled by the rear-axle centre")

    def make_core(self) -> Any:
        return core.vehicle.vehicle.Vehicle(self.wheelbase, self.x0, self.y0, self.heading0,
                                            self.reference_point, self.linear)

    def advance(self, t: float, h: float) -> None:
        self.core.step(self.alpha, self.v0 + self.dv, h)

    def publish(self) -> None:
        c = self.core
        self.x, self.y, self.heading = c.x, c.y, c.heading
        self.x_rear, self.y_rear = c.rear()
        self.x_front, self.y_front = c.front()
        self.distance = c.distance
        if not isfinite(self.x + self.y + self.heading):  # a sum is finite iff every term is
            self.finite_or_fail(x=self.x, y=self.y, heading=self.heading)
