"""Runs, variants, sweeps and parallel workers: a manifest's jobs run and its output
folder written.

:func:`execute` runs the jobs (:func:`agv_cosim.pipeline.prepare.prepare`) in worker
processes (:mod:`agv_cosim.workers.pool`; up to ``workers`` at once) or on a Dask cluster
(:mod:`agv_cosim.workers.distributed`), and writes the output folder::

    DIR/<run label>/timeseries.csv   time, then component.variable (csv module; repr floats)
    DIR/<run label>/metrics.json     metrics of the run (agv_cosim.report.metrics)
    DIR/<run label>/run.json         hashes, parameters, versions, status, and the run's
                                     inputs with their SHA-256
    DIR/<run label>/output.txt       what the run's process printed (only if it did)
    DIR/summary.csv                  one row per run: label, status, sweep values, metrics
    DIR/timings.csv                  one row per run: label, wall time, real-time pacing
                                     (agv_cosim.report.records.TIMING_COLUMNS)
    DIR/*.png                        the runs overlaid (agv_cosim.report.plots)
    DIR/montecarlo.json, .png        with [montecarlo] (agv_cosim.report.montecarlo)
    DIR/index.html                   the report (agv_cosim.report.page)
    DIR/partial.txt                  only in a folder kept after an interruption

A run's status is ``complete``, ``partial`` (rows recorded, then a failure), ``failed``,
``timed out`` (stopped at its wall-clock limit), ``interrupted`` (under way when a
signal came) or ``not run``.

Each run is independent and deterministic, and no file but ``timings.csv`` holds a
measurement of time, a date or anything else of the machine's timing: every other file
is byte-identical between two runs of the same manifest, FMUs and seeds, parallel or
serial. With ``resume`` the complete runs of an earlier ``DIR`` whose inputs are
unchanged are kept instead of run again, and what the command does not write (other
variants' runs, a user's files) is kept as it is (:mod:`.resume`); with ``real_time`` the one run
is paced to the wall clock (:class:`~agv_cosim.execution.Pacer`; its row of timings.csv
says how it went). ``DIR`` is assembled under a temporary name and
renamed into place; on SIGINT, SIGTERM or SIGHUP it is renamed into place marked partial
when any run has rows.
"""

import os
import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import Any

from ..errors import FolderLost, OutputError, ReportError, RunsStopped
from ..execution.pacing import factor_problem
from ..files import AtomicDir, printable, write_summary, write_text
from ..manifest import Manifest
from ..report import montecarlo, plots
from ..report.page import REPORT_FILE, draw_figures, write_report_quietly
from ..report.records import TIMINGS, RunResult, summary_rows, write_timings
from ..system import Job
from ..workers.initcheck import plan_checks
from ..workers.pool import call_concurrently
from ..workers.runner import DaskRunner, LocalRunner, Runner
from .prepare import prepare
from .resume import check_resumable, keep_others, keep_users, listed, reuse_runs
from .stepcheck import FACTORS, step_check, step_check_lines

__all__ = ["check_options", "default_out_dir", "execute", "progress_bar", "run_manifest"]


def default_out_dir(manifest: Manifest) -> Path:
    """``results/<manifest name>`` relative to the current folder."""
    return Path("results") / manifest.name


def execute(manifest: Manifest, jobs: list[Job], out_dir: str | Path | None = None,
            workers: int | None = None, quiet: bool = False, overwrite: bool = False,
            dask: str | None = None, resume: bool = False,
            real_time: float | None = None,
            init_limit: float | None = None,
            check_step: bool = False) -> tuple[Path, list[RunResult]]:
    """Run ``jobs`` and write the output folder (see the module docstring).

    Parameters
    ----------
    manifest : Manifest
    jobs : list of Job
    out_dir : path, optional
        Default :func:`default_out_dir`.
    workers : int, optional
        Runs at once, each in its own process (default: one per core).
    quiet : bool
        No progress bars.
    overwrite : bool
        Replace ``out_dir`` even when it is not a result folder of ours (see
        :class:`~agv_cosim.report.AtomicDir`; without it such a folder is refused).
    dask : str, optional
        Address of a Dask scheduler (``tcp://HOST:PORT``): run the jobs on that cluster
        (see :mod:`agv_cosim.distributed`) instead of local processes; ``workers`` is
        then unused. Raises :class:`~agv_cosim.distributed.ClusterError`.
    resume : bool
        Keep every complete run of the result folder ``out_dir`` whose inputs are
        unchanged, run the others, keep the runs of variants not in ``jobs`` and every
        file this tool does not write as they are (:mod:`.resume`); with every variant
        run, the folder written is the one a run without ``resume`` writes but for
        timings.csv (whose rows of the reused runs are the earlier ones) and the user's
        files kept. Raises
        :class:`~agv_cosim.errors.OutputError` when ``out_dir`` is not ours or of
        another manifest, or with ``overwrite``.
    real_time : float, optional
        Pace the one run at this real-time factor (:class:`~agv_cosim.execution.Pacer`;
        1 is the wall clock); its result's ``real_time`` and its row of timings.csv
        say how it went.
        Refused (:func:`check_options`) for more than one run, or with ``dask`` or
        ``resume``.
    init_limit : float, optional
        Do the initialisation check (:func:`~.initcheck.plan_checks`) of the runs to do,
        each FMU given this many seconds, in the first local worker before its first
        run (:func:`~.pool.run_isolated`): a refusal raises its
        :class:`~agv_cosim.errors.ManifestError` and no folder is written. Not with
        ``dask`` (refused).
    check_step : bool
        Run each complete run again at step/2 and step/4 through the same workers and
        write ``step_check.json`` (:mod:`.stepcheck`), shown on the page; a refinement
        that fails is said there, the base results stay as they are.

    Returns
    -------
    (Path, list of dict)
        The output folder and one result dict per job (in job order).
    """
    out_dir = Path(out_dir) if out_dir else default_out_dir(manifest)
    jobs = _prepare(manifest, jobs, out_dir, overwrite, dask, resume, real_time,
                    init_limit)
    about = {"manifest": manifest.name, "manifest_sha256": manifest.sha256}
    with AtomicDir(out_dir, overwrite=overwrite, about=about) as folder:
        start = _start(folder, manifest, jobs, resume, quiet)
        workers_asked = max(1, workers or os.cpu_count() or 1)
        workers = min(workers_asked, max(1, len(start.todo)))
        results = _run(manifest, jobs, start, folder, workers, dask, init_limit, quiet)
        _write_summary(folder, listed(manifest, results, start.kept))
        if check_step:
            _check_steps(manifest, jobs, results, start.written, workers, dask, quiet)
        page_error = _finish(manifest, jobs, results, start.written, workers_asked)
        target = folder.commit()
    if page_error:  # the results are kept: the command fails, saying where they are
        raise ReportError(f"{target / REPORT_FILE}: not written ({page_error}); the "
                          f"results are in {target}", kept=target, results=results)
    return target, results


def _prepare(manifest: Manifest, jobs: list[Job], out_dir: Path, overwrite: bool,
             dask: str | None, resume: bool, real_time: float | None,
             init_limit: float | None) -> list[Job]:
    """The options of :func:`execute` checked before any folder is touched, and the
    jobs to run (each paced at ``real_time`` when given)."""
    check_options(jobs, overwrite, dask, resume, real_time)
    if init_limit is not None and dask:
        raise OutputError("the initialisation check runs on this machine, not with --dask")
    if real_time is not None:
        jobs = [replace(job, real_time=real_time) for job in jobs]
    if resume:  # before AtomicDir, whose refusal of a folder not ours speaks of replacing
        check_resumable(out_dir, manifest)
    return jobs


@dataclass(frozen=True)
class _Start:
    """What :func:`execute` starts from in the new folder ``written``: the earlier runs
    it reuses (by job index; ``--resume``), the runs of other variants it keeps, and the
    jobs left to run."""

    written: Path
    reused: dict[int, RunResult]
    kept: list[RunResult]
    todo: list[Job]


def _start(folder: AtomicDir, manifest: Manifest, jobs: list[Job], resume: bool,
           quiet: bool) -> _Start:
    """Carry into ``folder`` what of its earlier content is kept (:mod:`.resume`: the
    reused runs, other variants' runs, the user's files), say so on stderr unless
    ``quiet``, and list the jobs left to run."""
    written = folder.path
    assert written is not None
    reused = reuse_runs(folder.target, manifest, jobs, written) if resume else {}
    kept, users = keep_others(folder.target, manifest, jobs, written) if resume \
        else ([], keep_users(folder.target, jobs, written))
    todo = [job for i, job in enumerate(jobs) if i not in reused]
    if not quiet:
        _say_kept(folder.target, len(jobs), len(todo), len(reused) if resume else None,
                  kept, users)
    return _Start(written, reused, kept, todo)


def _run(manifest: Manifest, jobs: list[Job], start: _Start, folder: AtomicDir,
         workers: int, dask: str | None, init_limit: float | None,
         quiet: bool) -> list[RunResult]:
    """Run ``start.todo`` on ``workers`` (or the cluster at ``dask``) with a progress bar
    and return the results of all ``jobs`` in job order, the reused ones merged in, each
    checked against its files. When the runs are stopped (RunsStopped) the folder is
    kept marked partial (:func:`_keep_partial`) and the error raised again."""
    reused, todo = start.reused, start.todo
    total = sum(job.plan.steps for job in todo)
    # smoothing 0: the rate (and the ETA) averaged since the start, not over the last
    # updates, which the first runs' start-up (FMUs unpacked, loaded) makes slow
    bar = progress_bar()(total=total, desc=manifest.name, unit="step", delay=2.0,
                         disable=quiet, file=sys.stderr, mininterval=0.5, smoothing=0,
                         postfix={"runs": f"{len(reused)}/{len(jobs)}"})
    finished = len(reused)

    def run_done() -> None:
        nonlocal finished
        finished += 1
        bar.set_postfix(runs=f"{finished}/{len(jobs)}")

    try:
        ran = _runner(manifest, jobs, todo, workers, dask, init_limit).run(
            todo, start.written, bar.update, run_done) if todo else []
    except RunsStopped as stop:
        bar.close()  # before any message: the error is the last line on stderr
        if reused:
            stop.results = _merged(len(jobs), reused, stop.results)
        _keep_partial(manifest, jobs, folder, stop, start.kept)
        raise
    except BaseException:
        bar.close()  # before any message: the error is the last line on stderr
        raise
    bar.close()
    results = _merged(len(jobs), reused, ran)
    folder.check_intact()
    return [_checked_files(job, result, start.written)
            for job, result in zip(jobs, results)]


def _check_steps(manifest: Manifest, jobs: list[Job], results: list[RunResult],
                 written: Path, workers: int, dask: str | None, quiet: bool) -> None:
    """``--check-step``: the refinements of the complete runs, on the runner of the
    runs (:func:`_runner`), and ``step_check.json``; its findings on stderr."""
    complete = [job for job, r in zip(jobs, results) if r["status"] == "complete"]
    total = sum(job.plan.steps * factor for job in complete for factor in FACTORS)
    bar = progress_bar()(total=total, desc=f"{manifest.name} step check", unit="step",
                         delay=2.0, disable=quiet, file=sys.stderr, mininterval=0.5,
                         smoothing=0)

    def run(todo: list[Job], root: Path) -> list[RunResult]:
        root.mkdir(parents=True, exist_ok=True)
        runner = _runner(manifest, jobs, todo, min(workers, len(todo)), dask, None)
        return runner.run(todo, root, bar.update, lambda: None)

    try:
        data = step_check(jobs, results, written, run)
    finally:
        bar.close()
    if not quiet:
        for line in step_check_lines(data):
            print(printable(f"agv-cosim: {line}"), file=sys.stderr)


def _say_kept(target: Path, runs: int, todo: int, reused: int | None,
              kept: list[RunResult], users: list[str]) -> None:
    """On stderr: what ``--resume`` reused (``reused`` of ``runs``; None: no resume)
    and the runs of other variants it kept; the user's files kept."""
    if reused is not None:
        print(printable(f"agv-cosim: resume: reused {reused} of {runs} "
                        f"run(s) of {target}; running {todo}"
                        + (f"; kept {len(kept)} run(s) of other variants as they "
                           "are" if kept else "")), file=sys.stderr)
    if users:
        shown = ", ".join(users[:5]) + (f" and {len(users) - 5} more"
                                         if len(users) > 5 else "")
        print(printable(f"agv-cosim: kept {len(users)} file(s) not written by "
                        f"agv-cosim: {shown}"), file=sys.stderr)


def _runner(manifest: Manifest, jobs: list[Job], todo: list[Job], workers: int,
            dask: str | None, init_limit: float | None) -> Runner:
    """What runs ``todo`` (of ``jobs``): the cluster at ``dask``, else ``workers`` local
    processes, the first doing the initialisation check with ``init_limit``."""
    if dask:
        return DaskRunner(dask)
    checks = plan_checks(manifest, todo, init_limit) if init_limit is not None else None
    # the figures' imports while the runs are under way
    return LocalRunner(workers, checks,
                       plots.import_drawing if _draws(manifest, len(jobs)) else None)


def check_options(jobs: list[Job], overwrite: bool = False, dask: str | None = None,
                  resume: bool = False, real_time: float | None = None) -> None:
    """Refuse options of :func:`execute` that do not go together
    (:class:`~agv_cosim.errors.OutputError`, one line)."""
    if resume and overwrite:
        raise OutputError("--resume and --overwrite exclude each other (--resume keeps "
                          "the complete runs of a result folder of ours, --overwrite "
                          "replaces any folder)")
    if real_time is None:
        return
    if not (real_time > 0 and real_time != float("inf")):
        raise OutputError(f"--real-time: {real_time!r} must be a positive, finite factor")
    span = max((job.plan.stop - job.plan.start for job in jobs), default=None)
    problem = factor_problem(real_time, span)
    if problem is not None:
        raise OutputError(f"--real-time: {problem}")
    if len(jobs) != 1:
        raise OutputError(f"--real-time: paces one run; the manifest has {len(jobs)} "
                          "(choose one with --variant, or a manifest without a sweep)")
    if dask:
        raise OutputError("--real-time: runs on this machine, not with --dask")
    if resume:
        raise OutputError("--real-time and --resume exclude each other")


def _merged(count: int, reused: dict[int, RunResult],
            ran: list[RunResult]) -> list[RunResult]:
    """The results of all ``count`` jobs in job order: the reused ones by index, the
    others from ``ran`` (in order)."""
    others = iter(ran)
    return [reused[i] if i in reused else next(others) for i in range(count)]


def progress_bar() -> type:
    """tqdm whose ``close`` ends the bar's line whenever the bar was drawn; in a Jupyter
    kernel with ipywidgets installed, tqdm's notebook bar (a widget) instead.

    tqdm's ``close`` leaves the line open when no ``update`` drew the bar after its
    ``delay``, although ``set_postfix`` and tqdm's monitor thread draw it through
    ``refresh``; a message printed after ``close`` would then land on the bar's line.
    In a kernel without ipywidgets the text bar goes to the cell's stderr, which
    Jupyter redraws in place."""
    if _in_kernel():
        from tqdm.notebook import tqdm as notebook_bar

        widget: type = notebook_bar
        return widget
    from tqdm import tqdm

    class Bar(tqdm):  # type: ignore[misc]  # tqdm ships no types
        drawn = False
        # no monitor thread: the runs' processes are forked from this process while it
        # has a single thread (agv_cosim.workers.channels.process_context)
        monitor_interval = 0

        def display(self, *args: Any, **kwargs: Any) -> Any:
            self.drawn = True
            return super().display(*args, **kwargs)

        def close(self) -> None:
            state: dict[str, Any] = self.__dict__
            if self.drawn and not self.disable and "last_print_t" in state:
                state["last_print_t"] = max(state["last_print_t"], self.start_t + self.delay)
            super().close()

    return Bar


def _in_kernel() -> bool:
    """Whether this is a Jupyter (IPython) kernel that can show tqdm's widget bar."""
    import importlib.util

    ipython = sys.modules.get("IPython")
    get_ipython = getattr(ipython, "get_ipython", None)
    shell = get_ipython() if callable(get_ipython) else None
    if shell is None or "IPKernelApp" not in getattr(shell, "config", {}):
        return False
    return importlib.util.find_spec("ipywidgets") is not None


def _write_summary(folder: AtomicDir, results: list[RunResult]) -> None:
    """summary.csv and timings.csv of ``results``."""
    assert folder.path is not None
    write_summary(folder.path / "summary.csv", summary_rows(results))
    write_timings(folder.path / TIMINGS, results)


def _checked_files(job: Job, result: RunResult, root: str | Path) -> RunResult:
    """``result``, unless the run's files are not what its process wrote (its folder
    removed or changed during the sweep): then the run is ``failed`` and says why."""
    if result["status"] not in ("complete", "partial"):
        return result
    run_dir = Path(root) / job.label
    problem = None
    try:
        size = (run_dir / "timeseries.csv").stat().st_size
        if not (run_dir / "run.json").is_file():
            problem = "its run.json is missing"
        elif result.get("csv_bytes") is not None and size != result["csv_bytes"]:
            problem = (f"its timeseries.csv has {size} bytes, {result['csv_bytes']} were "
                       "written")
    except OSError:
        problem = "its timeseries.csv is missing"
    if problem is None:
        return result
    return RunResult(**{**result, "status": "failed", "metrics": {},
                        "error": f"its folder was removed or changed during the sweep "
                                 f"({problem}); its results are lost"})


def _keep_partial(manifest: Manifest, jobs: list[Job], folder: AtomicDir,
                  stop: RunsStopped, kept: list[RunResult] | None = None) -> None:
    """After an interruption (or a cluster that went away), commit the folder marked
    partial, with its summary, timings and report (index.html), when a run has results
    (``stop.results``, one per job); ``stop.kept`` is then the folder. ``kept``: the
    runs of other variants ``--resume`` kept (listed in summary.csv too). Termination
    signals stay ignored meanwhile (until ``stop.restore``)."""
    try:
        results = stop.results
        if not any(r["rows"] for r in results):
            return
        if not folder.intact():
            return
        results = [_checked_files(job, result, str(folder.path))
                   for job, result in zip(jobs, results)]
        complete = sum(r["status"] == "complete" for r in results)
        try:
            _write_summary(folder, listed(manifest, results, kept or []))
            folder.mark_partial(stop.reason, complete, len(results))
            # the page of what was kept, partial.txt shown on it
            report_error = write_report_quietly(str(folder.path))
            if report_error:
                print(printable(f"agv-cosim: warning: {manifest.path}: report: "
                                f"{report_error}"), file=sys.stderr)
            stop.kept = folder.commit()
        except (OSError, FolderLost):  # nothing to keep: the first error is the story
            return
        stop.results = results
    finally:
        stop.restore()


def _finish(manifest: Manifest, jobs: list[Job], results: list[RunResult], written: Path,
            workers: int) -> str | None:
    """Write ``montecarlo.json``, then every figure of the folder (montecarlo.png, the
    ``[plots]`` figures, the page's figures; each task writes its own files) in up to
    ``workers`` processes at once (:func:`~.pool.call_concurrently`), then index.html,
    which lists the figures written. A figure's failure is written to the folder
    (``*_error.txt``; the page shows it, with no image for that figure) and said on
    stderr; the results stay. Returns why index.html was not written (None: it was)."""
    tasks: list[Callable[[], str | list[str] | None]] = []
    if manifest.montecarlo is not None:
        montecarlo.write_aggregate(manifest.montecarlo, jobs, results, written)
        tasks.append(partial(montecarlo.draw, manifest.montecarlo, jobs, results, written,
                             manifest.name))
    if manifest.plots:
        tasks.append(partial(_plots, manifest, jobs, results, written))
    if len(results) > 1:  # the page compares runs: of one run it draws no figure
        tasks.append(partial(draw_figures, written))
    outcomes = call_concurrently(tasks, workers,
                                 lambda failure: f"{type(failure).__name__}: {failure}")
    if manifest.montecarlo is not None:
        figure_error = outcomes.pop(0)
        if figure_error:
            write_text(written / "montecarlo_error.txt", f"{figure_error}\n")
            print(printable(f"agv-cosim: warning: {manifest.path}: montecarlo figure: "
                            f"{figure_error}"), file=sys.stderr)
    plot_error = outcomes.pop(0) if manifest.plots else None
    if plot_error:
        write_text(written / "plots_error.txt", f"{plot_error}\n")
        print(printable(f"agv-cosim: warning: {manifest.path}: plots: {plot_error}"),
              file=sys.stderr)
    drawn = outcomes.pop(0) if outcomes else []
    # index.html, read from the folder's files (the figures drawn above among them)
    report_error = printable(drawn) if isinstance(drawn, str) else \
        write_report_quietly(written, drawn)
    page = written / REPORT_FILE
    if not (page.is_file() and page.stat().st_size > 0):
        return report_error or "no page"
    if report_error:  # the page is there, without a figure it says could not be drawn
        print(printable(f"agv-cosim: warning: {manifest.path}: report: {report_error}"),
              file=sys.stderr)
    return None


def _draws(manifest: Manifest, runs: int) -> bool:
    """Whether the result folder of ``runs`` runs of ``manifest`` has figures
    (:func:`_finish`): a Monte Carlo, ``[plots]``, or the page's comparison of runs."""
    return manifest.montecarlo is not None or bool(manifest.plots) or runs > 1


def _plots(manifest: Manifest, jobs: list[Job], results: list[RunResult],
           out_dir: Path) -> str | None:
    if not manifest.plots:
        return None
    try:
        runs = []
        for job, result in zip(jobs, results):
            if not result["rows"]:
                continue
            # read in chunks and decimated: the parent never holds a run's time series
            run = plots.read_run(out_dir / job.label / "timeseries.csv", manifest.plots,
                                 job.label, rows=result["rows"],
                                 partial=result["status"] != "complete")
            run.events = [(event.at, event.name) for event in job.plan.events]
            runs.append(run)
        if runs:
            plots.plot_runs(runs, manifest.plots, out_dir, base_dir=manifest.files_dir)
    except Exception as failure:  # noqa: BLE001 - a plot must not lose the results
        return f"{type(failure).__name__}: {failure}"
    return None


def run_manifest(manifest_path: str | Path, out_dir: str | Path | None = None,
                 variants: list[str] | None = None, sets: Iterable[str] = (),
                 workers: int | None = None, quiet: bool = False
                 ) -> tuple[Path, list[RunResult], list[str]]:
    """Validate and run a manifest; return (out folder, results, warnings)."""
    manifest, jobs, warnings = prepare(manifest_path, variants, sets)
    target, results = execute(manifest, jobs, out_dir, workers, quiet)
    return target, results, warnings
