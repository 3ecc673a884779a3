"""The FMI adapter shared by the seed-003 per-axle PD controllers (fuzzy-scheduled and fixed).

Both FMUs have the same inputs, the same filter and saturation parameters and the same
outputs, so a manifest can swap one for the other. A slave script subclasses
:class:`AxlePdSlave`, declares its gain parameters in ``declare_gain_parameters`` and
returns the gain source of :class:`agv_core.fuzzy_pd.AxlePD` from ``make_gains``.
"""

from typing import Any

from ..axle_pd.fuzzy_pd import AxlePD
from .defaults import defaults_of
from .fmi_slave import AgvSlave, Boolean

INPUTS = ("lateral_error", "speed")


class AxlePdSlave(AgvSlave):
    """Common FMU interface of the seed-003 axle PD controllers."""

    #: description of the ``speed`` input (the fixed PD does not use it)
    speed_description = "Vehicle speed (scheduling variable)"
    #: descriptions of the gain outputs
    kp_description = "Scheduled proportional gain in use"
    kd_description = "Scheduled derivative gain in use"
    #: inputs the gain outputs depend on directly (none for constant gains)
    gain_depends_on = INPUTS

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.input("lateral_error", 0.0, "m", "Lateral error e of the axle's tracking point, "
                   "positive left of the path")
        self.input("speed", 0.0, "m/s", self.speed_description)
        self.declare_gain_parameters()
        d = defaults_of(AxlePD)  # the core's defaults (written once)
        self.parameter("tau_d", d["tau_d"], "s", "Derivative filter time constant")
        self.parameter("delta_max", d["delta_max"], "rad", "Steering saturation")
        self.output("delta", "rad", "Axle-equivalent steering angle, positive left, saturated",
                    depends_on=self.gain_depends_on or ("lateral_error",))
        self.output("Kp_used", "rad/m", self.kp_description,
                    depends_on=self.gain_depends_on)
        self.output("Kd_used", "rad.s/m", self.kd_description,
                    depends_on=self.gain_depends_on)
        self.output("error_rate", "m/s", "Filtered rate of the lateral error",
                    depends_on=("lateral_error",))
        self.output("saturated", None, "True while delta is limited by delta_max",
                    depends_on=self.gain_depends_on or ("lateral_error",), kind=Boolean,
                    start=False)

    def declare_gain_parameters(self) -> None:
        """Declare the gain parameters (override)."""

    def make_gains(self) -> Any:
        """The gain source (``gains(e, v_kmh) -> (Kp, Kd)``) from the parameters (override)."""
        raise NotImplementedError

    def make_core(self) -> Any:
        return AxlePD(self.make_gains(), self.tau_d, self.delta_max)

    def advance(self, t: float, h: float) -> None:
        self.core.advance(self.lateral_error, h)

    def publish(self) -> None:
        out = self.core.evaluate(self.lateral_error, self.speed)
        self.delta, self.Kp_used, self.Kd_used = out["delta"], out["Kp"], out["Kd"]
        self.error_rate, self.saturated = out["error_rate"], out["saturated"]
        self.finite_or_fail(delta=self.delta)
