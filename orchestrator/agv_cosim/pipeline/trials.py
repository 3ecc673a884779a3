"""Parameter vectors as runs: what ``agv-cosim fit`` and ``agv-cosim tune`` share.

A fit or a tuning varies some ``"component.parameter"`` of a manifest's runs and needs,
for a batch of parameter vectors, the runs at each vector. This module

- checks the varied parameters against the runs' FMUs (:func:`tunable`): each names a
  component every run has and a parameter of it that can be set before a run (causality
  ``parameter``, variability ``fixed`` or ``tunable``) and is a Real (FMI 3.0: Float32 or
  Float64) scalar; its start is the run's value (the manifest's, else the FMU's);
- turns one run (a prepared :class:`~agv_cosim.system.Job`) and one vector into the run
  at that vector (:func:`at_point`): the job with those parameter values, its label
  given, optionally recording only some signals at every step and computing no metrics;
- runs a batch of such jobs through a :class:`~agv_cosim.workers.runner.Runner` (the
  local worker pool or a Dask cluster, as a sweep's runs) into folders of a scratch
  folder (:class:`Trials`), and reads back each run's recorded signals; a run that is not
  ``complete`` raises :class:`~agv_cosim.errors.TrialFailed` naming its parameter values
  and its reason (:meth:`Trials.run`; :meth:`Trials.results` returns the runs' results,
  metrics included, whatever their status). A batch stopped (a termination signal, a
  cluster gone) raises the runner's :class:`~agv_cosim.errors.RunsStopped` with the
  termination signals restored: nothing of a batch is kept.

The local pool keeps its worker processes between batches (:class:`KeptLocalRunner`), so
the runs of one iteration do not pay for new processes and FMU loads each time.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TypeVar

import numpy as np

from ..errors import RunsStopped, TrialFailed
from ..manifest import Manifest
from ..report.records import RunResult
from ..system import Job
from ..timeseries import read_timeseries
from ..workers import pool
from ..workers.runner import DaskRunner, Runner

__all__ = ["KeptLocalRunner", "Trials", "Tunable", "at_point", "describe", "runner",
           "signal_problem", "tunable"]

#: The variabilities of a parameter that can be set before a run.
SETTABLE = ("fixed", "tunable")
T = TypeVar("T")
#: The FMI types of a Real parameter (FMI 2.0, FMI 3.0).
REAL_TYPES = ("Real", "Float64", "Float32")


@dataclass(frozen=True)
class Tunable:
    """A varied parameter: ``name`` ``"component.parameter"``, its ``start`` (the first
    run's value) and ``unit`` (the FMU's, or None)."""

    name: str
    component: str
    parameter: str
    start: float
    unit: str | None


def _problem(job: Job, cname: str, pname: str) -> str | None:
    """Why ``cname.pname`` cannot be varied in ``job`` (None: it can)."""
    models = job.plan.models
    if cname not in models:
        where = f" in variant '{job.variant}'" if job.variant else ""
        return f"unknown component '{cname}'{where} (components: {', '.join(models)})"
    info = models[cname]
    if getattr(info, "table", None) is not None:
        return f"'{cname}' is a time table: it has no parameters"
    variable = info.variables.get(pname)
    if variable is None:
        from ..errors import did_you_mean

        names = [n for n, v in info.variables.items() if v.causality == "parameter"]
        return (f"'{cname}' has no parameter '{pname}'{did_you_mean(pname, names)} "
                f"(its parameters: {', '.join(names) or 'none'})")
    if variable.causality != "parameter" or variable.variability not in SETTABLE:
        return (f"'{cname}.{pname}' is not a tunable parameter (causality "
                f"{variable.causality}, variability {variable.variability}; a parameter "
                "set before the run has causality parameter, variability fixed or "
                "tunable)")
    if variable.type not in REAL_TYPES or variable.dims:
        return (f"'{cname}.{pname}' is of type {variable.type}"
                f"{' (an array)' if variable.dims else ''}, not a Real scalar")
    return None


def tunable(manifest: Manifest, jobs: Sequence[Job], names: Sequence[str],
            key: str) -> list[Tunable]:
    """The parameters ``names`` (``"component.parameter"``) checked against every job;
    :class:`~agv_cosim.errors.ManifestError` at ``key.<name>`` (e.g.
    ``fit.parameters.act.K``) naming the first problem (see the module)."""
    out = []
    for name in names:
        cname, _, pname = name.partition(".")
        for job in jobs:
            problem = _problem(job, cname, pname)
            if problem is not None:
                raise manifest.error(f"{key}.{name}", problem)
        first = jobs[0]
        value = first.parameters.get(cname, {}).get(pname)
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise manifest.error(f"{key}.{name}", f"has no start value (the run's value "
                                 f"is {value!r}): give it in [components.{cname}]")
        unit = first.plan.models[cname].variables[pname].unit
        out.append(Tunable(name, cname, pname, float(value), unit))
    return out


def signal_problem(job: Job, name: str) -> str | None:
    """Why the signal ``name`` (``"component.variable"``) cannot be recorded in ``job``
    (None: it can): it must be a numeric output of one of the run's components."""
    cname, _, vname = name.partition(".")
    models = job.plan.models
    if cname not in models:
        return f"unknown component '{cname}' (components: {', '.join(models)})"
    variable = models[cname].variables.get(vname)
    if variable is None or variable.causality != "output":
        from ..errors import did_you_mean

        outputs = [n for n, v in models[cname].variables.items() if v.causality == "output"]
        return (f"'{name}' is not an output of '{cname}'{did_you_mean(vname, outputs)} "
                f"(its outputs: {', '.join(outputs) or 'none'})")
    unsupported = variable.unsupported("record")
    if unsupported or variable.type not in (*REAL_TYPES, "Integer", "Int32", "Int64"):
        return f"'{name}' cannot be fitted: {unsupported or f'of type {variable.type}'}"
    return None


def describe(parameters: Sequence[Tunable], values: Sequence[float]) -> str:
    """``comp.p = v, ...`` for a message."""
    return ", ".join(f"{p.name} = {float(v):.6g}" for p, v in zip(parameters, values))


def at_point(job: Job, parameters: Sequence[Tunable], values: Sequence[float], label: str,
             record: Sequence[str] | None = None, metrics: bool = True) -> Job:
    """``job`` with the ``parameters`` at ``values`` (floats), labelled ``label``, the
    values also in its ``point`` (run.json's sweep point). ``record``: record only these
    signals, at every communication step (None: the job's record). ``metrics``: False
    computes none."""
    plan_parameters = {c: dict(v) for c, v in job.plan.parameters.items()}
    effective = {c: dict(v) for c, v in job.parameters.items()}
    point = dict(job.point)
    for p, value in zip(parameters, values):
        plan_parameters.setdefault(p.component, {})[p.parameter] = float(value)
        effective.setdefault(p.component, {})[p.parameter] = float(value)
        point[p.name] = float(value)
    plan = replace(job.plan, parameters=plan_parameters)
    if record is not None:
        plan = replace(plan, record=list(record), record_every=1)
    return replace(job, label=label, plan=plan, parameters=effective, point=point,
                   metrics_spec=job.metrics_spec if metrics else None)


@dataclass
class KeptLocalRunner:
    """The local worker pool (:func:`~agv_cosim.workers.pool.run_isolated`, ``workers``
    at a time) whose workers stay between calls; :meth:`close` ends them."""

    workers: int

    def __post_init__(self) -> None:
        self.idle = pool.IdleWorkers()

    def run(self, jobs: list[Job], root: Path, on_progress: Callable[[int], None],
            on_done: Callable[[], None]) -> list[RunResult]:
        return pool.run_isolated(jobs, root, self.workers, on_progress, on_done,
                                 idle=self.idle)

    def close(self) -> None:
        self.idle.close()


def runner(jobs: int | None, dask: str | None) -> Runner:
    """The runner of ``--jobs`` / ``--dask``: the Dask cluster at ``dask``, else the
    local pool of ``jobs`` workers (default: one per core)."""
    if dask:
        return DaskRunner(dask)
    return KeptLocalRunner(max(1, jobs or os.cpu_count() or 1))


class Trials:
    """Batches of runs through ``runner`` into ``root/<batch>/<label>``; each batch's
    folder is removed once its signals are read (it is ours: made here). ``runs`` counts
    the runs made; ``what`` (the command) starts the message of a failed run."""

    def __init__(self, runner: Runner, root: Path, what: str = "fit") -> None:
        self.runner = runner
        self.what = what
        self.root = root
        self.batches = 0
        self.runs = 0

    def results(self, jobs: list[Job]) -> list[RunResult]:
        """Run ``jobs`` as one batch and return their results (status, error, metrics:
        a tuning reads the metrics and may take a run not complete as infeasible); the
        batch's folder is removed, so a run's folder named in its ``error`` or
        ``metrics_error`` is written ``<run folder>``."""
        def read(folder: Path, results: list[RunResult]) -> list[RunResult]:
            for job, result in zip(jobs, results):
                where = str(folder / job.label)
                error, metrics_error = result.get("error"), result.get("metrics_error")
                if error:
                    result["error"] = error.replace(where, "<run folder>")
                if metrics_error:
                    result["metrics_error"] = metrics_error.replace(where, "<run folder>")
            return results

        return self._batch(jobs, read)

    def run(self, jobs: list[Job], parameters: Sequence[Tunable],
            points: Sequence[Sequence[float]], signals: Sequence[str]
            ) -> list[dict[str, tuple[np.ndarray, np.ndarray]]]:
        """Run ``jobs`` (one per point of ``points``, made by :func:`at_point`
        recording ``signals``) and return each run's ``{signal: (time, values)}``;
        :class:`~agv_cosim.errors.TrialFailed` for a run not complete."""
        def read(folder: Path, results: list[RunResult]
                 ) -> list[dict[str, tuple[np.ndarray, np.ndarray]]]:
            out = []
            for job, result, point in zip(jobs, results, points):
                if result["status"] != "complete":
                    raise TrialFailed(f"{self.what}: run at {describe(parameters, point)} "
                                      f"{result['status']}: {result['error']}")
                time, columns = read_timeseries(folder / job.label / "timeseries.csv",
                                                signals)
                out.append({s: (time, columns[s]) for s in signals})
            return out

        return self._batch(jobs, read)

    def _batch(self, jobs: list[Job], read: Callable[[Path, list[RunResult]], T]) -> T:
        """Run ``jobs`` into a new batch folder, ``read`` what is needed, remove it."""
        folder = self.root / f"batch-{self.batches:05d}"
        self.batches += 1
        folder.mkdir(parents=True)
        try:
            try:
                results = self.runner.run(jobs, folder, lambda steps: None, lambda: None)
            except RunsStopped as stop:  # nothing of a batch is kept: signals back now
                stop.restore()
                raise
            self.runs += len(jobs)
            return read(folder, results)
        finally:
            shutil.rmtree(folder, ignore_errors=True)
