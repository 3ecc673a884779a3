"""Test FMU: passes u through and raises in doStep once t >= fail_time."""

from agv_boot import load_core

core = load_core("fmi.fmi_slave", "errors")


class AgvTestFail(core.fmi.fmi_slave.AgvSlave):
    """Feedthrough that fails (fmi2DoStep returns an error) from ``fail_time`` on."""

    description = "Test FMU that fails at a given time"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("u", 0.0, "1", "Input")
        self.parameter("fail_time", 1.0, "s", "Time from which doStep fails")
        self.output("y", "1", "Copy of u", depends_on=("u",))

    def make_core(self):
        if not self.fail_time >= 0.0:
            raise core.errors.ParameterError("fail_time", "must be >= 0")
        return {"fail_time": float(self.fail_time)}

    def advance(self, t, h):
        if t + 1e-12 >= self.core["fail_time"]:
            raise RuntimeError(f"deliberate failure at t={t}")

    def publish(self):
        self.y = self.u
