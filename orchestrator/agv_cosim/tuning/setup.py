"""A manifest's ``[tune]`` table checked against its runs: the objective's metrics
against what ``[metrics]`` gives, each tuned parameter against every run's FMU (it
exists, is a Real parameter set before initialisation, is not swept or sampled, has one
start value in every run, inside its bounds and the FMU's declared range)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from ..errors import ManifestError, did_you_mean
from ..fitting import Objective, Parameter
from ..manifest import Manifest, schema
from ..report.metrics import METRICS
from ..system import Job

__all__ = ["Setup", "available_metrics", "check_tune"]

#: Each ``[metrics]`` key -> the prefix of the metrics it gives (``duration`` always).
_FAMILIES = {"lateral_error": ("lateral_error_",), "reference": ("path_error_",),
             "heading_error": ("heading_error_",), "steering_angle": ("steering_angle_",),
             "steering_rate": ("steering_rate_",), "control": ("control_",),
             "saturation": ("saturated_",)}
#: Parameter variabilities a run may set before its initialisation (FMI 2.0 and 3.0).
_SETTABLE = ("fixed", "tunable")


@dataclass(frozen=True)
class Setup:
    """What ``[tune]`` asks for, checked: the objective, the parameters (start: the
    runs' value) and the optimiser's options."""

    objective: Objective
    parameters: tuple[Parameter, ...]
    method: str
    generations: int
    popsize: int
    seed: int
    tol: float

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)


def available_metrics(spec: schema.MetricsTable | None) -> list[str]:
    """The metrics a run of a manifest with this ``[metrics]`` table has, in the order of
    docs/metrics.md."""
    if spec is None:
        return []
    given = spec.spec()
    prefixes = tuple(p for key, ps in _FAMILIES.items() if given.get(key) is not None
                     for p in ps)
    return [name for name in METRICS if name.startswith(prefixes) or name == "duration"]


def _objective(manifest: Manifest, table: schema.TuneTable) -> Objective:
    if manifest.metrics is None:
        raise manifest.error("tune.objective", "the manifest has no [metrics] table: the "
                             "objective is a metric of it")
    known = available_metrics(manifest.metrics)
    weights = {table.objective: 1.0} if isinstance(table.objective, str) \
        else dict(table.objective)
    for metric, weight in weights.items():
        if metric not in known:
            raise manifest.error("tune.objective", f"'{metric}' is not a metric of this "
                                 f"manifest's [metrics]{did_you_mean(metric, known)} "
                                 f"(metrics: {', '.join(known)})")
        if weight == 0:
            raise manifest.error("tune.objective", f"weight of '{metric}' is 0 (give a "
                                 "non-zero weight, negative to maximise)")
    return Objective(weights, table.aggregate)


def _parameter(manifest: Manifest, jobs: Sequence[Job], name: str,
               bounds: schema.Bounds) -> Parameter:
    key = f"tune.parameters.{name}"
    low, high = bounds.min, bounds.max
    if not low < high:
        raise manifest.error(key, f"min {low!r} >= max {high!r}")
    if name in manifest.sweep:
        raise manifest.error(key, "is swept in [sweep]: a parameter is tuned or swept, "
                             "not both")
    if manifest.montecarlo is not None and name in manifest.montecarlo.names:
        raise manifest.error(key, "is sampled in [montecarlo]: a parameter is tuned or "
                             "sampled, not both")
    starts = {job.label: _start_in(manifest, jobs, job, name, low, high) for job in jobs}
    start = _common_start(manifest, key, starts)
    if not low <= start <= high:
        raise manifest.error(key, f"start {float(start)!r} (the manifest's value) is "
                             f"outside the bounds [{low!r}, {high!r}]")
    return Parameter(name, float(start), low, high)


def _start_in(manifest: Manifest, jobs: Sequence[Job], job: Job, name: str, low: float,
              high: float) -> Any:
    """The value the run ``job`` (one of ``jobs``) gives the tuned parameter ``name``
    (component.parameter), checked: a fixed or tunable Real parameter of its FMU whose
    declared range holds the bounds [``low``, ``high``]."""
    key = f"tune.parameters.{name}"
    cname, _, pname = name.partition(".")
    info = job.plan.models.get(cname)
    if info is None:
        known = sorted({c for j in jobs for c in j.plan.models})
        where = "" if len(jobs) == 1 else f"run '{job.label}' has "
        raise manifest.error(key, f"{where}no component '{cname}'"
                             f"{did_you_mean(cname, known)}")
    if getattr(info, "table", None) is not None:
        raise manifest.error(key, f"'{cname}' is a time table, which has no parameters")
    variable = info.variables.get(pname)
    if variable is None:
        params = [v.name for v in info.parameters]
        raise manifest.error(key, f"unknown parameter '{pname}' of '{cname}' "
                             f"({info.model_name}){did_you_mean(pname, params)}")
    if variable.causality != "parameter":
        raise manifest.error(key, f"'{name}' is {variable.causality}, not a parameter")
    if variable.variability not in _SETTABLE:
        raise manifest.error(key, f"'{name}' is a {variable.variability} parameter, "
                             "not tunable (only fixed and tunable parameters are set "
                             "for a run)")
    if variable.unsupported("parameter") or not variable.ftype.is_float or \
            variable.dims:
        raise manifest.error(key, f"'{name}' is of type {variable.type}, not Real: "
                             "only Real parameters are tuned")
    for edge, text in (("min", variable.min), ("max", variable.max)):
        if text is None:
            continue
        limit = float(text)
        if (edge == "min" and low < limit) or (edge == "max" and high > limit):
            raise manifest.error(key, f"{edge} {low if edge == 'min' else high!r} is "
                                 f"outside the FMU's range (its {edge} is {limit!r})")
    return job.parameters[cname].get(pname)


def _common_start(manifest: Manifest, key: str, starts: dict[str, Any]) -> Any:
    """The one start value of ``starts`` (run label -> value), checked: the same in
    every run, a finite number."""
    values = set(starts.values())
    if len(values) > 1:
        shown = ", ".join(f"{label}: {value!r}" for label, value in list(starts.items())[:4])
        raise manifest.error(key, f"its value differs between the runs ({shown}); tuning "
                             "sets one value in every run")
    start = next(iter(values))
    if isinstance(start, bool) or not isinstance(start, int | float) or \
            not math.isfinite(start):
        raise manifest.error(key, f"start value {start!r} is not a finite number")
    return start


def check_tune(manifest: Manifest, jobs: Sequence[Job]) -> Setup:
    """``[tune]`` of ``manifest`` checked against its ``jobs`` (every run); a
    :class:`~agv_cosim.errors.ManifestError` (one line, the key named) for a problem."""
    table = manifest.tune
    if table is None:
        raise ManifestError(manifest.path, "tune", "no [tune] table: say what to tune "
                            "(docs/tune.md)")
    objective = _objective(manifest, table)
    parameters = tuple(_parameter(manifest, jobs, name, bounds)
                       for name, bounds in table.parameters.items())
    return Setup(objective=objective, parameters=parameters, method=table.method,
                 generations=table.generations, popsize=table.popsize, seed=table.seed,
                 tol=table.tol)
