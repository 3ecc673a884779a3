"""FMU slave: per-axle Ackermann coordination about each car's hinge baseline
(agv_core.ackermann)."""

from typing import Any

from agv_boot import load_core

core: Any = load_core("fmi.fmi_slave", "ackermann.ackermann", "train.train")

_AXLES = (1, 2, 3, 4)


class AgvAckermann(core.fmi.fmi_slave.AgvSlave):
    """Seed 003 single-axle coordination: four axle angles in, eight wheel angles out."""

    description = ("Seed 003 per-axle Ackermann coordination: each axle's turning centre on "
                   "its car's hinge baseline sets its left and right wheel angles")

    #: Reference: the steady R = 20 m left-circle angles (+-asin(L1 / 2R), front +, rear -)
    #: from 0.5 s, then a right turn (signs flipped) from 1.0 s: each wheel angle against
    #: tan(dL) = l t / (l - (d/2) t), tan(dR) = l t / (l + (d/2) t), t = tan(delta).
    default_experiment = core.fmi.fmi_slave.DefaultExperiment(start_time=0.0, stop_time=1.5,
                                                              step_size=0.1)
    reference_inputs = {f"delta{i}": ((0.0, 0.0), (0.5, sign * 0.1253278311680654),
                                      (1.0, -sign * 0.1253278311680654))
                        for i, sign in zip(_AXLES, (1.0, -1.0, 1.0, -1.0))}

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        for i in _AXLES:
            self.input(f"delta{i}", 0.0, "rad",
                       f"Axle-equivalent steering angle of axle {i}, positive left")
        self.parameter("L1", 5.0, "m", "Axle spacing of each powered car")
        self.parameter("L2", 3.0, "m", "Inner axle to the car's hinge (baseline)")
        self.parameter("d", 2.1, "m", "Track width")
        for i in _AXLES:
            for side in ("left", "right"):
                self.output(f"delta{i}_{side}", "rad",
                            f"{side.capitalize()} wheel angle of axle {i}, positive left",
                            depends_on=(f"delta{i}",))
        for i in _AXLES:
            self.output(f"centre_curvature{i}", "1/m",
                        f"1/R of axle {i}'s turning centre on the baseline (positive: left "
                        "of the car's centre line; 0 = straight)", depends_on=(f"delta{i}",))

    def make_core(self) -> Any:
        geometry = core.train.train.TrainGeometry(self.L1, self.L2, self.d)
        return core.ackermann.ackermann.TrainCoordination(geometry.axle_offsets, geometry.d)

    def advance(self, t: float, h: float) -> None:
        pass  # static map: publish() evaluates it from the held inputs

    def publish(self) -> None:
        c = self.core
        deltas = [getattr(self, f"delta{i}") for i in _AXLES]
        for i, delta, offset, (left, right) in zip(_AXLES, deltas, c.offsets,
                                                   c.wheels(deltas)):
            setattr(self, f"delta{i}_left", left)
            setattr(self, f"delta{i}_right", right)
            setattr(self, f"centre_curvature{i}",
                    core.ackermann.ackermann.turning_curvature(delta, offset))
