"""One co-simulation run, composed of its parts.

FMI 2.0 and 3.0 co-simulation FMUs may be mixed, and with them Model Exchange FMUs,
which the orchestrator integrates (:mod:`.model_exchange`: the same unit interface).
:func:`simulate` instantiates the FMUs
(:mod:`.instance`), wires their value buffers (:mod:`.units`), initialises them
(``fmi2SetupExperiment``, parameters, enter / exit initialisation; for FMI 3.0 the
parameters before ``fmi3EnterInitializationMode``), then at every communication point
(t_k = start + k step, :mod:`.grid`; components with a step of their own at theirs,
:mod:`.multirate`) lets the :mod:`scenario <.scenario>` apply its
events, the :mod:`algorithm <.algorithm>` exchange the values, the observers
(:mod:`.observers`) take the recorded row, and the stepper step every FMU; an FMU's
stop request ends the run after that macro step.

A non-OK FMI status or a NaN/inf output stops the run with a
:class:`~agv_cosim.errors.SimulationError` naming component, variable (or FMI call) and
time; rows recorded so far are kept. Every FMU's extraction folder is removed when the
run ends, however it ends.
"""

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from ..errors import SimulationError
from ..system import System
from ..system.model import ModelInfo
from .algorithm import Algorithm, Stepper, algorithm_for
from .grid import Grid
from .instance import FmuInstance, extract_ahead
from .model_exchange import ModelExchangeUnit
from .multirate import multiples, run_multirate
from .observers import Observer
from .pacing import Pacer
from .scenario import Scenario
from .stretch import Tail, compiled_stretch
from .track import INITIALISATION, INSTANTIATION, PHASES, PROPAGATION, Track
from .units import Unit, build_units, enter_initialisation

__all__ = ["Outcome", "simulate"]

#: FMI 2.0 / 3.0 status codes above OK (the same numbers in both versions)
_STATUS_NAMES = {1: "Warning", 2: "Discard", 3: "Error", 4: "Fatal", 5: "Pending"}

#: Macro steps between two progress reports to the observers.
PROGRESS_EVERY = 1000


@dataclass
class Outcome:
    """How a run that did not fail ended."""

    #: rows recorded
    rows: int
    #: ``"<component> requested stop at t=<t> s"``, or None when it ran to its stop time
    ended_by: str | None = None
    #: the last successful time of the FMU that asked to end the run [s]
    stop_time: float | None = None


class _WriteFailed(Exception):
    """An observer raised: its error is the caller's (e.g. a full disk), not an FMU's."""

    def __init__(self, error: Exception) -> None:
        super().__init__(str(error))
        self.error = error


def _instantiate(system: System, instances: dict[str, FmuInstance], track: Track,
                 on_message: Callable[[str, int, str], None] | None) -> None:
    """Instantiate every FMU into ``instances`` (so the caller can close them whatever
    happens)."""
    extract_ahead(system.models.values())
    for i, (cname, info) in enumerate(system.models.items()):
        track[0] = i
        if info.table is None:
            instances[cname] = FmuInstance(info, cname, on_message)


def _initialise(system: System, instances: dict[str, FmuInstance],
                algorithm: Algorithm, track: Track) -> None:
    """Set up the experiment, set the parameters, enter and exit initialisation mode
    (the algorithm's exchanges in between)."""
    index = {cname: i for i, cname in enumerate(system.models)}
    models: dict[str, ModelInfo] = system.models
    track[1] = INITIALISATION
    for cname, instance in instances.items():
        track[0] = index[cname]
        enter_initialisation(instance.slave, models[cname], system.parameters.get(cname, {}),
                             system.start, system.stop)
    algorithm.initialise()
    track[1] = INITIALISATION
    for cname, instance in instances.items():
        track[0] = index[cname]
        instance.slave.exitInitializationMode()


def _record_from(system: System, units: dict[str, Unit]) -> list[tuple[int, Any, int]]:
    """Per recorded signal: (row position, buffer, position in it)."""
    found = []
    for i, name in enumerate(system.record, start=1):
        cname, _, vname = name.partition(".")  # component names have no dot
        found.append((i, *units[cname].address[vname]))
    return found


def _loop(system: System, algorithm: Algorithm, stepper: Stepper, scenario: Scenario,
          record: Callable[[float], None], progress: list[Callable[[int], None]],
          track: Track, pace: Pacer | None = None) -> Outcome:
    """The communication points after the first (t_k of :class:`.grid.Grid`): step,
    events, exchange, record."""
    steps = system.steps
    grid = Grid(system.start, system.stop, steps, system.step)
    time, step_size = grid.time, grid.step_size
    requests = stepper.requests
    step = stepper.step if pace is None else pace.wrap(stepper.step)
    stretch = compiled_stretch(algorithm, stepper, grid, pace)
    tail = Tail(steps, system.record_every, record, progress, PROGRESS_EVERY, requests,
                lambda _: algorithm)
    exchange, point = algorithm.exchange, tail.point
    t = system.start
    k = 0
    while k < steps:
        if stretch is not None and k + 1 != scenario.next_step:
            # the macro steps up to the next event, recording point or progress report
            # in C: each of k .. end - 1 steps and exchanges (stopping after a step that
            # brought a stop request)
            end = tail.bound
            if scenario.next_step > k + 1:
                end = min(end, scenario.next_step - 1)
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
        if requests:
            tail.stop(k, t_next)
            break
        exchange(t_next)
        k += 1
        if k >= tail.bound:
            point(k, t_next)
    tail.finish(k)
    return Outcome(rows=0, ended_by=tail.ended_by, stop_time=tail.stop_time)


def simulate(system: System, observers: Iterable[Observer] = (), *,
             track: Track | None = None,
             on_message: Callable[[str, int, str], None] | None = None,
             fast: bool = False, pace: Pacer | None = None) -> Outcome:
    """Run one co-simulation.

    Parameters
    ----------
    system : System
        The checked system of the run.
    observers : iterable of Observer
        Given each recorded row and the progress (:mod:`agv_cosim.execution.observers`).
    track : mutable sequence of 3 float, optional
        Kept current (cheaply, one store per FMU call): index of the component being
        called (in ``system.models`` order), code of the phase and time [s]
        (:mod:`agv_cosim.execution.track`).
    on_message : callable, optional
        ``on_message(component, status, text)`` for every message an FMU logs.
    fast : bool
        Step with the generated functions of :mod:`agv_cosim.execution.fastpath`
        instead of the reference loops (the same calls; bit-identical results).
    pace : Pacer, optional
        Hold the macro steps to a real-time factor (:mod:`.pacing`; the results are
        unchanged); its :meth:`~.pacing.Pacer.report` then says how it went.

    Returns
    -------
    Outcome
        Rows recorded; when an FMU asked to end the run (FMI 2.0 ``fmi2Discard`` with
        ``fmi2Terminated``, FMI 3.0 ``terminateSimulation``), which and when: every FMU
        finishes that macro step, the row of its end is recorded (if the FMU reached
        it; the FMU that stopped gets no more inputs) and the run ends normally. A
        Discard without the termination flag stays an error.

    Raises
    ------
    SimulationError
        An FMU returned a non-OK status or an output became NaN/inf, or the pacing
        itself failed (the message then names no component).
    Exception
        Whatever an observer raised (e.g. OSError for a full disk), unchanged.
    """
    from fmpy.fmi1 import FMICallException

    observers = list(observers)
    progress: list[Callable[[int], None]] = [
        o.steps for o in observers if type(o).steps is not Observer.steps]
    instances: dict[str, FmuInstance] = {}
    track = [0.0, 0.0, 0.0] if track is None else track
    track[0], track[1], track[2] = -1, INSTANTIATION, system.start
    try:
        _instantiate(system, instances, track, on_message)
        units = build_units(system.models, instances, system.connections, system.record,
                            track, ModelExchangeUnit)
        algorithm = algorithm_for(system, units, track, fast)
        _initialise(system, instances, algorithm, track)
        recorder = _Recorder(system, units, observers)
        scenario = Scenario(system.events, instances, system.models)
        multirate = any(m > 1 for m in multiples(system).values())
        stepper = None if multirate else Stepper(units.values(), track, fast)
        track[1] = PROPAGATION
        if scenario.next_step == 0:
            scenario.apply(0)
        algorithm.start(system.start, recorder.record)
        if stepper is not None:
            outcome = _loop(system, algorithm, stepper, scenario, recorder.record,
                            progress, track, pace)
        else:
            outcome = Outcome(rows=0)
            outcome.ended_by, outcome.stop_time, _ = run_multirate(
                system, units, algorithm, scenario, recorder.record, progress, track,
                fast, pace, PROGRESS_EVERY)
        outcome.rows = recorder.rows
        return outcome
    except FMICallException as error:
        raise _failed_call(error, system, instances, track) from None
    except SimulationError:
        raise
    except _WriteFailed as failed:  # not the FMU's fault: the caller's own error
        raise failed.error from None
    except Exception as error:  # noqa: BLE001 - e.g. a failed instantiation
        raise _failed_otherwise(error, system, instances, track) from None
    finally:
        for instance in instances.values():
            instance.close()


class _Recorder:
    """The recorded row at a communication point, handed to every observer."""

    def __init__(self, system: System, units: dict[str, Unit],
                 observers: list[Observer]) -> None:
        self.rows = 0
        self._row = [0.0] * (1 + len(system.record))
        self._from = _record_from(system, units)
        self._observers: list[Callable[[list[float]], None]] = [
            o.row for o in observers if type(o).row is not Observer.row]

    def record(self, t: float) -> None:
        row = self._row
        row[0] = t
        for i, buffer, pos in self._from:
            row[i] = buffer[pos]
        try:
            for write in self._observers:
                write(row)
        except Exception as error:  # noqa: BLE001 - re-raised as itself by simulate
            raise _WriteFailed(error) from None
        self.rows += 1


def _culprit(system: System, instances: dict[str, FmuInstance],
             track: Track) -> tuple[str, str]:
    """The component the track names and its own last error message ('' if none)."""
    names = list(system.models)
    name = names[int(track[0])] if int(track[0]) >= 0 else "?"
    return name, instances[name].last_error() if name in instances else ""


def _failed_call(error: Any, system: System, instances: dict[str, FmuInstance],
                 track: Track) -> SimulationError:
    """An FMI call's failure as one line: component, call, status, phase, time, and the
    FMU's own message."""
    name, detail = _culprit(system, instances, track)
    status = _STATUS_NAMES.get(int(error.status), "")
    if status == "Discard" and error.function.endswith("DoStep"):
        status += ", no stop requested"
    return SimulationError(f"component '{name}': {error.function} returned status "
                           f"{error.status}{f' ({status})' if status else ''} during "
                           f"{PHASES[int(track[1])]} at t={track[2]!r} s"
                           + (f": {detail}" if detail else ""))


def _failed_otherwise(error: Exception, system: System, instances: dict[str, FmuInstance],
                      track: Track) -> SimulationError:
    """Any other failure (e.g. an instantiation) as one line naming component and phase."""
    name, detail = _culprit(system, instances, track)
    return SimulationError(f"component '{name}': {PHASES[int(track[1])]} at "
                           f"t={track[2]!r} s: {type(error).__name__}: {error}"
                           + (f": {detail}" if detail else ""))
