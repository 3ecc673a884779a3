"""Tuning: bounded (controller) parameters that minimise a scalar objective over all of
a manifest's runs (issue 34's ``tune``), on an ``evaluate`` callable (no files, no
manifest).

``evaluate(batch)`` takes a list of parameter vectors (in the order of the parameters)
and returns, for each, ``{run: {metric: value}}``: every run of the manifest (variants
and sweep points) at that point, a batch so that a generation's candidates can run in
parallel.

- **Objective** (:class:`Objective`): per run, the weighted sum ``sum_m w_m metric_m``
  of the chosen metrics (a negative weight maximises a metric); then over the runs
  their ``"mean"`` or their ``"worst"`` (largest) value. A point where a run's objective
  is not finite (a loop that diverged) is infeasible: its value is ``inf``.
- **Optimiser**, ``method``:

  - ``"evolution"`` (the default): ``scipy.optimize.differential_evolution``, a global,
    derivative-free search that needs no smoothness, so it suits metrics with kinks
    such as a worst case or a maximum deviation, and regions where the loop diverges;
    ``vectorized=True`` so that each generation's population is one batch,
    ``updating="deferred"``, no gradient polish (every evaluation goes through the
    batch), the start point (the manifest's values) in the first generation, the
    random generator seeded: the same seed gives the same history;
  - ``"gradient"``: ``scipy.optimize.minimize`` with L-BFGS-B from the start point, the
    gradient by forward differences (step ``relative_step * max(|x|, 1e-3 (max -
    min))``, backward at the upper bound) evaluated with the value as one batch of
    ``p + 1`` points: far fewer runs for a smooth objective (a mean of integral
    metrics), a local optimum only, deterministic (the seed is not used).
- **Result**: the best point and value, the start's value, and the history (every
  evaluation, in order: generation, parameters, objective, each run's objective).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from ..errors import TuneError
from .parameters import Parameter, check_parameters

__all__ = ["AGGREGATES", "OPTIMISERS", "Evaluate", "Objective", "Trial", "TuneResult", "tune"]

#: The evaluation: a batch of parameter vectors -> for each, {run: {metric: value}}.
Evaluate = Callable[[list[np.ndarray]], Sequence[Mapping[str, Mapping[str, float]]]]
AGGREGATES = ("mean", "worst")
#: The optimiser of each method.
OPTIMISERS = {"evolution": "scipy.optimize.differential_evolution",
              "gradient": "scipy.optimize.minimize (L-BFGS-B), forward differences"}


@dataclass(frozen=True)
class Objective:
    """What is minimised: ``metrics`` (metric -> weight) summed per run, aggregated over
    the runs by ``aggregate`` (``"mean"`` or ``"worst"``)."""

    metrics: Mapping[str, float]
    aggregate: Literal["mean", "worst"] = "mean"

    def check(self) -> None:
        """TuneError for no metric, a weight that is not a finite non-zero number, an
        unknown aggregate."""
        if not self.metrics:
            raise TuneError("tune: no metric to minimise (give a metric or weights of "
                            "several)")
        for metric, weight in self.metrics.items():
            if isinstance(weight, bool) or not isinstance(weight, int | float) or \
                    not math.isfinite(weight) or weight == 0:
                raise TuneError(f"tune: weight of metric '{metric}': {weight!r} is not a "
                                "finite non-zero number")
        if self.aggregate not in AGGREGATES:
            raise TuneError(f"tune: aggregate {self.aggregate!r}: not one of "
                            f"{', '.join(AGGREGATES)}")

    def per_run(self, metrics: Mapping[str, Mapping[str, float]]) -> dict[str, float]:
        """Each run's weighted sum; TuneError for a run without a chosen metric."""
        if not metrics:
            raise TuneError("tune: the evaluation returned no run")
        out = {}
        for run, values in metrics.items():
            total = 0.0
            for metric, weight in self.metrics.items():
                if metric not in values:
                    known = ", ".join(sorted(values)) or "none"
                    raise TuneError(f"tune: run '{run}' has no metric '{metric}' "
                                    f"(metrics: {known})")
                total += weight * float(values[metric])
            out[run] = total if math.isfinite(total) else math.inf
        return out

    def value(self, per_run: Mapping[str, float]) -> float:
        """The runs' objectives aggregated: their mean or their largest."""
        values = list(per_run.values())
        if any(not math.isfinite(v) for v in values):
            return math.inf
        return float(np.mean(values)) if self.aggregate == "mean" else float(max(values))


@dataclass(frozen=True)
class Trial:
    """One evaluation: its ``number`` (from 0), ``generation`` (0 the initial
    population), ``parameters``, ``value`` (the aggregated objective, inf when
    infeasible) and ``runs`` (each run's objective)."""

    number: int
    generation: int
    parameters: dict[str, float]
    value: float
    runs: dict[str, float]

    def as_json(self) -> dict[str, Any]:
        return {"number": self.number, "generation": self.generation,
                "parameters": dict(self.parameters),
                "value": self.value if math.isfinite(self.value) else None,
                "runs": {k: (v if math.isfinite(v) else None) for k, v in self.runs.items()}}


@dataclass
class TuneResult:
    """What a tuning found: ``best`` parameters, ``best_value`` and each run's objective
    ``best_runs``, the start's (``start``, ``start_value``, ``start_runs``: the
    original controller, for the comparison on every run), the ``history`` of every
    trial, ``evaluations``, ``generations``, ``converged`` (the population's spread fell
    within the tolerance before the generation budget ran out), ``message``, ``seed``,
    ``objective``."""

    names: tuple[str, ...]
    best: dict[str, float]
    best_value: float
    best_runs: dict[str, float]
    start: dict[str, float]
    start_value: float
    start_runs: dict[str, float]
    history: list[Trial] = field(repr=False)
    evaluations: int
    generations: int
    converged: bool
    message: str
    seed: int
    objective: Objective
    method: str = "evolution"

    def as_json(self) -> dict[str, Any]:
        """tune.json's content."""
        def number(v: float) -> float | None:
            return v if math.isfinite(v) else None

        return {"best": {"parameters": dict(self.best), "value": number(self.best_value),
                         "runs": {k: number(v) for k, v in self.best_runs.items()}},
                "start": {"parameters": dict(self.start),
                          "value": number(self.start_value),
                          "runs": {k: number(v) for k, v in self.start_runs.items()}},
                "objective": {"metrics": dict(self.objective.metrics),
                              "aggregate": self.objective.aggregate},
                "evaluations": self.evaluations, "generations": self.generations,
                "converged": self.converged, "message": self.message, "seed": self.seed,
                "method": self.method, "optimiser": OPTIMISERS[self.method],
                "history": [t.as_json() for t in self.history]}


def tune(evaluate: Evaluate, parameters: Sequence[Parameter], objective: Objective, *,
         method: Literal["evolution", "gradient"] = "evolution", seed: int = 0,
         generations: int = 30, popsize: int = 10, tol: float = 1e-6,
         relative_step: float = 1e-6) -> TuneResult:
    """Minimise ``objective`` over the bounded ``parameters`` (see the module).

    ``"evolution"``: ``popsize`` candidates per parameter in each generation (scipy's
    multiplier, at least 5 candidates), at most ``generations`` generations after the
    initial one (``(generations + 1) popsize p`` evaluations at most), stopping earlier
    when the population's objectives spread less than ``tol`` times their mean's size.
    ``"gradient"``: at most ``generations`` iterations of L-BFGS-B (each batch ``p + 1``
    evaluations; a line search may take more than one batch per iteration), stopping
    when the relative reduction of the objective falls below ``tol``. TuneError for a
    bad set-up."""
    import scipy.optimize

    chosen = check_parameters(parameters, TuneError, "tune")
    objective.check()
    for name, value, low in (("seed", seed, 0), ("generations", generations, 1),
                             ("popsize", popsize, 1)):
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise TuneError(f"tune: {name} {value!r}: must be a whole number >= {low}")
    if not (math.isfinite(tol) and tol >= 0):
        raise TuneError(f"tune: tol {tol!r}: must be a number >= 0")
    if method not in OPTIMISERS:
        raise TuneError(f"tune: method {method!r}: not one of {', '.join(OPTIMISERS)}")
    if not (math.isfinite(relative_step) and 0 < relative_step < 0.1):
        raise TuneError(f"tune: relative_step {relative_step!r}: must be in (0, 0.1)")
    names = tuple(p.name for p in chosen)
    history: list[Trial] = []
    generation = [0]

    def batch(xs: np.ndarray) -> np.ndarray:
        points = [np.asarray(xs[:, k], dtype=float) for k in range(xs.shape[1])]
        results = list(evaluate(points))
        if len(results) != len(points):
            raise TuneError(f"tune: the evaluation returned {len(results)} result(s) for "
                            f"{len(points)} parameter point(s)")
        values = np.empty(len(points))
        for k, (x, metrics) in enumerate(zip(points, results)):
            runs = objective.per_run(metrics)
            values[k] = objective.value(runs)
            history.append(Trial(number=len(history), generation=generation[0],
                                 parameters={n: float(v) for n, v in zip(names, x)},
                                 value=float(values[k]), runs=runs))
        generation[0] += 1
        return values

    start = np.array([p.start for p in chosen])
    bounds = [(p.min, p.max) for p in chosen]
    if method == "evolution":
        solved = scipy.optimize.differential_evolution(
            batch, bounds, rng=np.random.default_rng(seed), maxiter=generations,
            popsize=popsize, tol=tol, atol=0.0, polish=False, init="latinhypercube",
            x0=start, vectorized=True, updating="deferred")
    else:
        lower = np.array([p.min for p in chosen])
        upper = np.array([p.max for p in chosen])

        def value_and_gradient(x: np.ndarray) -> tuple[float, np.ndarray]:
            x = np.clip(np.asarray(x, dtype=float), lower, upper)
            h = relative_step * np.maximum(np.abs(x), 1e-3 * (upper - lower))
            h = np.where(x + h > upper, -h, h)
            points = [x] + [x + h[j] * np.eye(len(x))[j] for j in range(len(x))]
            values = batch(np.column_stack(points))
            steps = np.array([points[j + 1][j] - x[j] for j in range(len(x))])
            return float(values[0]), (values[1:] - values[0]) / steps

        solved = scipy.optimize.minimize(
            value_and_gradient, start, jac=True, method="L-BFGS-B", bounds=bounds,
            options={"maxiter": generations, "maxfun": 4 * generations + 10,
                     "ftol": tol, "gtol": 0.0})
    finite = [t for t in history if math.isfinite(t.value)]
    best = min(finite, key=lambda t: t.value) if finite else history[0]
    first = next(t for t in history
                 if np.array_equal(np.array(list(t.parameters.values())), start))
    return TuneResult(names=names, best=dict(best.parameters), best_value=best.value,
                      best_runs=dict(best.runs), start={p.name: p.start for p in chosen},
                      start_value=first.value, start_runs=dict(first.runs),
                      history=history,
                      evaluations=len(history), generations=generation[0] - 1,
                      converged=bool(solved.success), message=str(solved.message),
                      seed=seed, objective=objective, method=method)
