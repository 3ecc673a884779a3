"""FMU slave: Stanley path tracking, a baseline (agv_core.stanley)."""

from typing import Any

from agv_boot import load_core

core: Any = load_core("fmi.fmi_slave", "fmi.path_law_fmi", "fmi.defaults", "stanley.stanley")
DEFAULTS: dict[str, Any] = core.fmi.defaults.defaults_of(  # the core's defaults (written once)
    core.stanley.stanley.make_controller)


class AgvStanley(core.fmi.path_law_fmi.PathLawSlave):
    """Stanley (Hoffmann, Thrun et al. 2007): rear-axle pose and speed in, wheel angle out."""

    description = ("Stanley path tracking (Hoffmann, Thrun et al. 2007) on the front-wheel "
                   "centre: delta = -theta - atan(k e / (k_soft + v)), saturated at "
                   "+/-delta_max")
    uses_speed = True

    def defaults(self) -> dict[str, Any]:
        return DEFAULTS

    def declare_gains(self, defaults: dict[str, Any]) -> None:
        self.parameter("k", defaults["k"], "1/s", "Cross-track gain (> 0)")
        self.parameter("k_soft", defaults["k_soft"], "m/s", "Softening speed added to v "
                       "(> 0)")

    def declare_extra_outputs(self) -> None:
        self.output("x_front", "m", "x of the front-wheel centre, the point regulated",
                    depends_on=self.depends)
        self.output("y_front", "m", "y of the front-wheel centre, the point regulated",
                    depends_on=self.depends)

    def publish_extra(self, out: dict[str, Any]) -> None:
        self.x_front, self.y_front = out["x_front"], out["y_front"]

    def make_law(self) -> Any:
        return core.stanley.stanley.make_controller(
            self.path, self.k, self.k_soft, self.wheelbase, self.delta_max, self.sample_period)
