"""The FMUs of a run as units of preallocated value buffers: what the algorithms move.

A :class:`FmuUnit` groups its variables by C getter / setter (:mod:`agv_cosim.fmitypes`):
one batched call per group, i.e. per type, per FMU and exchange (one ``fmi2GetReal``
and one ``fmi2GetInteger`` for an FMU with Real and Integer outputs). An input group
knows, per value, the source buffer and position it is copied from (:meth:`FmuUnit.link`).
A :class:`TableUnit` puts a time table in the place of an FMU (outputs only).

The FMI functions are fmpy's C functions of the FMU's library (``slave.dll.<name>``,
declared by fmpy with their argument types), called directly, their status checked
here (above Warning: the :class:`fmpy.fmi1.FMICallException` fmpy's own wrapper raises).
With an fmpy call logger set, fmpy's wrapper is called instead (it logs and raises).
"""

from collections.abc import Callable
from ctypes import byref, c_bool, c_double, c_int
from math import isfinite
from typing import Any

from .. import fmitypes
from ..errors import SimulationError
from ..system.model import ModelInfo, Variable, element_names
from ..system.table import Table
from .instance import FmuInstance

__all__ = ["FmuUnit", "Group", "InputGroup", "TableUnit", "Unit", "c_function",
           "check_finite", "enter_initialisation", "failed", "set_value"]

#: An output group: (function, args, buffer, is_float, C function name, names per position)
Group = tuple[Any, tuple[Any, ...], Any, bool, str, list[str]]
#: An input group: (function, args, buffer, links (position, source buffer, source
#: position), C function name)
InputGroup = tuple[Any, tuple[Any, ...], Any, tuple[tuple[int, Any, int], ...], str]


def c_function(slave: Any, name: str) -> Any:
    """The FMI function ``name`` of ``slave``'s library as fmpy declared it (argument
    and result types set), or fmpy's wrapper method when a call logger is set or the
    library function carries no declared types.

    fmpy's wrapper (a dictionary look-up, the logger check and the status check) costs
    about half a microsecond a call, most of the master's own per-step work; without a
    logger it only raises for a status above ``fmi2Warning``, which the callers here do
    themselves (:func:`failed`).
    """
    if getattr(slave, "fmiCallLogger", None) is not None:
        return getattr(slave, name)
    function = getattr(getattr(slave, "dll", None), name, None)
    if function is None or not getattr(function, "argtypes", None):
        return getattr(slave, name)
    return function


def failed(function: str, status: int) -> Exception:
    """The exception fmpy's wrapper raises for a status above ``fmi2Warning``."""
    from fmpy.fmi1 import FMICallException

    error: Exception = FMICallException(function=function, status=status)  # fmpy: untyped
    return error


def set_value(slave: Any, var: Variable, value: Any) -> None:
    """Set one variable (a parameter, or an event's value) with fmpy's setters."""
    fmitypes.set_parameter(slave, var.ftype, var.vr, value)



def enter_initialisation(slave: Any, info: ModelInfo, parameters: dict[str, Any],
                         start: float, stop: float,
                         note: Callable[[str], None] | None = None) -> None:
    """Set up the experiment, set ``parameters`` and enter initialisation mode, in the
    order the FMU's FMI version asks for (FMI 3.0 has no setupExperiment: its start and
    stop times come with enterInitializationMode). ``note`` is told the name of each FMI
    call (or parameter setting) before it is made, for error messages."""
    fmi = "fmi3" if info.fmi_version == "3.0" else "fmi2"
    if fmi == "fmi2":
        if note:
            note("fmi2SetupExperiment")
        slave.setupExperiment(startTime=start, stopTime=stop)
    for pname, value in parameters.items():
        if note:
            note(f"setting parameter '{pname}'")
        set_value(slave, info.variables[pname], value)
    if note:
        note(f"{fmi}EnterInitializationMode")
    if fmi == "fmi3":
        slave.enterInitializationMode(startTime=start, stopTime=stop)
    else:
        slave.enterInitializationMode()

def _vr_type(fmi3: bool) -> Any:
    if fmi3:
        from fmpy.fmi3 import fmi3ValueReference
        return fmi3ValueReference
    from fmpy.fmi2 import fmi2ValueReference
    return fmi2ValueReference


def _grouped(variables: list[Variable], what: str) -> list[tuple[str, list[Variable]]]:
    """``[(C function name, [variables])]`` in first-seen order."""
    groups: dict[str, list[Variable]] = {}
    for v in variables:
        groups.setdefault(getattr(v.ftype, what), []).append(v)
    return list(groups.items())


class FmuUnit:
    """One FMU with its preallocated value-reference and value buffers.

    A group's ``args`` is the prebuilt argument tuple (FMI 3.0 getters and setters take
    the value count twice).
    """

    table = False

    def __init__(self, instance: FmuInstance, index: int, outputs: list[Variable],
                 inputs: list[Variable]) -> None:
        self.inst = instance
        self.name = instance.name
        self.index = index
        self.slave = instance.slave
        self.component = self.slave.component
        self.fmi3 = instance.info.fmi_version == "3.0"
        vr_type = _vr_type(self.fmi3)
        self.do_step = self._step_function()
        self.step_extra: tuple[Any, ...] | None = None
        if self.fmi3:
            # fmi3DoStep's out-arguments: eventHandlingNeeded, terminateSimulation,
            # earlyReturn, lastSuccessfulTime
            self.flags = (c_bool(), c_bool(), c_bool(), c_double())
            self.step_extra = tuple(byref(flag) for flag in self.flags)
        self.out_names = [v.name for v in outputs]
        self.address: dict[str, tuple[Any, int]] = {}  # output -> (buffer, position)
        out_groups: list[Group] = []
        arrays = instance.info.variables
        for fname, variables in _grouped(outputs, "get"):
            ftype = variables[0].ftype
            # an array element is read with its whole array (FMI 3.0: one value
            # reference, all its values in row-major order)
            whole: dict[str, tuple[Variable, int]] = {}
            offset = 0
            for v in variables:
                base = arrays[v.element[0]] if v.element else v
                if base.name not in whole:
                    whole[base.name] = (base, offset)
                    offset += base.size or 0  # a known size: arrays are checked
            vrs = (vr_type * len(whole))(*[b.vr for b, _ in whole.values()])
            buf = (ftype.ctype * offset)()
            args = (self.component, vrs, len(whole), buf) + ((offset,) if self.fmi3 else ())
            names: list[str] = []  # per buffer position (for error messages)
            for base, _ in whole.values():
                names += (element_names(base.name, base.shape)
                          if base.dims and base.shape else [base.name])
            for v in variables:
                at = whole[v.element[0]][1] + v.element[1] if v.element else whole[v.name][1]
                self.address[v.name] = (buf, at)
            out_groups.append((c_function(self.slave, fname), args, buf, ftype.is_float,
                               fname, names))
        self.out_groups: tuple[Group, ...] = tuple(out_groups)
        self.in_address: dict[str, tuple[int, int]] = {}
        self._in_groups: list[tuple[Any, tuple[Any, ...], Any, list[tuple[int, Any, int]],
                                    str]] = []
        for fname, variables in _grouped(inputs, "set"):
            ftype = variables[0].ftype
            vrs = (vr_type * len(variables))(*[v.vr for v in variables])
            buf = (ftype.ctype * len(variables))()
            args = (self.component, vrs, len(variables), buf) + \
                ((len(variables),) if self.fmi3 else ())
            for pos, v in enumerate(variables):
                self.in_address[v.name] = (len(self._in_groups), pos)
            self._in_groups.append((c_function(self.slave, fname), args, buf, [], fname))
        self.in_groups: tuple[InputGroup, ...] = ()
        #: (input name, source unit, source output name)
        self.sources: list[tuple[str, Unit, str]] = []

    def _step_function(self) -> Any:
        """What :class:`~.algorithm.Stepper` calls to step this unit: its doStep."""
        return c_function(self.slave, "fmi3DoStep" if self.fmi3 else "fmi2DoStep")

    def link(self, input_name: str, source: "Unit", output_name: str) -> None:
        """Copy ``source``'s output ``output_name`` into input ``input_name`` at each set."""
        group, pos = self.in_address[input_name]
        buf, src_pos = source.address[output_name]
        self._in_groups[group][3].append((pos, buf, src_pos))
        self.sources.append((input_name, source, output_name))

    def freeze(self) -> None:
        """Make the input groups immutable tuples (after every :meth:`link`)."""
        self.in_groups = tuple((fn, args, buf, tuple(links), fname)
                               for fn, args, buf, links, fname in self._in_groups)

    def get(self) -> None:
        """Read every output group (one batched get each)."""
        for fn, args, _, _, fname, _ in self.out_groups:
            status = fn(*args)
            if status > 1:
                raise failed(fname, status)

    def set(self) -> None:
        """Copy every input from its source's buffer, then set each group (one batched
        set each)."""
        for fn, args, in_val, links, fname in self.in_groups:
            for j, src, pos in links:
                in_val[j] = src[pos]
            status = fn(*args)
            if status > 1:
                raise failed(fname, status)

    def finite(self) -> bool:
        """True when every float output read is finite (a sum is finite only if every
        term is; an overflowed sum makes :func:`check_finite` look, and find nothing)."""
        for _, _, buf, is_float, _, _ in self.out_groups:
            if is_float and not isfinite(sum(buf)):
                return False
        return True

    def stop_requested(self) -> tuple[bool, float | None]:
        """After a doStep: (True, last successful time) when the FMU asks to end the run.

        FMI 2.0: ``fmi2Discard`` with ``fmi2GetBooleanStatus(fmi2Terminated)`` true (and
        ``fmi2LastSuccessfulTime``); FMI 3.0: ``terminateSimulation`` (and
        ``lastSuccessfulTime``) of ``fmi3DoStep``.
        """
        if self.fmi3:
            return bool(self.flags[1].value), float(self.flags[3].value)
        from fmpy.fmi2 import fmi2LastSuccessfulTime, fmi2Terminated

        flag, when = c_int(0), c_double(float("nan"))
        try:
            status = self.slave.fmi2GetBooleanStatus(self.component, fmi2Terminated,
                                                     byref(flag))
        except Exception:  # noqa: BLE001 - an FMU that does not answer: not a request
            return False, None
        if status > 1 or not flag.value:
            return False, None
        try:
            self.slave.fmi2GetRealStatus(self.component, fmi2LastSuccessfulTime,
                                         byref(when))
        except Exception:  # noqa: BLE001 - the time is then unknown
            pass
        return True, float(when.value)


class TableUnit:
    """A time table (:mod:`agv_cosim.system.table`) in the place of an FMU: outputs only.

    Its one output group is a Python function that writes every column's value at the
    current communication point (``track[2]``) into a float buffer; it has no inputs and
    is not stepped.
    """

    table = True
    fmi3 = False
    step_extra = None
    component = None
    in_groups: tuple[InputGroup, ...] = ()

    def __init__(self, name: str, index: int, table: Table, track: Any) -> None:
        self.name = name
        self.index = index
        self.sources: list[tuple[str, Unit, str]] = []
        names = list(table.names)
        self.out_names = names
        buf = (c_double * len(names))()
        self.address = {n: (buf, i) for i, n in enumerate(names)}

        def fill() -> int:
            table.values_at(track[2], buf)  # type: ignore[arg-type]  # a float buffer
            return 0

        self.out_groups: tuple[Group, ...] = ((fill, (), buf, True, "table", names),)

    def freeze(self) -> None:
        pass

    def get(self) -> None:
        self.out_groups[0][0]()

    def set(self) -> None:
        pass

    def finite(self) -> bool:
        return True


Unit = FmuUnit | TableUnit


def check_finite(unit: Unit, t: float) -> None:
    """Raise naming the first non-finite float output of ``unit`` at ``t`` [s]."""
    for _, _, buf, is_float, _, names in unit.out_groups:
        if not is_float:
            continue
        for pos, value in enumerate(buf):
            if not isfinite(value):
                raise SimulationError(f"component '{unit.name}': output "
                                      f"'{names[pos]}' is {float(value)!r} at "
                                      f"t={t!r} s")


def build_units(models: dict[str, ModelInfo], instances: dict[str, FmuInstance],
                connections: list[Any], record: list[str],
                track: Any, model_exchange: Callable[..., FmuUnit] | None = None
                ) -> dict[str, Unit]:
    """Each component's unit (a table's: :class:`TableUnit`; one integrated as Model
    Exchange, its ``integration`` set: ``model_exchange(instance, index, outputs,
    inputs)``, :class:`~.model_exchange.ModelExchangeUnit`), its value buffers linked to
    its sources'; only outputs that are connected or recorded are read."""
    index = {cname: i for i, cname in enumerate(models)}
    connected: dict[str, list[Any]] = {}
    for conn in connections:
        connected.setdefault(conn.target[0], []).append(conn)
    needed_out: dict[str, set[str]] = {c: set() for c in models}
    for conn in connections:
        needed_out[conn.source[0]].add(conn.source[1])
    for name in record:
        cname, _, vname = name.partition(".")
        needed_out[cname].add(vname)
    units: dict[str, Unit] = {}
    for cname, info in models.items():
        if info.table is not None:
            units[cname] = TableUnit(cname, index[cname], info.table, track)
            continue
        outs = [v for v in info.outputs if v.name in needed_out[cname]]
        ins = [info.variables[c.target[1]] for c in connected.get(cname, [])]
        if getattr(info, "integration", None) is not None:
            if model_exchange is None:
                raise ValueError(f"component '{cname}' is to be integrated as Model "
                                 "Exchange, and no Model Exchange unit was given")
            units[cname] = model_exchange(instances[cname], index[cname], outs, ins)
            continue
        units[cname] = FmuUnit(instances[cname], index[cname], outs, ins)
    for cname, unit in units.items():
        for conn in connected.get(cname, []):
            unit_ = unit
            assert isinstance(unit_, FmuUnit)  # a table has no inputs (checked)
            unit_.link(conn.target[1], units[conn.source[0]], conn.source[1])
        unit.freeze()
    return units
