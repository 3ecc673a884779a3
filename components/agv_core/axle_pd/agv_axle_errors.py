"""FMU slave: lateral errors of seed 003's four axle tracking points from a reference path
(agv_core.track_path)."""

from typing import Any

from agv_boot import load_core

core: Any = load_core("fmi.fmi_slave", "axle_pd.track_path", "numerics.paths")

_AXLES = (1, 2, 3, 4)


class AgvAxleErrors(core.fmi.fmi_slave.AgvSlave):
    """Noise-free probe: four points in, their signed offsets from the path out."""

    description = ("Lateral errors of four tracking points (seed 003's axle centres) from "
                   "a reference path, positive left of the path; noise-free, no delay")

    #: Reference: four points held on either side of the default path (the x axis), moved
    #: at 0.5 s: e_i = y_i and s_i = x_i exactly.
    default_experiment = core.fmi.fmi_slave.DefaultExperiment(start_time=0.0, stop_time=1.0,
                                                              step_size=0.1)
    reference_inputs = {"x1": ((0.0, 10.0), (0.5, 12.0)), "y1": ((0.0, 0.5), (0.5, -0.25)),
                        "x2": ((0.0, 7.0), (0.5, 9.0)), "y2": ((0.0, -0.3), (0.5, 0.125)),
                        "x3": ((0.0, -2.0), (0.5, 0.0)), "y3": ((0.0, 0.2), (0.5, 0.0)),
                        "x4": ((0.0, -5.0), (0.5, -3.0)), "y4": ((0.0, 0.0), (0.5, 1.5))}

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        for i in _AXLES:
            self.input(f"x{i}", 0.0, "m", f"x of tracking point {i}")
            self.input(f"y{i}", 0.0, "m", f"y of tracking point {i}")
        self.parameter("path", "line", None,
                       "Reference path: 'curve:straight=..,radius=..,angle=..,transition=..' "
                       "or any agv_core.numerics.paths kind", kind=core.fmi.fmi_slave.String)
        for i in _AXLES:
            self.output(f"e{i}", "m", f"Signed lateral error of point {i}, positive left of "
                        "the path", depends_on=(f"x{i}", f"y{i}"))
        for i in _AXLES:
            self.output(f"s{i}", "m", f"Arc length of point {i}'s projection on the path",
                        depends_on=(f"x{i}", f"y{i}"))

    def make_core(self) -> Any:
        track_path = core.axle_pd.track_path
        return track_path.PointErrors(track_path.parse_track_path(self.path), 4)

    def _points(self) -> list[tuple[float, float]]:
        return [(getattr(self, f"x{i}"), getattr(self, f"y{i}")) for i in _AXLES]

    def advance(self, t: float, h: float) -> None:
        self.core.measure(self._points(), commit=True)   # hints from the held points

    def publish(self) -> None:
        for i, p in zip(_AXLES, self.core.measure(self._points())):
            setattr(self, f"e{i}", p.offset)
            setattr(self, f"s{i}", p.s)
