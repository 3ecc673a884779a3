"""FMU slave: seed 003's three-car articulated train, four steered axles (agv_core.train)."""

from typing import Any

from agv_boot import load_core

core: Any = load_core("fmi.fmi_slave", "train.train", "ackermann.ackermann", "fmi.defaults")
DEFAULTS = core.fmi.defaults.defaults_of(  # the core's defaults (written once)
    core.train.train.Train, core.train.train.TrainGeometry)

_AXLES = (1, 2, 3, 4)
_SIDES = ("left", "right")


class AgvTrain(core.fmi.fmi_slave.AgvSlave):
    """Head car, floating middle car, tail car; axle angles (or wheel angles) in, poses out."""

    description = ("Seed 003 three-car virtual-rail train (head car, floating middle car, "
                   "tail car), planar kinematics with four steered axles: head car exact "
                   "arc, articulation by RK4 with step doubling")

    #: Reference: axle 1 held at 0.05 rad, axles 2-4 straight, from a straight start at
    #: v0 = 14 km/h, dv = +1 m/s from 5 s. Closed forms: the head car is exact,
    #: heading1 = tan(0.05) / L1 * distance, distance = 10 v0 + 5 m; the tail car cannot
    #: turn (omega3 = 0, no side slip at J2), so heading3 = 0 and y_J2 = 0 while the
    #: floating car swings (|J1 - J2| = Lm). (Open loop the Ackermann steady-circle angles
    #: from a straight start jack-knife within seconds: see components/README.md.)
    default_experiment = core.fmi.fmi_slave.DefaultExperiment(start_time=0.0, stop_time=10.0,
                                                              step_size=0.05)
    reference_inputs = {"delta1": ((0.0, 0.05),), "dv": ((0.0, 0.0), (5.0, 1.0))}

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        S = core.fmi.fmi_slave.String
        self.input("dv", 0.0, "m/s", "Speed added to v0 (a speed profile; with v0 = 0 the "
                   "head car's longitudinal speed u1, body x velocity)", builds_core=True)
        for i in _AXLES:
            self.input(f"delta{i}", 0.0, "rad",
                       f"Axle-equivalent steering angle of axle {i}, positive left "
                       "(steering_input 'axle')")
        for i in _AXLES:
            for side in _SIDES:
                self.input(f"delta{i}_{side}", 0.0, "rad",
                           f"{side.capitalize()} wheel angle of axle {i}, positive left "
                           "(steering_input 'wheels')")
        self.parameter("L1", DEFAULTS["L1"], "m",
                       "Axle spacing of each powered car (head-car wheelbase)")
        self.parameter("L2", DEFAULTS["L2"], "m",
                       "Inner axle (head: rear, tail: front) to the car's hinge")
        self.parameter("d", DEFAULTS["d"], "m", "Track width (wheel slip diagnostics)")
        self.parameter("Lm", DEFAULTS["Lm"], "m", "Floating car, hinge J1 to hinge J2")
        self.parameter("v0", 14.0 / 3.6, "m/s", "Constant part of the head car's longitudinal "
                       "speed u1 (14 km/h); u1 = v0 + dv")
        self.parameter("x0", 0.0, "m", "Initial x of axle 1's centre (train straight)")
        self.parameter("y0", 0.0, "m", "Initial y of axle 1's centre (train straight)")
        self.parameter("heading0", 0.0, "rad", "Initial heading of the straight train, "
                       "counter-clockwise from x")
        self.parameter("steering_input", "axle", None,
                       "'axle': inputs delta1..delta4; 'wheels': inputs deltaI_left/right, "
                       "converted by the exact Ackermann inverse cot(delta) = mean of the "
                       "wheel cotangents", kind=S)
        self.parameter("tolerance", DEFAULTS["tolerance"], "rad",
                       "Bound on the estimated local error of the articulation angles per step")
        self.output("x_J1", "m", "x of hinge J1 (head car / floating car)")
        self.output("y_J1", "m", "y of hinge J1")
        self.output("x_J2", "m", "x of hinge J2 (floating car / tail car)")
        self.output("y_J2", "m", "y of hinge J2")
        self.output("heading1", "rad", "Head-car heading, counter-clockwise from x")
        self.output("heading2", "rad", "Floating-car heading (J2 towards J1)")
        self.output("heading3", "rad", "Tail-car heading")
        for i in _AXLES:
            self.output(f"x{i}", "m", f"x of axle {i}'s centre (tracking point)")
            self.output(f"y{i}", "m", f"y of axle {i}'s centre (tracking point)")
        for i in _AXLES:
            self.output(f"delta{i}_applied", "rad",
                        f"Axle-equivalent angle of axle {i} applied over the last step")
        self.output("u1", "m/s", "Longitudinal speed of the head car over the last step "
                    "(v0 + dv at initialisation before the first step)")
        self.output("u3", "m/s", "Longitudinal speed of the tail car (from the link, with "
                    "the last step's speed and axle angles)")
        self.output("distance", "m", "Distance travelled by the head car (|u1| t)")
        for i in _AXLES:
            for side in _SIDES:
                self.output(f"slip{i}_{side}", "rad",
                            f"Slip angle of axle {i}'s {side} wheel over the last step: "
                            "velocity direction minus wheel angle")
                self.output(f"speed{i}_{side}", "m/s",
                            f"Ground speed of axle {i}'s {side} wheel over the last step")

    def make_core(self) -> Any:
        if self.steering_input not in ("axle", "wheels"):
            raise core.errors.ParameterError(
                "steering_input", f"must be 'axle' or 'wheels', got '{self.steering_input}'")
        geometry = core.train.train.TrainGeometry(self.L1, self.L2, self.d, self.Lm)
        train = core.train.train.Train.straight(geometry, self.x0, self.y0, self.heading0,
                                                self.tolerance)
        train.u1 = float(self.v0 + self.dv)  # moving before the start: u1, u3 outputs at t0
        return train

    def advance(self, t: float, h: float) -> None:
        speed = self.v0 + self.dv
        if self.steering_input == "wheels":
            pairs = [(getattr(self, f"delta{i}_left"), getattr(self, f"delta{i}_right"))
                     for i in _AXLES]
            deltas = [core.ackermann.ackermann.axle_angle(*p) for p in pairs]
            self.core.step(speed, deltas, h, wheels=pairs)
        else:
            self.core.step(speed, [getattr(self, f"delta{i}") for i in _AXLES], h)

    def publish(self) -> None:
        c = self.core
        self.x_J1, self.y_J1 = c.x1, c.y1
        self.x_J2, self.y_J2 = c.hinge2()
        self.heading1, self.heading2, self.heading3 = c.psi1, c.psi2, c.psi3
        for i, (x, y) in zip(_AXLES, c.axle_points()):
            setattr(self, f"x{i}", x)
            setattr(self, f"y{i}", y)
            setattr(self, f"delta{i}_applied", c.deltas[i - 1])
        self.u1 = c.u1
        self.u3 = c.car_rates()[0]
        self.distance = c.distance
        states = iter(c.wheel_states())
        for i in _AXLES:
            for side in _SIDES:
                speed, slip = next(states)
                setattr(self, f"slip{i}_{side}", slip)
                setattr(self, f"speed{i}_{side}", speed)
        self.finite_or_fail(x_J1=self.x_J1, y_J1=self.y_J1, heading2=self.heading2,
                            heading3=self.heading3)
