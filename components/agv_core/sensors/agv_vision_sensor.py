"""FMU slave: camera measuring path deviation (agv_core.sensors.VisionSensor)."""

from math import isfinite
from typing import Any

from agv_boot import load_core

core: Any = load_core("fmi.fmi_slave", "numerics.paths", "sensors.sensors", "fmi.defaults")
DEFAULTS = core.fmi.defaults.defaults_of(  # the core's defaults (written once)
    core.sensors.sensors.VisionSensor)

_POSE = ("x", "y", "heading")


class AgvVisionSensor(core.fmi.fmi_slave.AgvSlave):
    """Vision sensor of seed 000: lateral deviation and heading error from a path."""

    #: publish reads the core (reads do not change what it shows) and sets outputs only
    lazy_publish = True

    description = ("Camera measuring lateral deviation and heading error of the tracked "
                   "point from a reference path, with frame period, latency and noise")

    #: Reference: the tracked point 0.1 m left of the default straight path with a 0.05 rad
    #: heading error, moving to 0.2 m at 0.5 s (frames, latency and noise as declared).
    default_experiment = core.fmi.fmi_slave.DefaultExperiment(start_time=0.0, stop_time=1.0,
                                                              step_size=0.01)
    reference_inputs = {"y": ((0.0, 0.1), (0.5, 0.2)), "heading": ((0.0, 0.05),)}

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.input("x", 0.0, "m", "x of the tracked point")
        self.input("y", 0.0, "m", "y of the tracked point")
        self.input("heading", 0.0, "rad", "Vehicle heading, counter-clockwise from x")
        self.parameter("path", "line", None,
                       "Reference path 'kind:key=value,...' (see components/README.md); a "
                       "waypoint file is relative to the host's working folder",
                       kind=core.fmi.fmi_slave.String)
        self.parameter("frame_period", DEFAULTS["frame_period"], "s",
                       "Frame capture period (PAL 25 frames/s); 0 = every communication "
                       "point")
        self.parameter("latency", DEFAULTS["latency"], "s",
                       "Image processing delay from capture to output")
        self.parameter("noise_lateral", DEFAULTS["noise_lateral"], "m",
                       "Std. dev. of the lateral-error noise")
        self.parameter("noise_heading", DEFAULTS["noise_heading"], "rad",
                       "Std. dev. of the heading-error noise")
        self.parameter("seed", DEFAULTS["seed"], None, "Random seed (>= 0)",
                       kind=core.fmi.fmi_slave.Integer)
        self.output("lateral_error", "m", "Lateral deviation from the path, positive left",
                    depends_on=_POSE)
        self.output("heading_error", "rad",
                    "Heading minus path heading, wrapped to (-pi, pi]", depends_on=_POSE)
        self.output("s", "m", "Arc length of the closest path point", depends_on=_POSE)
        self.output("curvature", "1/m", "Path curvature at s, positive turning left",
                    depends_on=_POSE)
        self.output("curvature_rate", "1/m2", "Path curvature derivative dc/ds at s",
                    depends_on=_POSE)

    def make_core(self) -> Any:
        path = core.numerics.paths.parse_path(self.path)
        return core.sensors.sensors.VisionSensor(path, self.frame_period, self.latency,
                                                 self.noise_lateral, self.noise_heading, self.seed,
                                                 self.time)

    def advance(self, t: float, h: float) -> None:
        self.core.step(t, h, self.x, self.y, self.heading)

    def publish(self) -> None:
        (self.lateral_error, self.heading_error, self.s, self.curvature,
         self.curvature_rate) = self.core.measure(self.time, self.x, self.y, self.heading)
        if not isfinite(self.lateral_error + self.s):  # finite iff every term is
            self.finite_or_fail(lateral_error=self.lateral_error, s=self.s)
