"""FMU slave: seed-000 state-feedback steering controller (agv_core.state_feedback)."""

from math import isfinite
from typing import Any

from agv_boot import load_core

core: Any = load_core("fmi.fmi_slave", "state_feedback.state_feedback", "fmi.defaults")
DEFAULTS = core.fmi.defaults.defaults_of(  # the core's defaults (written once)
    core.state_feedback.state_feedback.StateFeedback)


class AgvStateFeedback(core.fmi.fmi_slave.AgvSlave):
    """u = -(Ka alpha + Kb heading_error + Ke lateral_error), seed 000 eqs (9)-(10)."""

    #: publish reads the core (reads do not change what it shows) and sets outputs only
    lazy_publish = True

    description = ("Seed-000 state-feedback steering controller: wheel angle, heading error "
                   "and lateral error in, actuator voltage out")

    #: Reference: a 0.1 m lateral error from the start, a 0.05 rad heading error from
    #: 0.5 s and a -0.02 rad wheel angle from 1 s (u is their weighted sum).
    default_experiment = core.fmi.fmi_slave.DefaultExperiment(start_time=0.0, stop_time=2.0,
                                                              step_size=0.01)
    reference_inputs = {"lateral_error": ((0.0, 0.1),),
                        "heading_error": ((0.0, 0.0), (0.5, 0.05)),
                        "alpha": ((0.0, 0.0), (1.0, -0.02))}

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.input("alpha", 0.0, "rad", "Steered-wheel angle, positive steers left")
        self.input("heading_error", 0.0, "rad",
                   "Vehicle heading minus path heading, positive pointing left of the path")
        self.input("lateral_error", 0.0, "m",
                   "Signed distance of the front-wheel centre from the path, positive left")
        self.parameter("Ka", DEFAULTS["Ka"], "V/rad", "Gain on the wheel angle (seed 000 eq 10)")
        self.parameter("Kb", DEFAULTS["Kb"], "V/rad", "Gain on the heading error (seed 000 eq 10)")
        self.parameter("Ke", DEFAULTS["Ke"], "V/m", "Gain on the lateral error (seed 000 eq 10)")
        self.parameter("sample_period", DEFAULTS["sample_period"], "s",
                       "Sample-and-hold period, at multiples of it (0 = every step)")
        self.parameter("u_max", DEFAULTS["u_max"], "V", "Output limit (0 = off)")
        self.output("u", "V", "Actuator command, positive drives alpha positive",
                    depends_on=("alpha", "heading_error", "lateral_error"))

    def make_core(self) -> Any:
        return core.state_feedback.state_feedback.StateFeedback(self.Ka, self.Kb, self.Ke,
                                                                self.sample_period, self.u_max)

    def advance(self, t: float, h: float) -> None:
        # a sample instant inside this step is taken from the inputs held over it
        self.core.step(t, h, self.alpha, self.heading_error, self.lateral_error)

    def publish(self) -> None:
        self.u = self.core.update(self.time, self.alpha, self.heading_error,
                                  self.lateral_error)
        if not isfinite(self.u):
            self.finite_or_fail(u=self.u)
