"""Fixed-step co-simulation master (Gauss-Seidel or Jacobi) over fmpy FMU2Slave/FMU3Slave.

FMI 2.0 and 3.0 co-simulation FMUs may be mixed. Values of every scalar type move in
batched calls: one get (set) per C getter (setter) per FMU and exchange, e.g. one
``fmi2GetReal`` and one ``fmi2GetInteger`` for an FMU with Real and Integer outputs
(types: :mod:`agv_cosim.fmitypes`). "Batched get/set" below means those calls.

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

from dataclasses import dataclass, field
from math import isfinite

from . import fmitypes
from .model import FmuInstance, element_names


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
    #: scenario events: [(step index k, time [s], name, [(component, variable, value)])],
    #: sorted by k; applied at t_k = start + k step, before that instant's exchange
    events: list = field(default_factory=list)


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


def _passed_as_is(value):
    """``value`` (a converted argument of :func:`_bare_call`) in the form ctypes passes
    with the least work, the same bits reaching the C function.

    ctypes wraps every ctypes instance it is given in a new argument object at every
    call; a ``byref`` object (an address) and a small Python int pass without one. An
    array passes as the address of its first element, a pointer or ``c_void_p`` as the
    address it holds (the object at that address keeps the referent alive), an unsigned
    or int count below 2**31 as a Python int (a C int, which the x86-64 and AArch64
    calling conventions extend to the register). Anything else (the shared time and step
    ``c_double``, whose value changes between calls) is passed unchanged.
    """
    import ctypes

    if isinstance(value, ctypes.Array):
        return ctypes.byref(value)
    if isinstance(value, (ctypes._Pointer, ctypes.c_void_p)):
        address = ctypes.cast(value, ctypes.c_void_p).value
        if not address:
            return value
        target = ctypes.c_char.from_address(address)
        target.keep = value  # the pointer (and what it keeps) lives as long as the call
        return ctypes.byref(target)
    if isinstance(value, (ctypes.c_int, ctypes.c_uint, ctypes.c_size_t)) and \
            0 <= value.value < 2 ** 31:
        return int(value.value)
    return value


def _bare_call(function, args):
    """``(function, args)`` for a call without ctypes' per-call argument conversion.

    A raw ctypes function with ``argtypes`` converts every argument at every call. The
    batched get/set calls always pass the same objects (component, value-reference
    array, count, value buffer), so they are converted once here: each argument becomes
    an instance of its declared type (arrays pass as the pointer they are), and the call
    goes through a pointer to the same C function that has no ``argtypes``. Anything
    else (fmpy's wrapper, an argument this cannot convert) is returned unchanged.
    """
    import ctypes

    argtypes = getattr(function, "argtypes", None)
    if not isinstance(function, ctypes._CFuncPtr) or not argtypes or \
            len(argtypes) != len(args):
        return function, args
    converted = []
    for argtype, value in zip(argtypes, args):
        if isinstance(value, argtype):
            converted.append(value)
        elif isinstance(value, ctypes.Array) and isinstance(argtype, type) and \
                issubclass(argtype, ctypes._Pointer) and value._type_ is argtype._type_:
            converted.append(value)
        elif isinstance(argtype, type) and issubclass(argtype, ctypes._SimpleCData) and \
                not isinstance(value, (ctypes._SimpleCData, ctypes.Array, ctypes._Pointer)):
            converted.append(argtype(value))
        else:
            return function, args
    converted = [_passed_as_is(value) for value in converted]
    # PYFUNCTYPE: the GIL stays held during the call (an FMU whose slave is Python takes
    # it again at once; releasing and re-taking it cost more than the call itself)
    bare = ctypes.PYFUNCTYPE(function.restype)(ctypes.cast(function, ctypes.c_void_p).value)
    bare.argtypes = None
    bare.restype = function.restype
    bare.keep = function  # the library stays referenced by the slave; this is its entry
    return bare, tuple(converted)


def _failed(function, status):
    """The exception fmpy's wrapper raises for a status above ``fmi2Warning``."""
    from fmpy.fmi1 import FMICallException

    return FMICallException(function=function, status=status)


class _Unit:
    """One FMU with its preallocated value-reference and value buffers.

    Variables are grouped by C getter/setter (:mod:`agv_cosim.fmitypes`): one batched
    call per group, i.e. per type, per FMU and exchange. A group is ``(function, args,
    buffer, ...)`` with ``args`` the prebuilt argument tuple (FMI 3.0 getters and setters
    take the value count twice).
    """

    def __init__(self, instance, outputs, inputs):
        from ctypes import byref, c_bool, c_double, c_int

        self.inst = instance
        self.name = instance.name
        self.slave = self.inst.slave
        self.component = self.slave.component
        self.fmi3 = instance.info.fmi_version == "3.0"
        vr_type = _vr_type(self.fmi3)
        self.do_step = _raw_function(self.slave, "fmi3DoStep" if self.fmi3 else "fmi2DoStep")
        self.step_extra = None
        if self.fmi3:
            # fmi3DoStep's out-arguments: eventHandlingNeeded, terminateSimulation,
            # earlyReturn, lastSuccessfulTime
            self.flags = (c_bool(), c_bool(), c_bool(), c_double())
            self.step_extra = tuple(byref(flag) for flag in self.flags)
        self._byref, self._c_int, self._c_double = byref, c_int, c_double
        self.out_names = [v.name for v in outputs]
        self.out_types = [v.ftype for v in outputs]
        self.n_out = len(outputs)
        self.address = {}  # output name -> (buffer, position)
        self.out_groups = []
        arrays = instance.info.variables
        for fname, variables in _grouped(outputs, "get"):
            ftype = variables[0].ftype
            # an array element is read with its whole array (FMI 3.0: one value
            # reference, all its values in row-major order)
            whole, offset = {}, 0
            for v in variables:
                base = arrays[v.element[0]] if v.element else v
                if base.name not in whole:
                    whole[base.name] = (base, offset)
                    offset += base.size
            vrs = (vr_type * len(whole))(*[b.vr for b, _ in whole.values()])
            buf = (ftype.ctype * offset)()
            args = (self.component, vrs, len(whole), buf) + ((offset,) if self.fmi3 else ())
            names = []  # per buffer position (for error messages)
            for base, _ in whole.values():
                names += element_names(base.name, base.shape) if base.dims else [base.name]
            for v in variables:
                at = whole[v.element[0]][1] + v.element[1] if v.element else whole[v.name][1]
                self.address[v.name] = (buf, at)
            self.out_groups.append((*_bare_call(_raw_function(self.slave, fname), args), buf,
                                    ftype.is_float, fname, names))
        self.in_names = [v.name for v in inputs]
        self.n_in = len(inputs)
        self.in_address = {}
        self.in_groups = []
        for fname, variables in _grouped(inputs, "set"):
            ftype = variables[0].ftype
            vrs = (vr_type * len(variables))(*[v.vr for v in variables])
            buf = (ftype.ctype * len(variables))()
            args = (self.component, vrs, len(variables), buf) + \
                ((len(variables),) if self.fmi3 else ())
            for pos, v in enumerate(variables):
                self.in_address[v.name] = (len(self.in_groups), pos)
            self.in_groups.append([*_bare_call(_raw_function(self.slave, fname), args), buf, [],
                                   fname])
        self.sources = []  # (input name, source unit, source output name)
        # legacy single-buffer view for callers that read all-Real outputs
        first = self.out_groups[0][2] if self.out_groups else None
        self.out_val = first

    def link(self, input_name, source, output_name):
        group, pos = self.in_address[input_name]
        buf, src_pos = source.address[output_name]
        self.in_groups[group][3].append((pos, buf, src_pos))
        self.sources.append((input_name, source, output_name))

    def freeze(self):
        """Make the groups immutable tuples (after every :meth:`link`)."""
        self.in_groups = tuple((fn, args, buf, tuple(links), fname)
                               for fn, args, buf, links, fname in self.in_groups)
        self.out_groups = tuple(self.out_groups)

    def get(self):
        for fn, args, buf, _, fname, _ in self.out_groups:
            status = fn(*args)
            if status > 1:
                raise _failed(fname, status)

    def set(self):
        for fn, args, in_val, links, fname in self.in_groups:
            for j, src, pos in links:
                in_val[j] = src[pos]
            status = fn(*args)
            if status > 1:
                raise _failed(fname, status)

    def finite(self):
        for _, _, buf, is_float, _, _ in self.out_groups:
            if is_float and not isfinite(sum(buf)):
                return False
        return True

    def stop_requested(self):
        """After a doStep: (True, last successful time) when the FMU asks to end the run.

        FMI 2.0: ``fmi2Discard`` with ``fmi2GetBooleanStatus(fmi2Terminated)`` true (and
        ``fmi2LastSuccessfulTime``); FMI 3.0: ``terminateSimulation`` (and
        ``lastSuccessfulTime``) of ``fmi3DoStep``.
        """
        if self.fmi3:
            return bool(self.flags[1].value), float(self.flags[3].value)
        from fmpy.fmi2 import fmi2LastSuccessfulTime, fmi2Terminated

        flag, when = self._c_int(0), self._c_double(float("nan"))
        try:
            status = self.slave.fmi2GetBooleanStatus(self.component, fmi2Terminated,
                                                     self._byref(flag))
        except Exception:  # noqa: BLE001 - an FMU that does not answer: not a request
            return False, None
        if status > 1 or not flag.value:
            return False, None
        try:
            self.slave.fmi2GetRealStatus(self.component, fmi2LastSuccessfulTime,
                                         self._byref(when))
        except Exception:  # noqa: BLE001 - the time is then unknown
            pass
        return True, float(when.value)


class _TableUnit:
    """A time table (:mod:`agv_cosim.table`) in the place of an FMU: outputs only.

    Its one output group is a Python function that writes every column's value at the
    current communication point (``track[2]``) into a float buffer; it has no inputs and
    is not stepped.
    """

    fmi3 = False
    step_extra = None
    in_groups = ()

    def __init__(self, name, table, track):
        from ctypes import c_double

        self.name = name
        self.component = None
        self.sources = []
        names = list(table.names)
        self.out_names = names
        buf = (c_double * len(names))()
        self.address = {n: (buf, i) for i, n in enumerate(names)}

        def fill():
            table.values_at(track[2], buf)
            return 0

        self.out_groups = ((fill, (), buf, True, "table", names),)

    def freeze(self):
        pass

    def get(self):
        self.out_groups[0][0]()

    def set(self):
        pass

    def finite(self):
        return True


def _vr_type(fmi3):
    if fmi3:
        from fmpy.fmi3 import fmi3ValueReference
        return fmi3ValueReference
    from fmpy.fmi2 import fmi2ValueReference
    return fmi2ValueReference


def _grouped(variables, what):
    """``[(C function name, [variables])]`` in first-seen order."""
    groups = {}
    for v in variables:
        groups.setdefault(getattr(v.ftype, what), []).append(v)
    return list(groups.items())


def _set_parameter(slave, var, value):
    fmitypes.set_parameter(slave, var.ftype, var.vr, value)


def record_types(plan):
    """The :class:`~agv_cosim.fmitypes.FmiType` of each ``plan.record`` column."""
    found = []
    for name in plan.record:
        cname, _, vname = name.partition(".")
        found.append(plan.models[cname].variables[vname].ftype)
    return found


#: FMI 2.0 / 3.0 status codes above OK (the same numbers in both versions)
_STATUS_NAMES = {1: "Warning", 2: "Discard", 3: "Error", 4: "Fatal", 5: "Pending"}

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


def _instantiate(plan, instances, index, track, on_message):
    """Phase 1: instantiate the FMUs (into ``instances``, so the caller can close them
    whatever happens) and build each one's :class:`_Unit` (tables: :class:`_TableUnit`)
    with its value buffers linked to its sources.

    Returns (units by name, names of the table components, record map: (row position,
    buffer, position in it) per recorded signal).
    """
    units = {}
    tables = {c for c, info in plan.models.items() if info.table is not None}
    for cname in plan.models:
        track[0] = index[cname]
        if cname not in tables:
            instances[cname] = FmuInstance(plan.models[cname], cname, on_message)
    connected = {}
    for conn in plan.connections:
        connected.setdefault(conn.target[0], []).append(conn)
    needed_out = {c: set() for c in plan.models}
    for conn in plan.connections:
        needed_out[conn.source[0]].add(conn.source[1])
    for name in plan.record:
        cname, _, vname = name.partition(".")
        needed_out[cname].add(vname)
    for cname, info in plan.models.items():
        outs = [v for v in info.outputs if v.name in needed_out[cname]]
        ins = [info.variables[c.target[1]] for c in connected.get(cname, [])]
        units[cname] = (_TableUnit(cname, info.table, track) if cname in tables else
                        _Unit(instances[cname], outs, ins))
        units[cname].index = index[cname]
    for cname, unit in units.items():
        for conn in connected.get(cname, []):
            unit.link(conn.target[1], units[conn.source[0]], conn.source[1])
        unit.freeze()
    record_from = []
    for i, name in enumerate(plan.record, start=1):
        cname, _, vname = name.partition(".")  # component names have no dot
        record_from.append((i, *units[cname].address[vname]))
    return units, tables, record_from


def _initialise(plan, instances, units, all_units, index, track):
    """Phase 2: set up the experiment, set the parameters, enter and exit initialisation
    mode (with Jacobi, libcosim's exchanges while in initialisation mode)."""
    track[1] = _INITIALISATION
    for cname in instances:
        track[0] = index[cname]
        slave = instances[cname].slave
        info = plan.models[cname]
        if units[cname].fmi3:
            for pname, value in plan.parameters.get(cname, {}).items():
                _set_parameter(slave, info.variables[pname], value)
            slave.enterInitializationMode(startTime=plan.start, stopTime=plan.stop)
        else:
            slave.setupExperiment(startTime=plan.start, stopTime=plan.stop)
            for pname, value in plan.parameters.get(cname, {}).items():
                _set_parameter(slave, info.variables[pname], value)
            slave.enterInitializationMode()
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
    for cname in instances:
        track[0] = index[cname]
        instances[cname].slave.exitInitializationMode()


def _check_finite(unit, t):
    """Raise naming the first non-finite float output of ``unit`` at ``t`` [s]."""
    # Callers may skip this when every float buffer's sum is finite: a sum is
    # finite only if every term is (NaN and inf propagate); an overflowed sum
    # lands here.
    for _, _, buf, is_float, _, names in unit.out_groups:
        if not is_float:
            continue
        for pos, value in enumerate(buf):
            if not isfinite(value):
                raise SimulationError(f"component '{unit.name}': output "
                                      f"'{names[pos]}' is {float(value)!r} at "
                                      f"t={t!r} s")


class _Code:
    """Source text of a generated function and the objects it uses (its closure).

    The per-step functions (:func:`_gauss_seidel_pass`, :func:`_step_all`) are written
    out for the run's FMUs, one line per call, instead of loops over tuples of groups:
    every function, argument and buffer is a closure variable of the generated function
    (a fast local load), so a step pays little more than the FMI calls themselves. Only
    made-up identifiers (``f0``, ``a1``, ``b2``) and integers go into the source text;
    component, variable and function names stay data in the closure.
    """

    INDENT = "        "

    def __init__(self, **fixed):
        self.lines = []
        self.bound = dict(fixed)

    def bind(self, value, prefix="v"):
        """A fresh identifier for ``value``."""
        name = f"{prefix}{len(self.bound)}"
        self.bound[name] = value
        return name

    def line(self, text):
        self.lines.append(self.INDENT + text)

    def call(self, fn, args, what):
        """``s = fn(arg, ...)`` with each argument bound once, then the status check
        (above Warning: the exception fmpy's wrapper raises, naming ``what``)."""
        names = [self.bind(a, "a") for a in args]
        self.line(f"s = {self.bind(fn, 'f')}({', '.join(names)})")
        self.line(f"if s > 1: raise failed({self.bind(what, 'n')}, s)")

    def get(self, unit, group, check_finite):
        """One batched get of output ``group`` of ``unit`` and, with ``check_finite``,
        the finite check of a float buffer (a sum of its values first: a sum is finite
        only if every term is; an overflowed sum lands in the full check, which then
        finds nothing)."""
        fn, args, buf, is_float, fname, _ = group
        self.call(fn, args, fname)
        if check_finite and is_float and len(buf):
            b = self.bind(buf, "b")
            total = " + ".join(f"{b}[{i}]" for i in range(len(buf)))
            self.line(f"if not isfinite({total}): check({self.bind(unit, 'u')}, t)")

    def function(self, name, params):
        """The function ``name(params)`` whose body is the lines added so far."""
        closure = ", ".join(self.bound)
        body = "\n".join(self.lines) or self.INDENT + "pass"
        source = (f"def _make({closure}):\n    def {name}({params}):\n{body}\n"
                  f"    return {name}\n")
        namespace = {}
        exec(compile(source, f"<agv_cosim.master {name}>", "exec"), namespace)  # noqa: S102
        return namespace["_make"](**self.bound)


def _shared_values(in_val, links):
    """A pointer into the source buffer whose consecutive values are exactly those of
    input buffer ``in_val`` (every value linked, in order, from one source buffer), or
    None. A set then passes that pointer instead of copying the values first: the same
    doubles reach the FMU."""
    from ctypes import POINTER, byref, cast, sizeof

    if not links or len(links) != len(in_val):
        return None
    links = sorted(links, key=lambda link: link[0])
    src, first = links[0][1], links[0][2]
    if any(s is not src or j != k or pos != first + k for k, (j, s, pos) in enumerate(links)):
        return None
    ctype = in_val._type_
    if src._type_ is not ctype or first + len(in_val) > len(src):
        return None
    pointer = cast(byref(src, first * sizeof(ctype)), POINTER(ctype))
    pointer.keep = src  # the source buffer lives as long as the pointer
    return pointer


def _gauss_seidel_pass(plan, units, all_units, track):
    """The Gauss-Seidel pass at one communication point, generated for this run.

    Returns ``(gs_pass, pass_plan)``: ``gs_pass(t)`` runs the pass at ``t`` [s];
    ``pass_plan(stopped)`` is a pass function without sets to the units named in
    ``stopped``.
    """
    # Units whose outputs feed a unit visited before them (or themselves): their
    # outputs are read first, so that unit sees the value of this instant and not the
    # one read in the previous pass. Such an output cannot depend directly on an input
    # (the order puts every feedthrough source first), so reading it early is exact.
    position = {name: i for i, name in enumerate(plan.order)}
    backward = {src.name for unit in all_units for _, src, _ in unit.sources
                if position[src.name] >= position[unit.name]}
    pre_read = [units[name] for name in plan.order if name in backward]
    # A pre-read unit none of whose read outputs depends directly on an input shows the
    # same values after its sets (FMI: only a step changes them): it is read once, at
    # the start, and its values are checked there.
    read_once = {u.name for u in pre_read
                 if not any(plan.models[u.name].dependencies.get(o) for o in u.out_names)}

    def pass_plan(stopped=()):
        # The pass, unrolled: per unit the track store, each input group's copies from
        # its sources' buffers and its set, each output group's get and finite check;
        # a unit that asked to stop gets no more sets.
        code = _Code(track=track, failed=_failed, isfinite=isfinite, check=_check_finite)
        for unit in pre_read:
            code.line(f"track[0] = {int(unit.index)}")
            for group in unit.out_groups:
                code.get(unit, group, unit.name in read_once)
        for unit in (units[c] for c in plan.order):
            in_groups = () if unit.name in stopped else unit.in_groups
            out_groups = () if unit.name in read_once else unit.out_groups
            if not (in_groups or out_groups):
                continue
            code.line(f"track[0] = {int(unit.index)}")
            for fn, args, in_val, links, fname in in_groups:
                shared = _shared_values(in_val, links)
                if shared is not None:  # the source's buffer is the values argument
                    code.call(fn, args[:3] + (shared,) + args[4:], fname)
                    continue
                target = code.bind(in_val, "b")
                for j, src, pos in links:
                    code.line(f"{target}[{int(j)}] = {code.bind(src, 'b')}[{int(pos)}]")
                code.call(fn, args, fname)
            for group in out_groups:
                code.get(unit, group, True)
        return code.function("gs_pass", "t")

    return pass_plan(), pass_plan


def _fmi2_stepped(unit, status, stops):
    """After an ``fmi2DoStep`` status above Warning: a stop request (Discard with
    ``fmi2Terminated``) goes to ``stops``, anything else raises."""
    asked, when = unit.stop_requested() if status == 2 else (False, 0)
    if not asked:
        raise _failed("fmi2DoStep", status)
    stops.append((unit.name, when))


def _fmi3_stepped(unit, status, stops):
    """After an ``fmi3DoStep`` with a status above Warning or ``terminateSimulation``: a
    stop request goes to ``stops``; an Error (or a Discard without it) raises."""
    if status > 2:
        raise _failed("fmi3DoStep", status)
    if unit.flags[1].value:
        stops.append((unit.name, unit.stop_requested()[1]))
    elif status == 2:
        raise _failed("fmi3DoStep", status)


def _step_all(step_units, h, track, stops):
    """``step_all(t)``: every FMU of ``step_units`` steps from ``t`` to ``t + h`` [s] in
    turn (generated, one call a line; see :class:`_Code`); FMUs that ask to end the run
    are appended to ``stops`` as (name, last successful time)."""
    from ctypes import c_double

    # FMI 2.0: the time and step size pass as two C doubles shared by every doStep of the
    # macro step (the time's value stored once a step), the component and the flag
    # converted once (_bare_call): no per-call argument conversion
    t_c, h_c = c_double(0.0), c_double(h)
    code = _Code(track=track, h=h, stops=stops, t_c=t_c, h_c=h_c)
    code.line("track[2] = t")
    code.line(f"track[1] = {_DO_STEP}")
    code.line("t_c.value = t")
    for unit in step_units:
        d, c, u = code.bind(unit.do_step, "f"), code.bind(unit.component, "a"), \
            code.bind(unit, "u")
        code.line(f"track[0] = {int(unit.index)}")
        if unit.step_extra is None:
            bare, args = _bare_call(unit.do_step, (unit.component, t_c, h_c, 1))
            if bare is not unit.do_step:
                names = [code.bind(a, "a") for a in args]
                code.line(f"s = {code.bind(bare, 'f')}({', '.join(names)})")
            else:
                code.line(f"s = {d}({c}, t, h, 1)")
            code.line(f"if s > 1: {code.bind(_fmi2_stepped, 'g')}({u}, s, stops)")
        else:
            extra = ", ".join(code.bind(e, "a") for e in unit.step_extra)
            code.line(f"s = {d}({c}, t, h, True, {extra})")
            code.line(f"if s > 1 or {code.bind(unit.flags[1], 'a')}.value: "
                      f"{code.bind(_fmi3_stepped, 'g')}({u}, s, stops)")
    return code.function("step_all", "t")


def simulate(plan, write_row, progress=None, track=None, on_message=None, outcome=None):
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
    outcome : dict, optional
        Filled with ``ended_by`` (``"<component> requested stop at t=<t> s"``) and
        ``stop_time`` when an FMU asked to end the run (FMI 2.0 ``fmi2Discard`` with
        ``fmi2Terminated``, FMI 3.0 ``terminateSimulation``): every FMU finishes that
        macro step, the row of its end is recorded (if the FMU reached it; the FMU that
        stopped gets no more inputs) and the run ends normally. A Discard without the
        termination flag stays an error.

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
        # phase 1: instantiate every FMU, wire the preallocated buffers
        units, tables, record_from = _instantiate(plan, instances, index, track, on_message)

        # phase 2: parameters, initialisation mode (Jacobi: libcosim's exchanges)
        all_units = list(units.values())
        _initialise(plan, instances, units, all_units, index, track)

        # phase 3: the stepping loop (the Gauss-Seidel pass and the recorder below)
        n_steps = int(round((plan.stop - plan.start) / plan.step))
        h = plan.step
        row = [0.0] * (1 + len(record_from))

        check = _check_finite
        gs_pass, pass_plan = _gauss_seidel_pass(plan, units, all_units, track)

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

        def jacobi_get(t):
            for unit in all_units:
                track[0] = unit.index
                unit.get()
                if not unit.finite():
                    check(unit, t)

        # scenario events by step index: the values are set (fmpy's setters, one call
        # per variable) after the FMUs stepped to t_k and before t_k's exchange, so the
        # row of t_k already shows their effect on feedthrough outputs
        pending = [(k, [(instances[c].slave, plan.models[c].variables[v], value)
                        for c, v, value in sets]) for k, _, _, sets in plan.events]
        pending.reverse()
        next_event = pending[-1][0] if pending else -1

        def apply_events(k):
            nonlocal next_event
            while pending and pending[-1][0] == k:
                for slave, var, value in pending.pop()[1]:
                    _set_parameter(slave, var, value)
            next_event = pending[-1][0] if pending else -1

        track[1] = _PROPAGATION
        jacobi = plan.algorithm == "jacobi"
        if next_event == 0:
            apply_events(0)
        if jacobi:
            jacobi_get(plan.start)
            record(plan.start)
            for unit in all_units:
                track[0] = unit.index
                unit.set()
        else:
            gs_pass(plan.start)
            record(plan.start)
        every = plan.record_every
        done = 0
        stops = []  # (component, last successful time) of FMUs that asked to end the run
        step_all = _step_all([u for u in all_units if u.name not in tables], h, track, stops)
        for k in range(n_steps):
            t = plan.start + k * h
            step_all(t)
            t_next = plan.start + (k + 1) * h
            track[2] = t_next
            if k + 1 == next_event and not stops:
                apply_events(k + 1)
            if stops:
                track[1] = _GET if jacobi else _GS_PASS
                name, when = stops[0]
                outcome_ = outcome if outcome is not None else {}
                outcome_["ended_by"] = f"{name} requested stop at t={when!r} s"
                outcome_["stop_time"] = when
                # the last row: only when the FMU reached the communication point
                if when is not None and abs(when - t_next) <= 1e-9 * max(1.0, abs(t_next)):
                    if jacobi:
                        jacobi_get(t_next)
                    else:
                        pass_plan({n for n, _ in stops})(t_next)
                    record(t_next)
                break
            if jacobi:
                track[1] = _GET
                jacobi_get(t_next)
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
        status = _STATUS_NAMES.get(int(error.status), "")
        if status == "Discard" and error.function.endswith("DoStep"):
            status += ", no stop requested"
        raise SimulationError(f"component '{name}': {error.function} returned status "
                              f"{error.status}{f' ({status})' if status else ''} during "
                              f"{PHASES[int(track[1])]} at "
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
