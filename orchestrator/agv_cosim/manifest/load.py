"""A manifest file read and checked into a :class:`Manifest`.

The format is documented, key by key, in ``docs/manifest.md`` (checked against the
schema by tests/orchestrator/manifest/test_manifest_doc.py) and ``experiments/example.toml``.
:func:`load_manifest` checks the syntax, the shape (the schema of
:mod:`agv_cosim.manifest.schema`: unknown keys, types) and the numbers (no FMU is
opened). Every problem is a :class:`~agv_cosim.errors.ManifestError` whose text is
``<manifest>: <key>: <problem>``.
"""

import hashlib
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import Any

from ..errors import ManifestError, SchemaError, UnreadableFile, did_you_mean
from ..files import check_name, read_bytes
from . import schema
from .montecarlo import MonteCarlo
from .montecarlo import parse as parse_montecarlo

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


#: Most macro steps of one run: 2**53, where k step stops being exact in a double.
MAX_STEPS = float(2 ** 53)


def whole_multiple(span: float, step: float) -> bool:
    """True when ``span`` is n * ``step`` for a whole n >= 1, up to rounding.

    The tolerance is absolute in steps: 1e-9 of a step, plus the rounding error of the
    division (4 ulp per step counted), so a long run cannot hide half a step behind a
    relative tolerance (500000.5 steps is not 500000).
    """
    steps = span / step
    n = round(steps)
    return n >= 1 and abs(steps - n) <= 1e-9 + 4 * 2.220446049250313e-16 * n


@dataclass
class Component:
    """One component instance: its FMU and the parameter values the manifest gives, or a
    time table (``table``, see :mod:`agv_cosim.table`)."""

    name: str
    fmu: Path | None
    parameters: dict[str, Any] = field(default_factory=dict)
    table: Path | None = None
    interpolation: dict[str, str] = field(default_factory=dict)
    units: dict[str, str] = field(default_factory=dict)
    #: its own communication step [s] (``step``), a whole multiple of the simulation's;
    #: None: the simulation's step
    step: float | None = None
    #: ``interface``, ``solver``, ``tolerance`` as the manifest gives them (None: not
    #: given; :func:`agv_cosim.system.interface.select_interface` applies them)
    interface: str | None = None
    solver: str | None = None
    tolerance: float | None = None


@dataclass(frozen=True)
class Connection:
    """``source`` output -> ``target`` input, both ``(component, variable)``."""

    source: tuple[str, str]
    target: tuple[str, str]
    key: str

    def __str__(self) -> str:
        return f"{'.'.join(self.source)} -> {'.'.join(self.target)}"


@dataclass(frozen=True)
class EventSpec:
    """One checked ``[events.<name>]`` table: at ``at`` [s] the values ``set``
    (``"component.variable"`` -> value) are set. A variant's change of a base event may
    give only one of them (the other None)."""

    at: Any = None
    set: dict[str, Any] | None = None


@dataclass(frozen=True)
class Variant:
    """One checked ``[variants.<name>]`` table."""

    name: str
    description: str
    #: the variant's components: changes of the base's and new ones, by name
    components: dict[str, Component]
    #: the events it changes (field by field) or adds, by name
    events: dict[str, EventSpec]
    #: the base's components it removes, in the manifest's order
    remove: tuple[str, ...]
    #: the names in :attr:`components` that are new components, not changes
    new: tuple[str, ...]
    #: the variant's whole wiring: the base's connections not disconnected, then its own
    connections: tuple[Connection, ...]

    @property
    def replaced(self) -> set[str]:
        """The base's components to which the variant gives another FMU or table."""
        return {c for c, sub in self.components.items() if c not in self.new
                and (sub.fmu is not None or sub.table is not None)}


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
    components: dict[str, Component]
    connections: list[Connection]
    #: name -> the checked ``[variants.<name>]`` table
    variants: dict[str, "Variant"]
    sweep: dict[str, list[Any]]
    record: list[str] | None
    record_interval: float
    #: the ``[metrics]`` table as the schema checked it; None when absent or empty
    metrics: schema.MetricsTable | None
    #: the ``[plots]`` table as the schema checked it; None when absent or empty
    plots: schema.PlotsTable | None
    #: name -> the checked ``[events.<name>]`` table
    events: dict[str, "EventSpec"] = field(default_factory=dict)
    #: the folder an .ssp archive was unpacked into (run.json names its FMUs
    #: ``<package>!/<entry>``); None for a manifest file
    unpacked: Path | None = None
    #: the ``[montecarlo]`` table checked, or None
    montecarlo: MonteCarlo | None = None
    #: wall-clock limit of each run [s] (``[simulation] timeout``), None: no limit
    timeout: float | None = None
    #: inputs unconnected on purpose (``held``): ``"component.input"``, no warning
    held: list[str] = field(default_factory=list)
    #: dotted key -> its line in the manifest file (:func:`key_lines`); empty for an SSP
    lines: dict[str, int] = field(default_factory=dict)
    #: the folder relative FMU, table and parameter file names are relative to (the
    #: manifest file's, links resolved; of an SSP package, its unpacked SSD's); None:
    #: ``path``'s (:attr:`files_dir`)
    base_dir: Path | None = None
    #: the ``[tune]`` table as the schema checked it (``agv-cosim tune``), or None
    tune: schema.TuneTable | None = None
    #: the ``[fit]`` table as the schema checked it (``agv-cosim fit``), or None
    fit: schema.FitTable | None = None

    def error(self, key: str, problem: str) -> ManifestError:
        """A :class:`ManifestError` of ``key``, with its line when known."""
        return ManifestError(self.path, key, problem, line_of(self.lines, key))

    @property
    def files_dir(self) -> Path:
        """The folder relative file names of this manifest are relative to."""
        return self.base_dir if self.base_dir is not None else self.path.resolve().parent

    def step_index(self, at: float) -> int:
        """k of the communication point ``at`` = start + k step [s] (``at`` checked to
        be one: :func:`whole_multiple`)."""
        return step_index(self.start, self.step, at)

    @property
    def steps(self) -> int:
        """Macro steps of every run: (stop - start) / step."""
        return self.step_index(self.stop)

    @property
    def record_every(self) -> int:
        """A row is recorded every this many macro steps (``[record] interval``)."""
        return int(round(self.record_interval / self.step))


def step_index(start: float, step: float, at: float) -> int:
    """k of the communication point ``at`` = ``start`` + k ``step`` [s] (``at`` checked
    to be one: :func:`whole_multiple`)."""
    return 0 if at == start else int(round((at - start) / step))


def split_name(text: str) -> tuple[str, str]:
    """``"component.variable"`` as ``(component, variable)``, split at the first dot:
    component names are identifiers (no dot), FMI variable names may hold any number
    (``body.frame_a.r_0[1]``)."""
    component, _, variable = text.partition(".")
    return component, variable


def dotted_name(manifest: object, key: str, text: object) -> tuple[str, str]:
    """``text``, a ``"component.parameter"`` name, as ``(component, parameter)``;
    raises ManifestError (``key``) for anything else."""
    if not isinstance(text, str) or not all(text.partition(".")[::2]) or "." not in text:
        raise ManifestError(manifest, key, f"{text!r} is not of the form "
                            "'component.parameter'")
    return split_name(text)


def step_multiple(step: float, base: float) -> int | None:
    """``step`` / ``base`` when it is a whole number >= 1, in exact decimal arithmetic
    (the shortest decimals of both doubles, as :mod:`agv_cosim.execution.grid` reads
    them: 0.03 is 3 times 0.01); else None."""
    ratio = Fraction(repr(float(step))) / Fraction(repr(float(base)))
    return int(ratio) if ratio.denominator == 1 and ratio >= 1 else None


def component_steps(components: dict[str, Component], step: float) -> dict[str, float]:
    """Component -> its own step [s], for those whose ``step`` is a multiple > 1 of the
    simulation's ``step`` (one equal to it is the simulation's: the same run)."""
    return {cname: comp.step for cname, comp in components.items()
            if comp.step is not None and (step_multiple(comp.step, step) or 1) > 1}


def _component_step(manifest: object, key: str, step: float | None,
                    base: float) -> float | None:
    """A component's checked ``step``: a whole multiple of the simulation's ``base`` step."""
    if step is not None and step_multiple(step, base) is None:
        raise ManifestError(manifest, f"{key}.step", f"{step!r} s is not a whole multiple "
                            f"of the simulation step ({base!r} s)")
    return step


def _component(manifest: object, base_dir: Path, name: str, table: Any,
               key: str, base_step: float) -> Component:
    """A checked :class:`schema.ComponentTable` as a :class:`Component`: an FMU or a table."""
    step = _component_step(manifest, key, table.step, base_step)
    if table.table is not None:
        if table.fmu is not None or "parameters" in table.model_fields_set:
            raise ManifestError(manifest, f"{key}.table", "a component is an FMU or a "
                                "table, not both")
        for sub in INTERFACE_KEYS:
            if getattr(table, sub) is not None:
                raise ManifestError(manifest, f"{key}.{sub}", "only for an FMU component "
                                    "(a time table has no FMI interface)")
        return Component(name, None, {}, table=(base_dir / table.table).resolve(),
                         interpolation=dict(table.interpolation), units=dict(table.units),
                         step=step)
    for sub in ("interpolation", "units"):
        if sub in table.model_fields_set:
            raise ManifestError(manifest, f"{key}.interpolation", "only for a table component")
    _check_interface(manifest, key, table)
    fmu = table.fmu
    return Component(name, (base_dir / fmu).resolve() if fmu else None, dict(table.parameters),
                     step=step, interface=table.interface, solver=table.solver,
                     tolerance=table.tolerance)


#: A component's keys that choose its FMI interface and an integrated one's solver.
INTERFACE_KEYS = ("interface", "solver", "tolerance")


def _check_interface(manifest: object, key: str, table: Any) -> None:
    """``solver`` and ``tolerance`` are refused beside ``interface = "co-simulation"``
    (they apply to a Model Exchange FMU the orchestrator integrates)."""
    if table.interface != "co-simulation":
        return
    for sub in ("solver", "tolerance"):
        if getattr(table, sub) is not None:
            raise ManifestError(manifest, f"{key}.{sub}", "applies to a component "
                                "integrated as Model Exchange, not to one with interface = "
                                "\"co-simulation\"")


def _variant(path: Path, base_dir: Path, name: str, vtable: Any,
             components: dict[str, Component], connections: list[Connection],
             events: dict[str, EventSpec], base_step: float) -> Variant:
    """One checked ``[variants.<name>]`` table.

    Checked here, by name: removed components and disconnected inputs exist in the base,
    a removed component keeps no connection of the base, a new component names an FMU or
    a table. What needs the FMUs (variables, causality, types, units, an input driven
    twice, loops) is checked on the variant's resulting system by
    :func:`agv_cosim.system.validate`.
    """
    key = f"variants.{name}"
    try:
        check_name(name, "variant name")
    except ValueError as error:
        raise ManifestError(path, key, f"{error} (it names the run's folder)") from None
    removed = _removed(path, key, vtable.remove, components)
    dropped = _disconnected(path, key, vtable.disconnect, components, connections)
    for i, cname in enumerate(removed):
        kept = [conn for j, conn in enumerate(connections) if j not in dropped
                and cname in (conn.source[0], conn.target[0])]
        if kept:
            listed = ", ".join(f"{conn.key} ({conn})" for conn in kept)
            raise ManifestError(path, f"{key}.remove[{i}]", f"'{cname}' is removed but "
                                f"{listed} still connect it; disconnect them (disconnect = "
                                f'["{cname}"])')
    comps, new = _variant_components(path, base_dir, key, vtable.components, components,
                                     removed, base_step)
    # an event of the base is changed field by field; a new one needs both
    variant_events = {ename: _event(path, f"{key}.events.{ename}", etable,
                                    partial=ename in events)
                      for ename, etable in vtable.events.items()}
    wiring = [conn for j, conn in enumerate(connections) if j not in dropped]
    wiring += [Connection(split_name(c.source), split_name(c.target),
                          f"{key}.connections[{i}]") for i, c in enumerate(vtable.connections)]
    return Variant(name=name, description=vtable.description, components=comps,
                   events=variant_events, remove=tuple(removed), new=tuple(new),
                   connections=tuple(wiring))


def _removed(path: Path, key: str, names: list[str],
             components: dict[str, Component]) -> list[str]:
    """A variant's ``remove`` list checked: components of the base, each once."""
    removed: list[str] = []
    for i, cname in enumerate(names):
        if cname not in components:
            raise ManifestError(path, f"{key}.remove[{i}]", f"unknown component '{cname}'"
                                f"{did_you_mean(cname, components)}")
        if cname in removed:
            raise ManifestError(path, f"{key}.remove[{i}]", f"'{cname}' is listed twice")
        removed.append(cname)
    return removed


def _disconnected(path: Path, key: str, names: list[str], components: dict[str, Component],
                  connections: list[Connection]) -> set[int]:
    """The indices of the base's connections a variant's ``disconnect`` list drops: of an
    input, the connection driving it; of a component, every connection touching it."""
    dropped: set[int] = set()
    seen: set[str] = set()
    for i, text in enumerate(names):
        dkey = f"{key}.disconnect[{i}]"
        if text in seen:
            raise ManifestError(path, dkey, f"'{text}' is listed twice")
        seen.add(text)
        if "." in text:  # an input: the one connection of the base driving it
            target = split_name(text)
            found = [j for j, conn in enumerate(connections) if conn.target == target]
            if not found:
                driven = [".".join(conn.target) for conn in connections]
                raise ManifestError(path, dkey, f"no connection of the base drives '{text}'"
                                    f"{did_you_mean(text, driven)}")
        else:  # a component: every connection of the base to or from it
            if text not in components:
                raise ManifestError(path, dkey, f"unknown component '{text}'"
                                    f"{did_you_mean(text, components)} (give "
                                    "'component.input' or a component of the base)")
            found = [j for j, conn in enumerate(connections)
                     if text in (conn.source[0], conn.target[0])]
            if not found:
                raise ManifestError(path, dkey, f"no connection of the base touches '{text}'")
        dropped.update(found)
    return dropped


def _variant_components(path: Path, base_dir: Path, key: str, tables: dict[str, Any],
                        components: dict[str, Component], removed: list[str],
                        base_step: float) -> tuple[dict[str, Component], list[str]]:
    """A variant's ``components`` checked: each a change of the base's or a new one (an
    identifier with an FMU or a table); with the names of the new ones."""
    comps: dict[str, Component] = {}
    new: list[str] = []
    for cname, ctable in tables.items():
        ckey = f"{key}.components.{cname}"
        comp = _component(path, base_dir, cname, ctable, ckey, base_step)
        if cname in components and cname not in removed:
            comps[cname] = comp  # a change of the base's component
            continue
        if not _NAME.match(cname):
            raise ManifestError(path, ckey,
                                "instance names are identifiers ([A-Za-z_][A-Za-z0-9_]*)")
        if comp.fmu is None and comp.table is None:
            problem = (f"'{cname}' is removed: a component of that name is a new one and "
                       "needs 'fmu' or 'table'" if cname in removed else
                       f"unknown component '{cname}'{did_you_mean(cname, components)}; a "
                       "new component needs 'fmu' or 'table'")
            raise ManifestError(path, ckey, problem)
        comps[cname] = comp
        new.append(cname)
    return comps, new


def _event(manifest: object, key: str, table: Any, partial: bool = False) -> EventSpec:
    """One checked ``[events.<name>]`` table: ``at`` [s] and ``set`` ("comp.var" -> value);
    a variant's change of a base event (``partial``) may give only one of them."""
    for sub in ("at", "set"):
        if getattr(table, sub) is None and not partial:
            raise ManifestError(manifest, f"{key}.{sub}",
                                "missing (a number is required)" if sub == "at" else
                                'must be a non-empty table of "component.variable" = value')
    return EventSpec(at=table.at, set=None if table.set is None else dict(table.set))


def event_parts(name: str) -> list[str]:
    """``events.<event>.at`` as 3 parts, ``events.<event>.set.<component>.<variable>``
    as 5 (the variable's name may hold dots); anything else as its dot-separated
    parts."""
    parts = name.split(".", 4)
    return parts if len(parts) == 5 and parts[2] == "set" else name.split(".")


def event_key(manifest: object, key: str, name: str, events: dict[str, Any]) -> str:
    """An event field as a sweep / --set name: ``events.<event>.at`` (its time) or
    ``events.<event>.set.<component>.<variable>`` (a value it sets; a new target is
    added to the event). Returns the event's name, else raises ManifestError."""
    parts = event_parts(name)
    if not ((len(parts) == 3 and parts[2] == "at") or
            (len(parts) == 5 and parts[2] == "set" and all(parts[3:]))):
        raise ManifestError(manifest, key, f"{name!r}: an event's time or one of its values "
                            "can be swept or set ('events.<name>.at' or "
                            "'events.<name>.set.<component>.<variable>')")
    if parts[1] not in events:
        raise ManifestError(manifest, key, f"unknown event '{parts[1]}' in '{name}'"
                            f"{did_you_mean(parts[1], events)}")
    return parts[1]


#: Largest manifest file read [bytes] (a manifest of 3000 components is ~0.3 MB).
MAX_MANIFEST_BYTES = 16 << 20
#: Deepest nesting of tables and arrays in a manifest (the deepest key in use,
#: ``montecarlo.parameters."c.p".values``, is 4 levels down).
MAX_DEPTH = 32


def read_regular_file(path: str | Path, limit: int) -> bytes:
    """The bytes of the regular file at ``path``, at most ``limit`` of them
    (:func:`agv_cosim.files.read_bytes`: a FIFO, a device, a socket or a folder is
    refused before any read, and so is a file larger than ``limit``).
    Raises OSError (``strerror`` set) or ValueError (the problem in words).
    """
    try:
        return read_bytes(path, limit)
    except UnreadableFile as error:
        raise ValueError(error.problem) from None


def nesting_problem(data: Any, limit: int = MAX_DEPTH) -> str | None:
    """The dotted key of the first value nested deeper than ``limit`` levels in TOML
    data (tables and arrays), or None. Iterative: any depth is measured safely."""
    stack = [(data, "", 0)]
    while stack:
        value, key, depth = stack.pop()
        if depth > limit:
            return key or "(top level)"
        if isinstance(value, dict):
            stack.extend((v, f"{key}.{k}" if key else str(k), depth + 1)
                         for k, v in value.items())
        elif isinstance(value, list):
            stack.extend((v, f"{key}[{i}]", depth + 1) for i, v in enumerate(value))
    return None


def parse_toml(text: str) -> dict[str, Any]:
    """``tomllib.loads(text)`` whose nesting is checked (:data:`MAX_DEPTH`); a
    tomllib.TOMLDecodeError or ValueError names the problem."""
    try:
        data = tomllib.loads(text)
    except RecursionError:
        raise ValueError(f"nested more than {MAX_DEPTH} levels deep (arrays or inline "
                         "tables)") from None
    deep = nesting_problem(data)
    if deep is not None:
        raise ValueError(f"{deep}: nested more than {MAX_DEPTH} levels deep")
    return data


def load_manifest(path: str | Path) -> Manifest:
    """Read and syntax-check a manifest (no FMU is opened).

    The file must be a regular file of at most :data:`MAX_MANIFEST_BYTES`, nested at
    most :data:`MAX_DEPTH` levels.

    Raises
    ------
    ManifestError
        For an unreadable file (a FIFO, a device, too large), a TOML syntax error, too
        deep a nesting, a missing or mistyped key, bad numbers (step <= 0, stop <=
        start, ...).
    """
    path = Path(path)
    try:
        raw = read_regular_file(path, MAX_MANIFEST_BYTES)
    except OSError as error:
        raise ManifestError(path, "file", f"cannot read: {error.strerror}") from None
    except ValueError as error:
        raise ManifestError(path, "file", str(error)) from None
    try:
        text = raw.decode("utf-8")
        data = parse_toml(text)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError, ValueError) as error:
        raise ManifestError(path, "toml", str(error)) from None
    lines = key_lines(text)
    try:
        manifest = manifest_from_data(data, path, hashlib.sha256(raw).hexdigest())
    except ManifestError as error:
        raise placed(error, lines) from None
    manifest.lines = lines
    return manifest


_BARE = r"[A-Za-z0-9_-]+|\"(?:[^\"\\]|\\.)*\"|'[^']*'"
_HEADER = re.compile(rf"^\s*(\[\[?)\s*((?:{_BARE})(?:\s*\.\s*(?:{_BARE}))*)\s*\]\]?\s*(?:#.*)?$")
_ASSIGN = re.compile(rf"^\s*((?:{_BARE})(?:\s*\.\s*(?:{_BARE}))*)\s*=")
_PART = re.compile(_BARE)


def _key_parts(text: str) -> list[str]:
    return [part[1:-1] if part[0] in "\"'" else part for part in _PART.findall(text)]


def key_lines(text: str) -> dict[str, int]:
    """The line (from 1) of each table header and key assignment of a TOML text, by
    dotted key as the manifest's errors name it (``simulation.stop``,
    ``connections[2].to``; the n-th ``[[name]]`` is ``name[n]``, from 0). A plain scan of
    the lines: keys inside multi-line arrays and inline tables are not found (their
    enclosing key is)."""
    found: dict[str, int] = {}
    table: list[str] = []
    counts: dict[str, int] = {}
    for number, line in enumerate(text.splitlines(), 1):
        header = _HEADER.match(line)
        if header:
            name = ".".join(_key_parts(header.group(2)))
            if header.group(1) == "[[":
                index = counts.get(name, 0)
                counts[name] = index + 1
                name = f"{name}[{index}]"
            table = [name]
            _add(found, name, number)
            continue
        assign = _ASSIGN.match(line)
        if assign:
            _add(found, ".".join(table + _key_parts(assign.group(1))), number)
    return found


def _add(found: dict[str, int], key: str, number: int) -> None:
    """``key`` and each enclosing key not yet seen, at line ``number`` (the first line
    of anything under a key is where it begins)."""
    while key and key not in found:
        found[key] = number
        key = key[:max(key.rfind("."), key.rfind("["), 0)]


def line_of(lines: Mapping[str, int], key: str) -> int | None:
    """The line of ``key`` in :func:`key_lines`' map, else of its closest enclosing key
    found (a missing key: its table's header), else None. O(depth of the key)."""
    while key:
        if key in lines:
            return lines[key]
        key = key[:max(key.rfind("."), key.rfind("["), 0)]
    return None


def placed(error: ManifestError, lines: dict[str, int]) -> ManifestError:
    """``error`` and its others with the line of each key (:func:`line_of`), sorted by
    line (a problem without one last)."""
    every = [error, *error.others]
    out = [ManifestError(e.manifest, e.key, e.problem,
                         e.line if e.line is not None else line_of(lines, e.key))
           for e in every]
    out.sort(key=lambda e: (e.line is None, e.line or 0))
    out[0].others = out[1:]
    return out[0]


def manifest_from_data(data: dict[str, Any], path: str | Path, sha256: str,
                       base_dir: str | Path | None = None) -> Manifest:
    """Check a manifest given as data (the dict TOML gives) and build the Manifest.

    The one schema check for every source: a TOML file (:func:`load_manifest`) or an SSP
    package (:mod:`agv_cosim.ssp.importer`, whose SSD is mapped to this data directly).

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
    try:
        table = schema.check(schema.ManifestTable, data)
    except SchemaError as error:
        first = ManifestError(path, error.key, error.problem)
        first.others = [ManifestError(path, other.key, other.problem)
                        for other in error.others]
        raise first from None
    base_dir = path.resolve().parent if base_dir is None else Path(base_dir)
    sim = table.simulation
    start, stop, step = sim.start, sim.stop, sim.step
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

    components = {}
    for name, ctable in table.components.items():
        key = f"components.{name}"
        if not _NAME.match(name):
            raise ManifestError(path, key,
                                "instance names are identifiers ([A-Za-z_][A-Za-z0-9_]*)")
        comp = _component(path, base_dir, name, ctable, key, step)
        if comp.fmu is None and comp.table is None:
            raise ManifestError(path, f"{key}.fmu", "missing (path of the FMU, relative to "
                                "the manifest)")
        components[name] = comp

    connections = [Connection(split_name(c.source), split_name(c.target),
                              f"connections[{i}]") for i, c in enumerate(table.connections)]
    events = {name: _event(path, f"events.{name}", etable)
              for name, etable in table.events.items()}

    variants = {name: _variant(path, base_dir, name, vtable, components, connections,
                               events, step) for name, vtable in table.variants.items()}

    sweep = {}
    for name, values in table.sweep.items():
        key = f"sweep.{name}"
        if name.startswith("events."):
            event_key(path, key, name, events)
        else:
            dotted_name(path, key, name)
        sweep[name] = list(values)

    variables = table.record.variables
    if variables is not None and len(set(variables)) != len(variables):
        raise ManifestError(path, "record.variables", "a variable is listed twice")
    interval = step if table.record.interval is None else table.record.interval
    if interval <= 0 or interval / step > MAX_STEPS or not whole_multiple(interval, step):
        raise ManifestError(path, "record.interval", f"{interval!r} must be a positive whole "
                            f"multiple of the step ({step!r})")
    name = path.stem if table.name is None else table.name
    try:
        check_name(name)
    except ValueError as error:
        raise ManifestError(path, "name", f"{error} (it names the default output folder "
                            "results/<name>)") from None
    # a sampled component is the base's or a variant's (each run must have it: plan)
    known = list(components) + [c for v in variants.values() for c in v.new
                                if c not in components]
    sampling = parse_montecarlo(path, data.get("montecarlo"), known, sweep)
    return Manifest(path=path, sha256=sha256, name=name,
                    description=table.description, start=start, stop=stop,
                    step=step, algorithm=sim.algorithm, components=components,
                    connections=connections, variants=variants, sweep=sweep,
                    record=variables, record_interval=interval,
                    metrics=table.metrics if data.get("metrics") else None,
                    plots=table.plots if data.get("plots") else None,
                    events=events, montecarlo=sampling, timeout=sim.timeout,
                    base_dir=base_dir, held=list(table.held), tune=table.tune,
                    fit=table.fit)

