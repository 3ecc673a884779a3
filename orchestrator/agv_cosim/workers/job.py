"""One job run into its folder: the simulation with its CSV recorded, then its record
(metrics, ``metrics.json`` and ``run.json``: :func:`agv_cosim.report.records.finish_run`)."""

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from .. import fmitypes
from ..errors import SimulationError
from ..execution import CsvObserver, Observer, Pacer, ProgressObserver, simulate
from ..execution.track import Track
from ..report.records import RunResult, finish_run
from ..system import Job
from ..timeseries import CsvSink

__all__ = ["run_job"]


def run_job(job: Job, run_dir: str | Path, progress: Callable[[int], None] | None = None,
            track: Track | None = None,
            on_message: Callable[[str, int, str], None] | None = None,
            fast: bool = True, pacing: Any = None) -> RunResult:
    """Run one job into ``run_dir`` (created; its parent must exist); return its result.

    Never raises for a simulation failure: the status is ``complete``, ``partial`` (some
    rows recorded, then a failure) or ``failed`` (nothing recorded). ``track``,
    ``on_message`` and ``fast`` are passed to :func:`~agv_cosim.execution.simulate`
    (``fast``: its generated per-step functions). ``csv_bytes`` in the result is the
    size of the ``timeseries.csv`` written, ``wall_time_s`` the run's wall time (of the
    simulation with its time series written). A job with ``real_time`` is paced at
    that factor (:class:`~agv_cosim.execution.Pacer`); ``real_time`` in the result is then
    the pacer's report; its figures are kept in ``pacing`` when given (a sequence of
    :data:`~agv_cosim.execution.pacing.FIGURES` floats, e.g. shared with the process
    that may have to end this one). The timings are in the result only, never in the
    run's files.
    """
    run_dir = Path(run_dir)
    run_dir.mkdir(exist_ok=True)  # never its parents: a removed result folder stays gone
    types = job.plan.record_types()
    sink = CsvSink(run_dir / "timeseries.csv", job.plan.record,
                   None if all(t.is_float for t in types) else
                   [fmitypes.record_format(t) for t in types])
    observers: list[Observer] = [CsvObserver(sink)]
    if progress is not None:
        observers.append(ProgressObserver(progress))
    error, ended_by = None, None
    pace = None if job.real_time is None else Pacer(job.real_time, job.plan.start, pacing)
    begin = time.perf_counter()
    try:
        outcome = simulate(job.plan, observers, track=track, on_message=on_message,
                           fast=fast, pace=pace)
        ended_by = outcome.ended_by
    except SimulationError as failure:
        error = str(failure)
    except OSError as failure:  # writing the results failed (disk full, ...)
        error = f"cannot write {failure.filename or sink.path}: {failure.strerror or failure}"
    finally:
        try:
            sink.close()
        except OSError as failure:
            error = error or f"cannot write {sink.path}: {failure.strerror or failure}"
    rows = sink.rows
    wall = time.perf_counter() - begin
    status = "complete" if error is None else ("partial" if rows else "failed")
    result = finish_run(job, run_dir, rows, status, error, ended_by, sink.sha256())
    result["csv_bytes"] = sink.bytes
    result["wall_time_s"] = wall
    if pace is not None:
        result["real_time"] = pace.report()
    return result
