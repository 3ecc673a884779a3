"""The runs' components checked as one system.

:func:`validate` reads each component's model description (or time table) and checks,
for every planned run, the parameter values against the variables (name, causality, type,
range), the connections (output -> input, same type, same unit, one driver per input),
the events, and the recorded signals; :func:`~agv_cosim.system.order.feedthrough_order`
finds the Gauss-Seidel schedule. The result is a :class:`~agv_cosim.system.checked.Checked`.
"""

import math
from collections.abc import Iterable
from typing import Any

from .. import fmitypes
from ..errors import ManifestError, ModelError, TableError, did_you_mean
from ..manifest import Component, Connection, Manifest, split_name, whole_multiple
from ..plan import RunSpec
from .checked import Checked, CheckedRun, Event
from .model import ModelInfo, read_model
from .order import feedthrough_order
from .table import read_table

__all__ = ["check_connections", "check_events", "check_parameters", "check_run",
           "raise_all", "read_models", "validate"]


def _parameter_key(manifest: Manifest, run: RunSpec, cname: str, pname: str) -> str:
    full = f"{cname}.{pname}"
    if full in run.point:  # a sampled value is named by its [montecarlo] key
        sampled = manifest.montecarlo is not None and full in manifest.montecarlo.names
        return f"montecarlo.parameters.{full}" if sampled else f"sweep.{full}"
    if full in run.overrides:
        return "--set"
    if run.variant and pname in manifest.variants[run.variant]["components"].get(
            cname, Component(cname, None)).parameters:
        return f"variants.{run.variant}.components.{cname}.parameters.{pname}"
    return f"components.{cname}.parameters.{pname}"


def _fmu_key(manifest: Manifest, run: RunSpec, cname: str) -> str:
    if run.variant:
        sub = manifest.variants[run.variant]["components"].get(cname)
        if sub is not None and sub.fmu is not None:
            return f"variants.{run.variant}.components.{cname}.fmu"
    return f"components.{cname}.fmu"


def check_events(manifest: Manifest, run: RunSpec, models: dict[str, ModelInfo],
                 targets: dict[tuple[str, str], Connection]) -> list[Event]:
    """The run's events, checked, sorted by step (then by the manifest's order).

    An event sets, exactly at a communication point, a tunable parameter or an input
    that no connection drives (a connection would overwrite it at once); the value is
    checked like a parameter's (:func:`agv_cosim.fmitypes.parse`).
    """
    err = manifest.error
    resolved = []
    for name, event in run.events.items():
        key = f"events.{name}"
        at = event.get("at")
        if at is None or not event.get("set"):
            raise err(key, "an event needs 'at' and 'set'")
        if isinstance(at, bool) or not isinstance(at, (int, float)) or not math.isfinite(at):
            raise err(f"{key}.at", f"{at!r} is not a number")
        at = float(at)
        if not manifest.start <= at <= manifest.stop:
            raise err(f"{key}.at", f"{at!r} s is outside the run ({manifest.start!r} .. "
                      f"{manifest.stop!r} s)")
        k = manifest.step_index(at)
        if at != manifest.start and not whole_multiple(at - manifest.start, manifest.step):
            raise err(f"{key}.at", f"{at!r} s is not a communication point (start + k * "
                      f"{manifest.step!r} s)")
        sets = []
        for target, value in event["set"].items():
            cname, vname = split_name(target)
            vkey = f"{key}.set.{target}"
            if cname not in models:
                raise err(vkey, f"unknown component '{cname}'{did_you_mean(cname, models)}")
            var = models[cname].variables.get(vname)
            if var is None:
                raise err(vkey, f"unknown variable '{target}'"
                          f"{did_you_mean(vname, models[cname].variables)}")
            if var.causality == "parameter":
                if var.variability != "tunable":
                    raise err(vkey, f"'{target}' is a {var.variability} parameter (an "
                              "event can change only a tunable one)")
            elif var.causality == "input":
                if (cname, vname) in targets:
                    raise err(vkey, f"input '{target}' is driven by "
                              f"{targets[(cname, vname)].key} (an event can set only an "
                              "unconnected input)")
            else:
                raise err(vkey, f"'{target}' is {_article(var.causality)} (an event sets a "
                          "tunable parameter or an unconnected input)")
            why = var.unsupported()
            if why:
                raise err(vkey, f"'{target}' is {why}")
            try:
                sets.append((cname, vname, fmitypes.parse(var.ftype, value, var)))
            except ValueError as error:
                raise err(vkey, f"'{target}' {error}") from None
        resolved.append(Event(k=k, at=at, name=name, sets=tuple(sets)))
    position = {name: i for i, name in enumerate(run.events)}
    resolved.sort(key=lambda e: (e.k, position[e.name]))
    return resolved


def read_models(manifest: Manifest, run: RunSpec) -> dict[str, ModelInfo]:
    """Each component's model description (or time table) of ``run``, by instance name."""
    err = manifest.error
    models: dict[str, ModelInfo] = {}
    for cname, comp in run.components.items():
        if comp.table is not None:
            try:
                models[cname] = read_table(comp.table, comp.interpolation, comp.units)
            except TableError as error:
                raise err(f"components.{cname}.table", str(error)) from None
            continue
        if comp.fmu is None:  # the manifest gives an FMU or a table (checked there)
            raise err(f"components.{cname}.fmu", "missing")
        try:
            models[cname] = read_model(comp.fmu)
        except ModelError as error:
            raise err(_fmu_key(manifest, run, cname), str(error)) from None
    return models


def check_parameters(manifest: Manifest, run: RunSpec,
                     models: dict[str, ModelInfo]) -> dict[str, dict[str, Any]]:
    """The run's parameter values parsed against their variables (name, causality, type,
    range), per component; ``run`` is left as it is. Raises the first problem found,
    the others in its ``others``."""
    err = manifest.error
    problems: list[ManifestError] = []
    parsed: dict[str, dict[str, Any]] = {}
    for cname, comp in run.components.items():
        info = models[cname]
        values: dict[str, Any] = {}
        for pname, value in comp.parameters.items():
            key = _parameter_key(manifest, run, cname, pname)
            var = info.variables.get(pname)
            if var is None:
                names = [v.name for v in info.parameters]
                match = did_you_mean(pname, names)
                problems.append(err(key, f"unknown parameter '{pname}' of {cname} "
                                    f"({info.model_name}" + (f"){match}" if match else
                                    f"; parameters: {', '.join(names)})")))
                continue
            if var.causality != "parameter":
                problems.append(err(key, f"'{cname}.{pname}' is "
                                    f"{_article(var.causality)}, not a parameter"))
                continue
            why = var.unsupported("parameter")
            if why:
                problems.append(err(key, f"'{cname}.{pname}' is {why}"))
                continue
            try:
                values[pname] = (fmitypes.parse_array(var.ftype, value, var.size or 0, var)
                                 if var.dims else fmitypes.parse(var.ftype, value, var))
            except ValueError as error:
                problem = str(error)
                if problem.startswith("is "):
                    problem = f"type mismatch: '{cname}.{pname}' {problem}"
                else:
                    problem = f"'{cname}.{pname}' {problem}"
                problems.append(err(key, problem))
        parsed[cname] = values
    raise_all(problems)
    return parsed


def raise_all(problems: list[ManifestError]) -> None:
    """Raise the first of ``problems`` (if any) with the others, each once, in its
    ``others`` (the others of each flattened in): every problem reported at once."""
    found: list[ManifestError] = []
    seen: set[str] = set()
    for problem in problems:
        for one in [problem, *problem.others]:
            if str(one) not in seen:
                seen.add(str(one))
                found.append(one)
    if found:
        first = found[0]
        first.others = found[1:]
        raise first


def check_connections(manifest: Manifest,
                      models: dict[str, ModelInfo]) -> dict[tuple[str, str], Connection]:
    """Every connection checked (output -> input, same type, same unit, one driver per
    input); returns the connected inputs, ``(component, variable)`` -> connection."""
    err = manifest.error
    targets: dict[tuple[str, str], Connection] = {}
    for conn in manifest.connections:
        ends = []
        for side, (cname, vname), want in (("from", conn.source, "output"),
                                          ("to", conn.target, "input")):
            key = f"{conn.key}.{side}"
            if cname not in models:
                raise err(key, f"unknown component '{cname}'{did_you_mean(cname, models)}")
            var = models[cname].variables.get(vname)
            if var is None:
                names = [v.name for v in models[cname].of_causality(want)]
                match = did_you_mean(vname, names)
                raise err(key, f"unknown variable '{cname}.{vname}' of "
                          f"{models[cname].model_name}"
                          + (match or f" ({want}s: {', '.join(names)})"))
            if var.causality != want:
                raise err(key, f"wrong causality: '{cname}.{vname}' is "
                          f"{_article(var.causality)}, a connection goes output -> input")
            ends.append(var)
        src, dst = ends
        for (cname, _), var in zip((conn.source, conn.target), ends, strict=True):
            why = var.unsupported()
            if why:
                raise err(conn.key, f"'{cname}.{var.name}' is {why}")
        if not fmitypes.compatible(src.ftype, dst.ftype):
            raise err(conn.key, f"type mismatch: {conn.source[0]}.{src.name} is "
                      f"{src.type}, {conn.target[0]}.{dst.name} is {dst.type} (no "
                      "implicit conversion)")
        # no unit and "1" both mean dimensionless (third-party FMUs often omit it)
        if (src.unit or "1") != (dst.unit or "1"):
            raise err(conn.key, f"unit mismatch: {conn.source[0]}.{src.name} is "
                      f"[{src.unit}], {conn.target[0]}.{dst.name} is [{dst.unit}]")
        if conn.target in targets:
            raise err(f"{conn.key}.to", f"input '{'.'.join(conn.target)}' is already "
                      f"connected by {targets[conn.target].key}")
        targets[conn.target] = conn
    return targets


def _check_sweep(manifest: Manifest, models: dict[str, ModelInfo]) -> None:
    for name in manifest.sweep:
        if name.startswith("events."):
            continue
        cname, _ = split_name(name)
        if cname not in models:
            raise manifest.error(f"sweep.{name}", f"unknown component '{cname}'"
                                 f"{did_you_mean(cname, models)}")


def check_run(manifest: Manifest, run: RunSpec) -> tuple[CheckedRun, list[str]]:
    """One run checked as a system; with the names of its unconnected inputs. Raises
    the first problem found, the others (of the parameters, the sweep, the
    connections, then the events) in its ``others``."""
    models = read_models(manifest, run)
    problems: list[ManifestError] = []
    parameters: dict[str, dict[str, Any]] = {}
    targets: dict[tuple[str, str], Connection] | None = None
    for stage in ("parameters", "sweep", "connections"):
        try:
            if stage == "parameters":
                parameters = check_parameters(manifest, run, models)
            elif stage == "sweep":
                _check_sweep(manifest, models)
            else:
                targets = check_connections(manifest, models)
        except ManifestError as problem:
            problems.append(problem)
    if targets is None:  # the events need the connected inputs
        raise_all(problems)
    assert targets is not None
    try:
        events = check_events(manifest, run, models, targets)
    except ManifestError as problem:
        problems.append(problem)
    raise_all(problems)
    try:
        order = feedthrough_order(models, manifest.connections, manifest.path,
                                  manifest.algorithm)
    except ManifestError as error:  # placed at the line of its key
        raise manifest.error(error.key, error.problem) from None
    unconnected = [f"{c}.{v.name}" for c, info in models.items() for v in info.inputs
                   if (c, v.name) not in targets]
    return CheckedRun(run=run, models=models, parameters=parameters, order=order,
                      events=events), unconnected


def validate(manifest: Manifest, runs: list[RunSpec],
             extra_signals: Iterable[tuple[str, Iterable[str]]] = ()) -> Checked:
    """Check every run against the FMUs' model descriptions.

    ``extra_signals``: ``(key, signal names)`` that must be recorded (the ``[metrics]``
    and ``[plots]`` signals, named by ``key`` in a message).

    Returns
    -------
    Checked
        Per run its models, parsed parameters, Gauss-Seidel order and events; the
        recorded variables (the same for every run) and the warnings (unconnected
        inputs).

    Raises
    ------
    ManifestError
        Missing or broken FMU, unknown component / variable / parameter, wrong
        causality, type or unit mismatch, an input connected twice, a sweep over a
        non-parameter, an algebraic loop, a record or metrics/plots signal that is not
        recorded.
    """
    checked: list[CheckedRun] = []
    warnings: list[str] = []
    record: list[str] | None = None
    problems: list[ManifestError] = []
    for run in runs:
        try:
            one, unconnected = check_run(manifest, run)
        except ManifestError as problem:  # the others runs' problems are reported too
            problems.append(problem)
            continue
        if unconnected:
            message = (f"{manifest.path}: connections: unconnected inputs (held at their "
                       f"start values): {', '.join(unconnected)}")
            if message not in warnings:
                warnings.append(message)
        this_record = _record_list(manifest, one.models)
        if record is None:
            record = this_record
        elif this_record != record:
            raise manifest.error(_first_fmu_key(manifest, run), "this variant records "
                                 "other variables than the base (an FMU with other "
                                 "outputs); list record.variables")
        checked.append(one)
    raise_all(problems)
    recorded = set(record or ())
    for source, names in extra_signals:
        for name in names:
            if name not in recorded:
                problems.append(manifest.error(source, f"signal '{name}' is not recorded "
                                               "(see [record])"))
    raise_all(problems)
    return Checked(runs=checked, record=record or [], warnings=warnings)


def _first_fmu_key(manifest: Manifest, run: RunSpec) -> str:
    return f"variants.{run.variant}" if run.variant else "components"


def _article(causality: str) -> str:
    return ("an " if causality[0] in "aeiou" else "a ") + causality


def _record_list(manifest: Manifest, models: dict[str, ModelInfo]) -> list[str]:
    if manifest.record is None:
        return [f"{c}.{v.name}" for c, info in models.items() for v in info.outputs
                if not v.unsupported("record") and v.ftype.numeric]
    for i, name in enumerate(manifest.record):
        cname, vname = split_name(name)
        key = f"record.variables[{i}]"
        if cname not in models:
            raise manifest.error(key, f"unknown component '{cname}'"
                                 f"{did_you_mean(cname, models)}")
        var = models[cname].variables.get(vname)
        if var is None:
            outputs = [v.name for v in models[cname].outputs]
            raise manifest.error(key, f"unknown variable '{name}'"
                                 f"{did_you_mean(vname, outputs)}")
        if var.causality != "output":
            raise manifest.error(key, f"'{name}' is not an output (it is "
                                 f"{_article(var.causality)} {var.type})")
        why = var.unsupported("record")
        if why:
            raise manifest.error(key, f"'{name}' is {why}")
    return list(manifest.record)
