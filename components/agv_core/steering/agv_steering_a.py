"""FMU slave: steering actuator model a of seed 000 (agv_core.actuator)."""

from typing import Any

from agv_boot import load_core

core: Any = load_core("fmi.actuator_fmi", "fmi.defaults", "steering.actuator")


class AgvSteeringA(core.fmi.actuator_fmi.ActuatorSlave):
    """Steering actuator, seed 000 model a: K exp(-tau s)/s."""

    description = ("Steering actuator (seed 000 model a, K exp(-tau s)/s): control voltage u or "
                   "wheel-angle set-point alpha_ref in, wheel angle and rate out")
    model = "a"
    rate_depends_on = ()  # the dead time (tau > 0) separates the rate from the inputs

    def declare_model_parameters(self) -> None:
        default = core.fmi.defaults.defaults_of(core.steering.actuator.DelayedIntegratorActuator)
        self.parameter("tau", default["tau"], "s", "Dead time (seed 000 eq 8), > 0")

    def model_parameters(self) -> Any:
        return {"tau": self.tau}
