"""FMU slave: steering actuator model c of seed 000 (agv_core.actuator)."""

from agv_boot import load_core

core = load_core("fmi.actuator_fmi")


class AgvSteeringC(core.fmi.actuator_fmi.ActuatorSlave):
    """Steering actuator, seed 000 model c: identified eq 7 scaled to gain K."""

    description = ("Steering actuator (seed 000 model c, identified eq 7 scaled to gain K): "
                   "control voltage u or wheel-angle set-point alpha_ref in, wheel angle and "
                   "rate out")
    model = "c"
    rate_depends_on = ()  # the rate is a state of the second-order model: no feedthrough
