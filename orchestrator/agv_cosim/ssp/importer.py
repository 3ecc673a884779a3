"""SSP 1.0 import: an ``.ssp`` package read into a :class:`~agv_cosim.manifest.Manifest`.

Import (:func:`load_ssp`, :func:`opened`): the archive is checked entry by entry
(absolute paths, ``..``, drive letters and symbolic links are refused before anything is
written) and extracted within bounds (:mod:`agv_cosim.archive`,
:data:`~agv_cosim.archive.SSP_LIMITS`): at most 4 GiB uncompressed and 10 000 entries,
stored or deflate only, checked from the headers before anything is written and enforced
while writing (no entry writes more than its header declares); a refused archive leaves
nothing of what was unpacked. Its SSD is mapped onto the manifest's data (components,
connections, parameter values, experiment) and checked by the same schema as a manifest
file (:func:`agv_cosim.manifest.manifest_from_data`); no manifest text is written, so
names and values from the SSD stay data (component names must be identifiers, else
refused; a connector name may hold dots, as FMI variable names do: ``component.variable``
is split at the first dot). The runner then validates and runs it like
any other manifest. Parameter bindings are applied at every
level: on components and on the system (names ``component.parameter``), inline
``ssd:ParameterValues`` or ``.ssv`` files (``source``, with ``prefix``), in document
order, a system binding overriding the component's own; a Real with a ``unit`` is
converted through the ``ssc:Unit``/``BaseUnit`` factor and offset (of the parameter set,
else of the SSD) to the FMU variable's unit (its UnitDefinition), and refused when it
cannot be. What we do not support is refused with one line naming the .ssp and the
element: nested systems, signal dictionaries, non-FMU components, an ``implementation``
other than any, CoSimulation and ModelExchange,
sources outside the package, connections to system connectors, connection
transformations, parameter mappings, other binding types, ``sourceBase="component"``,
parameters of the system itself, Enumeration/Binary values, connectors that are not the
FMU's variable of that kind, type and unit (connector units are never converted). A
package without the ``org.agv-cosim`` annotation runs with the Jacobi
algorithm (the semantics of libcosim, the master SSP packages of this kind come from) and
records every Real output. Metrics and plots come from the annotation's ``agv:Metrics``
and ``agv:Plots`` (the exported manifest's tables); without ``agv:Plots`` the first
:data:`PLOTTED` recorded signals (every Real output when the package names none) are
drawn in ``signals.png``. A component's ``implementation`` is its ``interface``
(``ModelExchange``: integrated by agv-cosim; ``any``: the FMU's choice), and its own
``org.agv-cosim`` annotation's ``agv:Integration`` gives its ``solver`` and ``tolerance``.
"""

import contextlib
import json
import math
import shutil
import zipfile
import zlib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import unquote, urlparse
from xml.etree import ElementTree

from .. import archive, fmitypes
from ..archive import SSP_LIMITS, ArchiveRefused, Limits
from ..errors import ManifestError, ModelError, SspError, UnreadableFile
from ..files import XML_LIMIT, check_name, open_regular, read_bytes
from ..lifetime import scratch_dir
from ..manifest import Manifest, manifest_from_data
from ..system.model import Variable, file_sha256, read_model
from .common import (
    AGV_ANNOTATION,
    BASE_UNITS,
    FMU_MIME,
    IDENTIFIER,
    NS,
    OSP_ANNOTATION,
    PSET_MIME,
    SSD_NAME,
    TYPES,
    is_ssp,
    q,
    ssp_type,
    unit_definitions,
)

#: A unit definition: (SI base unit exponents, factor, offset).
_Unit = tuple[tuple[int, ...], float, float]
#: A parameter binding read (:func:`_bindings`): (name, SSP type, value, unit or None, the
#: unit's definition or None, where it was read).
_Binding = tuple[str, str, Any, str | None, _Unit | None, str]


def safe_extract(archive_path: str | Path, dest: str | Path,
                 limits: Limits | None = None) -> None:
    """Extract a zip archive into the existing folder ``dest`` within ``limits``
    (default :data:`~agv_cosim.archive.SSP_LIMITS`) by :func:`agv_cosim.archive.extract`:
    headers checked before anything is written, every entry streamed with a byte
    budget, what was written removed on failure.

    Raises
    ------
    SspError
        For an unreadable archive; an entry with an absolute path, a drive letter, a
        ``..`` component or a symbolic link; more entries or uncompressed bytes than
        ``limits`` (from the headers, or while writing); an entry larger than its header
        says. Nothing this call wrote is left then.
    """
    try:
        with open_regular(archive_path) as stream:
            archive.extract(archive_path, dest, SSP_LIMITS if limits is None else limits,
                            stream)
    except ArchiveRefused as refused:
        raise SspError(archive_path, "archive", refused.reason) from None
    except UnreadableFile as error:
        raise SspError(archive_path, "file", error.problem) from None
    except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError, OSError) as error:
        raise SspError(archive_path, "archive", f"not a readable zip archive: {error}") \
            from None


def _float_attr(package: Path, key: str, node: ElementTree.Element, attr: str,
                default: float | None = None) -> float:
    text = node.get(attr)
    if text is None:
        if default is None:
            raise SspError(package, key, f"missing attribute '{attr}'")
        return default
    try:
        value = float(text)
    except ValueError:
        raise SspError(package, key, f"{attr}={text!r} is not a number") from None
    if not math.isfinite(value):
        raise SspError(package, key, f"{attr}={text!r} is not finite")
    return value


def _parse_value(package: Path, key: str,
                 node: ElementTree.Element) -> tuple[str, Any, str | None]:
    """(type, value, unit or None) of an ssv:Parameter."""
    kind = next((child for child in node if child.tag in
                 [q("ssv", t) for t in TYPES]), None)
    if kind is None:
        raise SspError(package, key, "no ssv:Real/Integer/Boolean/String value "
                       "(Enumeration and Binary are not supported)")
    vtype = kind.tag.split("}")[1]
    text = kind.get("value")
    if text is None:
        raise SspError(package, key, "missing attribute 'value'")
    ftype = fmitypes.lookup("2.0", vtype)  # SSP's type names are FMI 2.0's
    assert ftype is not None  # TYPES are FMI 2.0 type names (fmitypes.SSP_VALUE_TYPES)
    unit = kind.get("unit") if ftype.is_float else None
    try:
        # a non-finite Real is checked against the FMU's variable later, like a
        # manifest's value (refused unless the variable declares it legal)
        value = fmitypes.parse_text(ftype, text)
    except ValueError:
        raise SspError(package, key, f"{text!r} is not a valid {vtype}") from None
    return vtype, value, unit


#: SI base units of FMI 2.0 / SSP unit definitions (exponents).
def _unit_of(package: Path, key: str, attrs: Mapping[str, str]) -> _Unit:
    """(exponents, factor, offset) of a BaseUnit attribute dict."""
    try:
        exponents = tuple(int(attrs.get(b, 0)) for b in BASE_UNITS)
        factor = float(attrs.get("factor", 1.0))
        offset = float(attrs.get("offset", 0.0))
    except ValueError:
        raise SspError(package, key, f"malformed BaseUnit {attrs}") from None
    if not (math.isfinite(factor) and factor != 0.0 and math.isfinite(offset)):
        raise SspError(package, key, f"BaseUnit factor/offset {attrs} is not usable")
    return exponents, factor, offset


def _units(package: Path, holder: ElementTree.Element,
           prefix: str) -> dict[str | None, _Unit]:
    """Unit name -> (exponents, factor, offset) of ``holder``'s ``<prefix>:Units``."""
    units: dict[str | None, _Unit] = {}
    for unit in holder.iterfind(f"{prefix}:Units/ssc:Unit", NS):
        base = unit.find("ssc:BaseUnit", NS)
        units[unit.get("name")] = _unit_of(package, f"Unit '{unit.get('name')}'",
                                           base.attrib if base is not None else {})
    return units


def _bindings(package: Path, base: Path, element: ElementTree.Element, key: str,
              ssd_units: Mapping[str | None, _Unit]) -> list[_Binding]:
    """The parameter values bound on ``element`` (ssd:System or ssd:Component), in order.

    Returns a list of (name, type, value, unit, unit definition or None, key). Every
    binding of SSP 1.0 is read: inline ssd:ParameterValues or a ``source`` .ssv file
    in the package, with its ``prefix``; what we cannot apply exactly is refused.
    """
    found: list[_Binding] = []
    bindings = element.findall("ssd:ParameterBindings/ssd:ParameterBinding", NS)
    for i, binding in enumerate(bindings, start=1):
        bkey = f"{key}: ParameterBinding {i}" if len(bindings) > 1 else \
            f"{key}: ParameterBinding"
        kind = binding.get("type", PSET_MIME)
        if kind != PSET_MIME:
            raise SspError(package, bkey, f"type '{kind}' is not supported (only "
                           f"{PSET_MIME})")
        if binding.find("ssd:ParameterMapping", NS) is not None:
            raise SspError(package, bkey, "ParameterMapping is not supported")
        if binding.get("sourceBase", "SSD") != "SSD":
            raise SspError(package, bkey, f"sourceBase '{binding.get('sourceBase')}' is not "
                           "supported (only 'SSD')")
        prefix = binding.get("prefix", "")
        source = binding.get("source")
        pset: ElementTree.Element | None
        if source:
            url = urlparse(source)
            path = None if url.scheme or url.netloc else _inside(base, unquote(url.path))
            if path is None or not path.is_file():
                raise SspError(package, bkey, f"source '{source}' is not a file in the "
                               "package")
            try:
                pset = ElementTree.fromstring(read_bytes(path, XML_LIMIT))
            except ElementTree.ParseError as error:
                raise SspError(package, bkey, f"{source}: not well-formed XML: {error}") \
                    from None
            except UnreadableFile as error:
                raise SspError(package, bkey, f"{source}: {error.problem}") from None
            except OSError as error:
                raise SspError(package, bkey, f"{source}: cannot read: {error.strerror}") \
                    from None
            if pset.tag != q("ssv", "ParameterSet"):
                raise SspError(package, bkey, f"{source}: root is not ssv:ParameterSet")
            bkey = f"{bkey} ({source})"
        else:
            pset = binding.find("ssd:ParameterValues/ssv:ParameterSet", NS)
            if pset is None:
                raise SspError(package, bkey, "no source and no inline ssv:ParameterSet")
        set_units = _units(package, pset, "ssv")
        for param in pset.iterfind("ssv:Parameters/ssv:Parameter", NS):
            pname = param.get("name")
            pkey = f"{bkey}: parameter '{pname}'"
            if not pname:
                raise SspError(package, f"{bkey}: Parameter", "missing attribute 'name'")
            vtype, value, unit = _parse_value(package, pkey, param)
            definition = None
            if unit is not None:
                definition = set_units.get(unit, ssd_units.get(unit))
            found.append((prefix + pname, vtype, value, unit, definition, pkey))
    return found


def _convert(package: Path, where: str, value: Any, unit: str | None,
             definition: _Unit | None, var: Variable, fmu_units: Mapping[str, _Unit]) -> Any:
    """``value`` in ``unit`` converted to the unit of the FMU variable ``var``."""
    if unit is None or (unit == var.unit and (definition is None
                                              or var.unit not in fmu_units)):
        return value
    if definition is None:
        raise SspError(package, where, f"unit '{unit}' has no ssc:Unit definition (in the "
                       "parameter set or the SSD), so it cannot be converted to "
                       f"[{var.unit or '1'}]")
    if var.unit is None:
        target = ((0,) * len(BASE_UNITS), 1.0, 0.0)
    elif var.unit in fmu_units:
        target = fmu_units[var.unit]
    else:
        raise SspError(package, where, f"the FMU's unit '{var.unit}' of '{var.name}' has "
                       "no UnitDefinition, so the value cannot be converted to it")
    if definition[0] != target[0]:
        raise SspError(package, where, f"unit '{unit}' cannot be converted to "
                       f"[{var.unit or '1'}] of '{var.name}' (other base units)")
    si = definition[1] * value + definition[2]
    return (si - target[2]) / target[1]


def _inside(base: Path, relative: str) -> Path | None:
    target = (base / relative).resolve()
    return target if base == target or base in target.parents else None


def _component(package: Path, base: Path, node: ElementTree.Element,
               ssd_units: Mapping[str | None, _Unit]) -> tuple[str, Path, list[_Binding]]:
    cname = node.get("name")
    key = f"Component '{cname}'"
    if not cname or not IDENTIFIER.match(cname):
        raise SspError(package, key, "component names must be identifiers "
                       "([A-Za-z_][A-Za-z0-9_]*, used as 'component.variable')")
    kind = node.get("type", FMU_MIME)
    if kind != FMU_MIME:
        raise SspError(package, key, f"type '{kind}' is not supported (only FMUs)")
    if node.get("implementation", "any").lower() not in IMPLEMENTATIONS:
        raise SspError(package, key, f"implementation '{node.get('implementation')}' is not "
                       "supported (only any, CoSimulation and ModelExchange)")
    source = node.get("source") or ""
    url = urlparse(source)
    if url.scheme or url.netloc or not source:
        raise SspError(package, key, f"source '{source}' is not a path inside the package")
    fmu = _inside(base, unquote(url.path))
    if fmu is None:
        raise SspError(package, key, f"source '{source}' is outside the package")
    if not fmu.is_file():
        raise SspError(package, key, f"source '{source}' is not in the package")
    return cname, fmu, _bindings(package, base, node, key, ssd_units)


def _own_step(package: Path, node: ElementTree.Element) -> float | None:
    """The component's own communication step [s] from our annotation (``agv:Component
    stepSize``), else from libcosim's (``osp:StepSizeHint value``), or None."""
    found: float | None = None
    key = f"Component '{node.get('name')}'"
    for note in node.iterfind("ssd:Annotations/ssc:Annotation", NS):
        ours = note.find("agv:Component", NS) if note.get("type") == AGV_ANNOTATION \
            else None
        if ours is not None and ours.get("stepSize"):
            return _float_attr(package, f"{key}: agv:Component", ours, "stepSize")
        hint = note.find("osp:StepSizeHint", NS) if note.get("type") == OSP_ANNOTATION \
            else None
        if hint is not None and hint.get("value") and found is None:
            found = _float_attr(package, f"{key}: osp:StepSizeHint", hint, "value")
    return found


#: SSP's ``implementation`` of a component -> its ``interface`` (None: the FMU's choice).
IMPLEMENTATIONS = {"any": None, "cosimulation": "co-simulation",
                   "modelexchange": "model-exchange"}


def _interface(package: Path, cname: str,
               node: ElementTree.Element) -> dict[str, Any]:
    """A component's ``interface``, ``solver`` and ``tolerance`` (those given) from its
    ``implementation`` and its ``org.agv-cosim`` annotation (``agv:Integration``)."""
    keys: dict[str, Any] = {}
    interface = IMPLEMENTATIONS[node.get("implementation", "any").lower()]
    if interface is not None:
        keys["interface"] = interface
    for note in node.iterfind("ssd:Annotations/ssc:Annotation", NS):
        integration = note.find("agv:Integration", NS)
        if note.get("type") != AGV_ANNOTATION or integration is None:
            continue
        key = f"Component '{cname}': agv:Integration"
        if integration.get("solver") is not None:
            keys["solver"] = integration.get("solver")
        if integration.get("tolerance") is not None:
            keys["tolerance"] = _float_attr(package, key, integration, "tolerance")
    return keys


def _check_connectors(package: Path, cname: str, fmu: Path,
                      node: ElementTree.Element) -> None:
    """Refuse connectors that do not match the FMU (we convert no connector units)."""
    connectors = node.findall("ssd:Connectors/ssd:Connector", NS)
    if not connectors:
        return
    try:
        info = read_model(fmu)
    except ModelError as error:
        raise SspError(package, f"Component '{cname}'", str(error)) from None
    for connector in connectors:
        name, kind = connector.get("name"), connector.get("kind")
        key = f"Component '{cname}': Connector '{name}'"
        var = info.variables.get(name) if name is not None else None
        if var is None:
            raise SspError(package, key, f"not a variable of {info.model_name}")
        if kind not in (None, var.causality) and not (kind == "inout" and
                                                       var.causality in ("input", "output")):
            raise SspError(package, key, f"kind '{kind}', but the FMU's variable is "
                           f"{var.causality}")
        typed = next((child for child in connector if child.tag in
                      [q("ssc", t) for t in TYPES + ("Enumeration", "Binary")]), None)
        if typed is None:
            continue
        vtype = typed.tag.split("}")[1]
        if vtype != ssp_type(var):
            raise SspError(package, key, f"type {vtype}, but the FMU's variable is "
                           f"{var.type}")
        unit = typed.get("unit")
        if unit is not None and unit != (var.unit or ""):
            raise SspError(package, key, f"unit '{unit}', but the FMU's variable is in "
                           f"[{var.unit or '1'}] (connector unit conversion is not "
                           "supported)")


def _bound_parameters(package: Path, components: Mapping[str, Path],
                      component_bound: Mapping[str, list[_Binding]],
                      system_bound: list[_Binding]) -> dict[str, dict[str, Any]]:
    """Component -> {parameter: value in the FMU's unit}.

    Precedence (our reading of SSP 1.0): within one element, a later binding overrides
    an earlier one; a system binding (``component.parameter``) overrides the
    component's own.
    """
    chosen: dict[str, dict[str, tuple[str, Any, str | None, _Unit | None, str]]] = {
        cname: {} for cname in components}
    for cname, bound in component_bound.items():
        for binding in bound:
            chosen[cname][binding[0]] = binding[1:]
    for binding in system_bound:
        name, rest = binding[0], binding[1:]
        where = rest[-1]
        cname, dot, pname = name.partition(".")
        if not dot:
            raise SspError(package, where, f"'{name}' names no component (a parameter of "
                           "the system itself is not supported; use 'component.parameter')")
        if cname not in components:
            raise SspError(package, where, f"unknown component '{cname}' in '{name}'")
        chosen[cname][pname] = rest
    params: dict[str, dict[str, Any]] = {}
    for cname, values in chosen.items():
        params[cname] = {}
        if not values:
            continue
        try:
            info = read_model(components[cname])
        except ModelError as error:
            raise SspError(package, f"Component '{cname}'", str(error)) from None
        fmu_units: dict[str, _Unit] = {}
        if any(unit is not None for _, _, unit, _, _ in values.values()):
            defs = unit_definitions(info.path)
            fmu_units = {u: _unit_of(package, f"Component '{cname}'", d)
                         for u, d in defs.items()}
        for pname, (vtype, value, unit, definition, where) in values.items():
            var = info.variables.get(pname)
            if var is None or var.causality != "parameter":
                what = "no variable" if var is None else f"'{pname}' is {var.causality}"
                raise SspError(package, where, f"{cname} ({info.model_name}) has "
                               f"{what}{' ' + repr(pname) if var is None else ''}, "
                               "not a parameter")
            if vtype == "Real" and (var.unsupported() or not var.ftype.is_float):
                raise SspError(package, where, f"a Real value for the {var.type} "
                               f"parameter '{pname}'")
            params[cname][pname] = _convert(package, where, value, unit, definition, var,
                                            fmu_units)
    return params


def read_ssd(package: Path, ssd_path: Path) -> dict[str, Any]:
    """Translate an SSD into the data of a manifest (a plain dict, TOML-shaped).

    Raises
    ------
    SspError
        For a malformed SSD or anything we do not support (see the module docstring).
    """
    ssd_path = Path(ssd_path)
    base = ssd_path.parent.resolve()
    root = _ssd_root(package, ssd_path)
    system = _system(package, root)
    ssd_units = _units(package, root, "ssd")
    elements = _read_elements(package, base, system, ssd_units)
    params = _bound_parameters(package, elements.fmus, elements.bound,
                               _bindings(package, base, system, "System", ssd_units))
    components: dict[str, dict[str, Any]] = {
        cname: {"fmu": str(fmu), "parameters": params[cname], **elements.interfaces[cname]}
        for cname, fmu in elements.fmus.items()}
    for cname, own in elements.steps.items():
        components[cname]["step"] = own
    connections = _connections(package, system)
    experiment = _experiment(package, root)
    data: dict[str, Any] = {"name": _system_name(package, root, system),
                            "description": system.get("description", ""),
                            "simulation": experiment.simulation, "components": components,
                            "connections": connections}
    data.update(experiment.tables)
    if "plots" not in data:  # a package without our [plots]: its recorded outputs
        data["plots"] = {"signals": (experiment.record
                                     or _real_outputs(components))[:PLOTTED]}
    if experiment.record or experiment.interval is not None:
        data["record"] = {}
        if experiment.record:
            data["record"]["variables"] = experiment.record
        if experiment.interval is not None:
            data["record"]["interval"] = experiment.interval
    return data


def _ssd_root(package: Path, ssd_path: Path) -> ElementTree.Element:
    """The SSD's root element, an SSP 1.0 ``ssd:SystemStructureDescription``."""
    try:
        root = ElementTree.fromstring(read_bytes(ssd_path, XML_LIMIT))
    except ElementTree.ParseError as error:
        raise SspError(package, SSD_NAME, f"not well-formed XML: {error}") from None
    except UnreadableFile as error:
        raise SspError(package, SSD_NAME, error.problem) from None
    except OSError:
        raise SspError(package, SSD_NAME, "missing (not an SSP package)") from None
    if root.tag != q("ssd", "SystemStructureDescription"):
        raise SspError(package, SSD_NAME, "root is not ssd:SystemStructureDescription "
                       "(SSP 1.0)")
    return root


def _system(package: Path, root: ElementTree.Element) -> ElementTree.Element:
    """The SSD's ``ssd:System`` (signal dictionaries refused)."""
    system = root.find("ssd:System", NS)
    if system is None:
        raise SspError(package, "System", "missing")
    for tag, what in (("SignalDictionaries", "signal dictionaries"),):
        if system.find(f"ssd:{tag}", NS) is not None:
            raise SspError(package, f"System: {tag}", f"{what} are not supported")
    return system


@dataclass
class _Elements:
    """The components of an ``ssd:System``, by name: FMU, parameter bindings, own step
    (multirate components only) and ``interface``/``solver``/``tolerance`` keys."""

    fmus: dict[str, Path] = field(default_factory=dict)
    bound: dict[str, list[_Binding]] = field(default_factory=dict)
    steps: dict[str, float] = field(default_factory=dict)
    interfaces: dict[str, dict[str, Any]] = field(default_factory=dict)


def _read_elements(package: Path, base: Path, system: ElementTree.Element,
                   ssd_units: Mapping[str | None, _Unit]) -> _Elements:
    """Every ``ssd:Component`` of ``system`` (anything else refused; at least one)."""
    found = _Elements()
    elements = system.find("ssd:Elements", NS)
    for node in (elements if elements is not None else []):
        tag = node.tag.split("}")[-1]
        if tag != "Component":
            raise SspError(package, f"Elements: {tag} '{node.get('name')}'",
                           "only Component elements are supported (no nested systems or "
                           "signal dictionaries)")
        cname, fmu, found.bound[cname] = _component(package, base, node, ssd_units)
        if cname in found.fmus:
            raise SspError(package, f"Component '{cname}'", "name used twice")
        _check_connectors(package, cname, fmu, node)
        found.fmus[cname] = fmu
        own = _own_step(package, node)
        if own is not None:
            found.steps[cname] = own
        found.interfaces[cname] = _interface(package, cname, node)
    if not found.fmus:
        raise SspError(package, "System: Elements", "no components")
    return found


def _connections(package: Path, system: ElementTree.Element) -> list[dict[str, str]]:
    """The manifest's ``[[connections]]`` of ``system`` (component to component only,
    no transformation)."""
    connections: list[dict[str, str]] = []
    for node in system.iterfind("ssd:Connections/ssd:Connection", NS):
        ends = [node.get(a) for a in ("startElement", "startConnector", "endElement",
                                      "endConnector")]
        key = f"Connection {ends[0]}.{ends[1]} -> {ends[2]}.{ends[3]}"
        if not ends[0] or not ends[2]:
            raise SspError(package, key, "connections to the system's own connectors are "
                           "not supported")
        if not ends[1] or not ends[3]:
            raise SspError(package, key, "connector names must be non-empty")
        if len(node):
            raise SspError(package, key, f"{node[0].tag.split('}')[-1]} is not supported")
        connections.append({"from": f"{ends[0]}.{ends[1]}", "to": f"{ends[2]}.{ends[3]}"})
    return connections


@dataclass
class _Experiment:
    """What ``ssd:DefaultExperiment`` and its annotations give: the master algorithm and
    step, the recorded variables and record interval (None: not given), the
    ``[metrics]``/``[plots]`` tables of our annotation, and the ``[simulation]`` table
    they make."""

    algorithm: str = "jacobi"
    step: float | None = None
    record: list[str | None] | None = None
    interval: float | None = None
    tables: dict[str, Any] = field(default_factory=dict)
    simulation: dict[str, Any] = field(default_factory=dict)


def _experiment(package: Path, root: ElementTree.Element) -> _Experiment:
    """The SSD's ``ssd:DefaultExperiment``: start and stop, the step from libcosim's
    annotation (``osp:FixedStepAlgorithm``) or ours, and the rest of ours, annotations
    read in document order."""
    experiment = root.find("ssd:DefaultExperiment", NS)
    if experiment is None:
        raise SspError(package, "DefaultExperiment", "missing (start, stop and step are "
                       "needed)")
    start = _float_attr(package, "DefaultExperiment", experiment, "startTime", 0.0)
    if experiment.get("stopTime") is None:
        raise SspError(package, "DefaultExperiment", "no stopTime")
    stop = _float_attr(package, "DefaultExperiment", experiment, "stopTime")
    found = _Experiment()
    for note in experiment.iterfind("ssd:Annotations/ssc:Annotation", NS):
        if note.get("type") == OSP_ANNOTATION and found.step is None:
            fixed = note.find("osp:Algorithm/osp:FixedStepAlgorithm", NS)
            if fixed is not None:
                found.step = _float_attr(package, "osp:FixedStepAlgorithm", fixed,
                                         "baseStepSize")
        elif note.get("type") == AGV_ANNOTATION:
            ours = note.find("agv:Experiment", NS)
            if ours is not None:
                _read_our_experiment(package, ours, found)
    if found.step is None:
        raise SspError(package, "DefaultExperiment", "no step size (an "
                       "osp:FixedStepAlgorithm annotation with baseStepSize is needed)")
    found.simulation = {"start": start, "stop": stop, "step": found.step,
                        "algorithm": found.algorithm}
    return found


def _read_our_experiment(package: Path, ours: ElementTree.Element,
                         found: _Experiment) -> None:
    """Our ``agv:Experiment`` annotation into ``found``: algorithm, step, record
    interval (those given), recorded variables, ``[metrics]`` and ``[plots]``."""
    found.algorithm = ours.get("algorithm", found.algorithm)
    if ours.get("stepSize"):
        found.step = _float_attr(package, "agv:Experiment", ours, "stepSize")
    if ours.get("recordInterval"):
        found.interval = _float_attr(package, "agv:Experiment", ours, "recordInterval")
    found.record = [r.get("variable") for r in ours.iterfind("agv:Record", NS)] or None
    for tag in ("Metrics", "Plots"):
        text = ours.findtext(f"agv:{tag}", None, NS)
        if text is not None:
            found.tables[tag.lower()] = _json_table(package, tag, text)


def _json_table(package: Path, tag: str, text: str) -> dict[str, Any]:
    """A manifest table carried as JSON text in our annotation (``agv:<tag>``)."""
    try:
        table = json.loads(text)
    except ValueError as error:
        raise SspError(package, f"agv:{tag}", f"not JSON: {error}") from None
    if not isinstance(table, dict):
        raise SspError(package, f"agv:{tag}", "not a JSON object")
    return table


def _system_name(package: Path, root: ElementTree.Element,
                 system: ElementTree.Element) -> str:
    """The system's name (the SSD's, else the system's, else the package's stem): a
    plain file name, since it names the default output folder."""
    name = root.get("name") if root.get("name") is not None else system.get("name")
    if name is None:
        name = Path(package).stem
    try:
        check_name(name, "system name")
    except ValueError as error:
        raise SspError(package, "SystemStructureDescription", f"{error} (it names the "
                       "default output folder results/<name>)") from None
    return name


#: Most signals plotted from a package that names no ``[plots]`` table.
PLOTTED = 8


def _real_outputs(components: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """``component.variable`` of every scalar Real (float) output, in component order."""
    names: list[str] = []
    for cname, spec in components.items():
        info = read_model(spec["fmu"])
        names += [f"{cname}.{v.name}" for v in info.variables.values()
                  if v.causality == "output" and not v.dims
                  and not v.unsupported("record") and v.ftype.is_float]
    return names


def _source_sha256(source: str | Path) -> str:
    """SHA-256 of an SSP source: the .ssp file, or the SSD of a package folder."""
    source = Path(source)
    return file_sha256(source / SSD_NAME if source.is_dir() else source)


def load_ssp(path: str | Path, workdir: str | Path) -> Manifest:
    """Read an SSP package into a :class:`~agv_cosim.manifest.Manifest`.

    Parameters
    ----------
    path : path
        An ``.ssp`` archive, or an unpacked package folder, or its ``.ssd`` file.
    workdir : path
        Folder to unpack an archive into (must outlive the run: the manifest points at
        the FMUs in it).

    Returns
    -------
    Manifest
        Named by ``path`` (messages and run.json name the package) with the package's
        SHA-256; ready for :func:`agv_cosim.pipeline.prepare`.

    Raises
    ------
    SspError
        Unsafe archive entries, a malformed SSD, or an unsupported SSP feature.
    ManifestError
        What the manifest schema refuses (named by the package).
    """
    path, workdir = Path(path), Path(workdir)
    if not path.exists():
        raise SspError(path, "file", "not found")
    if not (path.is_dir() or path.is_file()):  # a FIFO or a device: never opened
        raise SspError(path, "file", "not a regular file or a folder")
    unpacked = None
    if path.is_dir():
        ssd = path / SSD_NAME
    elif path.suffix.lower() == ".ssd":
        ssd = path
    else:
        unpacked = workdir / "package"
        _extract_into_new(path, unpacked)
        ssd = unpacked / SSD_NAME
    data = read_ssd(path, ssd)
    manifest = manifest_from_data(data, path, _source_sha256(path), base_dir=ssd.parent)
    manifest.unpacked = unpacked.resolve() if unpacked is not None else None
    return manifest


def _extract_into_new(path: Path, unpacked: Path) -> None:
    """:func:`safe_extract` into ``unpacked``, made with its missing parents; those
    folders are removed again when the archive is refused."""
    made = [folder for folder in (unpacked, *unpacked.parents) if not folder.exists()]
    unpacked.mkdir(parents=True, exist_ok=True)
    try:
        safe_extract(path, unpacked)
    except SspError:
        for folder in made:  # deepest first; each empty again (safe_extract undid its own)
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise


@contextlib.contextmanager
def opened(path: str | Path) -> Iterator[Manifest | str | Path]:
    """Context: the manifest to run for ``path``.

    A manifest path (or None) is yielded unchanged; an SSP package is unpacked into a
    temporary folder that is removed when the context ends, and its
    :class:`~agv_cosim.manifest.Manifest` is yielded. An error about the package names
    the entries in it as ``<package>!/<entry>``, never our temporary files.
    """
    if not is_ssp(path):
        yield path
        return
    work = scratch_dir("ssp")
    try:
        yield load_ssp(path, work)
    except ManifestError as error:
        if error.manifest != str(path):
            raise
        package = str((Path(work) / "package").resolve()) + "/"
        problem = error.problem.replace(package, f"{path}!/")
        raise SspError(path, error.key, problem) from None
    finally:
        shutil.rmtree(work, ignore_errors=True)
