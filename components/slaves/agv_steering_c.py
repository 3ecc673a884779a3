"""FMU slave: steering actuator model c of seed 000 (agv_core.actuator)."""

from agv_boot import load_core

core = load_core("fmi_slave", "actuator")


class AgvSteeringC(core.fmi_slave.AgvSlave):
    """Steering actuator, seed 000 model c: identified eq 7 scaled to gain K."""

    description = ("Steering actuator (seed 000 model c, identified eq 7 scaled to gain K): control voltage u or "
                   "wheel-angle set-point alpha_ref in, wheel angle and rate out")

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("u", 0.0, "V", "Motor control voltage (mode 'command'); positive drives "
                   "alpha positive")
        self.input("alpha_ref", 0.0, "rad", "Wheel-angle set-point (mode 'angle')")
        self.parameter("mode", "command", None,
                       "'command': input u drives the motor; 'angle': inner position loop "
                       "u = servo_gain*(alpha_ref - alpha)", kind=core.fmi_slave.String)
        self.parameter("K", 0.6, "rad/(V.s)", "Steady rate gain (seed 000 eq 8)")
        self.parameter("alpha0", 0.0, "rad", "Initial wheel angle")
        self.parameter("alpha_max", 0.0, "rad", "Wheel-angle limit (0 = off)")
        self.parameter("rate_max", 0.0, "rad/s", "Wheel-rate limit (0 = off)")
        self.parameter("servo_gain", 10.0, "V/rad", "Position-loop gain of mode 'angle'")
        self.output("alpha", "rad", "Steered-wheel angle, positive steers left")
        self.output("alpha_rate", "rad/s", "Wheel rate d(alpha)/dt",
                    depends_on=())

    def make_core(self):
        return core.actuator.IdentifiedActuator(
            K=self.K, alpha0=self.alpha0, alpha_max=self.alpha_max, rate_max=self.rate_max,
            mode=self.mode, servo_gain=self.servo_gain)

    def advance(self, t, h):
        self.core.step(t, h, self.u, self.alpha_ref)

    def publish(self):
        self.alpha = self.core.alpha
        self.alpha_rate = self.core.rate(self.u, self.alpha_ref)
        self.finite_or_fail(alpha=self.alpha, alpha_rate=self.alpha_rate)
