"""``agv-cosim fit MANIFEST --out DIR``: the tunable parameters of a manifest's run
fitted so that its recorded signals match measured data, the co-simulation itself the
model (output error; docs/fit.md).

The manifest's ``[fit]`` table names the data (a CSV file relative to the manifest), the
signals fitted to its columns, optional weights and the parameters with their bounds
(the start is the run's value). The set-up is checked before any run, each problem one
line, exit 2 (:func:`.checks.setup`): the run (one: a variant chosen with ``--variant`` when the
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
from ..files import MARKER, AtomicDir, write_json, write_text
from ..fitting import FitResult, Parameter
from ..fitting import fit as fit_signals
from ..manifest import Manifest
from ..pipeline.resume import keep_user_files
from ..pipeline.trials import KeptLocalRunner, Trials, at_point, runner
from ..report.records import versions
from ..system.files import file_sha256
from . import output
from .checks import FitSetup, setup

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
class FitOutcome:
    """What :func:`fit_manifest` did: the engine's ``result``, the ``folder`` written
    (None without ``out``), the ``setup``, the ``runs`` made (the fitted run too)."""

    result: FitResult
    folder: Path | None
    setup: FitSetup
    runs: int


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
        users = keep_user_files(folder.target, root, OURS) if folder is not None else []
        result, runs = _solve(fit_set, chosen, root, max_evaluations)
        if folder is None:
            return FitOutcome(result, None, fit_set, runs)
        record = _record(fit_set, result, runs, jobs, dask, max_evaluations, users)
        write_json(root / RESULT, result.as_json())
        write_json(root / RECORD, record)
        write_text(root / FRAGMENT, output.fragment(fit_set, result, VARIANT))
        output.draw(root / FIGURE, fit_set, result)
        write_text(root / PAGE, output.render(fit_set, result, record))
        if not result.converged:
            reason = f"fit not converged ({result.message}); the best point found is kept"
            folder.mark(complete=False, reason=reason)
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
