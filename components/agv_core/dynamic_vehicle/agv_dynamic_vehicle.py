"""FMU slave: dynamic single-track vehicle with tyre forces (agv_core.dynamic_vehicle)."""

from math import isfinite
from typing import Any

from agv_boot import load_core

core: Any = load_core("fmi.fmi_slave", "dynamic_vehicle.dynamic_vehicle", "fmi.defaults")
_MODULE = core.dynamic_vehicle.dynamic_vehicle
DEFAULTS = core.fmi.defaults.defaults_of(  # the core's defaults (written once)
    _MODULE.DynamicVehicle, _MODULE.SingleTrackParameters)


class AgvDynamicVehicle(core.fmi.fmi_slave.AgvSlave):
    """Single-track vehicle with lateral tyre forces; AgvVehicle's interface plus slip
    angles, lateral acceleration and yaw rate."""

    description = ("Dynamic single-track AGV (bicycle model with Fiala or linear tyres, "
                   "combined slip of the driven wheels, load transfer, tip-over check): "
                   "steered-wheel angle and speed in, pose and lateral dynamics out; "
                   "drop-in for AgvVehicle")

    #: Reference: straight at 1 m/s, the wheel steps to 0.2 rad at 1 s, the speed to 3 m/s
    #: at 5 s (the yaw rate rises with a lag and, at 3 m/s, settles below the kinematic
    #: u tan(0.2) / L: the tyres slip).
    default_experiment = core.fmi.fmi_slave.DefaultExperiment(start_time=0.0, stop_time=10.0,
                                                              step_size=0.01)
    reference_inputs = {"alpha": ((0.0, 0.0), (1.0, 0.2)), "dv": ((0.0, 0.0), (5.0, 2.0))}

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        S, B = core.fmi.fmi_slave.String, core.fmi.fmi_slave.Boolean
        self.input("alpha", 0.0, "rad", "Steered-wheel angle, positive turns left",
                   builds_core=True)
        self.input("dv", 0.0, "m/s", "Speed added to v0 (a speed profile; with v0 = 0 the "
                   "longitudinal speed)", builds_core=True)
        self.parameter("v0", 1.0, "m/s", "Constant part of the body's longitudinal speed "
                       "(held by the drive); the speed is v0 + dv")
        self.parameter("wheelbase", DEFAULTS["wheelbase"], "m",
                       "Wheelbase L, rear-axle centre to front wheel")
        self.parameter("x0", DEFAULTS["x0"], "m", "Initial x of the reference point")
        self.parameter("y0", DEFAULTS["y0"], "m", "Initial y of the reference point")
        self.parameter("heading0", DEFAULTS["heading0"], "rad",
                       "Initial heading, counter-clockwise from x")
        self.parameter("reference_point", DEFAULTS["reference_point"], None,
                       "Point reported as x, y: 'front' (wheel centre, seed 000) or 'rear' "
                       "(axle centre, seed 004)", kind=S)
        self.parameter("linear", DEFAULTS["linear"], None,
                       "The linear single-track model (linear tyres, small angles, exact "
                       "discretisation); tyre and mu are then not used", kind=B)
        self.parameter("mass", DEFAULTS["mass"], "kg", "Vehicle mass m")
        self.parameter("yaw_inertia", DEFAULTS["yaw_inertia"], "kg.m2",
                       "Yaw moment of inertia Iz about the centre of gravity")
        self.parameter("cg_to_rear", DEFAULTS["cg_to_rear"], "m",
                       "Rear-axle centre to the centre of gravity, b (0 < b < L)")
        self.parameter("cornering_stiffness_front", DEFAULTS["cornering_stiffness_front"],
                       "N/rad", "Cornering stiffness C_f of the front axle (its tyres together)")
        self.parameter("cornering_stiffness_rear", DEFAULTS["cornering_stiffness_rear"],
                       "N/rad", "Cornering stiffness C_r of the rear axle (its tyres together)")
        self.parameter("mu", DEFAULTS["mu"], "1", "Tyre-ground friction coefficient (Fiala "
                       "tyre: a wheel's force saturates at mu times its load, less what its "
                       "drive force takes)")
        self.parameter("tyre", DEFAULTS["tyre"], None,
                       "Tyre law of the nonlinear model: 'fiala' (brush model, saturating) "
                       "or 'linear'", kind=S)
        self.parameter("cg_height", DEFAULTS["cg_height"], "m",
                       "Height h of the centre of gravity above the ground (load transfer; "
                       "0: static loads)")
        self.parameter("track", DEFAULTS["track"], "m",
                       "Track t: distance between the left and right wheels of an axle")
        self.parameter("layout", DEFAULTS["layout"], None,
                       "'four' (two wheels per axle) or 'three' (one front wheel on the "
                       "centre line, two rear wheels)", kind=S)
        self.parameter("drive", DEFAULTS["drive"], None,
                       "Axle whose wheels carry the drive force that holds the speed: "
                       "'rear', 'front', or 'ideal' (the drive force costs no friction)",
                       kind=S)
        self.parameter("kinematic_below", DEFAULTS["kinematic_below"], "m/s",
                       "Below this speed the kinematic model runs (the dynamic one is "
                       "singular at standstill)")
        self.parameter("tolerance", DEFAULTS["tolerance"], "1",
                       "Bound on the estimated local error per step of each state, "
                       "relative to 1 + |state| (nonlinear model)")
        self.output("x", "m", "x of the reference point")
        self.output("y", "m", "y of the reference point")
        self.output("heading", "rad", "Heading, counter-clockwise from the x axis")
        self.output("x_rear", "m", "x of the rear-axle centre")
        self.output("y_rear", "m", "y of the rear-axle centre")
        self.output("x_front", "m", "x of the front-wheel centre")
        self.output("y_front", "m", "y of the front-wheel centre")
        self.output("distance", "m", "Distance travelled by the rear-axle centre")
        self.output("yaw_rate", "rad/s", "Yaw rate r, counter-clockwise positive")
        self.output("lateral_velocity", "m/s",
                    "Lateral velocity of the centre of gravity in the body frame, positive left")
        self.output("sideslip", "rad", "Sideslip angle of the centre of gravity, "
                    "atan2(lateral velocity, longitudinal speed)")
        self.output("slip_front", "rad", "Front tyre slip angle over the last step: velocity "
                    "direction minus wheel angle (0 in the kinematic regime)")
        self.output("slip_rear", "rad", "Rear tyre slip angle over the last step: velocity "
                    "direction minus wheel angle (0 in the kinematic regime)")
        self.output("lateral_acceleration", "m/s2", "Lateral acceleration of the centre of "
                    "gravity in the body frame over the last step, positive left")
        self.output("lateral_force_front", "N", "Front axle lateral tyre force, perpendicular "
                    "to the wheel, positive left (0 in the kinematic regime)")
        self.output("lateral_force_rear", "N", "Rear axle lateral tyre force, positive left "
                    "(0 in the kinematic regime)")
        for axle in ("front", "rear"):
            for side in ("left", "right"):
                self.output(f"load_{axle}_{side}", "N",
                            f"Vertical load of the {axle} {side} wheel over the last step "
                            "(layout 'three': each holds half the front wheel's load)")
        self.output("drive_force_front", "N", "Longitudinal force of the front wheels that "
                    "holds the speed, along the wheels (0 unless drive = 'front')")
        self.output("drive_force_rear", "N", "Longitudinal force of the rear wheels that "
                    "holds the speed (0 unless drive = 'rear')")
        self.output("friction_use_front", "1", "Largest sqrt(Fx^2 + Fy^2) / (mu Fz) of the "
                    "front wheels: 1 at the friction limit")
        self.output("friction_use_rear", "1", "Largest sqrt(Fx^2 + Fy^2) / (mu Fz) of the "
                    "rear wheels")
        self.output("tip_margin", "1", "Smallest wheel load over its static load: 1 at rest, "
                    "0 when a wheel lifts (the step then fails naming the wheel)")

    def make_core(self) -> Any:
        params = _MODULE.SingleTrackParameters(
            self.wheelbase, self.mass, self.yaw_inertia, self.cg_to_rear,
            self.cornering_stiffness_front, self.cornering_stiffness_rear, self.mu, self.tyre,
            self.cg_height, self.track, self.layout, self.drive)
        return _MODULE.DynamicVehicle(params, self.x0, self.y0, self.heading0,
                                      self.reference_point, self.linear, self.kinematic_below,
                                      self.tolerance, self.alpha, self.v0 + self.dv)

    def advance(self, t: float, h: float) -> None:
        self.core.step(self.alpha, self.v0 + self.dv, h)

    def publish(self) -> None:
        c = self.core
        self.x_rear, self.y_rear = c.rear()
        self.x_front, self.y_front = c.front()
        if c.reference_point == "rear":
            self.x, self.y = self.x_rear, self.y_rear
        else:
            self.x, self.y = self.x_front, self.y_front
        self.heading = c.psi
        self.distance = c.distance
        self.yaw_rate, self.lateral_velocity = c.r, c.vy
        self.sideslip = c.sideslip()
        slip_f, slip_r, ff, fr, dvy, _ = c.lateral()
        self.slip_front, self.slip_rear = slip_f, slip_r
        self.lateral_force_front, self.lateral_force_rear = ff, fr
        self.lateral_acceleration = c.lateral_acceleration(dvy)
        tyres = c.tyre_state()
        (self.load_front_left, self.load_front_right, self.load_rear_left,
         self.load_rear_right) = tyres["loads"]
        self.drive_force_front, self.drive_force_rear = tyres["drive_front"], tyres["drive_rear"]
        self.friction_use_front = tyres["friction_front"]
        self.friction_use_rear = tyres["friction_rear"]
        self.tip_margin = tyres["tip_margin"]
        if not isfinite(self.x + self.y + self.heading + self.yaw_rate + self.lateral_velocity):
            self.finite_or_fail(x=self.x, y=self.y, heading=self.heading,
                                yaw_rate=self.yaw_rate, lateral_velocity=self.lateral_velocity)
