"""Stage 1 of the pipeline, the manifest: an experiment's TOML file read and checked.

The pipeline, one module a stage::

    manifest (this module)  ->  plan (agv_cosim.plan)  ->  system (agv_cosim.system)
      -> run (agv_cosim.runner, agv_cosim.master)  ->  results (results, metrics, plots)

The format is documented, key by key, in ``experiments/example.toml`` and
``experiments/FORMAT.md``. :func:`load_manifest` checks the syntax and the numbers (no FMU
is opened). Every problem is a :class:`ManifestError` whose text is
``<manifest>: <key>: <problem>``.
"""

import hashlib
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from .results import check_name

ALGORITHMS = ("gauss-seidel", "jacobi")
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_TOP_KEYS = {"name", "description", "simulation", "components", "connections", "variants",
             "sweep", "record", "metrics", "plots", "events",
             "montecarlo"}  # [montecarlo]: parsed by agv_cosim.montecarlo


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
    #: the folder an .ssp archive was unpacked into (run.json names its FMUs
    #: ``<package>!/<entry>``); None for a manifest file
    unpacked: Path | None = None
    montecarlo: object = None  # a montecarlo.MonteCarlo ([montecarlo] table), or None

    def error(self, key, problem):
        return ManifestError(self.path, key, problem)


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
    return manifest_from_data(data, path, hashlib.sha256(raw).hexdigest())


def manifest_from_data(data, path, sha256, base_dir=None):
    """Check a manifest given as data (the dict TOML gives) and build the Manifest.

    The one schema check for every source: a TOML file (:func:`load_manifest`) or an SSP
    package (:mod:`agv_cosim.ssp_import`, whose SSD is mapped to this data directly).

    Parameters
    ----------
    data : dict
        The manifest's tables and values.
    path : path
        What the messages name (the manifest, or the SSP package).
    sha256 : str
        Hash of the source, kept in run.json.
    base_dir : path, optional
        Folder relative FMU and table paths are relative to (default: ``path``'s).
    """
    path = Path(path)
    unknown = set(data) - _TOP_KEYS
    if unknown:
        raise ManifestError(path, sorted(unknown)[0], "unknown top-level key (allowed: "
                            + ", ".join(sorted(_TOP_KEYS)) + ")")
    base_dir = path.resolve().parent if base_dir is None else Path(base_dir)
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
    from . import montecarlo  # [montecarlo] is parsed and checked there
    sampling = montecarlo.parse(path, data.get("montecarlo"), components, sweep)
    return Manifest(path=path, sha256=sha256, name=name,
                    description=str(data.get("description", "")), start=start, stop=stop,
                    step=step, algorithm=algorithm, components=components,
                    connections=connections, variants=variants, sweep=sweep,
                    record=variables, record_interval=interval,
                    metrics=_table(path, data, "metrics"), plots=_table(path, data, "plots"),
                    events=events, montecarlo=sampling)

