"""Fixed-step co-simulation master (Gauss-Seidel or Jacobi) over fmpy FMU2Slave.

Semantics (communication points t_k = start + k h, inputs held over each step):

Gauss-Seidel (default)
    At every t_k the FMUs are visited in topological order of the direct-feedthrough
    graph (an edge only through outputs that depend directly on inputs). Each FMU gets
    its inputs from its sources' current outputs (one batched ``fmi2SetReal``), then its
    outputs are read (one batched ``fmi2GetReal``; our FMUs recompute feedthrough outputs
    on a get after a set). An FMU whose outputs feed an FMU visited before it (a loop
    closed through an output without direct feedthrough, e.g. actuator -> vehicle) has
    those outputs read at the start of the pass. Every input therefore holds the value
    of the same instant t_k.
    The row of t_k is recorded, then every FMU steps from t_k to t_k + h.
Jacobi (what libcosim does)
    After the step to t_k, every FMU's outputs are read first (one batched get each);
    then every input is set from those values. An input therefore holds, during
    [t_k, t_k + h), what its source published at the end of the previous step: each
    connection through a feedthrough output adds one macro step of delay (a path through
    n feedthrough hops lags n steps). The recorded row holds the values read before the
    sets.
Start
    ``fmi2SetupExperiment``, parameters, enter/exit initialisation. Gauss-Seidel: one
    propagation pass after initialisation so the outputs at t0 are consistent, then t0 is
    recorded. Jacobi, as libcosim does: while the FMUs are in initialisation mode, N
    Jacobi exchanges (N = number of FMUs: every output read, then every input set),
    which propagate initial values through feedthrough chains; after initialisation
    the outputs are recorded as t0 and passed to the inputs once more.
    tests/test_ssp.py matches libcosim to 1e-9 on this.

A non-OK FMI status or a NaN/inf output stops the run with a :class:`SimulationError`
naming component, variable (or FMI call) and time; rows recorded so far are kept.
Every FMU's extraction folder is removed when the run ends, however it ends.
"""

from dataclasses import dataclass
from math import isfinite

import numpy as np

from .model import FmuInstance


class SimulationError(Exception):
    """The run stopped: an FMU failed or produced a non-finite value."""


class _WriteFailed(Exception):
    """``write_row`` raised: its error is the caller's (e.g. a full disk), not an FMU's."""

    def __init__(self, error):
        super().__init__(str(error))
        self.error = error


@dataclass
class Plan:
    """Everything :func:`simulate` needs for one run."""

    models: dict          # instance name -> ModelInfo
    parameters: dict      # instance name -> {parameter: value}
    connections: list     # manifest.Connection
    order: list           # Gauss-Seidel order of instance names
    record: list          # "component.variable" (Real outputs)
    start: float
    stop: float
    step: float
    algorithm: str
    record_every: int


def _raw_function(slave, name):
    """``slave.<name>`` without fmpy's per-call wrapper when that changes nothing.

    fmpy's ``FMU2Slave.fmi2XXX`` methods go through ``_call`` (a dictionary look-up, an
    optional call logger, a status check): about half a microsecond per call, which was
    most of the master's per-step overhead. Without a call logger the wrapper only
    raises ``FMICallException`` for a status above ``fmi2Warning``; the master calls the
    raw ctypes function (same argtypes, same arguments) and raises the same exception
    itself (:func:`_failed`). With a call logger, or an fmpy without ``_functions``, the
    wrapper is returned (it raises first; it also returns the status).
    """
    function = getattr(slave, "_functions", {}).get(name)
    if function is None or getattr(slave, "fmiCallLogger", None) is not None:
        return getattr(slave, name)
    return function


def _failed(function, status):
    """The exception fmpy's wrapper raises for a status above ``fmi2Warning``."""
    from fmpy.fmi1 import FMICallException

    return FMICallException(function=function, status=status)


class _Unit:
    """One FMU with its preallocated value-reference and value buffers."""

    def __init__(self, instance, outputs, inputs):
        from fmpy.fmi2 import fmi2Real, fmi2ValueReference

        self.inst = instance
        self.name = instance.name
        self.slave = instance.slave
        self.component = self.slave.component
        self.do_step = _raw_function(self.slave, "fmi2DoStep")
        self.get_real = _raw_function(self.slave, "fmi2GetReal")
        self.set_real = _raw_function(self.slave, "fmi2SetReal")
        self.out_names = [v.name for v in outputs]
        self.n_out = len(outputs)
        self.out_vr = (fmi2ValueReference * max(1, len(outputs)))(*[v.vr for v in outputs])
        self.out_val = (fmi2Real * max(1, len(outputs)))()
        self.out = np.ctypeslib.as_array(self.out_val)[: len(outputs)]
        self.in_names = [v.name for v in inputs]
        self.n_in = len(inputs)
        self.in_vr = (fmi2ValueReference * max(1, len(inputs)))(*[v.vr for v in inputs])
        self.in_val = (fmi2Real * max(1, len(inputs)))()
        self.in_arr = np.ctypeslib.as_array(self.in_val)[: len(inputs)]
        self.sources = []  # (input position, source unit, output position)
        self.links = ()    # (input position, source value buffer, output position)

    def get(self):
        if self.n_out:
            status = self.get_real(self.component, self.out_vr, self.n_out, self.out_val)
            if status > 1:
                raise _failed("fmi2GetReal", status)

    def set(self):
        if self.n_in:
            in_val = self.in_val
            for j, out_val, pos in self.links:
                in_val[j] = out_val[pos]
            status = self.set_real(self.component, self.in_vr, self.n_in, in_val)
            if status > 1:
                raise _failed("fmi2SetReal", status)


def _set_parameter(slave, var, value):
    if var.type == "Real":
        slave.setReal([var.vr], [float(value)])
    elif var.type in ("Integer", "Enumeration"):
        slave.setInteger([var.vr], [int(value)])
    elif var.type == "Boolean":
        slave.setBoolean([var.vr], [bool(value)])
    else:
        slave.setString([var.vr], [str(value)])


#: What a run is doing, by code (``track[1]``; see :func:`simulate`).
PHASES = ("instantiation", "initialisation", "initialisation exchange",
          "initial propagation", "doStep", "fmi2GetReal", "fmi2SetReal",
          "Gauss-Seidel pass")
(_INSTANTIATION, _INITIALISATION, _EXCHANGE, _PROPAGATION, _DO_STEP, _GET, _SET,
 _GS_PASS) = range(len(PHASES))


def describe_track(track, names):
    """``"component 'X' during <phase> at t=<t> s"`` from a :func:`simulate` track."""
    unit, phase, t = int(track[0]), int(track[1]), float(track[2])
    name = names[unit] if 0 <= unit < len(names) else "?"
    return f"component '{name}' during {PHASES[phase]} at t={t!r} s"


def simulate(plan, write_row, progress=None, track=None, on_message=None):
    """Run one co-simulation.

    Parameters
    ----------
    plan : Plan
    write_row : callable
        Called with each recorded row (list of float: time [s], then the ``plan.record``
        values in order).
    progress : callable, optional
        Called with the number of macro steps done since the last call.
    track : mutable sequence of 3 float, optional
        Kept current (cheaply, one store per FMU call): index of the component being
        called (in ``plan.models`` order), code of the phase (:data:`PHASES`) and time
        [s]. In shared memory, it lets a parent name the component, call and time of a
        run whose process died (:func:`describe_track`).
    on_message : callable, optional
        ``on_message(component, status, text)`` for every message an FMU logs.

    Returns
    -------
    int
        Number of rows written.

    Raises
    ------
    SimulationError
        An FMU returned a non-OK status or an output became NaN/inf.
    Exception
        Whatever ``write_row`` raised (e.g. OSError for a full disk), unchanged.
    """
    from fmpy.fmi1 import FMICallException

    instances, units = {}, {}
    names = list(plan.models)
    index = {cname: i for i, cname in enumerate(names)}
    track = [0.0, 0.0, 0.0] if track is None else track
    track[0], track[1], track[2] = -1, _INSTANTIATION, plan.start
    rows = 0
    try:
        for cname in plan.models:
            track[0] = index[cname]
            instances[cname] = FmuInstance(plan.models[cname], cname, on_message)
        connected = {}
        for conn in plan.connections:
            connected.setdefault(conn.target[0], []).append(conn)
        needed_out = {c: set() for c in plan.models}
        for conn in plan.connections:
            needed_out[conn.source[0]].add(conn.source[1])
        for name in plan.record:
            cname, vname = name.split(".")
            needed_out[cname].add(vname)
        for cname, info in plan.models.items():
            outs = [v for v in info.outputs if v.name in needed_out[cname]]
            ins = [info.variables[c.target[1]] for c in connected.get(cname, [])]
            units[cname] = _Unit(instances[cname], outs, ins)
            units[cname].index = index[cname]
        for cname, unit in units.items():
            for j, conn in enumerate(connected.get(cname, [])):
                src = units[conn.source[0]]
                unit.sources.append((j, src, src.out_names.index(conn.source[1])))
            unit.links = tuple((j, src.out_val, pos) for j, src, pos in unit.sources)
        record_idx = [(units[n.split(".")[0]], units[n.split(".")[0]].out_names.index(
            n.split(".")[1])) for n in plan.record]

        track[1] = _INITIALISATION
        for cname in plan.models:
            track[0] = index[cname]
            slave = instances[cname].slave
            slave.setupExperiment(startTime=plan.start, stopTime=plan.stop)
            info = plan.models[cname]
            for pname, value in plan.parameters.get(cname, {}).items():
                _set_parameter(slave, info.variables[pname], value)
            slave.enterInitializationMode()
        all_units = list(units.values())
        if plan.algorithm == "jacobi":
            # libcosim's initialisation: as many Jacobi exchanges as there are FMUs while
            # they are in initialisation mode, which propagates initial values through
            # any chain of direct feedthrough
            track[1] = _EXCHANGE
            for _ in all_units:
                for unit in all_units:
                    track[0] = unit.index
                    unit.get()
                for unit in all_units:
                    track[0] = unit.index
                    unit.set()
        track[1] = _INITIALISATION
        for cname in plan.models:
            track[0] = index[cname]
            instances[cname].slave.exitInitializationMode()

        step_plan = [(u.index, u.component, u.do_step) for u in all_units]
        n_steps = int(round((plan.stop - plan.start) / plan.step))
        h = plan.step
        row = [0.0] * (1 + len(record_idx))
        record_from = [(i, unit.out_val, pos)
                       for i, (unit, pos) in enumerate(record_idx, start=1)]

        def check(unit, t):
            # Callers may skip this when sum(unit.out_val) is finite: a sum is finite only
            # if every term is (NaN and inf propagate); an overflowed sum lands here.
            values = unit.out
            if unit.n_out and not np.isfinite(values).all():
                pos = int(np.flatnonzero(~np.isfinite(values))[0])
                raise SimulationError(f"component '{unit.name}': output "
                                      f"'{unit.out_names[pos]}' is {float(values[pos])!r} at "
                                      f"t={t!r} s")

        # The Gauss-Seidel pass, unrolled: per unit (name, component, set function, input
        # references, count, buffer, links, get function, output references, count,
        # buffer); a unit without inputs (outputs) skips the set (get), as _Unit does.
        gs_plan = [(u.index, u.component, u.set_real, u.in_vr, u.n_in, u.in_val, u.links,
                    u.get_real, u.out_vr, u.n_out, u.out_val, u) for u in
                   (units[c] for c in plan.order)]

        # Units whose outputs feed a unit visited before them (or themselves): their
        # outputs are read first, so that unit sees the value of this instant and not the
        # one read in the previous pass. Such an output cannot depend directly on an input
        # (the order puts every feedthrough source first), so reading it early is exact.
        position = {name: i for i, name in enumerate(plan.order)}
        backward = {src.name for unit in all_units for _, src, _ in unit.sources
                    if position[src.name] >= position[unit.name]}
        pre_read = [units[name] for name in plan.order if name in backward]

        def gs_pass(t):
            for unit in pre_read:
                track[0] = unit.index
                unit.get()
            for (i, comp, set_real, in_vr, n_in, in_val, links, get_real, out_vr, n_out,
                 out_val, unit) in gs_plan:
                track[0] = i
                if n_in:
                    for j, src, pos in links:
                        in_val[j] = src[pos]
                    status = set_real(comp, in_vr, n_in, in_val)
                    if status > 1:
                        raise _failed("fmi2SetReal", status)
                if n_out:
                    status = get_real(comp, out_vr, n_out, out_val)
                    if status > 1:
                        raise _failed("fmi2GetReal", status)
                    if not isfinite(sum(out_val)):
                        check(unit, t)

        def record(t):
            nonlocal rows
            row[0] = t
            for i, buffer, pos in record_from:
                row[i] = buffer[pos]
            try:
                write_row(row)
            except Exception as error:  # noqa: BLE001 - re-raised as itself below
                raise _WriteFailed(error) from None
            rows += 1

        track[1] = _PROPAGATION
        jacobi = plan.algorithm == "jacobi"
        if jacobi:
            for unit in all_units:
                track[0] = unit.index
                unit.get()
                if not isfinite(sum(unit.out_val)):
                    check(unit, plan.start)
            record(plan.start)
            for unit in all_units:
                track[0] = unit.index
                unit.set()
        else:
            gs_pass(plan.start)
            record(plan.start)
        every = plan.record_every
        done = 0
        for k in range(n_steps):
            t = plan.start + k * h
            track[2] = t
            track[1] = _DO_STEP
            for i, comp, do_step in step_plan:
                track[0] = i
                status = do_step(comp, t, h, 1)
                if status > 1:
                    raise _failed("fmi2DoStep", status)
            t_next = plan.start + (k + 1) * h
            track[2] = t_next
            if jacobi:
                track[1] = _GET
                for unit in all_units:
                    track[0] = unit.index
                    unit.get()
                    if not isfinite(sum(unit.out_val)):
                        check(unit, t_next)
                track[1] = _SET
                for unit in all_units:
                    track[0] = unit.index
                    unit.set()
            else:
                track[1] = _GS_PASS
                gs_pass(t_next)
            if (k + 1) % every == 0 or k + 1 == n_steps:
                record(t_next)
            if progress is not None:
                done += 1
                if done >= 1000:
                    progress(done)
                    done = 0
        if progress is not None and done:
            progress(done)
        return rows
    except FMICallException as error:
        name = names[int(track[0])] if int(track[0]) >= 0 else "?"
        detail = instances[name].last_error() if name in instances else ""
        raise SimulationError(f"component '{name}': {error.function} returned status "
                              f"{error.status} during {PHASES[int(track[1])]} at "
                              f"t={track[2]!r} s" + (f": {detail}" if detail else "")) \
            from None
    except SimulationError:
        raise
    except _WriteFailed as failed:  # not the FMU's fault: the caller's own error
        raise failed.error from None
    except Exception as error:  # noqa: BLE001 - e.g. a failed instantiation
        name = names[int(track[0])] if int(track[0]) >= 0 else "?"
        detail = instances[name].last_error() if name in instances else ""
        raise SimulationError(f"component '{name}': {PHASES[int(track[1])]} at "
                              f"t={track[2]!r} s: {type(error).__name__}: {error}"
                              + (f": {detail}" if detail else "")) from None
    finally:
        for instance in instances.values():
            instance.close()
