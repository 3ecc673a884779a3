"""FMU slave: seed 003's three-car train with tyre forces on every axle
(agv_core.dynamic_train), a drop-in for AgvTrain."""

from typing import Any

from agv_boot import load_core

core: Any = load_core("fmi.fmi_slave", "dynamic_train.dynamic_train", "ackermann.ackermann",
                 "fmi.defaults")
_MODULE = core.dynamic_train.dynamic_train
DEFAULTS = core.fmi.defaults.defaults_of(  # the core's defaults (written once)
    _MODULE.DynamicTrain, _MODULE.TrainDynamics, _MODULE.TrainGeometry)

_AXLES = (1, 2, 3, 4)
_SIDES = ("left", "right")


class AgvDynamicTrain(core.fmi.fmi_slave.AgvSlave):
    """Head car, floating car, tail car as rigid bodies with hinges and a lumped tyre per
    axle; AgvTrain's interface plus yaw rates, axle slips, tyre forces and accelerations."""

    description = ("Seed 003 three-car virtual-rail train, planar multibody dynamics: "
                   "rigid head, floating and tail cars, ideal hinges, lateral tyre forces on "
                   "the two wheels of each of the four steered axles (Fiala or linear, "
                   "Ackermann wheel angles, lateral load transfer); drop-in for AgvTrain")

    #: Reference: AgvTrain's reference inputs (axle 1 held at 0.05 rad, axles 2-4
    #: straight, 14 km/h, dv = +1 m/s from 5 s): the head car turns with tyre slip, the
    #: unsteered tail car is dragged round by the hinges, its tyres slipping.
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
                       "(steering_input 'axle')", builds_core=True)
        for i in _AXLES:
            for side in _SIDES:
                self.input(f"delta{i}_{side}", 0.0, "rad",
                           f"{side.capitalize()} wheel angle of axle {i}, positive left "
                           "(steering_input 'wheels')", builds_core=True)
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
        self.parameter("mass_end", DEFAULTS["mass_end"], "kg", "Mass of each end car")
        self.parameter("mass_float", DEFAULTS["mass_float"], "kg", "Mass of the floating car")
        self.parameter("inertia_end", DEFAULTS["inertia_end"], "kg.m2",
                       "Yaw inertia of each end car about its centre of gravity")
        self.parameter("inertia_float", DEFAULTS["inertia_float"], "kg.m2",
                       "Yaw inertia of the floating car about its centre")
        self.parameter("cg_end", DEFAULTS["cg_end"], "m",
                       "End car's hinge to its centre of gravity, along its axis towards "
                       "its axles")
        self.parameter("cornering_coefficient", DEFAULTS["cornering_coefficient"], "1/rad",
                       "Cornering stiffness of an axle per unit of its static vertical load")
        self.parameter("mu", DEFAULTS["mu"], "1", "Tyre-road friction coefficient (Fiala "
                       "tyre: an axle's force saturates at mu times its static load)")
        self.parameter("tyre", DEFAULTS["tyre"], None,
                       "Tyre law: 'fiala' (brush model, saturating) or 'linear'", kind=S)
        self.parameter("cg_height", DEFAULTS["cg_height"], "m",
                       "Height of the cars' centres of gravity (lateral load transfer "
                       "between each axle's wheels; 0: static wheel loads)")
        self.parameter("lumped_axles", DEFAULTS["lumped_axles"], None,
                       "One tyre per axle at its centre, turned by the axle angle, at the "
                       "static axle load (instead of two tyres per axle with their own "
                       "wheel angles and loads)", kind=core.fmi.fmi_slave.Boolean)
        self.parameter("kinematic_below", DEFAULTS["kinematic_below"], "m/s",
                       "Below this head-car speed the kinematic train runs (the dynamic one "
                       "is singular at standstill)")
        self.parameter("tolerance", DEFAULTS["tolerance"], "1",
                       "Bound on the estimated local error per step of each state, "
                       "relative to 1 + |state|")
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
        self.output("u3", "m/s", "Longitudinal speed of the tail car (J2's velocity along "
                    "the tail car's axis)")
        self.output("distance", "m", "Distance travelled by the head car (|u1| t)")
        for i in _AXLES:
            for side in _SIDES:
                self.output(f"slip{i}_{side}", "rad",
                            f"Slip angle of axle {i}'s {side} wheel over the last step: "
                            "velocity direction minus wheel angle (its tyre's input)")
                self.output(f"speed{i}_{side}", "m/s",
                            f"Ground speed of axle {i}'s {side} wheel over the last step")
        for k, car in ((1, "head car"), (2, "floating car"), (3, "tail car")):
            self.output(f"yaw_rate{k}", "rad/s", f"Yaw rate of the {car}")
        for i in _AXLES:
            self.output(f"axle_slip{i}", "rad", f"Slip angle of axle {i}'s centre against "
                        "the axle angle over the last step (the tyre law's input with "
                        "lumped_axles; 0 in the kinematic regime)")
            self.output(f"lateral_force{i}", "N", f"Lateral tyre force of axle {i} (sum of "
                        "its wheels' forces, each perpendicular to its wheel), positive "
                        "left (0 in the kinematic regime)")
        for i in _AXLES:
            for side in _SIDES:
                self.output(f"load{i}_{side}", "N", f"Vertical load of axle {i}'s {side} "
                            "wheel over the last step")
        for k, car in ((1, "head"), (3, "tail")):
            self.output(f"lateral_acceleration{k}", "m/s2",
                        f"Lateral acceleration of the {car} car's centre of gravity in its "
                        "frame, positive left")

    def make_core(self) -> Any:
        if self.steering_input not in ("axle", "wheels"):
            raise core.errors.ParameterError(
                "steering_input", f"must be 'axle' or 'wheels', got '{self.steering_input}'")
        geometry = _MODULE.TrainGeometry(self.L1, self.L2, self.d, self.Lm)
        dynamics = _MODULE.TrainDynamics(geometry, self.mass_end, self.mass_float,
                                         self.inertia_end, self.inertia_float, self.cg_end,
                                         self.cornering_coefficient, self.mu, self.tyre,
                                         self.cg_height, self.lumped_axles)
        train = _MODULE.DynamicTrain.straight(dynamics, self.x0, self.y0, self.heading0,
                                              self.kinematic_below, self.tolerance)
        deltas, pairs = self._steering()
        train.start(self.v0 + self.dv, deltas, pairs)  # moving before the start
        return train

    def _steering(self) -> tuple[list[float], tuple[tuple[float, float], ...] | None]:
        if self.steering_input == "wheels":
            pairs = tuple((getattr(self, f"delta{i}_left"), getattr(self, f"delta{i}_right"))
                          for i in _AXLES)
            return [core.ackermann.ackermann.axle_angle(*p) for p in pairs], pairs
        return [getattr(self, f"delta{i}") for i in _AXLES], None

    def advance(self, t: float, h: float) -> None:
        deltas, pairs = self._steering()
        self.core.step(self.v0 + self.dv, deltas, h, wheels=pairs)

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
        self.u3 = c.car_speeds()[3]
        self.distance = c.distance
        states = iter(c.wheel_states())
        for i in _AXLES:
            for side in _SIDES:
                speed, slip = next(states)
                setattr(self, f"slip{i}_{side}", slip)
                setattr(self, f"speed{i}_{side}", speed)
        self.yaw_rate1, self.yaw_rate2, self.yaw_rate3 = c.r1, c.r2, c.r3
        slips, forces = c.axle_forces()
        for i, slip, force in zip(_AXLES, slips, forces):
            setattr(self, f"axle_slip{i}", slip)
            setattr(self, f"lateral_force{i}", force)
        self.lateral_acceleration1, self.lateral_acceleration3 = c.lateral_accelerations()
        loads = iter(c.wheel_loads())
        for i in _AXLES:
            for side in _SIDES:
                setattr(self, f"load{i}_{side}", next(loads))
        self.finite_or_fail(x_J1=self.x_J1, y_J1=self.y_J1, heading2=self.heading2,
                            heading3=self.heading3, yaw_rate1=self.yaw_rate1)
