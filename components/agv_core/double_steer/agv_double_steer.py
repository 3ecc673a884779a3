"""FMU slave: double-steering-wheel AGV of seed 001 (agv_core.double_steer)."""

import math
from typing import Any

from agv_boot import load_core

core: Any = load_core("fmi.fmi_slave", "double_steer.double_steer", "fmi.defaults")
DEFAULTS = core.fmi.defaults.defaults_of(  # the core's defaults (written once)
    core.double_steer.double_steer.DoubleSteerVehicle)

WHEEL_INPUTS = ("theta_f", "v_f", "theta_b", "v_b")


class AgvDoubleSteer(core.fmi.fmi_slave.AgvSlave):
    """Rigid-body kinematics of the double-steer AGV, integrated exactly for held inputs."""

    description = ("Double-steering-wheel AGV (seed 001): front/rear wheel angles and speeds "
                   "in, centroid pose, speed, yaw rate and wheel contact points out (exact "
                   "for inputs held over a step)")

    #: Reference: symmetric steering theta_f = -theta_b = 0.2 rad at 0.5 m/s per wheel for
    #: 20 s: a circle of radius L / (2 sin 0.2) = 2.517 m about the centroid's turn centre
    #: (seed 001 claim G1).
    default_experiment = core.fmi.fmi_slave.DefaultExperiment(start_time=0.0, stop_time=20.0,
                                                              step_size=0.01)
    reference_inputs = {"theta_f": ((0.0, 0.2),), "v_f": ((0.0, 0.5),),
                        "theta_b": ((0.0, -0.2),), "v_b": ((0.0, 0.5),)}

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.input("theta_f", 0.0, "rad", "Front wheel angle to the body axis X', positive left")
        self.input("v_f", 0.0, "m/s", "Front wheel ground speed (negative: backwards)")
        self.input("theta_b", 0.0, "rad", "Rear wheel angle to the body axis X', positive left")
        self.input("v_b", 0.0, "m/s", "Rear wheel ground speed (negative: backwards)")
        self.parameter("wheelbase", DEFAULTS["wheelbase"], "m",
                       "Distance L between the wheel contact points")
        self.parameter("x0", DEFAULTS["x0"], "m", "Initial x of the centroid")
        self.parameter("y0", DEFAULTS["y0"], "m", "Initial y of the centroid")
        self.parameter("yaw0", DEFAULTS["yaw0"], "rad",
                       "Initial body yaw, counter-clockwise from x")
        self.output("x", "m", "x of the centroid C (midway between the wheels)")
        self.output("y", "m", "y of the centroid C")
        self.output("yaw", "rad", "Body yaw psi (direction of X'), continuous")
        self.output("course", "rad", "Course of the centroid velocity: yaw plus sideslip",
                    depends_on=WHEEL_INPUTS)
        self.output("speed", "m/s", "Centroid speed v_c", depends_on=WHEEL_INPUTS)
        self.output("yaw_rate", "rad/s", "Yaw rate omega", depends_on=WHEEL_INPUTS)
        self.output("stretch", "m/s",
                    "Vf cos(theta_f) - Vb cos(theta_b): non-zero when the wheel inputs "
                    "violate the rigid-body condition (least-squares twist used)",
                    depends_on=WHEEL_INPUTS)
        self.output("x_front", "m", "x of the front wheel contact point")
        self.output("y_front", "m", "y of the front wheel contact point")
        self.output("x_rear", "m", "x of the rear wheel contact point")
        self.output("y_rear", "m", "y of the rear wheel contact point")
        self.output("distance", "m", "Distance travelled by the centroid")

    def make_core(self) -> Any:
        return core.double_steer.double_steer.DoubleSteerVehicle(self.wheelbase, self.x0,
                                                                 self.y0, self.yaw0)

    def _wheels(self) -> tuple[float, float, float, float]:
        return self.theta_f, self.v_f, self.theta_b, self.v_b

    def advance(self, t: float, h: float) -> None:
        self.core.step(*self._wheels(), h)

    def publish(self) -> None:
        c = self.core
        u, v, w, stretch = c.twist(*self._wheels())
        self.x, self.y, self.yaw = c.x, c.y, c.yaw
        self.course = c.course(*self._wheels())
        self.speed = math.hypot(u, v)
        self.yaw_rate, self.stretch = w, stretch
        self.x_front, self.y_front = c.front()
        self.x_rear, self.y_rear = c.rear()
        self.distance = c.distance
        self.finite_or_fail(x=self.x, y=self.y, yaw=self.yaw)
