"""Test FMU: static gain y = k * u (direct feedthrough)."""

from agv_boot import load_core

core = load_core("fmi.fmi_slave")


class AgvTestGain(core.fmi.fmi_slave.AgvSlave):
    """Static gain for orchestrator tests (output depends directly on the input)."""

    description = "Test gain: y = k * u"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("u", 0.0, "1", "Input")
        self.parameter("k", 1.0, "1", "Gain")
        self.output("y", "1", "k * u", depends_on=("u",))

    def make_core(self):
        return {"k": float(self.k)}

    def advance(self, t, h):
        pass

    def publish(self):
        self.y = self.core["k"] * self.u
