"""Test FMU: outputs y = t until nan_time, then NaN."""

from agv_boot import load_core

core = load_core("fmi.fmi_slave")


class AgvTestNan(core.fmi.fmi_slave.AgvSlave):
    """Source whose output becomes NaN from ``nan_time`` on."""

    description = "Test FMU that outputs NaN from a given time"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.parameter("nan_time", 1.0, "s", "Time from which y is NaN")
        self.output("y", "1", "t, then NaN")

    def make_core(self):
        return {"nan_time": float(self.nan_time)}

    def advance(self, t, h):
        pass

    def publish(self):
        t = self.time
        self.y = float("nan") if t + 1e-12 >= self.core["nan_time"] else t
