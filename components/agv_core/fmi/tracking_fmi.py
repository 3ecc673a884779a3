"""The FMI adapter shared by the seed-001 trajectory-tracking controllers (MPC and PID).

Both FMUs have the same inputs and the same common outputs, so a manifest can swap one for
the other (the orchestrator's FMU substitution). A slave script subclasses
:class:`TrackingSlave`, declares its parameters in ``declare_parameters``, builds its core
in ``make_core`` (a core with ``update(t, x, y, heading, ref) -> dict`` (the output at
t), ``step(t, h, x, y, heading, ref)`` (commits the samples of a step, the rule of
agv_core.numerics.sampling) and ``get_state`` / ``set_state``), and may add outputs in
``declare_extra_outputs`` /
``publish_extra``. The core's errors of the kinds listed in ``solve_errors`` become an FMU
error naming the cause.
"""

from typing import Any

from .fmi_slave import AgvSlave

#: measured pose and reference inputs, in declaration order
INPUTS = ("x", "y", "heading", "x_ref", "y_ref", "heading_ref", "v_ref", "omega_ref")


class TrackingSlave(AgvSlave):
    """Common FMU interface of the seed-001 tracking controllers."""

    #: exception classes of the core that are reported as an FMU error with their message
    solve_errors: tuple[type[Exception], ...] = ()

    #: publish shows the core's sample of ``self.time`` for the current inputs (the
    #: sample-and-hold of agv_core.numerics.sampling): a publication skipped after a step
    #: is the one the next read (after the master's sets) makes, or the one the step
    #: from here makes when nothing reads, so each sample's law runs once per set of
    #: inputs it sees
    lazy_publish = True

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.input("x", 0.0, "m", "Measured x of the AGV centroid")
        self.input("y", 0.0, "m", "Measured y of the AGV centroid")
        self.input("heading", 0.0, "rad", "Measured heading of the AGV (body yaw)")
        self.input("x_ref", 0.0, "m", "Reference x at this time")
        self.input("y_ref", 0.0, "m", "Reference y at this time")
        self.input("heading_ref", 0.0, "rad", "Reference heading alpha_r")
        self.input("v_ref", 0.0, "m/s", "Reference speed v_r")
        self.input("omega_ref", 0.0, "rad/s", "Reference yaw rate omega_r")
        self.declare_parameters()
        self.output("v_c", "m/s", "Commanded centroid speed (held between samples)",
                    depends_on=INPUTS)
        self.output("omega", "rad/s", "Commanded yaw rate (held between samples)",
                    depends_on=INPUTS)
        self.output("e_x", "m", "x - x_ref at the last sample", depends_on=INPUTS)
        self.output("e_y", "m", "y - y_ref at the last sample", depends_on=INPUTS)
        self.output("e_heading", "rad", "heading - heading_ref, wrapped to (-pi, pi]",
                    depends_on=INPUTS)
        self.output("e_lat", "m", "Lateral error, positive left of the reference heading",
                    depends_on=INPUTS)
        self.output("e_long", "m", "Along-track error, positive ahead of the reference",
                    depends_on=INPUTS)
        self.output("e_pos", "m", "Position error |(x, y) - (x_ref, y_ref)|",
                    depends_on=INPUTS)
        self.declare_extra_outputs()

    def declare_parameters(self) -> None:
        """Declare the controller's parameters (override)."""

    def declare_extra_outputs(self) -> None:
        """Declare outputs only this controller has (override)."""

    def publish_extra(self, out: dict[str, Any]) -> None:
        """Copy the extra outputs from the core's result ``out`` (override)."""

    def _ref(self) -> dict[str, float]:
        return {"x": self.x_ref, "y": self.y_ref, "heading": self.heading_ref,
                "v": self.v_ref, "omega": self.omega_ref}

    def advance(self, t: float, h: float) -> None:
        # commits the samples of [t, t + h) from the held inputs (agv_core.numerics.sampling)
        try:
            self.core.step(t, h, self.x, self.y, self.heading, self._ref())
        except self.solve_errors as error:
            self._fail(f"t={t:.9g} s: {error}")

    def publish(self) -> None:
        try:
            out = self.core.update(self.time, self.x, self.y, self.heading, self._ref())
        except self.solve_errors as error:
            self._fail(f"t={self.time:.9g} s: {error}")
        self.v_c, self.omega = out["v_c"], out["omega"]
        for name in ("e_x", "e_y", "e_heading", "e_lat", "e_long", "e_pos"):
            setattr(self, name, out[name])
        self.publish_extra(out)
        self.finite_or_fail(v_c=self.v_c, omega=self.omega)
