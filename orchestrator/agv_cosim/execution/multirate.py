"""Multirate stepping: components with their own communication step (``step`` in
``[components.<name>]``), a whole multiple m of the simulation's step h.

The semantics are libcosim's fixed-step algorithm with a step-size multiplier
("decimation factor") per simulator; t_k = start + k h are the base points
(:mod:`.grid`), n = (stop - start) / h.

- A component of multiple m has its communication points at t_k with k a multiple of
  m, and at the stop time t_n. At such a t_k (k < n) it steps to its next point
  t_{k'}, k' = min(k + m, n), in one ``doStep`` of t_{k'} - t_k (its own step, the
  last one shorter when m does not divide n); at the other base points it is not
  called at all.
- Its outputs are read only at its points; between them every connection from it, and
  every recorded column of it, holds the value read at its last point.
- Its inputs are set only at its points, from the current values of its sources (a
  source of another rate gives the value read at that source's own last point).
- At a base point t_k the exchange is the algorithm's (:mod:`.algorithm`) over the
  components whose point t_k is, and only them:

  Jacobi (libcosim's): the outputs of those components are read, then their inputs
  are set from the values then current. libcosim transfers a simulator's outputs when
  its step ends and applies a simulator's inputs when its next step begins: the same
  values reach the same calls.
  Gauss-Seidel: those components are visited in the feedthrough order of the whole
  system; each gets its inputs from the current values (its sources already visited at
  this point give this instant's, the others their held ones), then its outputs are
  read.

  With every component at the simulation's step (m = 1) both are exactly the
  single-rate algorithms, call for call; a ``step`` equal to the simulation's is
  therefore the same run as none (the same bytes).
- Every component initialises, and takes part in the first exchange, at the start
  time, whatever its step.
- Events: an event that sets a variable of a component at a time that is not one of
  that component's points is refused when the manifest is checked
  (:func:`agv_cosim.system.check.check_events`): the FMU is then already at its next
  point, and applying the value there, or later, would move the event silently.
- ``[record]``: a row is recorded at every ``interval`` of the simulation, whatever
  the components' steps; a column of a component between its points shows its held
  output (the sample-and-hold value the rest of the system sees).
- A stop request (:class:`.algorithm.Stepper`) ends the run after the base step in
  which the FMU asked (its last row when it reached that base point).

The macro steps run in Python (each exchange through the compiled or generated
per-step functions when ``fast``); the compiled stretches of
:func:`agv_cosim.execution.simulation._loop` are not used for a multirate system.
"""

from collections.abc import Callable

from ..manifest.load import step_multiple
from ..system import System
from .algorithm import Algorithm, Stepper, algorithm_for
from .grid import Grid
from .pacing import Pacer
from .scenario import Scenario
from .track import Track
from .units import Unit

__all__ = ["multiples", "run_multirate"]


def multiples(system: System) -> dict[str, int]:
    """Component -> its multiple m of the simulation's step (1 for those without a
    ``step`` of their own)."""
    found = {cname: 1 for cname in system.models}
    for cname, step in system.component_steps.items():
        found[cname] = step_multiple(step, system.step) or 1
    return found


class _Rates:
    """The steppers by multiple, and the algorithm of each set of components at a
    point."""

    def __init__(self, system: System, units: dict[str, Unit], full: Algorithm,
                 track: Track, fast: bool) -> None:
        self.system, self.units, self.track, self.fast = system, units, track, fast
        self.multiple = multiples(system)
        self.steps = system.steps
        self.requests: list[tuple[str, float | None]] = []
        by_multiple: dict[int, list[Unit]] = {}
        for name, unit in units.items():
            by_multiple.setdefault(self.multiple[name], []).append(unit)
        #: (multiple, own step [s] or None: the simulation's, stepper), fastest first
        self.steppers: list[tuple[int, float | None, Stepper]] = []
        for m in sorted(by_multiple):
            own = None if m == 1 else next(system.component_steps[u.name]
                                           for u in by_multiple[m])
            self.steppers.append((m, own, Stepper(by_multiple[m], track, fast,
                                                  self.requests)))
        self._algorithms: dict[frozenset[int], Algorithm] = {
            frozenset(self.multiple.values()): full}

    def at(self, k: int) -> Algorithm:
        """The algorithm over the components whose communication point t_k is."""
        due = frozenset(m for m in set(self.multiple.values())
                        if k % m == 0 or k == self.steps)
        found = self._algorithms.get(due)
        if found is None:
            active = {name: unit for name, unit in self.units.items()
                      if self.multiple[name] in due}
            found = algorithm_for(self.system, active, self.track, self.fast)
            self._algorithms[due] = found
        return found


def run_multirate(system: System, units: dict[str, Unit], algorithm: Algorithm,
                  scenario: Scenario, record: Callable[[float], None],
                  progress: list[Callable[[int], None]], track: Track, fast: bool,
                  pace: Pacer | None, every_progress: int) -> tuple[str | None,
                                                                   float | None, bool]:
    """The base points after the first: each component due steps with its own step,
    events, the exchange of the components at their point, record (see the module's
    docstring). ``algorithm``: the system's algorithm over every unit (initialised and
    started by the caller).

    Returns ``(ended_by, stop_time, stopped)`` as :class:`.simulation.Outcome` holds
    them (``stopped``: an FMU asked to end the run).
    """
    from .simulation import _ended, _reached

    steps, every = system.steps, system.record_every
    grid = Grid(system.start, system.stop, steps, system.step)
    time, step_size = grid.time, grid.step_size
    rates = _Rates(system, units, algorithm, track, fast)
    requests = rates.requests
    k = 0

    def step_due(t: float, h: float) -> None:
        """Every component whose point t = t_k is steps to its next one (``h``: the
        base step, for the pacing)."""
        for m, own, stepper in rates.steppers:
            if k % m:
                continue
            reach = min(k + m, steps)
            t_reach = time(reach)
            stepper.step(t, step_size(t, t_reach, own if reach == k + m else None))

    step = step_due if pace is None else pace.wrap(step_due)
    done = 0
    t = system.start
    ended_by: str | None = None
    stop_time: float | None = None
    while k < steps:
        t_next = time(k + 1)
        step(t, step_size(t, t_next))
        t = t_next
        track[2] = t_next
        if k + 1 == scenario.next_step and not requests:
            scenario.apply(k + 1)
        exchange = rates.at(k + 1)
        if requests:
            ended_by, stop_time = _ended(requests[0])
            if _reached(requests[0], t_next):
                exchange.last(t_next, {n for n, _ in requests})
                record(t_next)
            break
        exchange.exchange(t_next)
        if (k + 1) % every == 0 or k + 1 == steps:
            record(t_next)
        if progress:
            done += 1
            if done >= every_progress:
                for report in progress:
                    report(done)
                done = 0
        k += 1
    if progress and done:
        for report in progress:
            report(done)
    return ended_by, stop_time, bool(requests)

