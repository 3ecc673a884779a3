"""FMU slave: symmetric-steering inverse kinematics of seed 001 (agv_core.double_steer)."""

from typing import Any

from agv_boot import load_core

core: Any = load_core("fmi.fmi_slave", "double_steer.double_steer")


class AgvDoubleSteerIk(core.fmi.fmi_slave.AgvSlave):
    """(v_c, omega) commands to wheel-angle set-points and wheel speeds, theta_b = -theta_f."""

    description = ("Double-steer AGV inverse kinematics (seed 001): centroid speed and yaw "
                   "rate commands in, symmetric wheel angles and speeds out")

    #: Reference: v_c = 0.4 m/s with omega stepping 0 -> 0.074 -> -0.3 rad/s (1 s each).
    default_experiment = core.fmi.fmi_slave.DefaultExperiment(start_time=0.0, stop_time=3.0,
                                                              step_size=0.1)
    reference_inputs = {"v_c": ((0.0, 0.4),), "omega": ((0.0, 0.0), (1.0, 0.074), (2.0, -0.3))}

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.input("v_c", 0.0, "m/s", "Commanded centroid speed along the body axis")
        self.input("omega", 0.0, "rad/s", "Commanded yaw rate, positive counter-clockwise")
        self.parameter("wheelbase", 1.0, "m", "Distance L between the wheel contact points")
        both = ("v_c", "omega")
        self.output("theta_f", "rad", "Front wheel angle atan2(omega L/2, v_c)", depends_on=both)
        self.output("v_f", "m/s", "Front wheel speed sqrt(v_c^2 + (omega L/2)^2)",
                    depends_on=both)
        self.output("theta_b", "rad", "Rear wheel angle -theta_f", depends_on=both)
        self.output("v_b", "m/s", "Rear wheel speed (= v_f)", depends_on=both)

    def make_core(self) -> Any:
        return core.double_steer.double_steer.InverseKinematics(self.wheelbase)

    def advance(self, t: float, h: float) -> None:
        pass  # algebraic

    def publish(self) -> None:
        self.theta_f, self.v_f, self.theta_b, self.v_b = \
            self.core.command(self.v_c, self.omega)
        self.finite_or_fail(theta_f=self.theta_f, v_f=self.v_f)
