"""SSP 1.0 export: one run of a manifest, as a package libcosim (and others) can run.

Export (:func:`export_ssp`, ``agv-cosim export-ssp MANIFEST [--variant NAME] -o FILE.ssp``)
writes one run of a manifest (one variant, no sweep) as a self-contained SSP 1.0 archive,
with that run's components and wiring (a variant that adds, removes or rewires components
is exported as the system it runs: one package per variant; a time-table component or a
scenario event, which SSP 1.0 cannot hold, is refused, naming the variant)::

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
what SSP has no place for: our master algorithm, the recorded variables, the record
interval and the manifest's ``[metrics]`` and ``[plots]`` tables (``agv:Metrics``,
``agv:Plots``: each table as JSON text; a path string is carried as written, a file it
names is not packed). Other tools ignore it. A component with a ``step`` of its own
(multirate) carries it in an ``org.agv-cosim`` annotation of its ``ssd:Component``
(``agv:Component stepSize``), which our import reads back, and in libcosim's
``com.opensimulationplatform`` one (``osp:StepSizeHint value``), from which libcosim
steps it at that step (its decimation factor); other tools ignore both and step the
component at the base step. A component run through an FMU's Model Exchange interface
carries SSP's ``implementation="ModelExchange"`` (``"CoSimulation"`` for one of an FMU
with both interfaces run as co-simulation) and an ``org.agv-cosim`` annotation of its
own, ``agv:Integration`` (solver, tolerance), in the same ``ssd:Annotations``.
"""

import json
import os
import tempfile
import zipfile
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

from .. import fmitypes
from ..errors import ManifestError, OutputError
from ..files import user_mode
from ..manifest import Manifest, load_manifest
from ..manifest.load import component_steps
from ..plan import Experiment, Override, plan_runs
from ..system import CheckedRun, ModelInfo, validate
from .common import (
    AGV_ANNOTATION,
    FMU_MIME,
    OSP_ANNOTATION,
    SSD_NAME,
    TYPES,
    model_description,
    number_text,
    q,
    ssp_type,
    unit_definitions,
)


def _enumeration_types(fmu_path: str | Path) -> dict[str, tuple[str, list[tuple[str, str]]]]:
    """``{variable name: (type name, [(item name, value text)])}`` of the Enumeration
    variables of an FMU (FMI 2.0 ``SimpleType``/``Enumeration``, FMI 3.0
    ``EnumerationType``, both as fmpy reads them)."""
    found: dict[str, tuple[str, list[tuple[str, str]]]] = {}
    for var in model_description(fmu_path).modelVariables:
        declared = var.declaredType
        if var.type == "Enumeration" and declared is not None:
            found[var.name] = (declared.name, [(item.name, str(item.value))
                                               for item in declared.items or ()])
    return found


def _fmu_file_names(models: dict[str, ModelInfo]) -> dict[str, str]:
    """Instance name -> ``resources/<file>`` (one entry per distinct FMU file)."""
    by_hash: dict[str, str] = {}
    names: dict[str, str] = {}
    taken: set[str] = set()
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


def _as_written(table: Any) -> dict[str, Any] | None:
    """A ``[metrics]`` / ``[plots]`` table as the manifest wrote it (keys it left out stay
    out), or None."""
    return None if table is None else table.model_dump(exclude_unset=True)


def _write_interface(comp: ElementTree.Element, info: ModelInfo) -> None:
    """The FMI interface a component runs through, on its ``ssd:Component``: SSP's
    ``implementation`` ("ModelExchange" or "CoSimulation") for an FMU that declares Model
    Exchange (an FMU with co-simulation only keeps SSP's default, "any"); an integrated
    one's solver and tolerance, which SSP has no place for, in an ``org.agv-cosim``
    annotation (``agv:Integration``) that our import reads back and other tools ignore."""
    if "model-exchange" not in info.interfaces:
        return
    integration = info.integration
    comp.set("implementation", "CoSimulation" if integration is None else "ModelExchange")
    if integration is None:
        return
    notes = comp.find(q("ssd", "Annotations"))
    if notes is None:
        notes = ElementTree.SubElement(comp, q("ssd", "Annotations"))
    ours = ElementTree.SubElement(notes, q("ssc", "Annotation"), {"type": AGV_ANNOTATION})
    ElementTree.SubElement(ours, q("agv", "Integration"),
                           {"solver": integration.solver,
                            "tolerance": number_text(integration.tolerance)})


def build_ssd(name: str, models: dict[str, ModelInfo], parameters: dict[str, dict[str, Any]],
              connections: list[Any], start: float, stop: float, step: float,
              algorithm: str, record: list[str] | None = None,
              record_interval: float | None = None,
              description: str = "", metrics: dict[str, Any] | None = None,
              plots: dict[str, Any] | None = None,
              steps: dict[str, float] | None = None) -> ElementTree.Element:
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
    steps : dict, optional
        Instance name -> its own communication step [s] (a multirate component),
        written as an ``org.agv-cosim`` annotation of the component (``agv:Component
        stepSize``).
    """
    sources = _fmu_file_names(models)
    root = ElementTree.Element(q("ssd", "SystemStructureDescription"),
                               {"name": name, "version": "1.0"})
    system = ElementTree.SubElement(root, q("ssd", "System"), {"name": name})
    if description:
        system.set("description", description)
    elements = ElementTree.SubElement(system, q("ssd", "Elements"))
    declared = _Declared()
    for cname, info in models.items():
        comp = ElementTree.SubElement(elements, q("ssd", "Component"),
                                      {"name": cname, "source": sources[cname],
                                       "type": FMU_MIME})
        _write_connectors(comp, cname, info, declared)
        _write_parameters(comp, cname, info, parameters.get(cname) or {})
        if steps and cname in steps:  # a multirate component's own step
            _write_own_step(comp, steps[cname])
        _write_interface(comp, info)
    _write_connections(system, connections)
    _write_declared(root, declared)
    _write_experiment(root, start, stop, step, algorithm, record, record_interval,
                      {"Metrics": metrics, "Plots": plots})
    ElementTree.indent(root)
    return root


@dataclass
class _Declared:
    """What the components' connectors use, declared once for the whole SSD: units
    (name -> BaseUnit attributes) and SSP enumerations (name -> [(item, value text)])."""

    units: dict[str, dict[str, str]] = field(default_factory=dict)
    enumerations: dict[str, list[tuple[str, str]]] = field(default_factory=dict)


def _write_connectors(comp: ElementTree.Element, cname: str, info: ModelInfo,
                      declared: _Declared) -> None:
    """The ``ssd:Connectors`` of a component: every scalar input and output of an SSP
    type, with its type (an enumeration named), and its unit; what they use goes into
    ``declared``."""
    connectors = ElementTree.SubElement(comp, q("ssd", "Connectors"))
    fmu_units = None
    fmu_enums = None
    for var in info.variables.values():
        if var.causality not in ("input", "output") or \
                ssp_type(var) not in TYPES + ("Enumeration",):
            continue
        node = ElementTree.SubElement(connectors, q("ssd", "Connector"),
                                      {"name": var.name, "kind": var.causality})
        kind = ElementTree.SubElement(node, q("ssc", str(ssp_type(var))))
        if ssp_type(var) == "Enumeration":
            if fmu_enums is None:
                fmu_enums = _enumeration_types(info.path)
            kind.set("name", _enumeration_name(cname, var.name, fmu_enums, declared))
        if var.unit:
            kind.set("unit", var.unit)
            if var.unit not in declared.units:
                if fmu_units is None:
                    fmu_units = unit_definitions(info.path)
                declared.units[var.unit] = fmu_units.get(var.unit, {})


def _enumeration_name(cname: str, vname: str,
                      fmu_enums: dict[str, tuple[str, list[tuple[str, str]]]],
                      declared: _Declared) -> str:
    """The SSP enumeration a connector names (required), declared in ``declared``: the
    FMU's type name, instance-qualified when another FMU's type of that name has other
    items."""
    tname, items = fmu_enums.get(vname) or (f"{cname}.{vname}", [])
    if declared.enumerations.get(tname, items) != items:
        tname = f"{cname}.{tname}"
    declared.enumerations[tname] = items
    return tname


def _write_parameters(comp: ElementTree.Element, cname: str, info: ModelInfo,
                      values: dict[str, Any]) -> None:
    """The component's parameter values, inline (``ssd:ParameterValues``), if any."""
    if not values:
        return
    bindings = ElementTree.SubElement(comp, q("ssd", "ParameterBindings"))
    binding = ElementTree.SubElement(bindings, q("ssd", "ParameterBinding"))
    holder = ElementTree.SubElement(binding, q("ssd", "ParameterValues"))
    pset = ElementTree.SubElement(holder, q("ssv", "ParameterSet"),
                                  {"version": "1.0", "name": f"{cname}"})
    plist = ElementTree.SubElement(pset, q("ssv", "Parameters"))
    for pname, value in values.items():
        var = info.variables[pname]
        param = ElementTree.SubElement(plist, q("ssv", "Parameter"), {"name": pname})
        attrs = {"value": fmitypes.format_text(var.ftype, value)}
        if var.ftype.is_float and var.unit:
            attrs["unit"] = var.unit
        ElementTree.SubElement(param, q("ssv", str(ssp_type(var))), attrs)


def _write_own_step(comp: ElementTree.Element, step: float) -> None:
    """A multirate component's own step, in libcosim's annotation (``osp:StepSizeHint``)
    and ours (``agv:Component stepSize``)."""
    notes = ElementTree.SubElement(comp, q("ssd", "Annotations"))
    hint = ElementTree.SubElement(notes, q("ssc", "Annotation"), {"type": OSP_ANNOTATION})
    ElementTree.SubElement(hint, q("osp", "StepSizeHint"), {"value": number_text(step)})
    note = ElementTree.SubElement(notes, q("ssc", "Annotation"), {"type": AGV_ANNOTATION})
    ElementTree.SubElement(note, q("agv", "Component"), {"stepSize": number_text(step)})


def _write_connections(system: ElementTree.Element, connections: list[Any]) -> None:
    conns = ElementTree.SubElement(system, q("ssd", "Connections"))
    for conn in connections:
        ElementTree.SubElement(conns, q("ssd", "Connection"), {
            "startElement": conn.source[0], "startConnector": conn.source[1],
            "endElement": conn.target[0], "endConnector": conn.target[1]})


def _write_declared(root: ElementTree.Element, declared: _Declared) -> None:
    """``ssd:Enumerations`` and ``ssd:Units`` (those used), each sorted by name."""
    if declared.enumerations:
        enums = ElementTree.SubElement(root, q("ssd", "Enumerations"))
        for tname in sorted(declared.enumerations):
            enum = ElementTree.SubElement(enums, q("ssc", "Enumeration"), {"name": tname})
            for item, value in declared.enumerations[tname]:
                ElementTree.SubElement(enum, q("ssc", "Item"),
                                       {"name": item, "value": value})
    if declared.units:
        units = ElementTree.SubElement(root, q("ssd", "Units"))
        for uname in sorted(declared.units):
            unit = ElementTree.SubElement(units, q("ssc", "Unit"), {"name": uname})
            ElementTree.SubElement(unit, q("ssc", "BaseUnit"), declared.units[uname])


def _write_experiment(root: ElementTree.Element, start: float, stop: float, step: float,
                      algorithm: str, record: list[str] | None,
                      record_interval: float | None,
                      tables: dict[str, dict[str, Any] | None]) -> None:
    """``ssd:DefaultExperiment``: start, stop, libcosim's fixed step annotation and ours
    (algorithm, step, record interval and variables, the manifest's tables as JSON)."""
    experiment = ElementTree.SubElement(root, q("ssd", "DefaultExperiment"),
                                        {"startTime": number_text(start),
                                         "stopTime": number_text(stop)})
    notes = ElementTree.SubElement(experiment, q("ssd", "Annotations"))
    osp = ElementTree.SubElement(notes, q("ssc", "Annotation"), {"type": OSP_ANNOTATION})
    algo = ElementTree.SubElement(osp, q("osp", "Algorithm"))
    ElementTree.SubElement(algo, q("osp", "FixedStepAlgorithm"),
                           {"baseStepSize": number_text(step)})
    ours = ElementTree.SubElement(notes, q("ssc", "Annotation"), {"type": AGV_ANNOTATION})
    exp = ElementTree.SubElement(ours, q("agv", "Experiment"),
                                 {"algorithm": algorithm, "stepSize": number_text(step)})
    if record_interval is not None:
        exp.set("recordInterval", number_text(record_interval))
    for item in record or ():
        ElementTree.SubElement(exp, q("agv", "Record"), {"variable": item})
    for tag, table in tables.items():
        if table:  # the manifest's [metrics] / [plots] table as JSON text
            ElementTree.SubElement(exp, q("agv", tag)).text = json.dumps(
                table, sort_keys=True)


def export_ssp(manifest: str | Path | Manifest, out_path: str | Path,
               variant: str | None = None, sets: Iterable[str | Override] = ()) -> Path:
    """Write one run of a manifest as a self-contained SSP 1.0 package.

    Parameters
    ----------
    manifest : path or Manifest
        The experiment manifest (a TOML file, or one already loaded, e.g. from an SSP
        package by :func:`agv_cosim.ssp.importer.opened`).
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
    if not isinstance(manifest, Manifest):
        manifest = load_manifest(manifest)
    runs = plan_runs(manifest, [variant] if variant else None, sets)
    if len(runs) != 1:
        key = "sweep" if manifest.sweep else "variants"
        choose = (f"choose --variant ({', '.join(manifest.variants)})"
                  if len(manifest.variants) > 1 and not variant else "choose --variant")
        raise manifest.error(key, f"expands to {len(runs)} runs; an SSP "
                            f"package holds one ({choose}, remove the sweep or fix "
                            "it with --set)")
    checked = validate(Experiment.of(manifest), runs)
    one = checked.runs[0]
    run, models = one.run, one.models
    _refuse_what_ssp_cannot_hold(manifest, one)
    params = {c: dict(values) for c, values in one.parameters.items()}
    for cname, values in params.items():
        for pname, value in values.items():
            if isinstance(value, tuple):
                raise manifest.error(f"components.{cname}.parameters.{pname}",
                                    "an FMI 3.0 array parameter cannot be written to an "
                                    "SSP package (SSP parameters are scalars)")
    name = manifest.name + (f"_{run.variant}" if run.variant else "")
    root = build_ssd(name, models, params, run.connections, manifest.start,
                     manifest.stop, manifest.step, manifest.algorithm, one.record,
                     manifest.record_interval, manifest.description,
                     _as_written(manifest.metrics), _as_written(manifest.plots),
                     component_steps(run.components, manifest.step))
    out_path = Path(out_path)
    if out_path.is_dir():
        raise OutputError(f"{out_path}: is a folder; give the name of the .ssp file to "
                          "write")
    try:
        out_path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise OutputError(f"{out_path}: cannot create '{error.filename or out_path.parent}'"
                          f": {error.strerror}") from None
    # a new file of our own beside the target (O_EXCL | O_NOFOLLOW), renamed over it
    handle, partial_name = tempfile.mkstemp(dir=out_path.parent, prefix=f".{out_path.name}.",
                                            suffix=".partial")
    partial = Path(partial_name)
    try:
        with os.fdopen(handle, "w+b") as stream, \
                zipfile.ZipFile(stream, "w", zipfile.ZIP_DEFLATED) as archive:
            archive.writestr(SSD_NAME, ElementTree.tostring(root, encoding="utf-8",
                                                            xml_declaration=True))
            written = set()
            for cname, source in _fmu_file_names(models).items():
                if source not in written:
                    archive.write(models[cname].path, source)
                    written.add(source)
        os.chmod(partial, user_mode(directory=False))  # mkstemp made it 0600
        partial.replace(out_path)
    finally:
        partial.unlink(missing_ok=True)
    return out_path


def _refuse_what_ssp_cannot_hold(manifest: Manifest, one: CheckedRun) -> None:
    """A time-table component (an SSP component is an FMU) or a scenario event (SSP 1.0
    has none) is refused, named by the variant's key when the variant gives it."""
    variant = one.run.variant
    changes = one.run.spec

    def refuse(own: str | None, base: str, problem: str) -> ManifestError:
        if own is not None:
            return manifest.error(own, problem)
        return manifest.error(base, (f"variant '{variant}': " if variant else "") + problem)

    for cname, info in one.models.items():
        if info.table is not None:
            sub = changes.components.get(cname) if changes else None
            own = f"variants.{variant}.components.{cname}.table" \
                if sub is not None and sub.table is not None else None
            raise refuse(own, f"components.{cname}.table", "a time table cannot be written "
                         "to an SSP package (SSP components are FMUs)")
    for event in one.events:
        own = f"variants.{variant}.events.{event.name}" \
            if changes and event.name in changes.events else None
        raise refuse(own, f"events.{event.name}", "a scenario event cannot be written to "
                     "an SSP package (SSP 1.0 has no events)")

