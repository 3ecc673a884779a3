"""Experiment manifests (TOML): loading, run expansion and validation.

The format is documented, key by key, in ``experiments/example.toml`` and
``experiments/FORMAT.md``. :func:`load_manifest` checks the syntax and the numbers;
:func:`plan_runs` expands variants x sweep points (applying ``--variant`` / ``--set``);
:func:`validate` checks every run against the FMUs' model descriptions. Every problem is a
:class:`ManifestError` whose text is ``<manifest>: <key>: <problem>``.

Parameter precedence for one run: FMU default < ``[components.X.parameters]`` < the
variant's parameters < ``--set`` < the sweep point (a ``--set`` on a swept parameter is an
error).
"""

import copy
import hashlib
import itertools
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from . import fmitypes
from .model import ModelError, read_model
from .table import TableError, read_table
from .results import check_name

ALGORITHMS = ("gauss-seidel", "jacobi")
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_TOP_KEYS = {"name", "description", "simulation", "components", "connections", "variants",
             "sweep", "record", "metrics", "plots", "events",
             "montecarlo"}  # issue 16: parsed by agv_cosim.montecarlo


#: Most macro steps of one run: 2**53, where k step stops being exact in a double.
MAX_STEPS = float(2 ** 53)


def whole_multiple(span, step):
    """True when ``span`` is n * ``step`` for a whole n >= 1, up to rounding.

    The tolerance is absolute in steps: 1e-9 of a step, plus the rounding error of the
    division (4 ulp per step counted), so a long run cannot hide half a step behind a
    relative tolerance (500000.5 steps is not 500000).
    """
    steps = span / step
    n = round(steps)
    return n >= 1 and abs(steps - n) <= 1e-9 + 4 * 2.220446049250313e-16 * n


class ManifestError(Exception):
    """A problem in a manifest, named by the manifest, the key and the culprit."""

    def __init__(self, manifest, key, problem):
        super().__init__(f"{manifest}: {key}: {problem}")
        self.manifest, self.key, self.problem = str(manifest), key, problem


@dataclass
class Component:
    """One component instance: its FMU and the parameter values the manifest gives, or a
    time table (``table``, see :mod:`agv_cosim.table`)."""

    name: str
    fmu: Path
    parameters: dict = field(default_factory=dict)
    table: Path = None
    interpolation: dict = field(default_factory=dict)
    units: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Connection:
    """``source`` output -> ``target`` input, both ``(component, variable)``."""

    source: tuple
    target: tuple
    key: str

    def __str__(self):
        return f"{'.'.join(self.source)} -> {'.'.join(self.target)}"


@dataclass
class Manifest:
    """A parsed manifest (before variants and sweeps are applied)."""

    path: Path
    sha256: str
    name: str
    description: str
    start: float
    stop: float
    step: float
    algorithm: str
    components: dict
    connections: list
    variants: dict
    sweep: dict
    record: list | None
    record_interval: float
    metrics: dict
    plots: dict
    events: dict = field(default_factory=dict)  # name -> {"at": s, "set": {"c.v": value}}
    montecarlo: object = None  # issue 16: a montecarlo.MonteCarlo, or None

    def error(self, key, problem):
        return ManifestError(self.path, key, problem)


@dataclass
class RunSpec:
    """One run: the resolved components of a variant at one sweep point."""

    label: str
    variant: str | None
    point: dict
    components: dict
    overrides: dict
    events: dict = field(default_factory=dict)


def _number(manifest, table, key, prefix, default=None):
    value = table.get(key, default)
    full = f"{prefix}.{key}" if prefix else key
    if value is None:
        raise ManifestError(manifest, full, "missing (a number is required)")
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ManifestError(manifest, full, f"{value!r} is not a number")
    if not math.isfinite(value):
        raise ManifestError(manifest, full, f"{value!r} is not finite")
    return float(value)


def _table(manifest, data, key, required=False):
    value = data.get(key)
    if value is None:
        if required:
            raise ManifestError(manifest, key, "missing table")
        return {}
    if not isinstance(value, dict):
        raise ManifestError(manifest, key, f"must be a table, not {type(value).__name__}")
    return value


def _dotted(manifest, key, text, what="component.variable"):
    if not isinstance(text, str) or text.count(".") != 1:
        raise ManifestError(manifest, key, f"{text!r} is not of the form '{what}'")
    left, right = text.split(".")
    if not left or not right:
        raise ManifestError(manifest, key, f"{text!r} is not of the form '{what}'")
    return left, right


def _component(manifest, base_dir, name, table, key):
    if not isinstance(table, dict):
        raise ManifestError(manifest, key, "must be a table with 'fmu' and 'parameters'")
    unknown = set(table) - {"fmu", "parameters", "table", "interpolation", "units"}
    if unknown:
        raise ManifestError(manifest, f"{key}.{sorted(unknown)[0]}", "unknown key "
                            "(allowed: fmu, parameters; table, interpolation, units)")
    if "table" in table:
        if "fmu" in table or "parameters" in table:
            raise ManifestError(manifest, f"{key}.table", "a component is an FMU or a "
                                "table, not both")
        if not isinstance(table["table"], str):
            raise ManifestError(manifest, f"{key}.table", f"{table['table']!r} is not a path")
        for sub in ("interpolation", "units"):
            if not isinstance(table.get(sub, {}), dict):
                raise ManifestError(manifest, f"{key}.{sub}", "must be a table")
        return Component(name, None, {}, table=(base_dir / table["table"]).resolve(),
                         interpolation=dict(table.get("interpolation", {})),
                         units=dict(table.get("units", {})))
    elif "interpolation" in table or "units" in table:
        raise ManifestError(manifest, f"{key}.interpolation", "only for a table component")
    params = table.get("parameters", {})
    if not isinstance(params, dict):
        raise ManifestError(manifest, f"{key}.parameters", "must be a table")
    fmu = table.get("fmu")
    if fmu is not None and not isinstance(fmu, str):
        raise ManifestError(manifest, f"{key}.fmu", f"{fmu!r} is not a path")
    return Component(name, (base_dir / fmu).resolve() if fmu else None, dict(params))


def _event(manifest, key, table, partial=False):
    """One ``[events.<name>]`` table: ``at`` [s] and ``set`` ("comp.var" -> value)."""
    if not isinstance(table, dict):
        raise ManifestError(manifest, key, "must be a table with 'at' and 'set'")
    unknown = set(table) - {"at", "set"}
    if unknown:
        raise ManifestError(manifest, f"{key}.{sorted(unknown)[0]}",
                            "unknown key (allowed: at, set)")
    event = {}
    if "at" in table or not partial:
        event["at"] = _number(manifest, table, "at", key)
    values = table.get("set")
    if values is not None or not partial:
        if not isinstance(values, dict) or not values:
            raise ManifestError(manifest, f"{key}.set", "must be a non-empty table of "
                                '"component.variable" = value')
        for name in values:
            _dotted(manifest, f"{key}.set", name)
        event["set"] = dict(values)
    return event


def _event_key(manifest, key, name, events):
    """An event field as a sweep / --set name: ``events.<event>.at`` (its time) or
    ``events.<event>.set.<component>.<variable>`` (a value it sets; a new target is
    added to the event). Returns the event's name, else raises ManifestError."""
    parts = name.split(".")
    if not ((len(parts) == 3 and parts[2] == "at") or
            (len(parts) == 5 and parts[2] == "set" and all(parts[3:]))):
        raise ManifestError(manifest, key, f"{name!r}: an event's time or one of its values "
                            "can be swept or set ('events.<name>.at' or "
                            "'events.<name>.set.<component>.<variable>')")
    if parts[1] not in events:
        raise ManifestError(manifest, key, f"unknown event '{parts[1]}' in '{name}'")
    return parts[1]


def _apply_event_key(events, name, value):
    """Set the event field named by :func:`_event_key` in ``events`` (a run's copy)."""
    parts = name.split(".")
    if parts[2] == "at":
        events[parts[1]]["at"] = value
    else:
        events[parts[1]]["set"][f"{parts[3]}.{parts[4]}"] = value


def load_manifest(path):
    """Read and syntax-check a manifest (no FMU is opened).

    Raises
    ------
    ManifestError
        For an unreadable file, a TOML syntax error, a missing or mistyped key, bad
        numbers (step <= 0, stop <= start, ...).
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as error:
        raise ManifestError(path, "file", f"cannot read: {error.strerror}") from None
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
        raise ManifestError(path, "toml", str(error)) from None
    unknown = set(data) - _TOP_KEYS
    if unknown:
        raise ManifestError(path, sorted(unknown)[0], "unknown top-level key (allowed: "
                            + ", ".join(sorted(_TOP_KEYS)) + ")")
    base_dir = path.resolve().parent
    sim = _table(path, data, "simulation", required=True)
    start = _number(path, sim, "start", "simulation", 0.0)
    stop = _number(path, sim, "stop", "simulation")
    step = _number(path, sim, "step", "simulation")
    if step <= 0:
        raise ManifestError(path, "simulation.step", f"{step!r} must be > 0")
    if stop <= start:
        raise ManifestError(path, "simulation.stop", f"{stop!r} must be > start ({start!r})")
    steps = (stop - start) / step
    if not steps <= MAX_STEPS:
        raise ManifestError(path, "simulation.step", f"(stop - start) / step = {steps!r} "
                            f"steps; at most {MAX_STEPS:.0f} (beyond, t = start + k step "
                            "no longer tells the steps apart)")
    if not whole_multiple(stop - start, step):
        raise ManifestError(path, "simulation.step", f"stop - start = {stop - start!r} is not "
                            f"a whole number of steps of {step!r}")
    algorithm = sim.get("algorithm", "gauss-seidel")
    if algorithm not in ALGORITHMS:
        raise ManifestError(path, "simulation.algorithm",
                            f"{algorithm!r} is not one of {', '.join(ALGORITHMS)}")
    extra = set(sim) - {"start", "stop", "step", "algorithm"}
    if extra:
        raise ManifestError(path, f"simulation.{sorted(extra)[0]}", "unknown key")

    components = {}
    for name, table in _table(path, data, "components", required=True).items():
        key = f"components.{name}"
        if not _NAME.match(name):
            raise ManifestError(path, key, "instance names are identifiers ([A-Za-z_][A-Za-z0-9_]*)")
        comp = _component(path, base_dir, name, table, key)
        if comp.fmu is None and comp.table is None:
            raise ManifestError(path, f"{key}.fmu", "missing (path of the FMU, relative to "
                                "the manifest)")
        components[name] = comp
    if not components:
        raise ManifestError(path, "components", "no components")

    connections = []
    raw_conns = data.get("connections", [])
    if not isinstance(raw_conns, list):
        raise ManifestError(path, "connections", "must be an array of tables")
    for i, conn in enumerate(raw_conns):
        key = f"connections[{i}]"
        if not isinstance(conn, dict) or set(conn) != {"from", "to"}:
            raise ManifestError(path, key, "must be a table with exactly 'from' and 'to'")
        connections.append(Connection(_dotted(path, f"{key}.from", conn["from"]),
                                      _dotted(path, f"{key}.to", conn["to"]), key))

    events = {}
    for name, table in _table(path, data, "events").items():
        events[name] = _event(path, f"events.{name}", table)

    variants = {}
    for name, table in _table(path, data, "variants").items():
        key = f"variants.{name}"
        try:
            check_name(name, "variant name")
        except ValueError as error:
            raise ManifestError(path, key, f"{error} (it names the run's folder)") from None
        if not isinstance(table, dict):
            raise ManifestError(path, key, "must be a table")
        extra = set(table) - {"description", "components", "events"}
        if extra:
            raise ManifestError(path, f"{key}.{sorted(extra)[0]}",
                                "unknown key (allowed: description, components, events)")
        comps = {}
        for cname, ctable in _table(path, table, "components").items():
            ckey = f"{key}.components.{cname}"
            if cname not in components:
                raise ManifestError(path, ckey, f"unknown component '{cname}'")
            comps[cname] = _component(path, base_dir, cname, ctable, ckey)
        variant_events = {}
        for ename, etable in _table(path, table, "events").items():
            ekey = f"{key}.events.{ename}"
            # an event of the base is changed field by field; a new one needs both
            variant_events[ename] = _event(path, ekey, etable, partial=ename in events)
        variants[name] = {"description": str(table.get("description", "")),
                          "components": comps, "events": variant_events}

    sweep = {}
    for name, values in _table(path, data, "sweep").items():
        key = f"sweep.{name}"
        if name.startswith("events."):
            _event_key(path, key, name, events)
        else:
            _dotted(path, key, name, "component.parameter")
        if not isinstance(values, list) or not values:
            raise ManifestError(path, key, "must be a non-empty array of values")
        sweep[name] = list(values)

    record = _table(path, data, "record")
    extra = set(record) - {"variables", "interval"}
    if extra:
        raise ManifestError(path, f"record.{sorted(extra)[0]}", "unknown key")
    variables = record.get("variables")
    if variables is not None:
        if not isinstance(variables, list) or not variables:
            raise ManifestError(path, "record.variables", "must be a non-empty array")
        for i, v in enumerate(variables):
            _dotted(path, f"record.variables[{i}]", v)
        if len(set(variables)) != len(variables):
            raise ManifestError(path, "record.variables", "a variable is listed twice")
    interval = _number(path, record, "interval", "record", step)
    if interval <= 0 or interval / step > MAX_STEPS or not whole_multiple(interval, step):
        raise ManifestError(path, "record.interval", f"{interval!r} must be a positive whole "
                            f"multiple of the step ({step!r})")
    name = data.get("name", path.stem)
    try:
        check_name(name)
    except ValueError as error:
        raise ManifestError(path, "name", f"{error} (it names the default output folder "
                            "results/<name>)") from None
    from . import montecarlo  # issue 16: [montecarlo] is parsed and checked there
    sampling = montecarlo.parse(path, data.get("montecarlo"), components, sweep)
    return Manifest(path=path, sha256=hashlib.sha256(raw).hexdigest(), name=name,
                    description=str(data.get("description", "")), start=start, stop=stop,
                    step=step, algorithm=algorithm, components=components,
                    connections=connections, variants=variants, sweep=sweep,
                    record=variables, record_interval=interval,
                    metrics=_table(path, data, "metrics"), plots=_table(path, data, "plots"),
                    events=events, montecarlo=sampling)


def parse_set(manifest, text):
    """Parse one ``--set comp.param=VALUE`` (VALUE as a TOML value, else a string)."""
    if "=" not in text:
        raise ManifestError(manifest.path, "--set", f"{text!r} is not comp.param=VALUE")
    name, value = text.split("=", 1)
    if name.strip().startswith("events."):
        _event_key(manifest.path, "--set", name.strip(), manifest.events)
    else:
        _dotted(manifest.path, "--set", name.strip(), "component.parameter")
    try:
        parsed = tomllib.loads(f"v = {value}")["v"]
    except tomllib.TOMLDecodeError:
        parsed = value
    return name.strip(), parsed


def _slug(text):
    return re.sub(r"[^A-Za-z0-9._=+-]", "_", text)


#: Longest run label (a folder name); longer labels (many or long sweep values) are cut
#: and end in a hash of the full label, so they stay distinct.
MAX_LABEL = 100


def run_label(parts):
    """The folder name of a run: its slugged parts joined by ``__``, bounded."""
    label = "__".join(_slug(p) for p in parts)
    if len(label) > MAX_LABEL:
        digest = hashlib.sha256(label.encode()).hexdigest()[:12]
        label = f"{label[:MAX_LABEL - 13]}-{digest}"
    return label


def plan_runs(manifest, variants=None, sets=()):
    """Expand a manifest into its runs: (chosen variants or all, or the base) x sweep.

    Parameters
    ----------
    manifest : Manifest
    variants : list of str, optional
        Variant names to run (default: every declared variant, or the base when there
        are none).
    sets : iterable of str
        ``comp.param=VALUE`` overrides applied to every run.
    """
    overrides = dict(parse_set(manifest, s) for s in sets)
    for name in overrides:
        if name in manifest.sweep:
            raise ManifestError(manifest.path, "--set", f"'{name}' is also swept in [sweep]")
        comp = name.split(".")[0]
        if comp != "events" and comp not in manifest.components:
            raise ManifestError(manifest.path, "--set", f"unknown component '{comp}' in "
                                f"'{name}'")
    for name in manifest.sweep:
        if name.split(".")[0] not in manifest.components and not name.startswith("events."):
            raise ManifestError(manifest.path, f"sweep.{name}",
                                f"unknown component '{name.split('.')[0]}'")
    if variants:
        for name in variants:
            if name not in manifest.variants:
                known = ", ".join(manifest.variants) or "none declared"
                raise ManifestError(manifest.path, "variants",
                                    f"unknown variant '{name}' (known: {known})")
        chosen = list(dict.fromkeys(variants))
    else:
        chosen = list(manifest.variants) or [None]
    names = list(manifest.sweep)
    points = [dict(zip(names, combo)) for combo in
              itertools.product(*(manifest.sweep[n] for n in names))]
    runs = []
    for variant in chosen:
        for point in points:
            comps = copy.deepcopy(manifest.components)
            events = copy.deepcopy(manifest.events)
            if variant is not None:
                for cname, sub in manifest.variants[variant]["components"].items():
                    if sub.fmu is not None:
                        comps[cname].fmu, comps[cname].table = sub.fmu, None
                    if sub.table is not None:
                        comps[cname].fmu, comps[cname].table = None, sub.table
                        comps[cname].interpolation = sub.interpolation
                        comps[cname].units = sub.units
                    comps[cname].parameters.update(sub.parameters)
                for ename, sub in manifest.variants[variant].get("events", {}).items():
                    event = events.setdefault(ename, {"at": None, "set": {}})
                    event["at"] = sub.get("at", event["at"])
                    event["set"].update(sub.get("set", {}))
            for name, value in list(overrides.items()) + list(point.items()):
                if name.startswith("events."):
                    _apply_event_key(events, name, value)
                    continue
                cname, pname = name.split(".")
                comps[cname].parameters[pname] = value
            parts = [variant or "base"] + [f"{k}={v!r}" for k, v in point.items()]
            runs.append(RunSpec(label=run_label(parts), variant=variant,
                                point=point, components=comps, overrides=overrides,
                                events=events))
    if manifest.montecarlo is not None:  # issue 16: each run x the Monte Carlo samples
        from . import montecarlo
        runs = montecarlo.expand_runs(manifest, runs)
    labels = [r.label for r in runs]
    if len(set(labels)) != len(labels):
        raise ManifestError(manifest.path, "sweep", "two sweep points give the same run "
                            "label (a value is repeated)")
    return runs


def _parameter_key(manifest, run, cname, pname):
    full = f"{cname}.{pname}"
    if full in run.point:  # issue 16: a sampled value is named by its [montecarlo] key
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
    # variable-level graph: input -> feedthrough output (inside an FMU), output -> input
    succ = {}
    for cname, info in models.items():
        for out, deps in info.dependencies.items():
            for inp in deps:
                succ.setdefault((cname, inp), []).append((cname, out))
    for conn in connections:
        succ.setdefault(conn.source, []).append(conn.target)
    cycle = _find_cycle(succ)
    if cycle:
        names = " -> ".join(".".join(v) for v in cycle)
        raise ManifestError(manifest_path, "connections",
                            f"algebraic loop (a cycle of direct feedthrough): {names}")
    names = list(models)
    edges = {n: set() for n in names}
    for conn in connections:
        src, dst = conn.source[0], conn.target[0]
        if models[src].dependencies.get(conn.source[1]) and src != dst:
            edges[src].add(dst)
    indegree = {n: 0 for n in names}
    for src in names:
        for dst in edges[src]:
            indegree[dst] += 1
    order, ready = [], [n for n in names if indegree[n] == 0]
    while ready:
        node = ready.pop(0)
        order.append(node)
        for dst in sorted(edges[node], key=names.index):
            indegree[dst] -= 1
            if indegree[dst] == 0:
                ready.append(dst)
        ready.sort(key=names.index)
    if len(order) != len(names):
        if algorithm == "jacobi":  # Jacobi needs no order: every FMU reads, then sets
            return names
        stuck = ", ".join(n for n in names if n not in order)
        raise ManifestError(manifest_path, "connections",
                            f"components {stuck} feed each other through feedthrough "
                            "outputs (no algebraic loop between variables, but a single "
                            "Gauss-Seidel pass cannot order them); use algorithm = 'jacobi'")
    return order


def _find_cycle(succ):
    state, stack = {}, []

    def visit(node):
        state[node] = 1
        stack.append(node)
        for nxt in succ.get(node, ()):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in state:
                found = visit(nxt)
                if found:
                    return found
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(succ):
        if node not in state:
            found = visit(node)
            if found:
                return found
    return None


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
            cname, vname = target.split(".")
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
                sets.append((cname, vname, fmitypes.parse(var.ftype, value)))
            except ValueError as error:
                raise err(vkey, f"'{target}' {error}") from None
        resolved.append((k, at, name, sets))
    resolved.sort(key=lambda e: (e[0], list(run.events).index(e[2])))
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
                        fmitypes.parse_array(var.ftype, value, var.size) if var.dims
                        else fmitypes.parse(var.ftype, value))
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
            cname, pname = name.split(".")
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
        cname, vname = name.split(".")
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
