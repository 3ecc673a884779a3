"""FMU slave: steering actuator model c of seed 000 (agv_core.actuator)."""

from typing import Any

from agv_boot import load_core

core: Any = load_core("fmi.actuator_fmi", "fmi.defaults", "steering.actuator")


class AgvSteeringC(core.fmi.actuator_fmi.ActuatorSlave):
    """Steering actuator, seed 000 model c: identified eq 7 scaled to gain K."""

    description = ("Steering actuator (seed 000 model c, identified eq 7 scaled to gain K): "
                   "control voltage u or wheel-angle set-point alpha_ref in, wheel angle and "
                   "rate out")
    model = "c"
    rate_depends_on = ()  # the rate is a state of the second-order model: no feedthrough

    def declare_model_parameters(self) -> None:
        d = core.fmi.defaults.defaults_of(core.steering.actuator.IdentifiedActuator)
        self.parameter("num1", d["num1"], "rad/(V.s2)",
                       "Rate transfer function (num1 s + num0)/(s^2 + den1 s + den0) "
                       "(seed 000 eq 6 in SI units), numerator coefficient of s")
        self.parameter("num0", d["num0"], "rad/(V.s3)",
                       "Rate transfer function: numerator constant, > 0")
        self.parameter("den1", d["den1"], "1/s",
                       "Rate transfer function: denominator coefficient of s, > 0")
        self.parameter("den0", d["den0"], "1/s2",
                       "Rate transfer function: denominator constant, > 0 (the transfer "
                       "function is scaled by K den0/num0 to steady rate gain K)")
        self.parameter("tau", d["tau"], "s", "Dead time of the command, >= 0 (0 = none)")

    def model_parameters(self) -> Any:
        return {"num1": self.num1, "num0": self.num0, "den1": self.den1, "den0": self.den0,
                "tau": self.tau}
