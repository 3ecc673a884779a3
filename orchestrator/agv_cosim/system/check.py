"""The runs' components checked as one system.

:func:`validate` reads each component's model description (or time table) and checks,
for every planned run (a :class:`~agv_cosim.plan.RunSpec` of an
:class:`~agv_cosim.plan.Experiment`, what the runs of a manifest share), the parameter
values against the variables (name, causality, type, range), the run's connections
(output -> input, same type, same unit, one driver per input), the events, and the
recorded signals;
:func:`~agv_cosim.system.order.feedthrough_order` finds the Gauss-Seidel schedule. A
problem in a variant's run names the variant. The result is a
:class:`~agv_cosim.system.checked.Checked`.
"""

import math
from collections.abc import Callable, Iterable
from typing import Any, TypeVar

from .. import fmitypes
from ..errors import ManifestError, ModelError, TableError, did_you_mean
from ..manifest import Component, Connection, Variant, split_name, whole_multiple
from ..manifest.load import step_multiple
from ..plan import Experiment, RunSpec
from .checked import Checked, CheckedRun, Event
from .files import file_problem
from .interface import select_interface
from .model import ModelInfo, read_model
from .order import feedthrough_order
from .table import read_table

_T = TypeVar("_T")

__all__ = ["check_connections", "check_events", "check_parameters", "check_run",
           "raise_all", "read_models", "validate"]


def check_events(experiment: Experiment, run: RunSpec, models: dict[str, ModelInfo],
                 targets: dict[tuple[str, str], Connection]) -> list[Event]:
    """The run's events, checked, sorted by step (then by the manifest's order).

    An event sets, exactly at a communication point, a tunable parameter or an input
    that no connection drives (a connection would overwrite it at once); the value is
    checked like a parameter's (:func:`agv_cosim.fmitypes.parse`).
    """
    err = experiment.error
    resolved = []
    for name, event in run.events.items():
        key = f"events.{name}"
        at = event.at
        if at is None or not event.set:
            raise err(key, "an event needs 'at' and 'set'")
        if isinstance(at, bool) or not isinstance(at, (int, float)) or not math.isfinite(at):
            raise err(f"{key}.at", f"{at!r} is not a number")
        at = float(at)
        if not experiment.start <= at <= experiment.stop:
            raise err(f"{key}.at", f"{at!r} s is outside the run ({experiment.start!r} .. "
                      f"{experiment.stop!r} s)")
        k = experiment.step_index(at)
        if at != experiment.start and not whole_multiple(at - experiment.start, experiment.step):
            raise err(f"{key}.at", f"{at!r} s is not a communication point (start + k * "
                      f"{experiment.step!r} s)")
        sets = [_event_value(experiment, models, targets, f"{key}.set.{target}", target,
                             value) for target, value in event.set.items()]
        for cname, vname, _ in sets:
            _on_its_grid(experiment, run, f"{key}.at", at, k, cname, vname)
        resolved.append(Event(k=k, at=at, name=name, sets=tuple(sets)))
    position = {name: i for i, name in enumerate(run.events)}
    resolved.sort(key=lambda e: (e.k, position[e.name]))
    return resolved


def _on_its_grid(experiment: Experiment, run: RunSpec, key: str, at: float, k: int,
                 cname: str, vname: str) -> None:
    """Refuse an event that sets a variable of a component with its own ``step`` at a
    time that is not one of that component's communication points (start + j step, or
    the stop time): between its points the FMU is already at its next one."""
    step = run.components[cname].step
    multiple = step_multiple(step, experiment.step) if step is not None else None
    last = experiment.step_index(experiment.stop)
    if multiple is None or multiple == 1 or k % multiple == 0 or k == last:
        return
    raise experiment.error(key, f"{at!r} s is not a communication point of component "
                         f"'{cname}' (its step is {step!r} s), whose '{vname}' the event "
                         "sets")


def _event_value(experiment: Experiment, models: dict[str, ModelInfo],
                 targets: dict[tuple[str, str], Connection], vkey: str, target: str,
                 value: Any) -> tuple[str, str, Any]:
    """One value an event sets, ``target`` = ``value``, checked (see
    :func:`check_events`): ``(component, variable, value parsed)``."""
    err = experiment.error
    cname, vname = split_name(target)
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
        parsed = fmitypes.parse(var.ftype, value, var)
    except ValueError as error:
        raise err(vkey, f"'{target}' {error}") from None
    problem = file_problem(parsed, experiment.files_dir)
    if problem:
        raise err(vkey, f"'{target}': {problem}")
    return cname, vname, parsed


def read_models(experiment: Experiment, run: RunSpec) -> dict[str, ModelInfo]:
    """Each component's model description (or time table) of ``run``, by instance name."""
    err = experiment.error
    models: dict[str, ModelInfo] = {}
    for cname, comp in run.components.items():
        if comp.table is not None:
            try:
                models[cname] = read_table(comp.table, comp.interpolation, comp.units)
            except TableError as error:
                raise err(run.component_key(cname, "table"), str(error)) from None
            continue
        if comp.fmu is None:  # the manifest gives an FMU or a table (checked there)
            raise err(f"components.{cname}.fmu", "missing")
        try:
            models[cname] = read_model(comp.fmu)
        except ModelError as error:
            raise err(run.component_key(cname), str(error)) from None
        try:
            models[cname] = select_interface(models[cname], comp.interface, comp.solver,
                                             comp.tolerance)
        except ModelError as error:
            raise err(_interface_key(run, cname, comp), str(error)) from None
    return models


def _interface_key(run: RunSpec, cname: str, comp: Component) -> str:
    """The key named when a component's interface, solver or tolerance cannot be
    honoured: the first of them that it gives (the variant's, when it gives it), else
    its ``fmu``."""
    for what in ("interface", "solver", "tolerance"):
        if getattr(comp, what) is not None:
            return run.component_key(cname, what)
    return run.component_key(cname)


def check_parameters(experiment: Experiment, run: RunSpec,
                     models: dict[str, ModelInfo]) -> dict[str, dict[str, Any]]:
    """The run's parameter values parsed against their variables (name, causality, type,
    range), per component; ``run`` is left as it is. Raises the first problem found,
    the others in its ``others``."""
    err = experiment.error
    problems: list[ManifestError] = []
    parsed: dict[str, dict[str, Any]] = {}
    for cname, comp in run.components.items():
        info = models[cname]
        values: dict[str, Any] = {}
        for pname, value in comp.parameters.items():
            key = run.parameter_key(cname, pname)
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
                continue
            unreadable = file_problem(values[pname], experiment.files_dir)
            if unreadable:
                problems.append(err(key, f"'{cname}.{pname}': {unreadable}"))
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
    for one in found:
        one.others = []
    if found:
        first = found[0]
        first.others = found[1:]
        raise first


def _collect(problems: list[ManifestError], check: Callable[..., _T], *args: Any) -> _T | None:
    """``check(*args)``, or None with its problem appended to ``problems``."""
    try:
        return check(*args)
    except ManifestError as problem:
        problems.append(problem)
        return None


def check_connections(experiment: Experiment, models: dict[str, ModelInfo],
                      connections: Iterable[Connection] | None = None
                      ) -> dict[tuple[str, str], Connection]:
    """Every connection (of ``connections``, default the base's) checked (output ->
    input, same type, same unit, one driver per input); returns the connected inputs,
    ``(component, variable)`` -> connection."""
    problems: list[ManifestError] = []
    targets: dict[tuple[str, str], Connection] = {}
    for conn in experiment.connections if connections is None else connections:
        _collect(problems, _check_connection, experiment, models, conn, targets)
    raise_all(problems)
    return targets


def _check_connection(experiment: Experiment, models: dict[str, ModelInfo], conn: Connection,
                      targets: dict[tuple[str, str], Connection]) -> None:
    """One connection checked (see :func:`check_connections`), its input added to
    ``targets``."""
    err = experiment.error
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
        driven, first = ".".join(conn.target), targets[conn.target].key
        hint = ""
        if conn.key.startswith("variants.") and not first.startswith("variants."):
            variant = conn.key.split(".")[1]
            hint = (f" (to replace it, list '{driven}' in variants.{variant}."
                    "disconnect)")
        raise err(f"{conn.key}.to", f"input '{driven}' is already connected by "
                  f"{first}{hint}")
    targets[conn.target] = conn


def _check_sweep(experiment: Experiment, models: dict[str, ModelInfo]) -> None:
    for name in experiment.sweep:
        if name.startswith("events."):
            continue
        cname, _ = split_name(name)
        if cname not in models:
            raise experiment.error(f"sweep.{name}", f"unknown component '{cname}'"
                                   f"{did_you_mean(cname, models)}")


def check_run(experiment: Experiment, run: RunSpec) -> tuple[CheckedRun, list[str]]:
    """One run checked as a system; with the names of its unconnected inputs. Raises
    the first problem found, the others (of the parameters, the sweep, the connections,
    then the events) in its ``others``.

    A problem of a variant's run names the variant: its own keys
    (``variants.<name>...``) do, and a problem at a key of the base gets
    ``variant '<name>': `` before it (the base's line kept)."""
    try:
        return _check_run(experiment, run)
    except ManifestError as error:
        first = _in_variant(experiment, run.spec, error)
        first.others = [_in_variant(experiment, run.spec, other) for other in error.others]
        raise first from None


def _check_run(experiment: Experiment, run: RunSpec) -> tuple[CheckedRun, list[str]]:
    models = read_models(experiment, run)
    problems: list[ManifestError] = []
    parameters = _collect(problems, check_parameters, experiment, run, models)
    _collect(problems, _check_sweep, experiment, models)
    targets = _collect(problems, check_connections, experiment, models, run.connections)
    events = None if targets is None else \
        _collect(problems, check_events, experiment, run, models, targets)  # needs targets
    raise_all(problems)
    assert parameters is not None and targets is not None and events is not None
    try:
        order = feedthrough_order(models, run.connections, experiment.path,
                                  experiment.algorithm)
    except ManifestError as error:  # placed at the line of its key
        raise experiment.error(error.key, error.problem) from None
    record = _record_list(experiment, models)
    unconnected = [f"{c}.{v.name}" for c, info in models.items() for v in info.inputs
                   if (c, v.name) not in targets]
    return CheckedRun(run=run, models=models, parameters=parameters, order=order,
                      events=events, record=record), unconnected


def _in_variant(experiment: Experiment, spec: Variant | None,
                error: ManifestError) -> ManifestError:
    """``error`` of a run of the variant ``spec`` naming the variant (unchanged for a
    base run or a key of the variant's own)."""
    if spec is None:
        return error
    variant = spec.name
    own = f"variants.{variant}"
    if error.key == own or error.key.startswith((f"{own}.", f"{own}[")):
        return error
    replaced = spec.replaced
    hint = ""
    index = error.key.removeprefix("connections[").partition("]")[0]
    if error.key.startswith("connections[") and index.isdigit() and \
            int(index) < len(experiment.connections):
        conn = experiment.connections[int(index)]
        touched = [c for c in (conn.source[0], conn.target[0]) if c in replaced]
        if touched:
            hint = (f"; variants.{variant} replaces '{touched[0]}': disconnect = "
                    f"[\"{'.'.join(conn.target)}\"] there drops this connection")
    parts = error.key.split(".")
    if len(parts) > 3 and parts[0] == "components" and parts[2] == "parameters" and \
            parts[1] in replaced:
        hint = (f"; variants.{variant} replaces '{parts[1]}' but keeps the base's "
                f"parameters (remove = [\"{parts[1]}\"] and add a new '{parts[1]}' to "
                "start without them)")
    out = ManifestError(error.manifest, error.key, f"variant '{variant}': "
                        f"{error.problem}{hint}", error.line)
    out.others = error.others
    return out


def validate(experiment: Experiment, runs: list[RunSpec],
             extra_signals: Iterable[tuple[str, Iterable[str]]] = ()) -> Checked:
    """Check every run against the FMUs' model descriptions.

    ``extra_signals``: ``(key, signal names)`` that every run must record (the
    ``[metrics]`` and ``[plots]`` signals, named by ``key`` in a message).

    Returns
    -------
    Checked
        Per run its models, parsed parameters, Gauss-Seidel order, events and recorded
        variables (``[record] variables``, else every numeric output of the run's
        components); the warnings (unconnected inputs).

    Raises
    ------
    ManifestError
        Missing or broken FMU, unknown component / variable / parameter, wrong
        causality, type or unit mismatch, an input connected twice, a sweep over a
        non-parameter, an algebraic loop, a record or metrics/plots signal that is not
        recorded; in a variant's run, naming the variant.
    """
    checked: list[CheckedRun] = []
    #: unconnected inputs -> the variants (None: the base) whose runs leave them so
    unconnected_by: dict[tuple[str, ...], list[str | None]] = {}
    sources = [(source, list(names)) for source, names in extra_signals]
    #: each problem as the base's keys give it -> (the problem, the variants it is in)
    found: dict[str, tuple[ManifestError, list[str | None]]] = {}
    specs = {run.variant: run.spec for run in runs}
    for run in runs:
        problems: list[ManifestError] = []
        try:
            one, unconnected = _check_run(experiment, run)
        except ManifestError as error:  # the other runs' problems are reported too
            problems = [error, *error.others]
            error.others = []
        else:
            if unconnected:
                leaving = unconnected_by.setdefault(tuple(unconnected), [])
                if run.variant not in leaving:
                    leaving.append(run.variant)
            recorded = set(one.record)
            problems = [experiment.error(source, f"signal '{name}' is not recorded (see "
                                         "[record])")
                        for source, names in sources for name in names
                        if name not in recorded]
            checked.append(one)
        for problem in problems:
            having = found.setdefault(str(problem), (problem, []))[1]
            if run.variant not in having:
                having.append(run.variant)
    every = list(dict.fromkeys(run.variant for run in runs))
    # the same problem in the runs of every variant (two or more) is the base's, said once;
    # else once per variant, naming it
    raise_all([one for problem, having in found.values()
               for one in ([problem] if having == every and len(every) > 1 else
                           [_in_variant(experiment, specs[variant], problem)
                            for variant in having])])
    held = _check_held(experiment, checked)
    warnings = []
    for inputs, variants in unconnected_by.items():
        inputs = tuple(name for name in inputs if name not in held)
        if not inputs:
            continue
        where = "" if variants == every or variants == [None] else \
            " in variant(s) " + ", ".join(str(v) for v in variants)
        warnings.append(f"{experiment.path}: connections: unconnected inputs{where} (held at "
                        f"their start values): {', '.join(inputs)}")
    return Checked(runs=checked, warnings=warnings)


def _check_held(experiment: Experiment, checked: list[CheckedRun]) -> set[str]:
    """The manifest's ``held`` names, each checked to be an input of its component in
    some run (a variant that rewires may connect it), or, when only some variants run, in
    some variant of the manifest (the list holds every variant's unconnected inputs);
    raises a :class:`ManifestError` naming the first that is not."""
    problems = []
    others: list[dict[str, ModelInfo]] | None = None
    for index, name in enumerate(experiment.held):
        cname, vname = split_name(name)
        models = [one.models[cname] for one in checked if cname in one.models]
        if vname not in {v.name for info in models for v in info.inputs}:
            if others is None:
                others = _other_variants_models(experiment, checked)
            models += [one[cname] for one in others if cname in one]
        if not models:
            known = sorted({c for one in checked for c in one.models})
            problems.append(experiment.error(f"held[{index}]", f"'{name}': unknown component "
                                             f"'{cname}'{did_you_mean(cname, known)}"))
            continue
        inputs = list(dict.fromkeys(v.name for info in models for v in info.inputs))
        if vname not in inputs:
            problems.append(experiment.error(
                f"held[{index}]", f"'{name}' is not an input of '{cname}' (its inputs: "
                f"{', '.join(inputs) or 'none'})"))
    raise_all(problems)
    return set(experiment.held)


def _other_variants_models(experiment: Experiment,
                           checked: list[CheckedRun]) -> list[dict[str, ModelInfo]]:
    """The models of each declared variant that none of ``checked`` runs (one run each;
    a variant whose FMUs cannot be read is left out: it is not being run)."""
    running = {one.run.variant for one in checked}
    models = []
    for variant in experiment.variants:
        if variant in running:
            continue
        try:
            run = experiment.plan_variant(variant)
            models.append(read_models(experiment, run))
        except ManifestError:
            continue
    return models


def _article(causality: str) -> str:
    return ("an " if causality[0] in "aeiou" else "a ") + causality


def _record_list(experiment: Experiment, models: dict[str, ModelInfo]) -> list[str]:
    if experiment.record is None:
        return [f"{c}.{v.name}" for c, info in models.items() for v in info.outputs
                if not v.unsupported("record") and v.ftype.numeric]
    for i, name in enumerate(experiment.record):
        cname, vname = split_name(name)
        key = f"record.variables[{i}]"
        if cname not in models:
            raise experiment.error(key, f"unknown component '{cname}'"
                                   f"{did_you_mean(cname, models)}")
        var = models[cname].variables.get(vname)
        if var is None:
            outputs = [v.name for v in models[cname].outputs]
            raise experiment.error(key, f"unknown variable '{name}'"
                                   f"{did_you_mean(vname, outputs)}")
        if var.causality != "output":
            raise experiment.error(key, f"'{name}' is not an output (it is "
                                   f"{_article(var.causality)} {var.type})")
        why = var.unsupported("record")
        if why:
            raise experiment.error(key, f"'{name}' is {why}")
    return list(experiment.record)
