"""Test FMU: ramp source y = offset + slope * t (no inputs)."""

from agv_boot import load_core

core = load_core("fmi.fmi_slave")


class RampCore:
    """Ramp y(t) = offset + slope * t [1]; JSON-safe state is the time [s]."""

    def __init__(self, offset, slope, t0):
        self.offset, self.slope, self.t = float(offset), float(slope), float(t0)

    def step(self, h):
        self.t += h

    @property
    def y(self):
        return self.offset + self.slope * self.t

    def get_state(self):
        return {"t": self.t}

    def set_state(self, state):
        self.t = float(state["t"])


class AgvTestSource(core.fmi.fmi_slave.AgvSlave):
    """Ramp source for orchestrator tests."""

    description = "Test source: y = offset + slope * t"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.parameter("offset", 0.0, "1", "Value at t = 0")
        self.parameter("slope", 1.0, "1/s", "Rate of change")
        self.output("y", "1", "Ramp value")
        self.output("t_out", "s", "Current time")
        self.output("count", None, "Number of steps taken", kind=core.fmi.fmi_slave.Integer,
                    start=0)

    def make_core(self):
        return RampCore(self.offset, self.slope, self.time)

    def advance(self, t, h):
        self.core.step(h)
        self.count += 1

    def publish(self):
        self.y = self.core.y
        self.t_out = self.core.t
