"""Stage 2 of the pipeline, the plan: a manifest's runs (variants x sweep points).

:func:`plan_runs` expands a :class:`~agv_cosim.manifest.Manifest` into one
:class:`RunSpec` per (chosen variant, or the base) x sweep point, each with its variant's
components (:func:`run_components`) and wiring, applying ``--set`` overrides
(:func:`parse_set`: ``comp.param=VALUE`` text, or the API's typed
:class:`~agv_cosim.plan.spec.Override` values), and its events (:func:`run_events`). A
sweep, ``--set`` or Monte Carlo name must name a component of every run. Parameter
precedence for one run: FMU default < ``[components.X.parameters]`` < the variant's
parameters < ``--set`` < the sweep point (a ``--set`` on a swept parameter is an error);
each run records which of them gave each value (:attr:`RunSpec.origins`), and carries its
:class:`~agv_cosim.manifest.Variant`, so that the system stage names a problem's key
without reading the manifest's variants. Nothing here opens an FMU: the runs are checked
against the FMUs by :func:`agv_cosim.system.validate`.
"""

import copy
import itertools
import math
import tomllib
from collections.abc import Iterable
from dataclasses import replace
from typing import Any

from ..errors import ManifestError, did_you_mean
from ..manifest import (
    Component,
    EventSpec,
    Manifest,
    Variant,
    dotted_name,
    event_key,
    event_parts,
    parse_toml,
    split_name,
)
from ..manifest.load import MAX_DEPTH, nesting_problem
from .sampling import expand_runs
from .spec import MAX_RUNS, Origin, Override, RunSpec, run_label


def _apply_event_key(events: dict[str, EventSpec], name: str, value: Any) -> None:
    """Set the event field named by :func:`agv_cosim.manifest.event_key` in ``events``
    (a run's own)."""
    parts = event_parts(name)
    event = events[parts[1]]
    if parts[2] == "at":
        events[parts[1]] = replace(event, at=value)
    else:
        assert event.set is not None  # a run's events have a set (:func:`run_events`)
        event.set[f"{parts[3]}.{parts[4]}"] = value


def run_components(manifest: Manifest, variant: str | None) -> dict[str, Component]:
    """The components of a run of ``variant`` (None: the base), copies in the base's
    order: a removed one left out (or, added again under its name, in its place), a
    changed one with the variant's FMU or table, its parameters over the base's and its
    ``step`` (when it gives one) instead of the base's, a new one after the base's."""
    if variant is None:
        return copy.deepcopy(manifest.components)
    changes = manifest.variants[variant]
    subs, new = changes.components, changes.new
    comps = {}
    for cname, comp in manifest.components.items():
        if cname in new:
            comps[cname] = copy.deepcopy(subs[cname])
        elif cname not in changes.remove:
            comps[cname] = copy.deepcopy(comp)
    for cname, sub in subs.items():
        if cname in new:
            comps.setdefault(cname, copy.deepcopy(sub))
            continue
        if sub.fmu is not None:
            comps[cname].fmu, comps[cname].table = sub.fmu, None
        if sub.table is not None:
            comps[cname].fmu, comps[cname].table = None, sub.table
            comps[cname].interpolation = dict(sub.interpolation)
            comps[cname].units = dict(sub.units)
            comps[cname].interface = comps[cname].solver = comps[cname].tolerance = None
        comps[cname].parameters.update(copy.deepcopy(sub.parameters))
        if sub.step is not None:
            comps[cname].step = sub.step
        _apply_interface(comps[cname], sub)
    return comps


def _apply_interface(comp: Component, sub: Component) -> None:
    """A variant's ``interface``, ``solver`` and ``tolerance`` over the base's, key by
    key; its ``interface = "co-simulation"`` drops the base's solver and tolerance (they
    apply to an integrated component only)."""
    if sub.interface is not None:
        comp.interface = sub.interface
        if sub.interface == "co-simulation":
            comp.solver = comp.tolerance = None
    if sub.solver is not None:
        comp.solver = sub.solver
    if sub.tolerance is not None:
        comp.tolerance = sub.tolerance


def run_origins(components: dict[str, Component],
                spec: Variant | None) -> dict[str, Origin]:
    """Where each parameter value of a run's ``components`` (:func:`run_components`)
    came from: the variant ``spec`` (None: the base) when it gives it, else the
    manifest's ``[components]``."""
    origins = {}
    for cname, comp in components.items():
        sub = spec.components.get(cname) if spec is not None else None
        for pname in comp.parameters:
            given = sub is not None and pname in sub.parameters
            origins[f"{cname}.{pname}"] = Origin.VARIANT if given else Origin.MANIFEST
    return origins


def run_events(manifest: Manifest, spec: Variant | None) -> dict[str, EventSpec]:
    """The events of a run of the variant ``spec`` (None: the base), copies in the
    base's order, then the variant's new ones: a variant's change of a base event
    replaces the fields it gives."""
    events = {name: EventSpec(at=event.at, set=copy.deepcopy(event.set) or {})
              for name, event in manifest.events.items()}
    for ename, sub in (spec.events.items() if spec is not None else ()):
        event = events.setdefault(ename, EventSpec(at=None, set={}))
        assert event.set is not None
        event.set.update(sub.set or {})
        events[ename] = replace(event, at=event.at if sub.at is None else sub.at)
    return events


def parse_set(manifest: Manifest, text: str | Override) -> tuple[str, Any]:
    """One ``--set``: ``comp.param=VALUE`` text (VALUE as a TOML value, else a string),
    or an :class:`Override` whose value is already typed; its name checked."""
    if isinstance(text, Override):
        name, value = text.name.strip(), text.value
        _check_set_name(manifest, name)
        deep = nesting_problem({"v": value})
        if deep is not None:
            raise manifest.error("--set", f"{name}: {deep}: nested more than {MAX_DEPTH} "
                                 "levels deep")
        return name, value
    if "=" not in text:
        raise manifest.error("--set", f"{text!r} is not comp.param=VALUE")
    name, value = text.split("=", 1)
    _check_set_name(manifest, name.strip())
    try:
        parsed = parse_toml(f"v = {value}")["v"]
    except tomllib.TOMLDecodeError:
        parsed = value
    except ValueError as error:  # nested too deeply
        raise manifest.error("--set", f"{name.strip()}: {error}") from None
    return name.strip(), parsed


def _check_set_name(manifest: Manifest, name: str) -> None:
    """A ``--set`` name is an event field of the manifest or ``component.parameter``."""
    if name.startswith("events."):
        event_key(manifest.path, "--set", name, manifest.events)
    else:
        dotted_name(manifest.path, "--set", name)


def plan_runs(manifest: Manifest, variants: list[str] | None = None,
              sets: Iterable[str | Override] = ()) -> list[RunSpec]:
    """Expand a manifest into its runs: (chosen variants or all, or the base) x sweep.

    Parameters
    ----------
    manifest : Manifest
    variants : list of str, optional
        Variant names to run (default: every declared variant, or the base when there
        are none).
    sets : iterable of str or Override
        ``comp.param=VALUE`` overrides applied to every run (text, or typed values).
    """
    overrides = dict(parse_set(manifest, s) for s in sets)
    _check_names(manifest, overrides)
    chosen = _chosen(manifest, variants)
    names = list(manifest.sweep)
    count = len(chosen) * math.prod(len(manifest.sweep[n]) for n in names)
    samples = manifest.montecarlo.samples if manifest.montecarlo is not None else 1
    if count * samples > MAX_RUNS:
        key = "montecarlo.samples" if samples > 1 and count <= MAX_RUNS else "sweep"
        raise manifest.error(key, f"{count * samples} runs (variants x sweep "
                            f"points x samples); at most {MAX_RUNS}")
    points = [dict(zip(names, combo)) for combo in
              itertools.product(*(manifest.sweep[n] for n in names))]
    runs = [_run(manifest, variant, point, overrides)
            for variant in chosen for point in points]
    if manifest.montecarlo is not None:  # each run x the Monte Carlo samples
        runs = expand_runs(manifest, runs)
    labels = [r.label for r in runs]
    if len(set(labels)) != len(labels):
        raise manifest.error("sweep", "two sweep points give the same run "
                            "label (a value is repeated)")
    return runs


def _check_names(manifest: Manifest, overrides: dict[str, Any]) -> None:
    """Each ``--set`` and sweep name names a component of the base or of a variant, and
    no name is both set and swept."""
    # the base's components and those variants add; each run must have the ones named
    comps_known = list(manifest.components) + [
        c for v in manifest.variants.values() for c in v.new if c not in manifest.components]
    for name in overrides:
        if name in manifest.sweep:
            raise manifest.error("--set", f"'{name}' is also swept in [sweep]")
        comp = name.split(".")[0]
        if comp != "events" and comp not in comps_known:
            raise manifest.error("--set", f"unknown component '{comp}' in "
                                f"'{name}'{did_you_mean(comp, comps_known)}")
    for name in manifest.sweep:
        if name.split(".")[0] not in comps_known and not name.startswith("events."):
            comp = name.split(".")[0]
            raise manifest.error(f"sweep.{name}", f"unknown component '{comp}'"
                                 f"{did_you_mean(comp, comps_known)}")


def _chosen(manifest: Manifest, variants: list[str] | None) -> list[str | None]:
    """The variants to run, each once (default: every declared one, or the base)."""
    if not variants:
        return list(manifest.variants) or [None]
    for name in variants:
        if name not in manifest.variants:
            known = ", ".join(manifest.variants) or "none declared"
            raise ManifestError(manifest.path, "variants",
                                f"unknown variant '{name}'"
                                f"{did_you_mean(name, manifest.variants)} (known: {known})")
    return list(dict.fromkeys(variants))


def _run(manifest: Manifest, variant: str | None, point: dict[str, Any],
         overrides: dict[str, Any]) -> RunSpec:
    """The run of ``variant`` (None: the base) at the sweep ``point``, ``--set``
    ``overrides`` then the point's values applied."""
    spec = manifest.variants[variant] if variant is not None else None
    comps = run_components(manifest, variant)
    origins = run_origins(comps, spec)
    events = run_events(manifest, spec)
    for key, name, value, origin in ([("--set", n, v, Origin.SET)
                                      for n, v in overrides.items()]
                                     + [(f"sweep.{n}", n, v, Origin.SWEEP)
                                        for n, v in point.items()]):
        if name.startswith("events."):
            _apply_event_key(events, name, value)
            continue
        cname, pname = split_name(name)
        if cname not in comps:
            raise manifest.error(key, f"variant '{variant}' has no component "
                                 f"'{cname}' (it removes it or the base has none)")
        comps[cname].parameters[pname] = value
        origins[name] = origin
    parts = [variant or "base"] + [f"{k}={v!r}" for k, v in point.items()]
    wiring = spec.connections if spec is not None else manifest.connections
    return RunSpec(label=run_label(parts), variant=variant, point=point, components=comps,
                   overrides=overrides, connections=list(wiring), events=events,
                   spec=spec, origins=origins)
