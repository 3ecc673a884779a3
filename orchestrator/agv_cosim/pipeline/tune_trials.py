"""Candidates turned into runs: each parameter vector of a batch set in every run of a
manifest (as ``--set`` sets it), all of the batch's runs handed to one runner (the local
worker pool or a Dask cluster) at once, each run's metrics read back.

This is the part of ``agv-cosim tune`` that turns an optimiser's candidates into
co-simulation runs; :class:`TrialRuns` is the ``evaluate`` callable of
:func:`agv_cosim.fitting.tune`, its batches run by :meth:`.trials.Trials.results` (the
mechanism ``agv-cosim fit`` uses too). A run that does not complete (it failed, timed out, its
metrics could not be computed) makes its candidate infeasible: its metrics are ``inf``
and the failure is kept in :attr:`TrialRuns.failures`; a metric that is empty (a
settling time of a run that never settles) is ``inf`` too.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..manifest import Manifest
from ..plan import Override
from ..report.records import RunResult
from ..system import Job
from .prepare import prepare
from .trials import Trials

__all__ = ["TrialRuns", "jobs_at"]


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
    ``trials`` as one batch."""

    manifest: Manifest
    names: tuple[str, ...]
    metrics: tuple[str, ...]
    trials: Trials
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
        results = self.trials.results(jobs)
        out: list[dict[str, dict[str, float]]] = [{} for _ in batch]
        for job, owner, result in zip(jobs, owners, results):
            label = job.label.split("__", 1)[1]
            out[owner][label] = self._metrics(self.evaluated + owner, label, result)
        self.evaluated += len(batch)
        if self.on_batch is not None:
            self.on_batch(self.evaluated, len(jobs))
        return out

    def _metrics(self, trial: int, label: str, result: RunResult) -> dict[str, float]:
        """The asked-for metrics of one run's result; all ``inf`` for a run that did
        not complete or whose metrics failed (recorded in :attr:`failures`)."""
        if result["status"] != "complete" or result.get("metrics_error"):
            reason = result.get("error") or result.get("metrics_error") or ""
            self.failures.append({"trial": trial, "run": label,
                                  "status": result["status"],
                                  "error": reason})
            return {name: math.inf for name in self.metrics}
        values = result["metrics"]
        out = {}
        for name in self.metrics:
            value = values.get(name)
            out[name] = float(value) if isinstance(value, int | float) \
                and not isinstance(value, bool) else math.inf
        return out
