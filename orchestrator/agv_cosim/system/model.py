"""What an FMU declares: its model description read (FMI 2.0 and 3.0, co-simulation
and Model Exchange).

:func:`read_model` checks the FMU archive (every entry's CRC) and maps fmpy's
``read_model_description`` (XML schema on; no extraction) onto a :class:`ModelInfo`; fmpy's
errors become one line naming the FMU. Own reading left (fmpy 0.3.32): only the root's
``fmiVersion`` before fmpy, so an FMI 1.0 FMU is named as such; fmpy's checks made after
parsing (undefined unit, input without start ..) are not errors, as before; FMI 3.0
``<Alias>`` variables fmpy adds are left out. :class:`ModelInfo` holds variables with
value reference, type (see
:mod:`agv_cosim.fmitypes`), causality, unit and description, and each output's direct
dependencies. An output whose ``<Unknown>`` (FMI 2.0) or ``<Output>`` (FMI 3.0) carries no
``dependencies`` attribute depends, per the standard, on every input. An FMU's
``<ModelExchange>`` is read into :class:`ModelExchangeInfo`; a model-exchange-only FMU
gets an :class:`Integration` (the orchestrator integrates it with a solver:
:mod:`agv_cosim.execution.model_exchange`), and its ``identifier`` is the Model
Exchange one.

The master steps with a fixed communication step and never saves or restores FMU state,
so ``canHandleVariableCommunicationStepSize="false"`` and ``canGetAndSetFMUstate="false"``
need nothing from it (both flags are read into :class:`ModelInfo` for the record).

Instantiating an FMU is :mod:`agv_cosim.execution.instance`.
"""

import hashlib
import itertools
import math
import re
import zipfile
import zlib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from .. import fmitypes
from ..archive import FMU_LIMITS, ArchiveRefused, open_bounded
from ..errors import ModelError
from ..files import XML_LIMIT, open_regular
from ..fmitypes import FmiType


@dataclass(frozen=True)
class Variable:
    """One scalar variable of a model description."""

    name: str
    vr: int
    type: str
    causality: str
    variability: str
    unit: str | None
    description: str
    start: str | None
    fmi: str = "2.0"     # FMI version of the FMU (selects the fmitypes table)
    dims: tuple[str, ...] = ()  # FMI 3.0 array dimensions as written (empty: a scalar)
    #: the dimensions as integers (None: a dimension is unknown)
    shape: tuple[int, ...] | None = None
    #: of an array element "y[2]": (array name, flat index)
    element: tuple[str, int] | None = None
    min: str | None = None   # as written (the variable's, else its declared type's)
    max: str | None = None

    @property
    def ftype(self) -> FmiType:
        """Its :class:`~agv_cosim.fmitypes.FmiType`. A Binary or Clock variable has
        none: :meth:`unsupported` names it, and the system check refuses it before
        this is used."""
        ftype = fmitypes.of(self)
        if ftype is None:
            raise ValueError(f"variable {self.name!r} is of type {self.type}, not supported")
        return ftype

    @property
    def size(self) -> int | None:
        """Number of values (1 for a scalar or an element; None if unknown)."""
        if not self.dims:
            return 1
        return math.prod(self.shape) if self.shape is not None else None

    def unsupported(self, use: str = "connect") -> str:
        """Why this variable cannot be used for ``use`` ('' if it can).

        ``use`` is "connect" (connection, SSP connector, event), "record" or "parameter".
        A whole array with known dimensions may be set as a parameter (a flat list in
        row-major order); its elements ``name[i]`` / ``name[i,j]`` may be recorded.
        """
        if fmitypes.of(self) is None:
            return f"of type {self.type} (not supported)"
        if self.dims:
            if self.shape is None:
                return "an array variable whose dimensions are not known (not supported)"
            if use == "parameter":
                return ""
            if use == "record" and self.causality == "output":
                return (f"an array variable (record its elements, "
                        f"'{element_names(self.name, self.shape)[0]}' ..)")
            return "an array variable (arrays can be set as parameters and their " \
                   "output elements recorded, not connected)"
        if self.element is not None and use != "record":
            return "an array element (only recorded; set the whole array as a parameter)"
        return ""


def element_names(name: str, shape: tuple[int, ...]) -> list[str]:
    """Element names of an array in row-major (FMI 3.0 serialisation) order, 1-based:
    ``y[1]``, ``y[2]`` for a vector, ``A[1,1]``, ``A[1,2]`` .. for a matrix."""
    return [f"{name}[{','.join(str(i + 1) for i in index)}]"
            for index in itertools.product(*(range(n) for n in shape))]


@dataclass(frozen=True)
class ModelExchangeInfo:
    """What an FMU's ``<ModelExchange>`` element declares."""

    identifier: str
    #: ``numberOfContinuousStates`` (FMI 2.0) or the count of continuous-state
    #: derivatives (FMI 3.0, fmpy's; an array state counts its elements)
    states: int = 0
    event_indicators: int = 0
    needs_completed_integrator_step: bool = False
    needs_execution_tool: bool = False


@dataclass(frozen=True)
class Integration:
    """How a Model Exchange FMU is integrated between communication points: the solver
    ("cvode": SUNDIALS CVODE through fmpy.sundials; "scipy": scipy.integrate.solve_ivp)
    and its relative tolerance (absolute: tolerance x each state's nominal)."""

    solver: str = "cvode"
    tolerance: float = 1e-6


@dataclass
class ModelInfo:
    """What the orchestrator needs from one FMU's model description.

    ``dependencies`` maps each output name to the input names it depends on directly.
    """

    path: Path
    sha256: str
    model_name: str
    identifier: str
    guid: str
    description: str
    variables: dict[str, Variable] = field(default_factory=dict)
    dependencies: dict[str, list[str]] = field(default_factory=dict)
    fmi_version: str = "2.0"
    can_handle_variable_step: bool = True
    can_get_set_state: bool = False
    #: a time table (:class:`agv_cosim.system.table.Table`) instead of an FMU
    table: Any = None
    #: the FMI interfaces the FMU declares: "co-simulation", "model-exchange"
    interfaces: tuple[str, ...] = ("co-simulation",)
    #: what its <ModelExchange> declares (None: no Model Exchange interface)
    model_exchange: "ModelExchangeInfo | None" = None
    #: how the orchestrator integrates it as a Model Exchange FMU (None: it is run
    #: through its co-simulation interface); see
    #: :func:`agv_cosim.execution.model_exchange.use_model_exchange`
    integration: "Integration | None" = None

    def of_causality(self, causality: str) -> list[Variable]:
        """Variables with the given causality, in model-description order."""
        return [v for v in self.variables.values() if v.causality == causality]

    @property
    def inputs(self) -> list[Variable]:
        return self.of_causality("input")

    @property
    def outputs(self) -> list[Variable]:
        return self.of_causality("output")

    @property
    def parameters(self) -> list[Variable]:
        return self.of_causality("parameter")


_CACHE: dict[tuple[str, int, int], ModelInfo] = {}


def file_sha256(path: str | Path) -> str:
    """SHA-256 (hex) of a file's bytes, read in blocks of 1 MiB (memory bounded
    whatever its size); a file that is not a regular file (a FIFO, a device) is refused
    before any read (:func:`agv_cosim.files.open_regular`)."""
    digest = hashlib.sha256()
    with open_regular(path) as stream:
        for chunk in iter(lambda: stream.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def read_model(path: str | Path) -> ModelInfo:
    """Read the model description of the FMU at ``path`` (cached by path, size, mtime).

    Raises
    ------
    ModelError
        If the file is missing, not a zip archive, or has no valid FMI 2.0
        co-simulation model description.
    """
    path = Path(path).resolve()
    try:
        stat = path.stat()
    except OSError:
        raise ModelError(f"FMU not found: '{path}'") from None
    if not path.is_file():
        raise ModelError(f"not a file: '{path}'")
    key = (str(path), stat.st_size, stat.st_mtime_ns)
    if key in _CACHE:
        return _CACHE[key]
    try:
        with open(path, "rb") as stream, open_bounded(stream, path, FMU_LIMITS) as archive:
            if archive.getinfo("modelDescription.xml").file_size > XML_LIMIT:
                raise ArchiveRefused(path, f"refused: modelDescription.xml is more than "
                                     f"{XML_LIMIT} bytes")
            # every entry's CRC now, so a corrupt binary is named here, not mid-run
            bad = archive.testzip()
    except KeyError:
        raise ModelError(f"broken FMU (no modelDescription.xml): '{path}'") from None
    except ArchiveRefused as refused:
        raise ModelError(f"FMU '{path}': {refused.reason}") from None
    except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError) as error:
        reason = "not a zip archive" if "File is not a zip" in str(error) else \
            f"corrupt zip archive: {error}"
        raise ModelError(f"broken FMU ({reason}): '{path}'") from None
    except OSError as error:
        raise ModelError(f"cannot read FMU '{path}': {error.strerror or error}") from None
    if bad is not None:
        raise ModelError(f"broken FMU (entry '{bad}' is corrupt): '{path}'")
    info = _CACHE[key] = _parse_model(path)
    return info


#: A modelIdentifier: a C identifier (FMI 2.0 and 3.0), never a path.
IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")

#: How fmpy 0.3.32 words an XML-schema problem (lxml's error log); its later checks differ.
_SCHEMA_PROBLEM = re.compile(r"[A-Z]+ \(line \d+, column \d+\): ")


def _parse_model(path: Path) -> ModelInfo:
    """Map fmpy's ModelDescription (``fmpy.read_model_description``, schema and fmpy's
    own checks on) onto a :class:`ModelInfo`; fmpy's errors become one line."""
    md = _read_description(path)
    version = md.fmiVersion or ""
    version = "3.0" if version.startswith("3.") else version
    if version not in ("2.0", "3.0"):
        raise ModelError(f"not an FMI 2.0 or 3.0 FMU (fmiVersion={md.fmiVersion!r}): "
                         f"'{path}'")
    cosim, me, identifier = _interfaces(md, path)
    interfaces = tuple(kind for kind, there in (("co-simulation", cosim is not None),
                                                ("model-exchange", me is not None)) if there)
    info = ModelInfo(path=path, sha256=file_sha256(path), model_name=md.modelName or "",
                     identifier=identifier, guid=md.guid or "",
                     description=md.description or "", fmi_version=version,
                     can_handle_variable_step=bool(
                         cosim.canHandleVariableCommunicationStepSize) if cosim else True,
                     can_get_set_state=bool(cosim.canGetAndSetFMUstate) if cosim else False,
                     interfaces=interfaces, model_exchange=me,
                     integration=Integration() if cosim is None else None)
    # fmpy appends FMI 3.0 <Alias> entries as extra variables: agv-cosim does not list them
    own = [sv for sv in md.modelVariables if getattr(sv, "alias", None) is None]
    ordered = [_variable(sv, version) for sv in own]
    _add_variables(info, ordered)
    _add_dependencies(info, md, ordered)
    if cosim is None:
        problem = model_exchange_refusal(info)
        if problem:
            raise ModelError(f"a model-exchange-only FMU the orchestrator cannot "
                             f"integrate: it {problem}: '{path}'")
    return info


def _broken(path: Path, reason: object) -> ModelError:
    """The error of an FMU whose model description is broken, ``reason`` on one line."""
    reason = " ".join(str(reason).split())
    return ModelError(f"broken FMU (modelDescription.xml: {reason}): '{path}'")


def _read_description(path: Path) -> Any:
    """fmpy's ModelDescription of the FMU at ``path`` (schema checked; fmpy's checks
    made after parsing accepted); an FMI version other than 2.0/3.x and fmpy's errors
    as one line."""
    from fmpy.model_description import ValidationError, read_model_description
    from lxml.etree import XMLSyntaxError

    version = _fmi_version(path)
    if version is not None and version != "2.0" and not version.startswith("3."):
        raise ModelError(f"not an FMI 2.0 or 3.0 FMU (fmiVersion={version!r}): '{path}'")
    try:
        try:
            return read_model_description(str(path), validate=True)
        except ValidationError as error:
            if any(_SCHEMA_PROBLEM.match(p) for p in error.problems):
                raise
            # only fmpy's checks after parsing (a unit missing from UnitDefinitions, an
            # input without start ..): accepted, as before fmpy read the description
            return read_model_description(str(path), validate=False)
    except ValidationError as error:
        raise _broken(path, _first_problem(error.problems)) from None
    except XMLSyntaxError as error:
        raise _broken(path, error) from None
    except (IndexError, KeyError) as error:  # fmpy resolving an index / reference
        raise _broken(path, f"an index or value reference in ModelStructure or Dimension "
                      f"names no variable ({type(error).__name__}: {error})") from None
    except Exception as error:  # noqa: BLE001 - fmpy raises plain Exception too
        text = str(error)
        if text.startswith("Unsupported FMI version"):
            raise ModelError(f"not an FMI 2.0 or 3.0 FMU ({text}): '{path}'") from None
        raise _broken(path, text or type(error).__name__) from None


def _first_problem(problems: list[str]) -> str:
    """The first of fmpy's validation ``problems`` (lxml's location shortened to the
    line), and how many more there are."""
    first = problems[0] if problems else "failed to validate"
    # lxml's schema problems read "ERROR (line 15, column 0): Element ..: ..."
    first = re.sub(r"^ERROR \(line (\d+), column \d+\): ", r"line \1: ", first)
    first = first.rstrip(".")
    more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
    return first + more


def _interfaces(md: Any, path: Path) -> tuple[Any, ModelExchangeInfo | None, str]:
    """The FMU's ``<CoSimulation>`` (None: a model-exchange-only FMU, integrated by the
    orchestrator), its Model Exchange interface and its identifier (checked: a C
    identifier)."""
    cosim = md.coSimulation
    me = _model_exchange(md)
    if cosim is None or not cosim.modelIdentifier:
        if me is None:
            raise ModelError(f"neither a co-simulation nor a Model Exchange FMU: '{path}'")
        cosim = None  # a model-exchange-only FMU: integrated by the orchestrator
    identifier = cosim.modelIdentifier if cosim is not None else me.identifier  # type: ignore[union-attr]
    for name in {identifier, me.identifier if me is not None else identifier}:
        if not IDENTIFIER.fullmatch(name):
            raise ModelError(f"broken FMU (modelIdentifier {name!r} is not a "
                             "name: FMI wants a C identifier, which also names the FMU's "
                             f"binary inside it): '{path}'")
    return cosim, me, identifier


def _add_variables(info: ModelInfo, ordered: list[Variable]) -> None:
    """``ordered`` into ``info.variables``; each element of an output array also as its
    own variable (recordable as its own column)."""
    for variable in ordered:
        info.variables[variable.name] = variable
        if variable.causality == "output" and variable.shape:
            starts = (variable.start or "").split()
            for i, ename in enumerate(element_names(variable.name, variable.shape)):
                info.variables.setdefault(ename, replace(
                    variable, name=ename, dims=(), shape=None, element=(variable.name, i),
                    start=starts[i] if len(starts) == variable.size else None))


def _add_dependencies(info: ModelInfo, md: Any, ordered: list[Variable]) -> None:
    """Each output's direct dependencies (inputs) into ``info.dependencies``: those its
    ``<Unknown>``/``<Output>`` lists, every input without the attribute or the entry."""
    input_names = [v.name for v in ordered if v.causality == "input"]
    for unknown in md.outputs:
        name = unknown.variable.name
        if unknown.dependencies is None:  # no attribute: depends on every input
            info.dependencies[name] = list(input_names)
        else:
            info.dependencies[name] = [d.name for d in unknown.dependencies
                                       if d.name in input_names]
    for variable in ordered:
        if variable.causality == "output" and variable.name not in info.dependencies:
            info.dependencies[variable.name] = list(input_names)


def model_exchange_refusal(info: ModelInfo) -> str:
    """Why the orchestrator cannot integrate the FMU ``info`` through its Model Exchange
    interface ('' if it can): none declared, it needs its exporting tool, or it has Clock
    variables (clocked Model Exchange is not supported)."""
    me = info.model_exchange
    if me is None:
        return (f"has no Model Exchange interface (it declares "
                f"{', '.join(info.interfaces) or 'none'})")
    if me.needs_execution_tool:
        return ("its Model Exchange interface needs its exporting tool "
                "(needsExecutionTool=\"true\"), which agv-cosim cannot provide")
    clocks = [v.name for v in info.variables.values() if v.type == "Clock"]
    if clocks:
        return (f"has Clock variables ({', '.join(clocks[:3])}"
                f"{' ..' if len(clocks) > 3 else ''}): clocked Model Exchange is not "
                "supported")
    return ""


def _model_exchange(md: Any) -> ModelExchangeInfo | None:
    """The FMU's ``<ModelExchange>`` as a :class:`ModelExchangeInfo` (None: none)."""
    me = md.modelExchange
    if me is None or not me.modelIdentifier:
        return None
    return ModelExchangeInfo(
        identifier=me.modelIdentifier, states=int(md.numberOfContinuousStates or 0),
        event_indicators=int(md.numberOfEventIndicators or 0),
        needs_completed_integrator_step=bool(me.needsCompletedIntegratorStep)
        and not bool(getattr(me, "completedIntegratorStepNotNeeded", False)),
        needs_execution_tool=bool(getattr(me, "needsExecutionTool", False)))


def _fmi_version(path: Path) -> str | None:
    """The root's ``fmiVersion`` (None if unreadable), read before fmpy so that an FMI 1.0
    FMU is named as such instead of failing fmpy's FMI 1.0 schema check."""
    from lxml import etree

    try:
        with zipfile.ZipFile(path) as archive, archive.open("modelDescription.xml") as xml:
            for _, root in etree.iterparse(xml, events=("start",)):
                return root.get("fmiVersion") or ""
    except etree.XMLSyntaxError:
        return None  # fmpy names the syntax error
    return None


def _variable(sv: Any, version: str) -> Variable:
    """One fmpy ModelVariable as our :class:`Variable`."""
    dims = tuple(str(d.start) if d.start is not None else f"vr:{d.valueReference}"
                 for d in sv.dimensions)
    declared = sv.declaredType
    return Variable(name=sv.name, vr=sv.valueReference, type=sv.type,
                    causality=sv.causality, variability=sv.variability,
                    unit=sv.unit, description=sv.description or "", start=sv.start,
                    fmi=version, dims=dims,
                    shape=tuple(int(n) for n in sv.shape) if dims else None,
                    min=sv.min if sv.min is not None else getattr(declared, "min", None),
                    max=sv.max if sv.max is not None else getattr(declared, "max", None))


def find_fmus(path: str | Path) -> list[Path]:
    """The FMUs at ``path``: the file itself, or every ``*.fmu`` in a folder (sorted)."""
    path = Path(path)
    if path.is_dir():
        return sorted(path.glob("*.fmu"))
    return [path]


def interfaces_text(info: ModelInfo) -> str:
    """The FMI interfaces an FMU declares, as ``agv-cosim list`` shows them: Model
    Exchange with its continuous states and event indicators, then which one a component
    runs through by default (or why the orchestrator cannot integrate it)."""
    shown = list(info.interfaces)
    me = info.model_exchange
    if me is not None:
        shown[shown.index("model-exchange")] = (
            f"model-exchange ({me.states} continuous states, {me.event_indicators} event "
            "indicators)")
    problem = model_exchange_refusal(info) if me is not None else ""
    if problem:
        how = f"Model Exchange cannot be integrated: it {problem}"
    elif me is None:
        how = "run as co-simulation"
    elif "co-simulation" in info.interfaces:
        how = 'run as co-simulation unless a component sets interface = "model-exchange"'
    else:
        how = "integrated by the orchestrator (solver cvode unless a component sets one)"
    return f"{', '.join(shown)}: {how}"


def describe(info: ModelInfo) -> str:
    """Human-readable listing of an FMU's variables (``agv-cosim list``): causality, value
    reference (``vr=N``, what a host passes to fmi2GetReal/fmi3GetFloat64 and the like),
    type, name, start value, unit, description; a tunable parameter is marked as such."""
    lines = [f"{info.path.name}  ({info.model_name}): {info.description}"]
    lines.append(f"  interfaces: {interfaces_text(info)}")
    order = {"parameter": 0, "input": 1, "output": 2}
    variables = sorted((v for v in info.variables.values() if v.element is None),
                       key=lambda v: (order.get(v.causality, 3), v.vr))
    for v in variables:
        unit = f"[{v.unit}]" if v.unit else ""
        extra = ""
        if v.causality == "parameter" and v.variability == "tunable":
            extra = "  (tunable: an event may change it during a run)"
        if v.causality == "output":
            deps = info.dependencies.get(v.name, [])
            extra = f"  (feedthrough from {', '.join(deps)})" if deps else ""
        start = f" = {v.start}" if v.start is not None and v.causality != "output" else ""
        vtype = v.type
        if v.dims:  # an FMI 3.0 array: its shape (elements recorded as name[i])
            vtype += f"[{'x'.join(map(str, v.shape)) if v.shape else '?'}]"
        lines.append(f"  {v.causality:<9} {f'vr={v.vr}':<6} {vtype:<7} {v.name}{start} "
                     f"{unit}  {v.description}{extra}")
    return "\n".join(lines)
