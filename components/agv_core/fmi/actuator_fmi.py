"""The FMI adapter shared by the three steering-actuator FMUs (models a, b, c).

The three FMUs have identical interfaces so that a manifest can swap one for another; only
the model, its extra parameters and the direct dependencies of ``alpha_rate`` differ. A
slave script subclasses :class:`ActuatorSlave` and sets ``model``, ``description``,
``rate_depends_on`` and, where needed, ``declare_model_parameters``.
"""

from math import isfinite
from typing import Any

from ..steering.actuator import SteeringActuator, make_actuator
from .defaults import defaults_of
from .fmi_slave import AgvSlave, DefaultExperiment, String


class ActuatorSlave(AgvSlave):
    """Common FMU interface of the steering actuators (see agv_core.actuator)."""

    #: "a", "b" or "c" (agv_core.actuator.MODELS)
    model: Any = None  # "a", "b" or "c": set by the slave script
    #: inputs that ``alpha_rate`` depends on directly
    rate_depends_on = ()
    #: Reference: a 1 V step of u at 0.5 s (mode 'command'), 2 s at 1 ms, which resolves
    #: model a's 50 ms dead time and model c's transient.
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=2.0,
                                           step_size=0.001)
    reference_inputs = {"u": ((0.0, 0.0), (0.5, 1.0))}

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.input("u", 0.0, "V", "Motor control voltage (mode 'command'); positive drives "
                   "alpha positive")
        self.input("alpha_ref", 0.0, "rad", "Wheel-angle set-point (mode 'angle')")
        d = defaults_of(SteeringActuator)  # the core's defaults (written once)
        self.parameter("mode", d["mode"], None,
                       "'command': input u drives the motor; 'angle': inner position loop "
                       "u = servo_gain*(alpha_ref - alpha)", kind=String)
        self.parameter("K", d["K"], "rad/(V.s)", "Steady rate gain (seed 000 eq 8)")
        self.declare_model_parameters()
        self.parameter("alpha0", d["alpha0"], "rad", "Initial wheel angle")
        self.parameter("alpha_max", d["alpha_max"], "rad", "Wheel-angle limit (0 = off)")
        self.parameter("rate_max", d["rate_max"], "rad/s", "Wheel-rate limit (0 = off)")
        self.parameter("servo_gain", d["servo_gain"], "V/rad", "Position-loop gain of mode 'angle'")
        self.output("alpha", "rad", "Steered-wheel angle, positive steers left")
        self.output("alpha_rate", "rad/s", "Wheel rate d(alpha)/dt",
                    depends_on=self.rate_depends_on)

    def declare_model_parameters(self) -> None:
        """Declare the parameters only this model has (override)."""

    def model_parameters(self) -> Any:
        """Values of the parameters only this model has, as keyword arguments."""
        return {}

    def make_core(self) -> Any:
        return make_actuator(self.model, K=self.K, alpha0=self.alpha0,
                             alpha_max=self.alpha_max, rate_max=self.rate_max,
                             mode=self.mode, servo_gain=self.servo_gain,
                             **self.model_parameters())

    def advance(self, t: float, h: float) -> None:
        self.core.step(t, h, self.u, self.alpha_ref)

    def publish(self) -> None:
        self.alpha = self.core.alpha
        self.alpha_rate = self.core.rate(self.u, self.alpha_ref)
        if not isfinite(self.alpha + self.alpha_rate):  # finite iff every term is
            self.finite_or_fail(alpha=self.alpha, alpha_rate=self.alpha_rate)
