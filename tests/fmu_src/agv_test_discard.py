"""Test FMU: y = t, whose doStep returns False from ``discard_time`` on.

pythonfmu 0.7 turns a False ``do_step`` into ``fmi2Discard`` with
``fmi2GetBooleanStatus(fmi2Terminated)`` true and ``fmi2LastSuccessfulTime`` = the start
of the refused step (measured): a stop request in the middle of a macro step.
"""

from agv_boot import load_core

core = load_core("fmi.fmi_slave")


class AgvTestDiscard(core.fmi.fmi_slave.AgvSlave):
    """y = t; refuses every step from discard_time on (a stop request)."""

    description = "Test FMU that asks to stop (fmi2Discard + terminated) at a given time"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.parameter("discard_time", 0.3, "s", "Time from which doStep is refused")
        self.output("y", "s", "Current time")

    def make_core(self):
        return {"discard_time": float(self.discard_time)}

    def advance(self, t, h):
        pass

    def publish(self):
        self.y = self.time

    def do_step(self, current_time, step_size):
        super().do_step(current_time, step_size)
        return current_time + 1e-12 < self.core["discard_time"]
