"""SSP 1.0 packages: export a manifest as ``.ssp``, run an ``.ssp`` with our master.

Export (:func:`export_ssp`, ``agv-cosim export-ssp MANIFEST [--variant NAME] -o FILE.ssp``)
writes one run of a manifest (one variant, no sweep) as a self-contained SSP 1.0 archive::

    SystemStructure.ssd     components, connectors (type, unit), connections, units,
                            inline parameter values, DefaultExperiment
    resources/<model>.fmu   every FMU the run uses (one copy per distinct file)

The SSD is written the way libcosim 0.11 reads it (it matches the literal prefixes
``ssd:``, ``ssc:``, ``ssv:``, ``osp:``, not the namespaces): parameters as inline
``ssd:ParameterValues`` (libcosim also reads ``.ssv`` files, but inline keeps the package
one file shorter and is what it reads first), every connected variable declared as an
``ssd:Connector`` with an ``ssc:Real``/``ssc:Integer``/... child carrying the unit (an
``ssc:Enumeration`` names its FMU enumeration type, whose items are written to
``ssd:Enumerations``; FMI 3.0 array variables and their elements get no connector), and the
step as ``osp:FixedStepAlgorithm baseStepSize`` in a ``com.opensimulationplatform``
annotation of ``ssd:DefaultExperiment``. A second annotation, ``org.agv-cosim``, keeps
what SSP has no place for: our master algorithm, the recorded variables and the record
interval. Other tools ignore it.

Import (:func:`load_ssp_as_manifest`, :func:`ssp_manifest`): the archive is checked entry
by entry (absolute paths, ``..``, drive letters and symbolic links are refused before
anything is written), extracted, and its SSD is translated into an ordinary manifest
(TOML) next to the FMUs, which the runner then validates and runs like any other; names
from the SSD are data (quoted TOML strings; component names must be identifiers and
connector names free of '.', else refused). Parameter bindings are applied at every
level: on components and on the system (names ``component.parameter``), inline
``ssd:ParameterValues`` or ``.ssv`` files (``source``, with ``prefix``), in document
order, a system binding overriding the component's own; a Real with a ``unit`` is
converted through the ``ssc:Unit``/``BaseUnit`` factor and offset (of the parameter set,
else of the SSD) to the FMU variable's unit (its UnitDefinition), and refused when it
cannot be. What we do not support is refused with one line naming the .ssp and the
element: nested systems, signal dictionaries, non-FMU or model-exchange components,
sources outside the package, connections to system connectors, connection
transformations, parameter mappings, other binding types, ``sourceBase="component"``,
parameters of the system itself, Enumeration/Binary values, connectors that are not the
FMU's variable of that kind, type and unit (connector units are never converted). A
package without the ``org.agv-cosim`` annotation runs with the Jacobi
algorithm (the semantics of libcosim, the master SSP packages of this kind come from) and
records every Real output.
"""

import argparse
import contextlib
import math
import re
import shutil
import stat
import sys
import zipfile
import zlib
from pathlib import Path, PurePosixPath
from urllib.parse import unquote, urlparse
from xml.etree import ElementTree

from . import fmitypes
from .manifest import ManifestError, load_manifest
from .plan import plan_runs
from .system import validate
from .lifetime import scratch_dir
from .results import OutputError, check_name

NS = {
    "ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
    "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
    "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
    "osp": "http://opensimulationplatform.com/SSP/OSPAnnotations",
    "agv": "https://agv-cosim.org/SSP/Experiment",
}
OSP_ANNOTATION = "com.opensimulationplatform"
AGV_ANNOTATION = "org.agv-cosim"
FMU_MIME = "application/x-fmu-sharedlibrary"
SSD_NAME = "SystemStructure.ssd"
_TYPES = ("Real", "Integer", "Boolean", "String")
PSET_MIME = "application/x-ssp-parameter-set"
_IDENTIFIER = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")

for _prefix, _uri in NS.items():
    ElementTree.register_namespace(_prefix, _uri)


class SspError(ManifestError):
    """An SSP package we cannot read or run; the text is ``<package>: <element>: <problem>``."""


def _q(prefix, tag):
    return f"{{{NS[prefix]}}}{tag}"


def _number_text(value):
    """Shortest text that reads back as the same double (``repr``)."""
    return repr(float(value))


def _ssp_type(var):
    """The SSP type name of an FMU variable (SSP's names are FMI 2.0's), or None."""
    return None if var.unsupported() else var.ftype.ssp_type


# ---------------------------------------------------------------------------- export
def _unit_definitions(fmu_path):
    """``{unit name: {BaseUnit attribute: text}}`` from an FMU's modelDescription.xml."""
    with zipfile.ZipFile(fmu_path) as archive:
        root = ElementTree.fromstring(archive.read("modelDescription.xml"))
    units = {}
    for unit in root.iterfind("UnitDefinitions/Unit"):
        base = unit.find("BaseUnit")
        units[unit.get("name")] = dict(base.attrib) if base is not None else {}
    return units


def _enumeration_types(fmu_path):
    """``{variable name: (type name, [(item name, value text)])}`` of the Enumeration
    variables of an FMU (FMI 2.0 ``SimpleType``/``Enumeration``, FMI 3.0
    ``EnumerationType``)."""
    with zipfile.ZipFile(fmu_path) as archive:
        root = ElementTree.fromstring(archive.read("modelDescription.xml"))
    types = {}
    for simple in root.iterfind("TypeDefinitions/SimpleType"):
        enum = simple.find("Enumeration")
        if enum is not None:
            types[simple.get("name")] = [(i.get("name"), i.get("value"))
                                         for i in enum.iterfind("Item")]
    for enum in root.iterfind("TypeDefinitions/EnumerationType"):
        types[enum.get("name")] = [(i.get("name"), i.get("value"))
                                   for i in enum.iterfind("Item")]
    found = {}
    for node in root.iterfind("ModelVariables/ScalarVariable"):  # FMI 2.0
        enum = node.find("Enumeration")
        if enum is not None and enum.get("declaredType") in types:
            found[node.get("name")] = (enum.get("declaredType"),
                                       types[enum.get("declaredType")])
    for node in root.iterfind("ModelVariables/Enumeration"):  # FMI 3.0
        if node.get("declaredType") in types:
            found[node.get("name")] = (node.get("declaredType"),
                                       types[node.get("declaredType")])
    return found


def _fmu_file_names(models):
    """Instance name -> ``resources/<file>`` (one entry per distinct FMU file)."""
    by_hash, names, taken = {}, {}, set()
    for cname, info in models.items():
        if info.sha256 not in by_hash:
            stem = Path(info.path).stem
            candidate, n = f"{stem}.fmu", 2
            while candidate in taken:
                candidate, n = f"{stem}_{n}.fmu", n + 1
            taken.add(candidate)
            by_hash[info.sha256] = candidate
        names[cname] = f"resources/{by_hash[info.sha256]}"
    return names


def build_ssd(name, models, parameters, connections, start, stop, step, algorithm,
              record=None, record_interval=None, description=""):
    """The ``SystemStructure.ssd`` of one run, as an ElementTree element.

    Parameters
    ----------
    name : str
        System name.
    models : dict
        Instance name -> :class:`agv_cosim.model.ModelInfo`.
    parameters : dict
        Instance name -> ``{parameter: value}`` (the values to bind; others keep the
        FMU defaults).
    connections : list of agv_cosim.manifest.Connection
    start, stop, step : float
        Start and stop time and fixed macro step [s].
    algorithm : {"jacobi", "gauss-seidel"}
        Our master algorithm (kept in the ``org.agv-cosim`` annotation).
    record : list of str, optional
        Recorded ``component.variable`` names.
    record_interval : float, optional
        Record interval [s].
    """
    sources = _fmu_file_names(models)
    root = ElementTree.Element(_q("ssd", "SystemStructureDescription"),
                               {"name": name, "version": "1.0"})
    system = ElementTree.SubElement(root, _q("ssd", "System"), {"name": name})
    if description:
        system.set("description", description)
    elements = ElementTree.SubElement(system, _q("ssd", "Elements"))
    used_units = {}
    enumerations = {}  # SSP enumeration name -> [(item name, value text)]
    for cname, info in models.items():
        comp = ElementTree.SubElement(elements, _q("ssd", "Component"),
                                      {"name": cname, "source": sources[cname],
                                       "type": FMU_MIME})
        connectors = ElementTree.SubElement(comp, _q("ssd", "Connectors"))
        fmu_units = None
        fmu_enums = None
        for var in info.variables.values():
            if var.causality not in ("input", "output") or \
                    _ssp_type(var) not in _TYPES + ("Enumeration",):
                continue
            node = ElementTree.SubElement(connectors, _q("ssd", "Connector"),
                                          {"name": var.name, "kind": var.causality})
            kind = ElementTree.SubElement(node, _q("ssc", _ssp_type(var)))
            if _ssp_type(var) == "Enumeration":
                # SSP names the enumeration (required), defined in ssd:Enumerations;
                # two FMUs with one type name but other items get instance-qualified
                # names
                if fmu_enums is None:
                    fmu_enums = _enumeration_types(info.path)
                tname, items = fmu_enums.get(var.name, (None, None))
                if tname is None:
                    tname, items = f"{cname}.{var.name}", []
                if enumerations.get(tname, items) != items:
                    tname = f"{cname}.{tname}"
                enumerations[tname] = items
                kind.set("name", tname)
            if var.unit:
                kind.set("unit", var.unit)
                if var.unit not in used_units:
                    if fmu_units is None:
                        fmu_units = _unit_definitions(info.path)
                    used_units[var.unit] = fmu_units.get(var.unit, {})
        values = parameters.get(cname) or {}
        if values:
            bindings = ElementTree.SubElement(comp, _q("ssd", "ParameterBindings"))
            binding = ElementTree.SubElement(bindings, _q("ssd", "ParameterBinding"))
            holder = ElementTree.SubElement(binding, _q("ssd", "ParameterValues"))
            pset = ElementTree.SubElement(holder, _q("ssv", "ParameterSet"),
                                          {"version": "1.0", "name": f"{cname}"})
            plist = ElementTree.SubElement(pset, _q("ssv", "Parameters"))
            for pname, value in values.items():
                var = info.variables[pname]
                param = ElementTree.SubElement(plist, _q("ssv", "Parameter"), {"name": pname})
                attrs = {"value": fmitypes.format_text(var.ftype, value)}
                if var.ftype.is_float and var.unit:
                    attrs["unit"] = var.unit
                ElementTree.SubElement(param, _q("ssv", _ssp_type(var)), attrs)
    conns = ElementTree.SubElement(system, _q("ssd", "Connections"))
    for conn in connections:
        ElementTree.SubElement(conns, _q("ssd", "Connection"), {
            "startElement": conn.source[0], "startConnector": conn.source[1],
            "endElement": conn.target[0], "endConnector": conn.target[1]})
    if enumerations:
        enums = ElementTree.SubElement(root, _q("ssd", "Enumerations"))
        for tname in sorted(enumerations):
            enum = ElementTree.SubElement(enums, _q("ssc", "Enumeration"), {"name": tname})
            for item, value in enumerations[tname]:
                ElementTree.SubElement(enum, _q("ssc", "Item"),
                                       {"name": item, "value": value})
    if used_units:
        units = ElementTree.SubElement(root, _q("ssd", "Units"))
        for uname in sorted(used_units):
            unit = ElementTree.SubElement(units, _q("ssc", "Unit"), {"name": uname})
            ElementTree.SubElement(unit, _q("ssc", "BaseUnit"), used_units[uname])
    experiment = ElementTree.SubElement(root, _q("ssd", "DefaultExperiment"),
                                        {"startTime": _number_text(start),
                                         "stopTime": _number_text(stop)})
    notes = ElementTree.SubElement(experiment, _q("ssd", "Annotations"))
    osp = ElementTree.SubElement(notes, _q("ssc", "Annotation"), {"type": OSP_ANNOTATION})
    algo = ElementTree.SubElement(osp, _q("osp", "Algorithm"))
    ElementTree.SubElement(algo, _q("osp", "FixedStepAlgorithm"),
                           {"baseStepSize": _number_text(step)})
    ours = ElementTree.SubElement(notes, _q("ssc", "Annotation"), {"type": AGV_ANNOTATION})
    exp = ElementTree.SubElement(ours, _q("agv", "Experiment"),
                                 {"algorithm": algorithm, "stepSize": _number_text(step)})
    if record_interval is not None:
        exp.set("recordInterval", _number_text(record_interval))
    for item in record or ():
        ElementTree.SubElement(exp, _q("agv", "Record"), {"variable": item})
    ElementTree.indent(root)
    return root


def export_ssp(manifest_path, out_path, variant=None, sets=()):
    """Write one run of a manifest as a self-contained SSP 1.0 package.

    Parameters
    ----------
    manifest_path : path
        The experiment manifest (TOML).
    out_path : path
        The ``.ssp`` file to write (replaced atomically).
    variant : str, optional
        The variant to export; required when the manifest declares more than one.
    sets : iterable of str
        ``comp.param=VALUE`` overrides, as for ``agv-cosim run --set``.

    Returns
    -------
    Path
        ``out_path``.

    Raises
    ------
    ManifestError
        A manifest problem, or a manifest that expands to more than one run.
    """
    manifest = load_manifest(manifest_path)
    runs = plan_runs(manifest, [variant] if variant else None, sets)
    if len(runs) != 1:
        key = "sweep" if manifest.sweep else "variants"
        raise ManifestError(manifest.path, key, f"expands to {len(runs)} runs; an SSP "
                            "package holds one (choose --variant, remove the sweep or fix "
                            "it with --set)")
    checked = validate(manifest, runs)
    run, models = runs[0], checked.models[0]
    params = {c: dict(comp.parameters) for c, comp in run.components.items()}
    for cname, values in params.items():
        for pname, value in values.items():
            if isinstance(value, tuple):
                raise ManifestError(manifest.path, f"components.{cname}.parameters.{pname}",
                                    "an FMI 3.0 array parameter cannot be written to an "
                                    "SSP package (SSP parameters are scalars)")
    name = manifest.name + (f"_{run.variant}" if run.variant else "")
    root = build_ssd(name, models, params, manifest.connections, manifest.start,
                     manifest.stop, manifest.step, manifest.algorithm, checked.record,
                     manifest.record_interval, manifest.description)
    out_path = Path(out_path)
    if out_path.is_dir():
        raise OutputError(f"{out_path}: is a folder; give the name of the .ssp file to "
                          "write")
    try:
        out_path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise OutputError(f"{out_path}: cannot create '{error.filename or out_path.parent}'"
                          f": {error.strerror}") from None
    partial = out_path.with_name(out_path.name + ".partial")
    try:
        with zipfile.ZipFile(partial, "w", zipfile.ZIP_DEFLATED) as archive:
            archive.writestr(SSD_NAME, ElementTree.tostring(root, encoding="utf-8",
                                                            xml_declaration=True))
            written = set()
            for cname, source in _fmu_file_names(models).items():
                if source not in written:
                    archive.write(models[cname].path, source)
                    written.add(source)
        partial.replace(out_path)
    finally:
        partial.unlink(missing_ok=True)
    return out_path


# ---------------------------------------------------------------------------- import
def _unsafe_reason(info):
    name = info.filename
    if stat.S_ISLNK(info.external_attr >> 16):
        return "a symbolic link"
    if name.startswith(("/", "\\")) or re.match(r"^[A-Za-z]:", name):
        return "an absolute path"
    if ".." in re.split(r"[\\/]", name):
        return "a '..' path"
    return None


def safe_extract(archive_path, dest):
    """Extract a zip archive into ``dest`` after checking every entry.

    Raises
    ------
    SspError
        For an unreadable archive, or an entry with an absolute path, a drive letter,
        a ``..`` component or a symbolic link (nothing is extracted then).
    """
    try:
        with zipfile.ZipFile(archive_path) as archive:
            entries = archive.infolist()
            for info in entries:
                reason = _unsafe_reason(info)
                if reason:
                    raise SspError(archive_path, "archive", f"refused: entry "
                                   f"'{info.filename}' is {reason}")
            dest = Path(dest).resolve()
            for info in entries:
                target = (dest / info.filename).resolve()
                if dest != target and dest not in target.parents:
                    raise SspError(archive_path, "archive",
                                   f"refused: entry '{info.filename}' leaves the folder")
            archive.extractall(dest)
    except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError, OSError) as error:
        raise SspError(archive_path, "archive", f"not a readable zip archive: {error}") \
            from None


def _float_attr(package, key, node, attr, default=None):
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


def _parse_value(package, key, node):
    """(type, value, unit or None) of an ssv:Parameter."""
    kind = next((child for child in node if child.tag in
                 [_q("ssv", t) for t in _TYPES]), None)
    if kind is None:
        raise SspError(package, key, "no ssv:Real/Integer/Boolean/String value "
                       "(Enumeration and Binary are not supported)")
    vtype = kind.tag.split("}")[1]
    text = kind.get("value")
    if text is None:
        raise SspError(package, key, "missing attribute 'value'")
    ftype = fmitypes.lookup("2.0", vtype)  # SSP's type names are FMI 2.0's
    unit = kind.get("unit") if ftype.is_float else None
    try:
        value = fmitypes.parse_text(ftype, text)
        if ftype.is_float and not math.isfinite(value):
            raise ValueError(text)
    except ValueError:
        raise SspError(package, key, f"{text!r} is not a valid {vtype}") from None
    return vtype, value, unit


#: SI base units of FMI 2.0 / SSP unit definitions (exponents).
_BASE = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")


def _unit_of(package, key, attrs):
    """(exponents, factor, offset) of a BaseUnit attribute dict."""
    try:
        exponents = tuple(int(attrs.get(b, 0)) for b in _BASE)
        factor = float(attrs.get("factor", 1.0))
        offset = float(attrs.get("offset", 0.0))
    except ValueError:
        raise SspError(package, key, f"malformed BaseUnit {attrs}") from None
    if not (math.isfinite(factor) and factor != 0.0 and math.isfinite(offset)):
        raise SspError(package, key, f"BaseUnit factor/offset {attrs} is not usable")
    return exponents, factor, offset


def _units(package, holder, prefix):
    """Unit name -> (exponents, factor, offset) of ``holder``'s ``<prefix>:Units``."""
    units = {}
    for unit in holder.iterfind(f"{prefix}:Units/ssc:Unit", NS):
        base = unit.find("ssc:BaseUnit", NS)
        units[unit.get("name")] = _unit_of(package, f"Unit '{unit.get('name')}'",
                                           base.attrib if base is not None else {})
    return units


def _bindings(package, base, element, key, ssd_units):
    """The parameter values bound on ``element`` (ssd:System or ssd:Component), in order.

    Returns a list of (name, type, value, unit, unit definition or None, key). Every
    binding of SSP 1.0 is read: inline ssd:ParameterValues or a ``source`` .ssv file
    in the package, with its ``prefix``; what we cannot apply exactly is refused.
    """
    found = []
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
        if source:
            url = urlparse(source)
            path = None if url.scheme or url.netloc else _inside(base, unquote(url.path))
            if path is None or not path.is_file():
                raise SspError(package, bkey, f"source '{source}' is not a file in the "
                               "package")
            try:
                pset = ElementTree.parse(path).getroot()
            except ElementTree.ParseError as error:
                raise SspError(package, bkey, f"{source}: not well-formed XML: {error}") \
                    from None
            if pset.tag != _q("ssv", "ParameterSet"):
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


def _convert(package, where, value, unit, definition, var, fmu_units):
    """``value`` in ``unit`` converted to the unit of the FMU variable ``var``."""
    if unit is None or (unit == var.unit and (definition is None
                                              or var.unit not in fmu_units)):
        return value
    if definition is None:
        raise SspError(package, where, f"unit '{unit}' has no ssc:Unit definition (in the "
                       "parameter set or the SSD), so it cannot be converted to "
                       f"[{var.unit or '1'}]")
    if var.unit is None:
        target = ((0,) * len(_BASE), 1.0, 0.0)
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


def _inside(base, relative):
    target = (base / relative).resolve()
    return target if base == target or base in target.parents else None


def _component(package, base, node, ssd_units):
    cname = node.get("name")
    key = f"Component '{cname}'"
    if not cname or not _IDENTIFIER.match(cname):
        raise SspError(package, key, "component names must be identifiers "
                       "([A-Za-z_][A-Za-z0-9_]*, used as 'component.variable')")
    kind = node.get("type", FMU_MIME)
    if kind != FMU_MIME:
        raise SspError(package, key, f"type '{kind}' is not supported (only FMUs)")
    if node.get("implementation", "any").lower() not in ("any", "cosimulation"):
        raise SspError(package, key, f"implementation '{node.get('implementation')}' is not "
                       "supported (only CoSimulation)")
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


def _check_connectors(package, cname, fmu, node):
    """Refuse connectors that do not match the FMU (we convert no connector units)."""
    from .model import ModelError, read_model

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
        var = info.variables.get(name)
        if var is None:
            raise SspError(package, key, f"not a variable of {info.model_name}")
        if kind not in (None, var.causality) and not (kind == "inout" and
                                                       var.causality in ("input", "output")):
            raise SspError(package, key, f"kind '{kind}', but the FMU's variable is "
                           f"{var.causality}")
        typed = next((child for child in connector if child.tag in
                      [_q("ssc", t) for t in _TYPES + ("Enumeration", "Binary")]), None)
        if typed is None:
            continue
        vtype = typed.tag.split("}")[1]
        if vtype != _ssp_type(var):
            raise SspError(package, key, f"type {vtype}, but the FMU's variable is "
                           f"{var.type}")
        unit = typed.get("unit")
        if unit is not None and unit != (var.unit or ""):
            raise SspError(package, key, f"unit '{unit}', but the FMU's variable is in "
                           f"[{var.unit or '1'}] (connector unit conversion is not "
                           "supported)")


def _bound_parameters(package, components, component_bound, system_bound):
    """Component -> {parameter: value in the FMU's unit}.

    Precedence (our reading of SSP 1.0): within one element, a later binding overrides
    an earlier one; a system binding (``component.parameter``) overrides the
    component's own.
    """
    from .model import ModelError, read_model

    chosen = {cname: {} for cname in components}
    for cname, bound in component_bound.items():
        for name, *rest in bound:
            chosen[cname][name] = rest
    for name, *rest in system_bound:
        where = rest[-1]
        cname, dot, pname = name.partition(".")
        if not dot:
            raise SspError(package, where, f"'{name}' names no component (a parameter of "
                           "the system itself is not supported; use 'component.parameter')")
        if cname not in components:
            raise SspError(package, where, f"unknown component '{cname}' in '{name}'")
        chosen[cname][pname] = rest
    params = {}
    for cname, values in chosen.items():
        params[cname] = {}
        if not values:
            continue
        try:
            info = read_model(components[cname])
        except ModelError as error:
            raise SspError(package, f"Component '{cname}'", str(error)) from None
        fmu_units = {}
        if any(unit is not None for _, _, unit, _, _ in values.values()):
            defs = _unit_definitions(info.path)
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


def read_ssd(package, ssd_path):
    """Translate an SSD into the data of a manifest (a plain dict, TOML-shaped).

    Raises
    ------
    SspError
        For a malformed SSD or anything we do not support (see the module docstring).
    """
    ssd_path = Path(ssd_path)
    base = ssd_path.parent.resolve()
    try:
        root = ElementTree.parse(ssd_path).getroot()
    except ElementTree.ParseError as error:
        raise SspError(package, SSD_NAME, f"not well-formed XML: {error}") from None
    except OSError:
        raise SspError(package, SSD_NAME, "missing (not an SSP package)") from None
    if root.tag != _q("ssd", "SystemStructureDescription"):
        raise SspError(package, SSD_NAME, "root is not ssd:SystemStructureDescription "
                       "(SSP 1.0)")
    system = root.find("ssd:System", NS)
    if system is None:
        raise SspError(package, "System", "missing")
    for tag, what in (("SignalDictionaries", "signal dictionaries"),):
        if system.find(f"ssd:{tag}", NS) is not None:
            raise SspError(package, f"System: {tag}", f"{what} are not supported")
    components, connections, bound = {}, [], {}
    ssd_units = _units(package, root, "ssd")
    elements = system.find("ssd:Elements", NS)
    for node in (elements if elements is not None else []):
        tag = node.tag.split("}")[-1]
        if tag != "Component":
            raise SspError(package, f"Elements: {tag} '{node.get('name')}'",
                           "only Component elements are supported (no nested systems or "
                           "signal dictionaries)")
        cname, fmu, bound[cname] = _component(package, base, node, ssd_units)
        if cname in components:
            raise SspError(package, f"Component '{cname}'", "name used twice")
        _check_connectors(package, cname, fmu, node)
        components[cname] = fmu
    if not components:
        raise SspError(package, "System: Elements", "no components")
    params = _bound_parameters(package, components, bound,
                               _bindings(package, base, system, "System", ssd_units))
    components = {cname: {"fmu": str(fmu), "parameters": params[cname]}
                  for cname, fmu in components.items()}
    for node in system.iterfind("ssd:Connections/ssd:Connection", NS):
        ends = [node.get(a) for a in ("startElement", "startConnector", "endElement",
                                      "endConnector")]
        key = f"Connection {ends[0]}.{ends[1]} -> {ends[2]}.{ends[3]}"
        if not ends[0] or not ends[2]:
            raise SspError(package, key, "connections to the system's own connectors are "
                           "not supported")
        if not ends[1] or not ends[3] or "." in ends[1] + ends[3]:
            raise SspError(package, key, "connector names must be non-empty and without "
                           "'.' (used as 'component.variable')")
        if len(node):
            raise SspError(package, key, f"{node[0].tag.split('}')[-1]} is not supported")
        connections.append({"from": f"{ends[0]}.{ends[1]}", "to": f"{ends[2]}.{ends[3]}"})

    experiment = root.find("ssd:DefaultExperiment", NS)
    if experiment is None:
        raise SspError(package, "DefaultExperiment", "missing (start, stop and step are "
                       "needed)")
    start = _float_attr(package, "DefaultExperiment", experiment, "startTime", 0.0)
    if experiment.get("stopTime") is None:
        raise SspError(package, "DefaultExperiment", "no stopTime")
    stop = _float_attr(package, "DefaultExperiment", experiment, "stopTime")
    step, algorithm, record, interval = None, "jacobi", None, None
    for note in experiment.iterfind("ssd:Annotations/ssc:Annotation", NS):
        if note.get("type") == OSP_ANNOTATION and step is None:
            fixed = note.find("osp:Algorithm/osp:FixedStepAlgorithm", NS)
            if fixed is not None:
                step = _float_attr(package, "osp:FixedStepAlgorithm", fixed, "baseStepSize")
        elif note.get("type") == AGV_ANNOTATION:
            ours = note.find("agv:Experiment", NS)
            if ours is not None:
                algorithm = ours.get("algorithm", algorithm)
                if ours.get("stepSize"):
                    step = _float_attr(package, "agv:Experiment", ours, "stepSize")
                if ours.get("recordInterval"):
                    interval = _float_attr(package, "agv:Experiment", ours, "recordInterval")
                record = [r.get("variable") for r in ours.iterfind("agv:Record", NS)] or None
    if step is None:
        raise SspError(package, "DefaultExperiment", "no step size (an "
                       "osp:FixedStepAlgorithm annotation with baseStepSize is needed)")
    simulation = {"start": start, "stop": stop, "step": step, "algorithm": algorithm}
    name = root.get("name") if root.get("name") is not None else system.get("name")
    if name is None:
        name = Path(package).stem
    try:
        check_name(name, "system name")
    except ValueError as error:
        raise SspError(package, "SystemStructureDescription", f"{error} (it names the "
                       "default output folder results/<name>)") from None
    data = {"name": name,
            "description": system.get("description", ""),
            "simulation": simulation, "components": components, "connections": connections}
    if record or interval is not None:
        data["record"] = {}
        if record:
            data["record"]["variables"] = record
        if interval is not None:
            data["record"]["interval"] = interval
    return data


def _toml_value(value):
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return '"' + "".join(c if c.isprintable() and c not in '"\\' else
                             f"\\u{ord(c):04x}" for c in value) + '"'
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {value!r} as TOML")


def manifest_toml(data):
    """TOML text of a manifest given as the dict :func:`read_ssd` returns."""
    lines = [f"name = {_toml_value(data['name'])}",
             f"description = {_toml_value(data.get('description', ''))}", "",
             "[simulation]"]
    lines += [f"{k} = {_toml_value(v)}" for k, v in data["simulation"].items()]
    for cname, comp in data["components"].items():
        # names are data: written as quoted, escaped TOML strings, never pasted
        table = f"components.{_toml_value(cname)}"
        lines += ["", f"[{table}]", f"fmu = {_toml_value(comp['fmu'])}"]
        if comp["parameters"]:
            lines.append(f"[{table}.parameters]")
            lines += [f"{_toml_value(k)} = {_toml_value(v)}"
                      for k, v in comp["parameters"].items()]
    for conn in data["connections"]:
        lines += ["", "[[connections]]", f"from = {_toml_value(conn['from'])}",
                  f"to = {_toml_value(conn['to'])}"]
    if data.get("record"):
        lines += ["", "[record]"]
        lines += [f"{k} = {_toml_value(v)}" for k, v in data["record"].items()]
    return "\n".join(lines) + "\n"


def load_ssp_as_manifest(path, workdir):
    """Unpack an SSP package into ``workdir`` and write the equivalent manifest there.

    Parameters
    ----------
    path : path
        An ``.ssp`` archive, or an unpacked package folder, or its ``.ssd`` file.
    workdir : path
        Folder to unpack into (must outlive the run: the manifest points at the FMUs
        in it).

    Returns
    -------
    Path
        The manifest (``workdir/<system name>.toml``), ready for
        :func:`agv_cosim.runner.prepare`.

    Raises
    ------
    SspError
        Unsafe archive entries, a malformed SSD, or an unsupported SSP feature.
    """
    path, workdir = Path(path), Path(workdir)
    if not path.exists():
        raise SspError(path, "file", "not found")
    if path.is_dir():
        ssd = path / SSD_NAME
    elif path.suffix.lower() == ".ssd":
        ssd = path
    else:
        unpacked = workdir / "package"
        unpacked.mkdir(parents=True, exist_ok=True)
        safe_extract(path, unpacked)
        ssd = unpacked / SSD_NAME
    data = read_ssd(path, ssd)
    stem = re.sub(r"[^A-Za-z0-9._-]", "_", data["name"]) or "ssp"
    manifest = workdir / f"{stem}.toml"
    manifest.write_text(manifest_toml(data), encoding="utf-8")
    return manifest


def is_ssp(path):
    """True when ``path`` names an SSP package (``.ssp`` file or ``.ssd``)."""
    return path is not None and Path(str(path)).suffix.lower() in (".ssp", ".ssd")


@contextlib.contextmanager
def ssp_manifest(path):
    """Context: the manifest to run for ``path``.

    A manifest path (or None) is yielded unchanged; an SSP package is unpacked into a
    temporary folder that is removed when the context ends, and the generated manifest
    is yielded.
    """
    if not is_ssp(path):
        yield path
        return
    work = scratch_dir("ssp")
    manifest = Path(work) / "?"
    try:
        manifest = load_ssp_as_manifest(path, work)
        yield str(manifest)
    except ManifestError as error:
        if error.manifest not in (str(manifest), str(path)):
            raise
        # an error in the package or in the manifest made from it: name the package and
        # the entries in it, never our temporary files
        package = str((Path(work) / "package").resolve()) + "/"
        problem = error.problem.replace(package, f"{path}!/")
        raise SspError(path, error.key, problem) from None
    finally:
        shutil.rmtree(work, ignore_errors=True)


# ---------------------------------------------------------------------------- libcosim
def run_libcosim(ssp_path, variables, step=None, stop=None, start=0.0):
    """Run an SSP package in libcosim (libcosimpy) and return recorded time series.

    Parameters
    ----------
    ssp_path : path
        The ``.ssp`` package.
    variables : list of str
        ``component.variable`` Real variables to record.
    step, stop : float, optional
        Macro step and stop time [s] (default: read from the package's SSD).
    start : float
        Start time [s] of the package (libcosim reads it from the SSD; used here only to
        turn step numbers into times).

    Returns
    -------
    (numpy.ndarray, dict of str -> numpy.ndarray)
        Times [s] t_k = start + k step for k = 0 ... n and the values libcosim observed
        at them (after the step that ended at t_k; k = 0 after initialisation).
    """
    import numpy as np
    from libcosimpy import _internal
    from libcosimpy.CosimEnums import CosimVariableType
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver

    if step is None or stop is None:
        work = scratch_dir("ssp")
        try:
            unpacked = Path(work)
            safe_extract(ssp_path, unpacked)
            data = read_ssd(ssp_path, unpacked / SSD_NAME)
        finally:
            shutil.rmtree(work, ignore_errors=True)
        step = data["simulation"]["step"] if step is None else step
        stop = data["simulation"]["stop"] if stop is None else stop
        start = data["simulation"]["start"]
    step_ns = int(round(step * 1e9))
    n_steps = int(round((stop - start) / step))
    log_output_level(CosimLogLevel.WARNING)
    try:
        execution = CosimExecution.from_ssp_file(str(ssp_path), step_size=step_ns)
    except AssertionError:
        raise RuntimeError(f"libcosim: {_internal.get_last_error_message()}") from None
    observer = CosimObserver.create_time_series(buffer_size=n_steps + 2)
    execution.add_observer(observer)
    infos = {}
    for item in variables:
        cname, vname = item.split(".")
        index = execution.slave_index_from_instance_name(cname)
        if cname not in infos:
            infos[cname] = {v.name.decode(): v.reference
                            for v in execution.slave_variables(index)}
        ref = infos[cname][vname]
        observer.start_time_series(index, ref, CosimVariableType.REAL)
        infos.setdefault("_refs", {})[item] = (index, ref)
    if not execution.step(n_steps):
        raise RuntimeError(f"libcosim: {_internal.get_last_error_message()}")
    series = {}
    times = start + np.arange(n_steps + 1) * step
    for item in variables:
        index, ref = infos["_refs"][item]
        # libcosimpy trims its result by counting step numbers equal to 0 (taken as empty
        # slots), so a request that includes step 0 loses its newest sample: read step 0
        # (with one sample more, then trimmed back to one) and steps 1.. separately
        column = np.full(n_steps + 1, np.nan)
        for first, count in ((0, 2), (1, n_steps)):
            _, steps, values = observer.time_series_real_samples(index, ref, from_step=first,
                                                                 sample_count=count)
            steps = np.asarray(steps, dtype=int)
            keep = steps <= n_steps if first else steps == 0
            column[steps[keep]] = np.asarray(values)[keep]
        if np.isnan(column).any():
            missing = int(np.flatnonzero(np.isnan(column))[0])
            raise RuntimeError(f"libcosim: no sample of {item} at step {missing}")
        series[item] = column
    return times, series


# ---------------------------------------------------------------------------- CLI
def _cmd_export_ssp(args):
    with ssp_manifest(args.manifest) as manifest:
        out = export_ssp(manifest, args.output, args.variant, args.set)
    print(out)
    return 0


def add_cli(subparsers):
    """Register ``agv-cosim export-ssp`` on the CLI's subparsers."""
    parser = subparsers.add_parser(
        "export-ssp", help="write one run of a manifest as an SSP 1.0 package",
        description="Write one run (one variant, no sweep) of a manifest as a "
                    "self-contained SSP 1.0 package: SystemStructure.ssd (components, "
                    "connectors with units, connections, parameter values, default "
                    "experiment with the fixed step libcosim reads) and the FMUs under "
                    "resources/.")
    parser.add_argument("manifest", help="experiment manifest (TOML)")
    parser.add_argument("--variant", metavar="NAME", help="the variant to export")
    parser.add_argument("--set", action="append", default=[], metavar="COMP.PARAM=VALUE",
                        help="override a parameter (repeatable)")
    parser.add_argument("-o", "--output", required=True, metavar="FILE.ssp",
                        help="the package to write")
    parser.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                        help="show tracebacks on errors")
    parser.set_defaults(func=_cmd_export_ssp)
    return parser


if __name__ == "__main__":  # pragma: no cover - manual use
    sys.exit("use: agv-cosim export-ssp MANIFEST -o FILE.ssp")
