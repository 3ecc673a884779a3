"""FMU slave: pure-pursuit path tracking, a baseline (agv_core.pure_pursuit)."""

from typing import Any

from agv_boot import load_core

core: Any = load_core(
    "fmi.fmi_slave", "fmi.path_law_fmi", "fmi.defaults", "pure_pursuit.pure_pursuit")
DEFAULTS: dict[str, Any] = core.fmi.defaults.defaults_of(  # the core's defaults (written once)
    core.pure_pursuit.pure_pursuit.make_controller)


class AgvPurePursuit(core.fmi.path_law_fmi.PathLawSlave):
    """Pure pursuit (Coulter 1992): rear-axle pose and speed in, wheel angle out."""

    description = ("Pure-pursuit path tracking (Coulter 1992) on the rear axle, look-ahead "
                   "Ld = k_ld v + L_min: delta = atan(2 L sin(alpha) / Ld), saturated at "
                   "+/-delta_max")
    uses_speed = True

    def defaults(self) -> dict[str, Any]:
        return DEFAULTS

    def declare_gains(self, defaults: dict[str, Any]) -> None:
        self.parameter("k_ld", defaults["k_ld"], "s", "Look-ahead gain: Ld grows by k_ld "
                       "per m/s (>= 0)")
        self.parameter("L_min", defaults["L_min"], "m", "Look-ahead at standstill (> 0)")

    def declare_extra_outputs(self) -> None:
        d = self.depends
        self.output("alpha", "rad", "Angle from the heading to the chord towards the goal, "
                    "positive left", depends_on=d)
        self.output("lookahead", "m", "Look-ahead Ld = k_ld v + L_min", depends_on=("dv",))
        self.output("goal_x", "m", "x of the goal point on the path", depends_on=d)
        self.output("goal_y", "m", "y of the goal point on the path", depends_on=d)
        self.output("on_chord", None, "True when the goal lies at Ld (false: the path is "
                    "farther than Ld and the closest point is pursued)", depends_on=d,
                    kind=core.fmi.fmi_slave.Boolean, start=True)

    def publish_extra(self, out: dict[str, Any]) -> None:
        self.alpha, self.lookahead = out["alpha"], out["lookahead"]
        self.goal_x, self.goal_y, self.on_chord = out["goal_x"], out["goal_y"], out["on_chord"]

    def make_law(self) -> Any:
        return core.pure_pursuit.pure_pursuit.make_controller(
            self.path, self.k_ld, self.L_min, self.wheelbase, self.delta_max,
            self.sample_period)
