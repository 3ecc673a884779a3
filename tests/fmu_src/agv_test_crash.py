"""Test FMU: kills the process that runs it (SIGABRT) once t >= crash_time, or in
fmi2ExitInitializationMode when ``crash_time`` < 0."""

import os

from agv_boot import load_core

core = load_core("fmi.fmi_slave")


class AgvTestCrash(core.fmi.fmi_slave.AgvSlave):
    """Counts time; aborts its host process from ``crash_time`` on (a crashing FMU)."""

    description = "Test FMU that crashes its host at a given time"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.parameter("crash_time", 1.0, "s", "Time from which doStep aborts the process "
                       "(< 0: initialisation aborts it)")
        self.output("t_out", "s", "Current time")

    def make_core(self):
        if self.crash_time < 0.0:
            os.abort()
        return {"crash_time": float(self.crash_time)}

    def advance(self, t, h):
        if t + 1e-12 >= self.core["crash_time"]:
            os.abort()

    def publish(self):
        self.t_out = self.time
