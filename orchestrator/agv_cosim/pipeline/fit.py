"""``agv-cosim fit MANIFEST --out DIR``: the tunable parameters of a manifest's run
fitted so that its recorded signals match measured data, the co-simulation itself the
model (output error; docs/fit.md).

The manifest's ``[fit]`` table names the data (a CSV file relative to the manifest), the
signals fitted to its columns, optional weights and the parameters with their bounds
(the start is the run's value). The set-up is checked before any run, each problem one
line, exit 2 (:func:`setup`): the run (one: a variant chosen with ``--variant`` when the
manifest has several), each signal an output of it, each weight a fitted signal's, each
parameter a settable Real parameter (:func:`agv_cosim.pipeline.trials.tunable`) with
min < max and its start within them, the data readable with a column per signal, time
increasing and inside the simulated interval.

Then :func:`agv_cosim.fitting.fit` (bounded least squares) calls the simulation with
batches of parameter vectors; each batch becomes runs of the manifest's run at those
values (:mod:`agv_cosim.pipeline.trials`), recording only the fitted signals at every
communication step, and goes through the worker pool (``--jobs``) or a Dask cluster
(``--dask``) as a sweep's runs do. A run that does not complete stops the fit
(:class:`~agv_cosim.errors.TrialFailed`, exit 1, naming the parameter values and the
run's reason; no folder is written): a failed run has no residual, and a penalty in its
place would mislead the solver's local model.

The folder (:data:`OURS`; assembled under a temporary name and renamed into place like
``run``'s: a folder not ours is refused, a user's files in ours are kept):

- ``fit.json``: :meth:`agv_cosim.fitting.FitResult.as_json`;
- ``fit_variant.toml``: a manifest fragment, ``[variants.fitted]`` with the fitted
  values (and the FMU each fitted component ran), to paste into any manifest;
- ``fitted/``: the run at the fitted values as ``run`` writes it (the manifest's record
  and metrics);
- ``fit.png``: measured and fitted signals overlaid, the residuals below;
- ``fit_run.json``: the set-up (manifest, data and their SHA-256, signals, weights,
  bounds, solver), the versions;
- ``index.html``: the page.

A fit that does not converge keeps the best point in the same files, marked: fit.json's
``converged`` false, the folder's marker ``complete: false`` with the reason,
``not_converged.txt``, a banner on the page; it raises
:class:`~agv_cosim.errors.FitNotConverged` (exit 2) carrying the folder (``kept``).
"""

from __future__ import annotations

import itertools
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import FitNotConverged, OutputError, TrialFailed
from ..files import (
    MARKER,
    AtomicDir,
    _write_marker,
    marker_data,
    read_json_object,
    write_json,
    write_text,
)
from ..fitting import FitResult, MeasuredData, Parameter, check_interval, read_data
from ..fitting import fit as fit_signals
from ..manifest import Manifest
from ..report import fit_page
from ..report.page import RECORD as PAGE_RECORD
from ..report.records import versions
from ..system import Job
from ..system.files import file_sha256
from .prepare import prepare
from .resume import FOLDER_FILES, _carry
from .trials import KeptLocalRunner, Trials, Tunable, at_point, runner, signal_problem, tunable

__all__ = ["FITTED", "OURS", "FitOutcome", "FitSetup", "fit_manifest", "setup"]

RESULT = "fit.json"
RECORD = "fit_run.json"
FRAGMENT = "fit_variant.toml"
FIGURE = "fit.png"
PAGE = "index.html"
NOT_CONVERGED = "not_converged.txt"
#: the run at the fitted values (a run folder as ``run`` writes it)
FITTED = "fitted"
#: What a fit writes at the top of its folder (the rest of a folder of ours is the
#: user's, and kept).
OURS = (MARKER, RESULT, RECORD, FRAGMENT, FIGURE, PAGE, NOT_CONVERGED, FITTED)
#: The variant the fragment defines.
VARIANT = "fitted"


@dataclass
class FitSetup:
    """A fit checked and ready: the manifest, its one run (``job``), the parameters,
    the signals (signal -> column), the weights given, the data (and its file)."""

    manifest: Manifest
    job: Job
    parameters: list[Tunable]
    bounds: dict[str, tuple[float, float]]
    signals: dict[str, str]
    weights: dict[str, float]
    data: MeasuredData
    data_path: Path
    warnings: list[str]


@dataclass
class FitOutcome:
    """What :func:`fit_manifest` did: the engine's ``result``, the ``folder`` written
    (None without ``out``), the ``setup``, the ``runs`` made (the fitted run too)."""

    result: FitResult
    folder: Path | None
    setup: FitSetup
    runs: int


def setup(manifest: str | Path | Manifest, variant: str | None = None) -> FitSetup:
    """The fit of ``manifest`` checked (see the module); ManifestError (a key of
    ``[fit]`` and its line) or FitDataError (the data file, line, column), one line."""
    loaded, jobs, warnings = prepare(manifest, [variant] if variant else None)
    spec = loaded.fit
    if spec is None:
        raise loaded.error("fit", "missing: a fit needs a [fit] table (data, signals, "
                           "parameters; docs/fit.md)")
    if len(jobs) != 1:
        raise loaded.error("fit", f"the manifest has {len(jobs)} runs (variants x sweep "
                           "points x samples); a fit needs one: choose a variant with "
                           "--variant, and no sweep or [montecarlo]")
    job = jobs[0]
    for signal in spec.signals:
        problem = signal_problem(job, signal)
        if problem is not None:
            raise loaded.error(f"fit.signals.{signal}", problem)
    for signal in spec.weights:
        if signal not in spec.signals:
            raise loaded.error(f"fit.weights.{signal}", "not a fitted signal (signals: "
                               f"{', '.join(spec.signals)})")
        if not spec.weights[signal] > 0:
            raise loaded.error(f"fit.weights.{signal}",
                               f"{spec.weights[signal]!r} must be > 0")
    parameters = tunable(loaded, [job], list(spec.parameters), "fit.parameters")
    bounds = {}
    for p in parameters:
        table = spec.parameters[p.name]
        key = f"fit.parameters.{p.name}"
        if not table.min < table.max:
            raise loaded.error(key, f"min {table.min!r} >= max {table.max!r}")
        if not table.min <= p.start <= table.max:
            raise loaded.error(key, f"start {p.start!r} (the run's value) is outside the "
                               f"bounds [{table.min!r}, {table.max!r}]")
        bounds[p.name] = (table.min, table.max)
    data_path = loaded.files_dir / spec.data
    data = read_data(data_path, list(dict.fromkeys(spec.signals.values())))
    check_interval(data, loaded.start, loaded.stop)
    return FitSetup(manifest=loaded, job=job, parameters=parameters, bounds=bounds,
                    signals=dict(spec.signals), weights=dict(spec.weights), data=data,
                    data_path=data_path, warnings=warnings)


def _keep_users(target: Path, root: Path) -> list[str]:
    """Carry into ``root`` every entry of the folder of ours ``target`` that neither a
    fit nor a run writes (a user's file is never deleted); the entries kept."""
    if target.is_symlink() or not target.is_dir() or marker_data(target) is None:
        return []
    report = read_json_object(target / PAGE_RECORD) or {}
    figures = {n for n in report.get("files", []) if isinstance(n, str)}
    kept = []
    for entry in sorted(os.listdir(target)):
        old = target / entry
        if entry in OURS or entry in FOLDER_FILES or entry in figures:
            continue
        if old.is_dir() and not old.is_symlink() and (old / "run.json").is_file():
            continue  # a run folder of ours
        _carry(old, root / entry)
        kept.append(entry)
    return kept


def fit_manifest(manifest: str | Path | Manifest, out: str | Path | None, *,
                 variant: str | None = None, jobs: int | None = None,
                 dask: str | None = None, overwrite: bool = False,
                 max_evaluations: int | None = None,
                 checked: FitSetup | None = None) -> FitOutcome:
    """Check and run the fit of ``manifest``; write the folder ``out`` (None: no
    folder, the runs in a scratch folder). Raises ManifestError, FitDataError, FitError,
    OutputError (a folder not ours), TrialFailed, FitNotConverged (the folder kept,
    marked; ``kept`` is it)."""
    import tempfile

    fit_set = checked if checked is not None else setup(manifest, variant)
    about = {"manifest": fit_set.manifest.name, "command": "fit"}
    folder = AtomicDir(out, overwrite=overwrite, about=about) if out is not None else None
    scratch = None if folder is not None else tempfile.TemporaryDirectory(prefix="agv-fit-")
    chosen = runner(jobs, dask)
    try:
        root = folder.path if folder is not None else Path(scratch.name)  # type: ignore
        assert root is not None
        users = _keep_users(folder.target, root) if folder is not None else []
        result, runs = _solve(fit_set, chosen, root, max_evaluations)
        if folder is None:
            return FitOutcome(result, None, fit_set, runs)
        record = _record(fit_set, result, runs, jobs, dask, max_evaluations, users)
        write_json(root / RESULT, result.as_json())
        write_json(root / RECORD, record)
        write_text(root / FRAGMENT, fit_page.fragment(fit_set, result, VARIANT))
        fit_page.draw(root / FIGURE, fit_set, result)
        write_text(root / PAGE, fit_page.render(fit_set, result, record))
        if not result.converged:
            reason = f"fit not converged ({result.message}); the best point found is kept"
            _write_marker(root, **about, complete=False, reason=reason)
            write_text(root / NOT_CONVERGED, reason + "\n")
        written = folder.commit()
    except BaseException:
        if folder is not None:
            folder.discard()
        raise
    finally:
        if isinstance(chosen, KeptLocalRunner):
            chosen.close()
        if scratch is not None:
            scratch.cleanup()
    if not result.converged:
        error = FitNotConverged(f"fit: not converged ({result.message}); the best point "
                                f"found is kept, marked not converged, in {written}",
                                result=result)
        error.kept = written
        raise error
    return FitOutcome(result, written, fit_set, runs)


def _solve(fit_set: FitSetup, chosen: Any, root: Path,
           max_evaluations: int | None) -> tuple[FitResult, int]:
    """The engine over batches of runs; then the run at the fitted values into
    ``root/fitted``. Returns the result and the runs made."""
    trials = Trials(chosen, root / ".trials")
    job, parameters = fit_set.job, fit_set.parameters
    signals = list(fit_set.signals)
    numbers = itertools.count()

    def simulate(batch: list[np.ndarray]) -> list[dict[str, tuple[np.ndarray, np.ndarray]]]:
        runs = [at_point(job, parameters, list(x), f"trial-{next(numbers):05d}",
                         record=signals,
                         metrics=False) for x in batch]
        return trials.run(runs, parameters, [list(x) for x in batch], signals)

    engine = [Parameter(p.name, p.start, *fit_set.bounds[p.name]) for p in parameters]
    try:
        result = fit_signals(simulate, fit_set.data, fit_set.signals, engine,
                             weights=fit_set.weights or None, max_nfev=max_evaluations)
    finally:
        shutil.rmtree(root / ".trials", ignore_errors=True)  # ours: the batches' folders
    values = [result.values[p.name] for p in parameters]
    fitted = at_point(job, parameters, values, FITTED)
    outcome = chosen.run([fitted], root, lambda steps: None, lambda: None)[0]
    if outcome["status"] != "complete":
        raise TrialFailed(f"fit: the run at the fitted values {outcome['status']}: "
                          f"{outcome['error']}")
    return result, trials.runs + 1


def _record(fit_set: FitSetup, result: FitResult, runs: int, jobs: int | None,
            dask: str | None, max_evaluations: int | None,
            users: list[str]) -> dict[str, Any]:
    """fit_run.json's content."""
    manifest = fit_set.manifest
    try:
        data_sha = file_sha256(fit_set.data_path)
    except OSError as error:
        raise OutputError(f"{fit_set.data_path}: cannot read: {error.strerror}") from None
    return {
        "manifest": manifest.name, "manifest_path": os.path.abspath(manifest.path),
        "manifest_sha256": manifest.sha256, "variant": fit_set.job.variant,
        "data": str(manifest.fit.data) if manifest.fit else None,
        "data_path": os.path.abspath(fit_set.data_path), "data_sha256": data_sha,
        "samples": int(fit_set.data.time.size),
        "data_interval": [float(fit_set.data.time[0]), float(fit_set.data.time[-1])],
        "simulation": {"start": manifest.start, "stop": manifest.stop,
                       "step": manifest.step},
        "signals": dict(fit_set.signals), "weights_given": dict(fit_set.weights),
        "parameters": {p.name: {"start": p.start, "min": fit_set.bounds[p.name][0],
                                "max": fit_set.bounds[p.name][1], "unit": p.unit}
                       for p in fit_set.parameters},
        "solver": {"method": "scipy.optimize.least_squares (trf, bounds, x_scale=jac)",
                   "max_evaluations": max_evaluations},
        "runs": runs, "runner": f"dask {dask}" if dask else f"local, jobs {jobs or 'auto'}",
        "converged": result.converged, "kept_user_files": users, "versions": versions()}
