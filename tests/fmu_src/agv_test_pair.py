"""Test FMU: two independent feedthrough channels y1 = u1, y2 = n * u2.

Two of them wired crosswise (A.y1 -> B.u1, B.y2 -> A.u2) feed each other at the
component level without a loop between variables; n is an Integer parameter.
"""

from agv_boot import load_core

core = load_core("fmi.fmi_slave")


class AgvTestPair(core.fmi.fmi_slave.AgvSlave):
    """Two feedthrough channels for orchestrator tests."""

    description = "Test pair: y1 = u1, y2 = n * u2"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("u1", 0.0, "1", "First input")
        self.input("u2", 0.0, "1", "Second input")
        self.parameter("n", 1, None, "Integer gain of the second channel",
                       kind=core.fmi.fmi_slave.Integer)
        self.output("y1", "1", "u1", depends_on=("u1",))
        self.output("y2", "1", "n * u2", depends_on=("u2",))

    def make_core(self):
        return {"n": int(self.n)}

    def advance(self, t, h):
        pass

    def publish(self):
        self.y1 = self.u1
        self.y2 = self.core["n"] * self.u2
