"""Real-time pacing: a run's stepping held to a multiple of the wall clock.

:class:`Pacer` wraps the stepper's step function (see
:func:`agv_cosim.execution.simulate`'s ``pace``): after the step that reaches the
communication point ``t``, it sleeps until that point's wall deadline,
``wall_start + (t - start) / factor`` on :func:`time.monotonic`. Deadlines are absolute
from the first step, so a late step does not shift the later ones (no drift builds up);
a step that ends after its deadline is an overrun, and the worst lateness is kept. The
values the FMUs exchange are untouched: a paced run's results equal an unpaced run's.
An unpaced run does not go through here at all.
"""

import time
from collections.abc import Callable
from typing import Any

__all__ = ["Pacer"]


class Pacer:
    """Paces the macro steps of one run at ``factor`` x wall time (``factor`` > 0; 1 is
    the wall clock, 2 twice as fast); :meth:`report` says how it went."""

    def __init__(self, factor: float, start: float) -> None:
        if not factor > 0:
            raise ValueError(f"real-time factor {factor!r} must be > 0")
        self.factor = factor
        self.start = start
        self.wall_start: float | None = None
        self.wall_end: float | None = None
        self.reached = start
        self.steps = 0
        self.overruns = 0
        self.max_lateness = 0.0

    def wrap(self, step: Callable[[float, float], None]) -> Callable[[float, float], None]:
        """``step(t, h)`` (from the communication point ``t`` to ``t + h``, the next one)
        followed by the wait for ``t + h``'s deadline."""
        clock, sleep, factor, start = time.monotonic, time.sleep, self.factor, self.start

        def paced(t: float, h: float) -> None:
            if self.wall_start is None:
                self.wall_start = clock()
            step(t, h)
            reached = t + h
            deadline = self.wall_start + (reached - start) / factor
            now = clock()
            if now > deadline:
                self.overruns += 1
                self.max_lateness = max(self.max_lateness, now - deadline)
            else:
                sleep(deadline - now)
                now = clock()
            self.reached, self.wall_end = reached, now
            self.steps += 1

        return paced

    def report(self) -> dict[str, Any]:
        """``target`` and ``achieved`` factor (simulated time / wall time of the
        stepping, None before a step), ``overruns`` (steps that ended after their
        deadline), ``max_lateness_s``, ``steps`` and ``wall_s``."""
        wall = (self.wall_end - self.wall_start
                if self.wall_start is not None and self.wall_end is not None else None)
        achieved = (self.reached - self.start) / wall if wall else None
        return {"target": self.factor, "achieved": achieved, "overruns": self.overruns,
                "max_lateness_s": self.max_lateness, "steps": self.steps, "wall_s": wall}
