"""``run --check-step``: is the communication step small enough?

Each complete run is run again with the step divided by 2 and by 4 (through the same
workers: :class:`~agv_cosim.workers.runner.Runner`), recording at the same times (the
record interval in steps multiplied alike, so the finer runs' rows are at the base's
times exactly: t_k = start + k (stop - start) / n is the same double for k 2 of 2 n
steps), with every event at its same time (its step index multiplied alike) and every
Model Exchange component's solver tolerance divided by the same factor (h/2: tol/2,
h/4: tol/4), so that the solver's error, first order in its tolerance, shrinks with the
coupling error instead of hiding it.

For each metric of the run's ``metrics.json`` (values m_h, m_h/2, m_h/4) and each
recorded signal x (the maximum differences over the base's recorded times d1 = max
|x_h - x_h/2|, d2 = max |x_h/2 - x_h/4|; for a metric d1 = |m_h - m_h/2|, d2 = |m_h/2 -
m_h/4|)::

    observed order   p = log2(d1 / d2)
    remaining error  E = d1 2^p / (2^p - 1)   (Richardson: the base's distance to the
                                               limit when the error is C h^p)
    tolerance        tol = RTOL |m_h/4| + ATOL     (a signal: RTOL max |x_h/4| + ATOL)

and the flag (:func:`assess`):

- ``converged``: E <= tol; or d1 = d2 = 0 (E = 0); or p is unusable and both changes
  are within tol.
- ``not converged``: E > tol (p usable: p >= MIN_ORDER, or d2 = 0 < d1, when E = d1,
  the limit of the formula as p grows).
- ``order unusable``: p < MIN_ORDER (the change does not shrink with the step: halving
  it reduces the change by less than sqrt 2, or increases it; also d1 = 0 < d2) and a
  change exceeds tol: no estimate (E is null); not converged.
- ``undefined``: a value is empty (null) in one of the three runs.

A refinement that does not complete leaves the run's check ``failed`` (saying which step
and why); the base results are never touched. The refined runs' folders are removed
once compared: ``step_check.json`` holds the findings.
"""

import csv
import math
import shutil
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

from ..files import write_json
from ..report.page import STEP_CHECK_FILE
from ..report.records import RunResult
from ..system import Job

__all__ = ["ATOL", "FACTORS", "MIN_ORDER", "RTOL", "STEP_CHECK_FILE", "assess",
           "compare_signals", "refined", "step_check"]

#: The step divisors of the refinements
FACTORS = (2, 4)
#: Relative tolerance of convergence (of |m_h/4|, of a signal's max |x_h/4|)
RTOL = 1e-3
#: Absolute tolerance of convergence, in the quantity's unit
ATOL = 1e-9
#: Lowest observed order used for an estimate
MIN_ORDER = 0.5
#: Written into step_check.json's ``schema``
SCHEMA = "agv-cosim step check 1"
#: The folder (inside the result folder being written) the refined runs go to
_WORK = ".step_check"


def refined(job: Job, factor: int) -> Job:
    """``job`` with its step divided by ``factor``: ``factor`` times the steps, recording
    at the same times, events at the same times, Model Exchange tolerances divided by
    ``factor``."""
    plan = job.plan
    models = {}
    for cname, info in plan.models.items():
        integration = getattr(info, "integration", None)
        if integration is not None:
            info = replace(info, integration=replace(
                integration, tolerance=integration.tolerance / factor))
        models[cname] = info
    events = [replace(event, k=event.k * factor) for event in plan.events]
    # multirate: a component's own step is its rate (a sampled controller, a sensor's
    # frame rate), part of the model, and stays: a whole multiple of the divided step
    # still (m x factor)
    finer = replace(plan, models=models, step=plan.step / factor,
                    steps=plan.steps * factor, record_every=plan.record_every * factor,
                    events=events)
    return replace(job, plan=finer, real_time=None)


def assess(d1: float, d2: float, scale: float) -> dict[str, Any]:
    """The observed order, the remaining-error estimate and the flag of a quantity whose
    changes are ``d1`` (h -> h/2) and ``d2`` (h/2 -> h/4), ``scale`` its size (see the
    module docstring)."""
    tol = RTOL * abs(scale) + ATOL
    order: float | None = None
    estimate: float | None
    if d1 == 0 and d2 == 0:
        estimate = 0.0
    elif d2 == 0:
        estimate = d1
    elif d1 == 0:
        estimate = None
    else:
        order = math.log2(d1 / d2)
        if order >= MIN_ORDER:
            power = 2.0 ** order
            estimate = d1 * power / (power - 1.0) if math.isfinite(power) else d1
        else:
            estimate = None
    if estimate is not None:
        flag = "converged" if estimate <= tol else "not converged"
    else:
        flag = "converged" if max(d1, d2) <= tol else "order unusable"
    return {"order": order, "estimate": estimate, "tolerance": tol, "flag": flag}


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value) if math.isfinite(value) else None


def compare_metrics(runs: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Each metric of the base ``runs[0]`` across the three runs' metrics."""
    out: dict[str, dict[str, Any]] = {}
    for name in runs[0]:
        values = [_number(one.get(name)) for one in runs]
        entry: dict[str, Any] = {"values": values}
        m0, m1, m2 = values
        if m0 is None or m1 is None or m2 is None:
            entry.update(change=None, change_fine=None, order=None, estimate=None,
                         tolerance=None, flag="undefined")
        else:
            entry.update(change=m1 - m0, change_fine=m2 - m1)
            entry.update(assess(abs(m1 - m0), abs(m2 - m1), m2))
        out[name] = entry
    return out


def _rows(path: Path) -> Iterator[list[str]]:
    with open(path, newline="", encoding="utf-8") as stream:
        yield from csv.reader(stream)


def _float(text: str) -> float | None:
    try:
        value = float(text)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def compare_signals(paths: list[Path]) -> dict[str, dict[str, Any]]:
    """Each recorded signal's maximum differences over the base's times, read from the
    three runs' ``timeseries.csv`` in step (row by row). Raises ValueError when the
    files do not hold the same columns at the same times."""
    readers = [_rows(path) for path in paths]
    heads = [next(reader) for reader in readers]
    if heads[1] != heads[0] or heads[2] != heads[0] or heads[0][:1] != ["time"]:
        raise ValueError("the refined runs record other columns")
    names = heads[0][1:]
    d1 = [0.0] * len(names)
    d2 = [0.0] * len(names)
    scale = [0.0] * len(names)
    empty = [False] * len(names)
    for rows in zip(*readers, strict=True):
        if not rows[0][0] == rows[1][0] == rows[2][0]:
            raise ValueError(f"the refined runs record other times ({rows[0][0]}, "
                             f"{rows[1][0]}, {rows[2][0]})")
        for i in range(len(names)):
            a, b, c = (_float(row[i + 1]) for row in rows)
            if a is None or b is None or c is None:
                empty[i] = True
                continue
            d1[i] = max(d1[i], abs(a - b))
            d2[i] = max(d2[i], abs(b - c))
            scale[i] = max(scale[i], abs(c))
    out: dict[str, dict[str, Any]] = {}
    for i, name in enumerate(names):
        if empty[i]:
            out[name] = {"change": None, "change_fine": None, "scale": None,
                         "order": None, "estimate": None, "tolerance": None,
                         "flag": "undefined"}
            continue
        out[name] = {"change": d1[i], "change_fine": d2[i], "scale": scale[i],
                     **assess(d1[i], d2[i], scale[i])}
    return out


def _tolerances(job: Job) -> dict[str, list[float]]:
    out = {}
    for cname, info in job.plan.models.items():
        integration = getattr(info, "integration", None)
        if integration is not None:
            out[cname] = [integration.tolerance / f for f in (1, *FACTORS)]
    return out


def _check_run(job: Job, base: RunResult, fine: list[tuple[Job, RunResult]],
               root: Path, work: Path) -> dict[str, Any]:
    entry: dict[str, Any] = {
        "label": job.label, "variant": job.variant,
        "steps": [job.plan.step] + [j.plan.step for j, _ in fine],
        "solver_tolerances": _tolerances(job), "status": "checked", "error": None,
        "metrics": {}, "signals": {}, "not_converged": []}
    if base["status"] != "complete":
        entry.update(status="not checked",
                     error=f"the run is {base['status']}: only complete runs are checked")
        return entry
    for (finer, result), factor in zip(fine, FACTORS):
        if result["status"] != "complete":
            entry.update(status="failed", error=f"the run at step/{factor} "
                         f"({finer.plan.step:g} s) is {result['status']}: "
                         f"{result['error']}")
            return entry
    dirs = [root / job.label] + [work / f"h{factor}" / job.label for factor in FACTORS]
    try:
        entry["metrics"] = compare_metrics([base["metrics"]] + [r["metrics"] for _, r in fine])
        entry["signals"] = compare_signals([d / "timeseries.csv" for d in dirs])
    except (OSError, ValueError, StopIteration) as error:
        entry.update(status="failed", error=f"cannot compare the runs: {error}")
        return entry
    entry["not_converged"] = [
        name for group in ("metrics", "signals") for name, one in entry[group].items()
        if one["flag"] in ("not converged", "order unusable")]
    return entry


def step_check(jobs: list[Job], results: list[RunResult], root: Path,
               runner: Callable[[list[Job], Path], list[RunResult]]) -> dict[str, Any]:
    """Run the refinements of the complete runs among ``jobs`` (their ``results``,
    written under ``root``) with ``runner(jobs, folder)``, compare, write
    ``root/step_check.json`` and return its content."""
    data: dict[str, Any] = {"schema": SCHEMA, "factors": [1, *FACTORS], "rtol": RTOL,
                            "atol": ATOL, "min_order": MIN_ORDER, "error": None,
                            "runs": []}
    checked = [i for i, r in enumerate(results) if r["status"] == "complete"]
    fine: dict[int, list[tuple[Job, RunResult]]] = {i: [] for i in checked}
    work = root / _WORK
    try:
        if checked:
            for factor in FACTORS:
                todo = [refined(jobs[i], factor) for i in checked]
                ran = runner(todo, work / f"h{factor}")
                for i, job, result in zip(checked, todo, ran):
                    fine[i].append((job, result))
        if data["error"] is None:
            for i, (job, base) in enumerate(zip(jobs, results)):
                data["runs"].append(_check_run(job, base, fine.get(i, []), root, work))
    except Exception as error:  # noqa: BLE001 - the base results stay, whatever failed
        data["error"] = f"{type(error).__name__}: {error}"
    finally:
        shutil.rmtree(work, ignore_errors=True)
    write_json(root / STEP_CHECK_FILE, data)
    return data


def step_check_lines(data: dict[str, Any]) -> list[str]:
    """The terminal's lines about a check: its error, each run failed or not converged."""
    if data.get("error"):
        return [f"step check: {data['error']}"]
    lines = []
    for run in data["runs"]:
        if run["status"] == "failed":
            lines.append(f"step check: run {run['label']}: {run['error']}")
        elif run["not_converged"]:
            names = run["not_converged"]
            shown = ", ".join(names[:6]) + (f" and {len(names) - 6} more"
                                            if len(names) > 6 else "")
            lines.append(f"step check: run {run['label']}: not converged in the step "
                         f"({shown})")
    return lines
