"""Stage 3 of the pipeline, the system: the runs' components checked as one system.

:func:`validate` reads each component's model description (or time table) and checks,
for every planned run, the parameter values against the variables (name, causality, type,
range), the connections (output -> input, same type, same unit, one driver per input),
the events, and the recorded signals; :func:`feedthrough_order` finds the Gauss-Seidel
schedule with :mod:`graphlib` (an algebraic loop is refused, its cycle named). The
result, :class:`Checked`, is what the runner turns into one :class:`agv_cosim.master.Plan` per run.
"""

import graphlib
import heapq
import math
from dataclasses import dataclass, field

from . import fmitypes
from .manifest import Component, ManifestError, split_name, whole_multiple
from .model import ModelError, read_model
from .table import TableError, read_table


def _parameter_key(manifest, run, cname, pname):
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


def _fmu_key(manifest, run, cname):
    if run.variant:
        sub = manifest.variants[run.variant]["components"].get(cname)
        if sub is not None and sub.fmu is not None:
            return f"variants.{run.variant}.components.{cname}.fmu"
    return f"components.{cname}.fmu"


def feedthrough_order(models, connections, manifest_path="manifest",
                      algorithm="gauss-seidel"):
    """Gauss-Seidel order of the components, or raise on an algebraic loop.

    Parameters
    ----------
    models : dict
        Instance name -> :class:`~agv_cosim.model.ModelInfo`.
    connections : list of Connection
    manifest_path : path
        For the messages.
    algorithm : {"gauss-seidel", "jacobi"}
        Jacobi needs no order: components that feed each other without a variable loop
        are then accepted (in manifest order); an algebraic loop is refused for both.

    Returns
    -------
    list of str
        Instance names in topological order of the direct-feedthrough graph: an edge
        A -> B exists when a connection runs from an output of A that depends directly
        on an input of A to an input of B. Ties keep the manifest's order.
    """
    # variable-level graph: input -> feedthrough output (inside an FMU), output -> input;
    # graphlib takes each node with its predecessors, so a reported cycle runs forwards
    variables = graphlib.TopologicalSorter()
    for cname, info in models.items():
        for out, deps in info.dependencies.items():
            for inp in deps:
                variables.add((cname, out), (cname, inp))
    for conn in connections:
        variables.add(conn.target, conn.source)
    try:
        variables.prepare()
    except graphlib.CycleError as error:
        names = " -> ".join(".".join(v) for v in _rotated(error.args[1]))
        raise ManifestError(manifest_path, "connections",
                            f"algebraic loop (a cycle of direct feedthrough): {names}") from None
    names = list(models)
    components = graphlib.TopologicalSorter({n: set() for n in names})
    for conn in connections:
        src, dst = conn.source[0], conn.target[0]
        if models[src].dependencies.get(conn.source[1]) and src != dst:
            components.add(dst, src)
    try:
        components.prepare()
    except graphlib.CycleError as error:
        if algorithm == "jacobi":  # Jacobi needs no order: every FMU reads, then sets
            return names
        cycle = " -> ".join(_rotated(error.args[1], key=names.index))
        raise ManifestError(manifest_path, "connections",
                            f"components {cycle} feed each other through feedthrough "
                            "outputs (no algebraic loop between variables, but a single "
                            "Gauss-Seidel pass cannot order them); use algorithm = 'jacobi'"
                            ) from None
    # ties keep the manifest's order: always take the first ready component (a heap of
    # manifest positions: linear-logarithmic in the number of components)
    position = {name: i for i, name in enumerate(names)}
    order, ready = [], []
    while components.is_active():
        for node in components.get_ready():
            heapq.heappush(ready, position[node])
        node = names[heapq.heappop(ready)]
        order.append(node)
        components.done(node)
    return order


def _rotated(cycle, key=None):
    """A cycle ``[a, b, ..., a]`` started at its smallest node (a stable message)."""
    ring = list(cycle[:-1])
    first = ring.index(min(ring, key=key))
    ring = ring[first:] + ring[:first]
    return ring + ring[:1]


@dataclass
class Checked:
    """The result of :func:`validate`: models per run, GS orders, record list, warnings."""

    runs: list
    models: list
    orders: list
    record: list
    warnings: list
    events: list = field(default_factory=list)  # per run: see _check_events


def _check_events(manifest, run, models, targets):
    """The run's events, checked: ``[(step index, time, name, [(comp, var, value)])]``.

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
        k = 0 if at == manifest.start else round((at - manifest.start) / manifest.step)
        if at != manifest.start and not whole_multiple(at - manifest.start, manifest.step):
            raise err(f"{key}.at", f"{at!r} s is not a communication point (start + k * "
                      f"{manifest.step!r} s)")
        sets = []
        for target, value in event["set"].items():
            cname, vname = split_name(target)
            vkey = f"{key}.set.{target}"
            if cname not in models:
                raise err(vkey, f"unknown component '{cname}'")
            var = models[cname].variables.get(vname)
            if var is None:
                raise err(vkey, f"unknown variable '{target}'")
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
        resolved.append((k, at, name, sets))
    position = {name: i for i, name in enumerate(run.events)}
    resolved.sort(key=lambda e: (e[0], position[e[2]]))
    return resolved


def validate(manifest, runs, extra_signals=()):
    """Check every run against the FMUs' model descriptions.

    Returns
    -------
    Checked
        Models and Gauss-Seidel order per run, the recorded variables (of the first run;
        identical for all) and warnings (unconnected inputs).

    Raises
    ------
    ManifestError
        Missing or broken FMU, unknown component / variable / parameter, wrong
        causality, type or unit mismatch, an input connected twice, a sweep over a
        non-parameter, an algebraic loop, a record or metrics/plots signal that is not
        recorded.
    """
    err = manifest.error
    models_per_run, orders, warnings, record, events_per_run = [], [], [], None, []
    for run in runs:
        models = {}
        for cname, comp in run.components.items():
            if comp.table is not None:
                try:
                    models[cname] = read_table(comp.table, comp.interpolation, comp.units)
                except TableError as error:
                    raise err(f"components.{cname}.table", str(error)) from None
                continue
            try:
                models[cname] = read_model(comp.fmu)
            except ModelError as error:
                raise err(_fmu_key(manifest, run, cname), str(error)) from None
        for cname, comp in run.components.items():
            info = models[cname]
            for pname, value in comp.parameters.items():
                key = _parameter_key(manifest, run, cname, pname)
                var = info.variables.get(pname)
                if var is None:
                    known = ", ".join(v.name for v in info.parameters)
                    raise err(key, f"unknown parameter '{pname}' of {cname} "
                              f"({info.model_name}; parameters: {known})")
                if var.causality != "parameter":
                    raise err(key, f"'{cname}.{pname}' is {_article(var.causality)}, "
                              "not a parameter")
                why = var.unsupported("parameter")
                if why:
                    raise err(key, f"'{cname}.{pname}' is {why}")
                try:
                    comp.parameters[pname] = (
                        fmitypes.parse_array(var.ftype, value, var.size, var) if var.dims
                        else fmitypes.parse(var.ftype, value, var))
                except ValueError as error:
                    problem = str(error)
                    if problem.startswith("is "):
                        problem = f"type mismatch: '{cname}.{pname}' {problem}"
                    else:
                        problem = f"'{cname}.{pname}' {problem}"
                    raise err(key, problem) from None
        for name in manifest.sweep:
            if name.startswith("events."):
                continue
            cname, pname = split_name(name)
            if cname not in models:
                raise err(f"sweep.{name}", f"unknown component '{cname}'")
        targets = {}
        for conn in manifest.connections:
            ends = []
            for side, (cname, vname), want in (("from", conn.source, "output"),
                                              ("to", conn.target, "input")):
                key = f"{conn.key}.{side}"
                if cname not in models:
                    raise err(key, f"unknown component '{cname}'")
                var = models[cname].variables.get(vname)
                if var is None:
                    known = ", ".join(v.name for v in models[cname].of_causality(want))
                    raise err(key, f"unknown variable '{cname}.{vname}' of "
                              f"{models[cname].model_name} ({want}s: {known})")
                if var.causality != want:
                    raise err(key, f"wrong causality: '{cname}.{vname}' is "
                              f"{_article(var.causality)}, a connection goes output -> input")
                ends.append(var)
            src, dst = ends
            for (cname, _), var in zip((conn.source, conn.target), ends):
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
        events_per_run.append(_check_events(manifest, run, models, targets))
        orders.append(feedthrough_order(models, manifest.connections, manifest.path,
                                        manifest.algorithm))
        unconnected = [f"{c}.{v.name}" for c, info in models.items() for v in info.inputs
                       if (c, v.name) not in targets]
        if unconnected:
            message = (f"{manifest.path}: connections: unconnected inputs (held at their "
                       f"start values): {', '.join(unconnected)}")
            if message not in warnings:
                warnings.append(message)
        this_record = _record_list(manifest, models)
        if record is None:
            record = this_record
        elif this_record != record:
            raise err(_first_fmu_key(manifest, run), "this variant records other variables "
                      "than the base (an FMU with other outputs); list record.variables")
        models_per_run.append(models)
    recorded = set(record or ())
    for source, names in extra_signals:
        for name in names:
            if name not in recorded:
                raise err(source, f"signal '{name}' is not recorded (see [record])")
    return Checked(runs=runs, models=models_per_run, orders=orders, record=record or [],
                   warnings=warnings, events=events_per_run)


def _first_fmu_key(manifest, run):
    return f"variants.{run.variant}" if run.variant else "components"


def _article(causality):
    return ("an " if causality[0] in "aeiou" else "a ") + causality


def _record_list(manifest, models):
    if manifest.record is None:
        return [f"{c}.{v.name}" for c, info in models.items() for v in info.outputs
                if not v.unsupported("record") and v.ftype.numeric]
    for i, name in enumerate(manifest.record):
        cname, vname = split_name(name)
        key = f"record.variables[{i}]"
        if cname not in models:
            raise manifest.error(key, f"unknown component '{cname}'")
        var = models[cname].variables.get(vname)
        if var is None:
            raise manifest.error(key, f"unknown variable '{name}'")
        if var.causality != "output":
            raise manifest.error(key, f"'{name}' is not an output (it is "
                                 f"{_article(var.causality)} {var.type})")
        why = var.unsupported("record")
        if why:
            raise manifest.error(key, f"'{name}' is {why}")
    return list(manifest.record)
