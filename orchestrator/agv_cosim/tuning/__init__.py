"""``agv-cosim tune`` and :func:`agv_cosim.tune`: the parameters of a manifest's
``[tune]`` table that minimise its objective over all of the manifest's runs (docs/tune.md).
(The package is ``tuning`` so that ``agv_cosim.tune`` stays the function.)

:mod:`.setup` checks ``[tune]`` against the runs; the candidates become runs through
:class:`agv_cosim.pipeline.tune_trials.TrialRuns` over
:class:`agv_cosim.pipeline.trials.Trials` (the runner of ``agv-cosim fit``: the local
pool, its workers kept between batches, or a Dask cluster); the search is
:func:`agv_cosim.fitting.tune`; then the original and the tuned parameters run once more
on every run for the comparison, and :mod:`.output` writes the folder.
"""

from __future__ import annotations

import os
import re
import shutil
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import OutputError
from ..files import AtomicDir, marker_data, printable
from ..fitting import TuneResult, tune
from ..manifest import Manifest, load_manifest
from ..pipeline import prepare
from ..pipeline.trials import KeptLocalRunner, Trials, runner
from ..pipeline.tune_trials import TrialRuns, jobs_at
from ..report.records import RunResult
from ..system import Job
from ..workers.runner import Runner
from .setup import Setup, available_metrics, check_tune

__all__ = ["Setup", "Tuning", "available_metrics", "check_tune", "keep_users",
           "tune_manifest"]


@dataclass
class Tuning:
    """What a tuning found and wrote: the search's :class:`~agv_cosim.fitting.TuneResult`,
    tune.json's content (``record``), the runs of the original and the tuned parameters
    (their jobs and results, in the manifest's run order), the runs that failed during
    the trials, and the folder written."""

    result: TuneResult
    record: dict[str, Any]
    setup: Setup
    original: list[tuple[Job, RunResult]]
    tuned: list[tuple[Job, RunResult]]
    failures: list[dict[str, Any]]
    folder: Path


def tune_manifest(manifest: str | Path | Manifest, out: str | Path, *,
                  workers: int | None = None, dask: str | None = None,
                  overwrite: bool = False, quiet: bool = False,
                  timeout: float | None = None) -> Tuning:
    """Tune the parameters of ``manifest``'s ``[tune]`` over all of its runs and write
    the folder ``out`` (see the package docstring and docs/tune.md).

    Raises :class:`~agv_cosim.errors.ManifestError` for a bad manifest or ``[tune]``,
    :class:`~agv_cosim.errors.OutputError` for a folder that is not ours,
    :class:`~agv_cosim.errors.TuneError` for a search that cannot be set up."""
    from .output import tune_record, write_folder

    if not isinstance(manifest, Manifest):
        manifest = load_manifest(manifest)
    manifest, jobs, _ = prepare(manifest, timeout=timeout)
    setup = check_tune(manifest, jobs)
    about = {"command": "tune", "manifest": manifest.name,
             "manifest_sha256": manifest.sha256}
    chosen = runner(workers, dask)
    with AtomicDir(out, overwrite=overwrite, about=about) as folder:
        assert folder.path is not None
        kept = keep_users(folder.target, folder.path)
        if kept and not quiet:
            print(printable(f"agv-cosim tune: kept {len(kept)} file(s) not written by "
                            f"agv-cosim: {', '.join(kept[:5])}"), file=sys.stderr)
        try:
            with tempfile.TemporaryDirectory(prefix=".trials-", dir=folder.path) as scratch:
                trials = TrialRuns(manifest, setup.names, tuple(setup.objective.metrics),
                                   Trials(chosen, Path(scratch), "tune"), timeout,
                                   on_batch=None if quiet else _say_batch(len(jobs)))
                result = tune(trials, setup.parameters, setup.objective,
                              method=setup.method,  # type: ignore[arg-type]
                              seed=setup.seed, generations=setup.generations,
                              popsize=setup.popsize, tol=setup.tol)
            original = _final_runs(manifest, setup, result.start, chosen,
                                   folder.path / "original", timeout)
            tuned = _final_runs(manifest, setup, result.best, chosen,
                                folder.path / "tuned", timeout)
        finally:
            if isinstance(chosen, KeptLocalRunner):
                chosen.close()
        record = tune_record(manifest, setup, result, trials.failures, len(jobs))
        write_folder(folder.path, manifest, setup, result, record, original, tuned)
        target = folder.commit()
    return Tuning(result=result, record=record, setup=setup, original=original,
                  tuned=tuned, failures=trials.failures, folder=target)


#: What ``tune`` writes into its folder (the rest of a folder it replaces is the user's).
_OURS = re.compile(r"^(tune\.json|tuned_variant\.toml|index\.html|original|tuned|"
                   r"tune_history\.png|tune_run\d+\.png|\.agv-cosim)$")


def keep_users(target: Path, root: Path) -> list[str]:
    """Carry every entry of the earlier tune folder ``target`` that ``tune`` does not
    write into the new folder ``root`` (hard links, else copies; a link stays a link):
    replacing a folder of ours never deletes a user's file. Nothing when ``target`` is
    not a tune folder with our marker. Returns the entries kept."""
    about = marker_data(target) if target.is_dir() and not target.is_symlink() else None
    if about is None or about.get("command") != "tune":
        return []
    kept = []
    for entry in sorted(os.listdir(target)):
        if _OURS.match(entry):
            continue
        old, new = target / entry, root / entry
        if old.is_dir() and not old.is_symlink():
            shutil.copytree(old, new, symlinks=True, copy_function=_link_or_copy)
        elif old.is_symlink():
            os.symlink(os.readlink(old), new)
        else:
            _link_or_copy(str(old), str(new))
        kept.append(entry)
    return kept


def _link_or_copy(source: str, destination: str) -> None:
    try:
        os.link(source, destination, follow_symlinks=False)
    except OSError:
        shutil.copy2(source, destination, follow_symlinks=False)


def _final_runs(manifest: Manifest, setup: Setup, values: dict[str, float],
                chosen: Runner, root: Path, timeout: float | None
                ) -> list[tuple[Job, RunResult]]:
    """Every run of ``manifest`` at the parameter ``values`` through ``chosen``, into
    ``root/<run>`` (kept: the folder's results)."""
    jobs = jobs_at(manifest, setup.names, [values[n] for n in setup.names], timeout)
    try:
        root.mkdir()
    except OSError as error:
        raise OutputError(f"{root}: cannot create: {error.strerror}") from None
    return list(zip(jobs, chosen.run(jobs, root, lambda steps: None, lambda: None)))


def _say_batch(runs: int) -> Any:
    """A line on stderr after each batch of trials."""
    def say(evaluated: int, batch_runs: int) -> None:
        print(printable(f"agv-cosim tune: {evaluated} candidate(s) evaluated "
                        f"({batch_runs} run(s) in the last batch, {runs} per candidate)"),
              file=sys.stderr)
    return say
