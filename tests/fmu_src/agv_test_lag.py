"""Test FMU: first-order lag tau x' = u - x, exact for an input held over the step."""

import math

from agv_boot import load_core

core = load_core("fmi.fmi_slave")


class AgvTestLag(core.fmi.fmi_slave.AgvSlave):
    """First-order lag for orchestrator tests (no direct feedthrough): over a step of
    length h with u held, x <- u + (x - u) exp(-h / tau), the exact solution."""

    description = "Test lag: tau dx/dt = u - x"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("u", 0.0, "1", "Input")
        self.parameter("tau", 1.0, "s", "Time constant")
        self.parameter("x0", 0.0, "1", "Initial value")
        self.output("x", "1", "State")

    def make_core(self):
        return {"x": float(self.x0), "tau": float(self.tau)}

    def advance(self, t, h):
        state = self.core
        u = self.u
        state["x"] = u + (state["x"] - u) * math.exp(-h / state["tau"])

    def publish(self):
        self.x = self.core["x"]
