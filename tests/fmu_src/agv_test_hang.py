"""Test FMU: hangs in doStep once t >= hang_time (busy or blocked), or in initialisation.

``hang_time`` < 0 hangs in fmi2ExitInitializationMode instead. ``busy`` true spins in a
Python loop (the CPU busy), false blocks in a sleep. The hang lasts ``hang_seconds``
(long enough that only a wall-clock limit ends the run).
"""

import time

from agv_boot import load_core

core = load_core("fmi.fmi_slave")


def _hang(seconds, busy):
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if not busy:
            time.sleep(min(1.0, max(0.0, end - time.monotonic())))


class AgvTestHang(core.fmi.fmi_slave.AgvSlave):
    """Counts time; from ``hang_time`` on doStep does not return for ``hang_seconds``."""

    description = "Test FMU that hangs at a given time"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        fs = core.fmi.fmi_slave
        self.parameter("hang_time", 1.0, "s", "Time from which doStep hangs (< 0: hang "
                       "in initialisation)")
        self.parameter("hang_seconds", 3600.0, "s", "How long a hang lasts")
        self.parameter("busy", False, None, "Spin (true) or sleep (false)", kind=fs.Boolean)
        self.output("t_out", "s", "Current time")

    def make_core(self):
        if self.hang_time < 0.0:
            _hang(float(self.hang_seconds), bool(self.busy))
        return {"hang_time": float(self.hang_time)}

    def advance(self, t, h):
        if t + 1e-12 >= self.core["hang_time"]:
            _hang(float(self.hang_seconds), bool(self.busy))

    def publish(self):
        self.t_out = self.time
