"""The co-simulation algorithms (Gauss-Seidel, Jacobi) and the stepping of the FMUs.

Semantics (communication points t_k = start + k h, inputs held over each step):

Gauss-Seidel (default)
    At every t_k the FMUs are visited in topological order of the direct-feedthrough
    graph (an edge only through outputs that depend directly on inputs). Each FMU gets
    its inputs from its sources' current outputs (one batched set per type), then its
    outputs are read (one batched get per type; our FMUs recompute feedthrough outputs
    on a get after a set). An FMU whose outputs feed an FMU visited before it (a loop
    closed through an output without direct feedthrough, e.g. actuator -> vehicle) has
    those outputs read at the start of the pass. Every input therefore holds the value
    of the same instant t_k. The row of t_k is recorded, then every FMU steps from t_k
    to t_k + h.
Jacobi (what libcosim does)
    After the step to t_k, every FMU's outputs are read first; then every input is set
    from those values. An input therefore holds, during [t_k, t_k + h), what its source
    published at the end of the previous step: each connection through a feedthrough
    output adds one macro step of delay. The recorded row holds the values read before
    the sets. While the FMUs are in initialisation mode, N Jacobi exchanges (N = number
    of FMUs) propagate initial values through feedthrough chains, as libcosim does.

Each algorithm has a plain loop, the reference, and the generated functions of
:mod:`agv_cosim.execution.fastpath` (``fast=True``), which make the same calls in the
same order. With ``fast=True`` and the compiled call path available
(:mod:`agv_cosim.execution.compiled`), those functions are compiled programs
(:mod:`agv_cosim.execution.programs`: the same calls made from C without ctypes) when
the run's units allow it, the generated Python functions otherwise; :attr:`exchanges`
then says what one exchange runs, so that whole stretches of macro steps can run in C
(:func:`agv_cosim.execution.simulation._loop`).
"""

from collections.abc import Callable, Iterable
from math import isfinite
from typing import Protocol

from ..system import System
from . import fastpath, programs
from .track import DO_STEP, EXCHANGE, GET, GS_PASS, SET, Track
from .units import FmuUnit, Unit, check_finite, failed

__all__ = ["Algorithm", "GaussSeidel", "Jacobi", "Stepper", "StopRequest", "algorithm_for"]

#: (component, last successful time [s] or None): an FMU that asked to end the run
StopRequest = tuple[str, float | None]


class Algorithm(Protocol):
    """How values move between the FMUs at a communication point."""

    def initialise(self) -> None:
        """While the FMUs are in initialisation mode."""

    def start(self, t: float, record: Callable[[float], None]) -> None:
        """At the start time, after initialisation: make the outputs consistent, record
        the first row (``record(t)``)."""

    def exchange(self, t: float) -> None:
        """After the step to ``t``: the exchange whose values the row of ``t`` shows."""

    def last(self, t: float, stopped: Iterable[str]) -> None:
        """After an FMU asked to end the run at ``t``: read the outputs for the last
        row (the units named in ``stopped`` get no more inputs)."""


class GaussSeidel:
    """Gauss-Seidel: one pass over the FMUs in feedthrough order at every point."""

    def __init__(self, system: System, units: dict[str, Unit], track: Track,
                 fast: bool) -> None:
        self.track = track
        self.fast = fast
        # ``units``: every unit, or (multirate) those at a communication point of theirs
        order = [name for name in system.order if name in units]
        self.ordered = [units[name] for name in order]
        # Units whose outputs feed a unit visited before them (or themselves): their
        # outputs are read first, so that unit sees the value of this instant and not
        # the one read in the previous pass. Such an output cannot depend directly on an
        # input (the order puts every feedthrough source first), so reading it early is
        # exact.
        position = {name: i for i, name in enumerate(order)}
        backward = {src.name for unit in units.values() for _, src, _ in unit.sources
                    if src.name in position and position[src.name] >= position[unit.name]}
        self.pre_read = [units[name] for name in order if name in backward]
        # A pre-read unit none of whose read outputs depends directly on an input shows
        # the same values after its sets (FMI: only a step changes them): it is read
        # once, at the start, and its values are checked there.
        self.read_once = {u.name for u in self.pre_read
                          if not any(system.models[u.name].dependencies.get(o)
                                     for o in u.out_names)}
        compiled = programs.gauss_seidel_pass(self.pre_read, self.ordered, self.read_once,
                                              track) if fast else None
        self._pass: Callable[[float], None] = compiled or (
            fastpath.gauss_seidel_pass(self.pre_read, self.ordered, self.read_once, track)
            if fast else self.pass_at)
        #: ((phase, program), ...) of one exchange when it is compiled, else None
        self.exchanges: tuple[tuple[int, object], ...] | None = (
            ((GS_PASS, compiled),) if compiled is not None else None)

    def pass_at(self, t: float, stopped: Iterable[str] = ()) -> None:
        """The pass at ``t`` [s], the reference loop; units in ``stopped`` get no sets."""
        track = self.track
        for unit in self.pre_read:
            track[0] = unit.index
            for group in unit.out_groups:
                fn, args, buf, is_float, fname, _ = group
                status = fn(*args)
                if status > 1:
                    raise failed(fname, status)
                if unit.name in self.read_once and is_float and len(buf) and \
                        not isfinite(sum(buf)):
                    check_finite(unit, t)
        for unit in self.ordered:
            in_groups = () if unit.name in stopped else unit.in_groups
            out_groups = () if unit.name in self.read_once else unit.out_groups
            if not (in_groups or out_groups):
                continue
            track[0] = unit.index
            for fn, args, in_val, links, fname in in_groups:
                for j, src, pos in links:
                    in_val[j] = src[pos]
                status = fn(*args)
                if status > 1:
                    raise failed(fname, status)
            for fn, args, buf, is_float, fname, _ in out_groups:
                status = fn(*args)
                if status > 1:
                    raise failed(fname, status)
                if is_float and len(buf) and not isfinite(sum(buf)):
                    check_finite(unit, t)

    def initialise(self) -> None:
        pass

    def start(self, t: float, record: Callable[[float], None]) -> None:
        self._pass(t)
        record(t)

    def exchange(self, t: float) -> None:
        self.track[1] = GS_PASS
        self._pass(t)

    def last(self, t: float, stopped: Iterable[str]) -> None:
        self.track[1] = GS_PASS
        stopped = set(stopped)
        if self.fast:
            (programs.gauss_seidel_pass(self.pre_read, self.ordered, self.read_once,
                                        self.track, stopped)
             or fastpath.gauss_seidel_pass(self.pre_read, self.ordered, self.read_once,
                                           self.track, stopped))(t)
        else:
            self.pass_at(t, stopped)


class Jacobi:
    """Jacobi: every FMU's outputs read, then every input set."""

    def __init__(self, system: System, units: dict[str, Unit], track: Track,
                 fast: bool) -> None:
        self.track = track
        self.units = list(units.values())
        read = programs.jacobi_get(self.units, track) if fast else None
        write = programs.jacobi_set(self.units, track) if fast else None
        self._read: Callable[[float], None] = read or (
            fastpath.jacobi_get(self.units, track) if fast else self.read_all)
        self._set: Callable[[], None] = write or (
            fastpath.jacobi_set(self.units, track) if fast else self.set_all)
        #: ((phase, program), ...) of one exchange when it is compiled, else None
        self.exchanges: tuple[tuple[int, object], ...] | None = (
            ((GET, read), (SET, write)) if read is not None and write is not None else None)

    def read_all(self, t: float) -> None:
        """Every unit's outputs read, then checked for NaN/inf (the reference loop)."""
        for unit in self.units:
            self.track[0] = unit.index
            unit.get()
            if not unit.finite():
                check_finite(unit, t)

    def set_all(self) -> None:
        """Every unit's inputs set from the values last read (the reference loop)."""
        for unit in self.units:
            self.track[0] = unit.index
            unit.set()

    def initialise(self) -> None:
        # libcosim's initialisation: as many Jacobi exchanges as there are FMUs while
        # they are in initialisation mode, which propagates initial values through any
        # chain of direct feedthrough
        self.track[1] = EXCHANGE
        for _ in self.units:
            for unit in self.units:
                self.track[0] = unit.index
                unit.get()
            for unit in self.units:
                self.track[0] = unit.index
                unit.set()

    def start(self, t: float, record: Callable[[float], None]) -> None:
        self._read(t)
        record(t)
        self._set()

    def exchange(self, t: float) -> None:
        self.track[1] = GET
        self._read(t)
        self.track[1] = SET
        self._set()

    def last(self, t: float, stopped: Iterable[str]) -> None:
        self.track[1] = GET
        self._read(t)


def algorithm_for(system: System, units: dict[str, Unit], track: Track,
                  fast: bool) -> Algorithm:
    """The system's algorithm (``system.algorithm``: "gauss-seidel" or "jacobi")."""
    kind = Jacobi if system.algorithm == "jacobi" else GaussSeidel
    return kind(system, units, track, fast)


def fmi2_stepped(unit: FmuUnit, status: int, requests: list[StopRequest]) -> None:
    """After an ``fmi2DoStep`` status above Warning: a stop request (Discard with
    ``fmi2Terminated``) goes to ``requests``, anything else raises."""
    asked, when = unit.stop_requested() if status == 2 else (False, 0.0)
    if not asked:
        raise failed("fmi2DoStep", status)
    requests.append((unit.name, when))


def fmi3_stepped(unit: FmuUnit, status: int, requests: list[StopRequest]) -> None:
    """After an ``fmi3DoStep`` with a status above Warning or ``terminateSimulation``: a
    stop request goes to ``requests``; an Error (or a Discard without it) raises."""
    if status > 2:
        raise failed("fmi3DoStep", status)
    if unit.flags[1].value:
        requests.append((unit.name, unit.stop_requested()[1]))
    elif status == 2:
        raise failed("fmi3DoStep", status)


class Stepper:
    """Every FMU steps from t to t + h in turn (tables are not stepped); an FMU that asks
    to end the run (FMI 2.0 ``fmi2Discard`` with ``fmi2Terminated``, FMI 3.0
    ``terminateSimulation``) is added to :attr:`requests`, and the others still step.
    :attr:`step` is ``step(t, h)``: t the communication point t_k, h the step size to
    t_{k+1} (:meth:`.grid.Grid.step_size`)."""

    def __init__(self, units: Iterable[Unit], track: Track, fast: bool,
                 requests: list[StopRequest] | None = None) -> None:
        self.units = [u for u in units if isinstance(u, FmuUnit)]
        self.track = track
        #: the stop requests (``requests``: a list shared with other steppers)
        self.requests: list[StopRequest] = [] if requests is None else requests
        #: the compiled step program, or None
        self.compiled = programs.step_all(self.units, track, DO_STEP, fmi2_stepped,
                                          fmi3_stepped, self.requests) if fast else None
        self.step: Callable[[float, float], None] = self.compiled or (
            fastpath.step_all(self.units, track, DO_STEP, fmi2_stepped, fmi3_stepped,
                              self.requests) if fast else self.step_reference)

    def step_reference(self, t: float, h: float) -> None:
        """The step from ``t`` to ``t + h`` [s], the reference loop."""
        track, requests = self.track, self.requests
        track[2] = t
        track[1] = DO_STEP
        for unit in self.units:
            track[0] = unit.index
            if unit.step_extra is None:
                status = unit.do_step(unit.component, t, h, 1)
                if status > 1:
                    fmi2_stepped(unit, status, requests)
            else:
                status = unit.do_step(unit.component, t, h, True, *unit.step_extra)
                if status > 1 or unit.flags[1].value:
                    fmi3_stepped(unit, status, requests)
