"""Real-time pacing: a run's stepping held to a multiple of the wall clock.

:class:`Pacer` wraps the stepper's step function (see
:func:`agv_cosim.execution.simulate`'s ``pace``): after the step that reaches the
communication point ``t``, it sleeps until that point's wall deadline,
``wall_start + (t - start) / factor`` on :func:`time.monotonic`. Deadlines are absolute
from the first step, so a late step does not shift the later ones (no drift builds up);
a step that ends after its deadline is an overrun, and the worst lateness is kept. The
values the FMUs exchange are untouched: a paced run's results equal an unpaced run's.
An unpaced run does not go through here at all.

The factor is a finite number in [:data:`MIN_FACTOR`, :data:`MAX_FACTOR`], and a run's
paced wall duration, (stop - start) / factor, at most :data:`MAX_WALL_S` (every deadline
and every wait is then a number of seconds the clock and ``time.sleep`` represent):
:func:`factor_problem`. A failure of the pacing itself (the clock, the wait) raises a
:class:`~agv_cosim.errors.SimulationError` that names the pacing, never the FMU that
stepped last.
"""

import time
from collections.abc import Callable
from typing import Any

from ..errors import SimulationError

__all__ = ["FIGURES", "MAX_FACTOR", "MAX_WALL_S", "MIN_FACTOR", "Pacer",
           "factor_problem", "report_of"]

#: Smallest real-time factor (1 s simulated in 11.6 days of wall time).
MIN_FACTOR = 1e-6
#: Largest real-time factor (beyond, a paced run is an unpaced one).
MAX_FACTOR = 1e6
#: Longest paced wall duration of a run [s] (about 31.7 years; ``time.sleep`` takes at
#: most about 9.2e9 s).
MAX_WALL_S = 1e9


def factor_problem(factor: float, span: float | None = None) -> str | None:
    """Why ``factor`` cannot pace a run of ``span`` simulated seconds (stop - start;
    None: any run), or None when it can."""
    if not (isinstance(factor, (int, float)) and not isinstance(factor, bool)
            and MIN_FACTOR <= factor <= MAX_FACTOR):
        return (f"{factor!r} must be > 0, a real-time factor from {MIN_FACTOR:g} to "
                f"{MAX_FACTOR:g}")
    if span is not None and not span / factor <= MAX_WALL_S:
        return (f"{factor!r} would pace the run's {span!r} s over {span / factor:.3g} s of "
                f"wall time; at most {MAX_WALL_S:g} s")
    return None


#: The pacing figures of a run, each a position in :attr:`Pacer.figures`: steps done,
#: overruns, worst lateness [s], simulated time reached [s], wall time of the stepping
#: so far [s] (NaN before the first step).
STEPS, OVERRUNS, LATENESS, REACHED, WALL = range(5)
#: Length of :attr:`Pacer.figures`.
FIGURES = 5


class Pacer:
    """Paces the macro steps of one run at ``factor`` x wall time (``factor`` > 0; 1 is
    the wall clock, 2 twice as fast); :meth:`report` says how it went.

    The figures are kept in ``figures`` (a sequence of :data:`FIGURES` floats, e.g. a
    ``multiprocessing`` shared array; default a list), current after every step: a
    process that ends the run's process (a timeout, an interruption) reads from it what
    the pacing did up to then (:func:`report_of`)."""

    def __init__(self, factor: float, start: float, figures: Any = None) -> None:
        problem = factor_problem(factor)
        if problem is not None:
            raise ValueError(problem)
        self.factor = factor
        self.start = start
        self.figures: Any = [0.0] * FIGURES if figures is None else figures
        self.figures[:] = [0.0, 0.0, 0.0, start, float("nan")]

    def wrap(self, step: Callable[[float, float], None]) -> Callable[[float, float], None]:
        """``step(t, h)`` (from the communication point ``t`` to ``t + h``, the next one)
        followed by the wait for ``t + h``'s deadline."""
        clock, sleep, factor, start = time.monotonic, time.sleep, self.factor, self.start
        figures = self.figures
        wall_start: float | None = None

        def paced(t: float, h: float) -> None:
            nonlocal wall_start
            if wall_start is None:
                wall_start = clock()
            step(t, h)
            reached = t + h
            try:
                deadline = wall_start + (reached - start) / factor
                now = clock()
                if now > deadline:
                    figures[OVERRUNS] += 1
                    figures[LATENESS] = max(figures[LATENESS], now - deadline)
                else:
                    sleep(deadline - now)
                    now = clock()
            except Exception as error:  # noqa: BLE001 - the pacing's, not the FMUs'
                raise SimulationError(f"real-time pacing failed at t={reached!r} s: "
                                      f"{type(error).__name__}: {error}") from None
            figures[REACHED] = reached
            figures[WALL] = now - wall_start
            figures[STEPS] += 1

        return paced

    def report(self) -> dict[str, Any]:
        """The pacing so far (:func:`report_of`)."""
        return report_of(self.factor, self.start, self.figures)


def report_of(factor: float, start: float, figures: Any) -> dict[str, Any]:
    """``target`` and ``achieved`` factor (simulated time / wall time of the stepping,
    None before a step), ``overruns`` (steps that ended after their deadline),
    ``max_lateness_s``, ``steps`` and ``wall_s`` of a run paced at ``factor`` from
    ``start`` whose :attr:`Pacer.figures` are ``figures``."""
    wall = figures[WALL]
    wall = None if wall != wall else float(wall)  # NaN: no step yet
    achieved = (figures[REACHED] - start) / wall if wall else None
    return {"target": factor, "achieved": achieved, "overruns": int(figures[OVERRUNS]),
            "max_lateness_s": float(figures[LATENESS]), "steps": int(figures[STEPS]),
            "wall_s": wall}
