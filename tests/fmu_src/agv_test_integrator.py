"""Test FMU: integrator y' = u, exact for an input held over the step."""

from agv_boot import load_core

core = load_core("fmi.fmi_slave")


class AgvTestIntegrator(core.fmi.fmi_slave.AgvSlave):
    """Integrator for orchestrator tests (no direct feedthrough)."""

    description = "Test integrator: dy/dt = u"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("u", 0.0, "1", "Rate input")
        self.parameter("y0", 0.0, "1", "Initial value")
        self.output("y", "1", "Integral of u")

    def make_core(self):
        return {"y": float(self.y0)}

    def advance(self, t, h):
        self.core["y"] += h * self.u

    def publish(self):
        self.y = self.core["y"]
