"""Candidates turned into runs: each parameter vector of a batch set in every run of a
manifest (as ``--set`` sets it), all of the batch's runs handed to one runner (the local
worker pool or a Dask cluster) at once, each run's metrics read back.

This is the part of ``agv-cosim tune`` that turns an optimiser's candidates into
co-simulation runs; :class:`TrialRuns` is the ``evaluate`` callable of
:func:`agv_cosim.fitting.tune`. A run that does not complete (it failed, timed out, its
metrics could not be computed) makes its candidate infeasible: its metrics are ``inf``
and the failure is kept in :attr:`TrialRuns.failures`; a metric that is empty (a
settling time of a run that never settles) is ``inf`` too.
"""

from __future__ import annotations

import math
import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..manifest import Manifest
from ..plan import Override
from ..report.records import RunResult
from ..system import Job
from .prepare import prepare

__all__ = ["RunJobs", "TrialRuns", "jobs_at"]

#: Runs ``jobs``, each into ``root / job.label``; one result per job, in job order.
RunJobs = Callable[[list[Job], Path], list[RunResult]]


def jobs_at(manifest: Manifest, names: Sequence[str], values: Sequence[float],
            timeout: float | None = None) -> list[Job]:
    """Every run of ``manifest`` with the parameters ``names`` set to ``values`` in each
    (the jobs ``agv-cosim run M --set name=value ...`` runs, checked as it checks them)."""
    sets = [Override(name, float(value)) for name, value in zip(names, values)]
    return prepare(manifest, sets=sets, timeout=timeout)[1]


@dataclass
class TrialRuns:
    """``evaluate`` of :func:`agv_cosim.fitting.tune` over the runs of ``manifest``:
    a batch of parameter vectors (in the order of ``names``) -> for each, ``{run label:
    {metric: value}}`` of the ``metrics`` asked for. The runs of a batch go to
    ``run_jobs`` together, under a folder of ``scratch`` removed once their metrics are
    read."""

    manifest: Manifest
    names: tuple[str, ...]
    metrics: tuple[str, ...]
    run_jobs: RunJobs
    scratch: Path
    timeout: float | None = None
    #: each run that did not complete: ``{"trial", "run", "status", "error"}``
    failures: list[dict[str, Any]] = field(default_factory=list)
    #: candidates evaluated so far (the next one's trial number)
    evaluated: int = 0
    #: called after each batch with (candidates evaluated, runs of the batch)
    on_batch: Callable[[int, int], None] | None = None

    def __call__(self, batch: list[np.ndarray]) -> list[dict[str, dict[str, float]]]:
        jobs: list[Job] = []
        owners: list[int] = []
        for k, vector in enumerate(batch):
            for job in jobs_at(self.manifest, self.names, list(vector), self.timeout):
                jobs.append(replace(job, label=f"c{k}__{job.label}"))
                owners.append(k)
        root = self.scratch / f"batch-{self.evaluated}"
        root.mkdir(parents=True)
        try:
            results = self.run_jobs(jobs, root)
        finally:
            shutil.rmtree(root, ignore_errors=True)
        out: list[dict[str, dict[str, float]]] = [{} for _ in batch]
        for job, owner, result in zip(jobs, owners, results):
            label = job.label.split("__", 1)[1]
            out[owner][label] = self._metrics(self.evaluated + owner, label, result,
                                              str(root / job.label))
        self.evaluated += len(batch)
        if self.on_batch is not None:
            self.on_batch(self.evaluated, len(jobs))
        return out

    def _metrics(self, trial: int, label: str, result: RunResult,
                 folder: str) -> dict[str, float]:
        """The asked-for metrics of one run's result; all ``inf`` for a run that did
        not complete or whose metrics failed (recorded in :attr:`failures`, the run's
        temporary ``folder`` named ``<run folder>`` in its reason)."""
        if result["status"] != "complete" or result.get("metrics_error"):
            reason = result.get("error") or result.get("metrics_error") or ""
            self.failures.append({"trial": trial, "run": label,
                                  "status": result["status"],
                                  "error": reason.replace(folder, "<run folder>")})
            return {name: math.inf for name in self.metrics}
        values = result["metrics"]
        out = {}
        for name in self.metrics:
            value = values.get(name)
            out[name] = float(value) if isinstance(value, int | float) \
                and not isinstance(value, bool) else math.inf
        return out
