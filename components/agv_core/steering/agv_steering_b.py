"""FMU slave: steering actuator model b of seed 000 (agv_core.actuator)."""

from typing import Any

from agv_boot import load_core

core: Any = load_core("fmi.actuator_fmi")


class AgvSteeringB(core.fmi.actuator_fmi.ActuatorSlave):
    """Steering actuator, seed 000 model b: K/s."""

    description = ("Steering actuator (seed 000 model b, K/s): control voltage u or "
                   "wheel-angle set-point alpha_ref in, wheel angle and rate out")
    model = "b"
    rate_depends_on = ("u", "alpha_ref")  # alpha' = K u: the rate passes the input through
