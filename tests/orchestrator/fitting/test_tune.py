"""tune (issue 34 item 4): a seeded global search over bounded parameters of a scalar
objective computed over every run: the known optimum of analytic objectives (mean and
worst case over runs give different optima), the same seed giving the same history,
the evaluations in batches with the start first, infeasible points, and bad input as
one line."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from agv_cosim.errors import TuneError
from agv_cosim.fitting import Objective, Parameter, tune

#: x in [0, 5], y in [-2, 2], start (4, 1).
PARAMETERS = (Parameter("x", 4.0, 0.0, 5.0), Parameter("y", 1.0, -2.0, 2.0))
#: Mean-case optimum: d/dx [(x - 1)^2 + 2 (x - 3)^2] = 0.
MEAN_X = 7.0 / 3.0
#: Worst-case optimum: (x - 1)^2 = 2 (x - 3)^2 with 1 < x < 3.
WORST_X = (1.0 + 3.0 * math.sqrt(2.0)) / (1.0 + math.sqrt(2.0))
Y = -0.5


class Runs:
    """Two runs ("slow", "fast") with metrics "error" and "effort" of a point (x, y):
    error (x - 1)^2 resp. 2 (x - 3)^2, plus (y + 0.5)^2 in both, effort |y + 0.5|;
    NaN beyond x > ``nan_above``. Records each batch's size."""

    def __init__(self, nan_above: float = math.inf) -> None:
        self.batches: list[int] = []
        self.nan_above = nan_above

    def __call__(self, batch: list[np.ndarray]) -> list[dict[str, dict[str, float]]]:
        self.batches.append(len(batch))
        out = []
        for x, y in batch:
            bad = math.nan if x > self.nan_above else 0.0
            common = (y - Y) ** 2 + bad
            out.append({"slow": {"error": (x - 1.0) ** 2 + common, "effort": abs(y - Y)},
                        "fast": {"error": 2.0 * (x - 3.0) ** 2 + common,
                                 "effort": abs(y - Y)}})
        return out


@pytest.mark.parametrize("aggregate, x_best, value", [
    ("mean", MEAN_X, ((MEAN_X - 1) ** 2 + 2 * (MEAN_X - 3) ** 2) / 2),
    ("worst", WORST_X, (WORST_X - 1) ** 2),
])
def test_tune_finds_the_known_optimum(aggregate: str, x_best: float, value: float) -> None:
    runs = Runs()
    result = tune(runs, PARAMETERS, Objective({"error": 1.0}, aggregate),  # type: ignore[arg-type]
                  seed=1, generations=200)
    print(aggregate, result.best, result.best_value, result.evaluations,
          result.generations, result.message)
    assert result.best["x"] == pytest.approx(x_best, abs=1e-3)
    assert result.best["y"] == pytest.approx(Y, abs=1e-3)
    assert result.best_value == pytest.approx(value, abs=1e-5)
    assert result.best_value <= min(t.value for t in result.history)
    # the start was evaluated first, in the first batch; every batch is a generation
    first = result.history[0]
    assert first.parameters == {"x": 4.0, "y": 1.0} and first.generation == 0
    slow, fast = (4 - 1) ** 2 + 1.5 ** 2, 2 * (4 - 3) ** 2 + 1.5 ** 2
    assert result.start_value == pytest.approx(
        (slow + fast) / 2 if aggregate == "mean" else max(slow, fast))
    assert first.runs == pytest.approx({"slow": slow, "fast": fast})
    assert result.start_runs == first.runs
    assert result.as_json()["start"]["runs"] == first.runs
    assert result.best_runs["slow"] < slow and result.best_runs["fast"] < fast
    assert runs.batches == [20] * (result.generations + 1)
    assert result.evaluations == len(result.history) == sum(runs.batches)
    assert [t.number for t in result.history] == list(range(result.evaluations))
    assert all(p.min <= t.parameters[p.name] <= p.max for t in result.history
               for p in PARAMETERS)


def test_gradient_method_on_a_smooth_objective() -> None:
    runs = Runs()
    result = tune(runs, PARAMETERS, Objective({"error": 1.0}), method="gradient")
    print("gradient", result.best, result.evaluations, result.generations, result.message)
    assert result.converged and result.method == "gradient"
    assert result.best["x"] == pytest.approx(MEAN_X, abs=1e-5)
    assert result.best["y"] == pytest.approx(Y, abs=1e-5)
    # value and forward-difference gradient as one batch of p + 1 points, start first
    assert set(runs.batches) == {3} and result.evaluations == sum(runs.batches) <= 60
    assert result.history[0].parameters == {"x": 4.0, "y": 1.0}
    assert result.as_json()["optimiser"].startswith("scipy.optimize.minimize (L-BFGS-B)")
    again = tune(Runs(), PARAMETERS, Objective({"error": 1.0}), method="gradient")
    assert again.history == result.history


def test_weighted_sum_of_metrics() -> None:
    # error + 4 effort: effort |y + 0.5| has its kink at the same y; a negative weight
    # maximises: -effort pushes y to the bound farthest from -0.5 (y = 2)
    result = tune(Runs(), PARAMETERS, Objective({"error": 1.0, "effort": 4.0}), seed=2,
                  generations=200)
    assert result.best["y"] == pytest.approx(Y, abs=1e-3)
    away = tune(Runs(), PARAMETERS, Objective({"error": 1.0, "effort": -10.0}), seed=2,
                generations=200)
    assert away.best["y"] == pytest.approx(2.0, abs=1e-3)


def test_same_seed_same_history() -> None:
    objective = Objective({"error": 1.0}, "worst")
    first = tune(Runs(), PARAMETERS, objective, seed=7, generations=15)
    again = tune(Runs(), PARAMETERS, objective, seed=7, generations=15)
    other = tune(Runs(), PARAMETERS, objective, seed=8, generations=15)
    assert json.dumps(first.as_json()) == json.dumps(again.as_json())
    assert first.history == again.history
    assert [t.parameters for t in other.history[1:]] != \
        [t.parameters for t in first.history[1:]]


def test_infeasible_points_are_kept_out_of_the_best() -> None:
    # beyond x = 2 every run's metric is NaN: the optimum within x <= 2 is at the edge
    result = tune(Runs(nan_above=2.0), (Parameter("x", 1.5, 0.0, 5.0), PARAMETERS[1]),
                  Objective({"error": 1.0}), seed=3, generations=100)
    infeasible = [t for t in result.history if t.parameters["x"] > 2.0]
    assert infeasible and all(t.value == math.inf for t in infeasible)
    assert all(t.as_json()["value"] is None for t in infeasible)
    assert result.best["x"] <= 2.0 and result.best["x"] == pytest.approx(2.0, abs=1e-2)
    assert math.isfinite(result.best_value)


def test_budget_and_result_fields() -> None:
    result = tune(Runs(), PARAMETERS, Objective({"error": 1.0}), seed=0, generations=3,
                  popsize=5)
    assert result.generations == 3 and result.evaluations == 4 * 10
    assert not result.converged and "Maximum number of iterations" in result.message
    out = result.as_json()
    assert out["optimiser"] == "scipy.optimize.differential_evolution"
    assert out["method"] == "evolution"
    assert out["seed"] == 0 and len(out["history"]) == 40
    assert out["best"]["parameters"] == result.best
    assert out["objective"] == {"metrics": {"error": 1.0}, "aggregate": "mean"}


@pytest.mark.parametrize("parameters, objective, options, parts", [
    ((), Objective({"error": 1.0}), {}, ["tune: no parameter to vary"]),
    ((Parameter("x", 1.0, 2.0, 1.0),), Objective({"error": 1.0}), {},
     ["parameter 'x': min 2.0 >= max 1.0"]),
    ((Parameter("x", -1.0, 0.0, 1.0),), Objective({"error": 1.0}), {},
     ["parameter 'x': start -1.0 is outside its bounds [0.0, 1.0]"]),
    (PARAMETERS, Objective({}), {}, ["tune: no metric to minimise"]),
    (PARAMETERS, Objective({"error": 0.0}), {},
     ["weight of metric 'error': 0.0 is not a finite non-zero number"]),
    (PARAMETERS, Objective({"error": 1.0}, "median"), {},  # type: ignore[arg-type]
     ["aggregate 'median': not one of mean, worst"]),
    (PARAMETERS, Objective({"overshoot": 1.0}), {},
     ["run 'slow' has no metric 'overshoot' (metrics: effort, error)"]),
    (PARAMETERS, Objective({"error": 1.0}), {"generations": 0},
     ["generations 0: must be a whole number >= 1"]),
    (PARAMETERS, Objective({"error": 1.0}), {"seed": -1},
     ["seed -1: must be a whole number >= 0"]),
    (PARAMETERS, Objective({"error": 1.0}), {"method": "tpe"},
     ["method 'tpe': not one of evolution, gradient"]),
])
def test_bad_tuning_input(parameters: tuple[Parameter, ...], objective: Objective,
                          options: dict[str, object], parts: list[str]) -> None:
    with pytest.raises(TuneError) as error:
        tune(Runs(), parameters, objective, **options)  # type: ignore[arg-type]
    text = str(error.value)
    assert "\n" not in text and error.value.exit_code == 2
    for part in parts:
        assert part in text, (part, text)
