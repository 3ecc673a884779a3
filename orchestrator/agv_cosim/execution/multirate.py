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
  values reach the same calls (tests/orchestrator/execution/test_multirate.py runs an
  exported package in libcosim, its decimation factors from ``osp:StepSizeHint``, and
  finds our Jacobi's values).
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

With ``fast``, the macro steps in which only the components at the simulation's step
step and exchange (neither t_k nor t_{k+1} a point of a slower one) run in C, in
stretches, as :func:`agv_cosim.execution.simulation._loop` runs a single-rate system's
(the same calls: :func:`agv_cosim.execution.compiled.module`'s ``run_stretch`` over the
base-rate components' step program and exchange); the others run in Python, each
exchange through the compiled or generated per-step functions.
"""

from collections.abc import Callable

from ..manifest.load import step_multiple
from ..system import System
from .algorithm import Algorithm, Stepper, algorithm_for
from .grid import Grid
from .pacing import Pacer
from .scenario import Scenario
from .stretch import Tail, compiled_stretch
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
        return self._over(frozenset(m for m in set(self.multiple.values())
                                    if k % m == 0 or k == self.steps))

    def base_only(self) -> Algorithm:
        """The algorithm over the components at the simulation's step alone."""
        return self._over(frozenset((1,)))

    def _over(self, due: frozenset[int]) -> Algorithm:
        found = self._algorithms.get(due)
        if found is None:
            active = {name: unit for name, unit in self.units.items()
                      if self.multiple[name] in due}
            found = algorithm_for(self.system, active, self.track, self.fast)
            self._algorithms[due] = found
        return found


def _fast_stretch(rates: _Rates, grid: Grid,
                  pace: Pacer | None) -> Callable[[int, int], int] | None:
    """``run(k0, k1)``: macro steps k0 .. k1 - 1 in which only the components at the
    simulation's step step and exchange, run in C
    (:func:`agv_cosim.execution.stretch.compiled_stretch`); None when the run cannot use it
    (no base-rate component, or their stepper or exchange not compiled)."""

    if rates.steppers[0][0] != 1:
        return None
    return compiled_stretch(rates.base_only(), rates.steppers[0][2], grid, pace)


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

    steps = system.steps
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
    stretch = _fast_stretch(rates, grid, pace)
    slow = sorted({m for m in rates.multiple.values() if m > 1})
    tail = Tail(steps, system.record_every, record, progress, every_progress, requests,
                rates.at)
    point = tail.point
    t = system.start
    while k < steps:
        if stretch is not None and k + 1 != scenario.next_step:
            # the macro steps in which only the base-rate components step and exchange,
            # up to the next slow point, event, recording point or progress report, in
            # C (the calls of the Python loop below)
            end = min(steps - 1, tail.bound,
                      *(k + (m - 1 - k % m) if k % m else k for m in slow))
            if scenario.next_step > k + 1:
                end = min(end, scenario.next_step - 1)
            if end > k:
                k += stretch(k, end)
                if requests:  # macro step k stepped (no exchange): its stop request
                    tail.stop(k, time(k + 1))
                    break
                t = time(k)
                if k >= tail.bound:
                    point(k, t)
                continue
        t_next = time(k + 1)
        step(t, step_size(t, t_next))
        t = t_next
        track[2] = t_next
        if k + 1 == scenario.next_step and not requests:
            scenario.apply(k + 1)
        exchange = rates.at(k + 1)
        if requests:
            tail.stop(k, t_next)
            break
        exchange.exchange(t_next)
        k += 1
        if k >= tail.bound:
            point(k, t_next)
    tail.finish(k)
    return tail.ended_by, tail.stop_time, bool(requests)
