"""The scenario of a run: its events, each setting values at one communication point."""

from typing import Any

from ..system import Event, ModelInfo
from .instance import FmuInstance
from .units import set_value

__all__ = ["Scenario"]


class Scenario:
    """The events of a run, applied by step index.

    The values are set (fmpy's setters, one call per variable) after the FMUs stepped to
    t_k and before t_k's exchange, so the row of t_k already shows their effect on
    feedthrough outputs. Events at k = 0 are applied before the first exchange.
    """

    def __init__(self, events: list[Event], instances: dict[str, FmuInstance],
                 models: dict[str, ModelInfo]) -> None:
        self._pending: list[tuple[int, list[tuple[Any, Any, Any]]]] = [
            (event.k, [(instances[c].slave, models[c].variables[v], value)
                       for c, v, value in event.sets]) for event in events]
        self._pending.reverse()
        #: step index of the next event, -1 when none is left
        self.next_step = self._pending[-1][0] if self._pending else -1

    def apply(self, k: int) -> None:
        """Apply the events of step ``k`` (the next ones, :attr:`next_step`)."""
        while self._pending and self._pending[-1][0] == k:
            for slave, var, value in self._pending.pop()[1]:
                set_value(slave, var, value)
        self.next_step = self._pending[-1][0] if self._pending else -1
