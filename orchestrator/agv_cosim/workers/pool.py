"""The local worker pool: every job run in a worker process, a worker reused only after a
run that ended complete.

Why worker processes: an FMU runs inside the process that loads it, and a failing
pythonfmu 0.7 FMU can damage its host's heap (see agv_core/fmi/pythonfmu_workarounds.py).
A worker runs the next job only after a run that ended ``complete``; after any other
ending it exits and a fresh worker takes the next job, so the damage ends with the run.
A worker that dies is reported as its run's failure (partial if it had recorded rows),
and the other runs go on. Reusing a worker after clean runs spares each later run the
process start and the import of the FMUs' bundled cores. Each worker leads a process
group of its own, so a run that exceeds its limit is ended with every process its FMUs
started. Workers are forked from the command's process while it runs a single thread
(:func:`process_context`; else they come from a fork server), so they start at once
with what the command has imported.
"""

import gc
import os
import shutil
import signal
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from multiprocessing import get_context
from multiprocessing.connection import Connection, wait
from multiprocessing.process import BaseProcess
from pathlib import Path
from typing import Any

from ..errors import Interrupted, RunsStopped
from ..execution.instance import keep_extractions
from ..execution.pacing import FIGURES, WALL, report_of
from ..execution.track import Track, describe_track
from ..lifetime import (
    TERMINATION_SIGNALS,
    Orphans,
    ignore_termination,
    kill_group,
    scratch_dir,
)
from ..manifest import Manifest
from ..report.records import RunResult, finish_run, record_output, run_result
from ..system import Job
from ..timeseries import count_rows
from .channels import (
    FORKSERVER_PRELOAD,
    OUTPUT_FILE,
    Frames,
    OutputLog,
    child_setup,
    flush_c_stdio,
    inherited_fds,
    process_context,
    send_frame,
    start_process,
)
from .initcheck import InitChecks, plan_checks, run_checks
from .job import run_job

__all__ = ["FORKSERVER_PRELOAD", "IdleWorkers", "Worker", "call_concurrently",
           "check_initialisation", "inherited_fds", "not_run", "process_context",
           "run_isolated", "start_process"]

#: The tasks of :func:`call_concurrently` under way: its forked processes inherit them
#: and are sent an index, so that no task need be pickled.
_TASKS: Sequence[Callable[[], Any]] = ()


def _call_task(index: int) -> Any:
    return _TASKS[index]()


def call_concurrently(tasks: Sequence[Callable[[], Any]], workers: int,
                      failed: Callable[[BaseException], Any]) -> list[Any]:
    """Call each of ``tasks`` and return what they returned, in order.

    With more than one task and ``workers``, while this process runs a single thread,
    in up to ``workers`` processes forked from it (started at once, with this process's
    objects frozen out of their garbage collector, as :func:`start_process`); each
    task's result is sent back pickled. Otherwise here, one after the other. A task that
    raises, or whose process died, gives ``failed(exception)`` instead.
    """
    global _TASKS
    if workers < 2 or len(tasks) < 2 or threading.active_count() != 1:
        return [_guarded(task, failed) for task in tasks]
    sys.stdout.flush()
    sys.stderr.flush()
    _TASKS = tasks
    try:
        with ProcessPoolExecutor(max_workers=min(workers, len(tasks)),
                                 mp_context=get_context("fork"),
                                 initializer=_figure_child) as executor:
            gc.freeze()
            try:  # a fork context starts every process at the first submit
                futures = [executor.submit(_call_task, i) for i in range(len(tasks))]
            finally:
                gc.unfreeze()
            return [_guarded(future.result, failed) for future in futures]
    finally:
        _TASKS = ()


def _figure_child() -> None:
    """Start of a process of :func:`call_concurrently`: a signal is the command's to
    handle (its process group gets the terminal's SIGINT too), so it ignores SIGINT and
    ends at SIGTERM or SIGHUP without a traceback."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for sig in TERMINATION_SIGNALS:
        signal.signal(sig, signal.SIG_DFL)


def _guarded(call: Callable[[], Any], failed: Callable[[BaseException], Any]) -> Any:
    try:
        return call()
    except Exception as failure:  # noqa: BLE001 - given to the caller's ``failed``
        return failed(failure)


def _exit_fd(pid: int | None) -> int | None:
    """A pidfd of process ``pid`` (Linux 5.3 and later), which reads ready once the
    process has ended, or None. A forked worker's sentinel (a pipe the worker holds)
    reads ready while the worker is still exiting, which a wait on it would spin on."""
    pidfd_open = getattr(os, "pidfd_open", None)
    if pidfd_open is None or pid is None:
        return None
    try:
        return int(pidfd_open(pid))
    except OSError:
        return None


def _worker(jobs: Connection, channel: Connection, output: Connection, life: Connection,
            scratch: str, track: Track, inherited: list[int] | None = None,
            checks: list[Any] | None = None, pacing: Any = None) -> None:
    """Body of a worker process: run the jobs the parent sends, one at a time; with
    ``checks`` (:attr:`~agv_cosim.workers.initcheck.InitChecks.items`), first the
    initialisation check (:func:`~agv_cosim.workers.initcheck.run_checks`:
    ``("checked", None)`` when it passed, else the worker exits after its ``failed``
    message).

    ``jobs`` is the reading end of a pipe that brings ``(job, run_dir)`` or None (stop);
    ``channel`` (frames, see above) carries progress, FMU messages and each result back;
    ``output`` receives the process's stdout and stderr; ``life`` closes when the
    command's process ends (see :func:`child_setup`); ``pacing`` (shared with the
    parent) holds a paced run's figures as they are (:class:`~agv_cosim.execution.Pacer`).
    A worker runs the next job only after a run that ended ``complete``: any other
    ending (a failed or partial run, an FMU error) may have left the process damaged (pythonfmu, see
    agv_core/fmi/pythonfmu_workarounds.py), so the worker then exits and the parent
    starts a fresh one. Reusing a worker spares each later run the process start and the
    import of the FMUs' bundled cores (benchmarks/bench_runs.py).

    FMUs are extracted under ``scratch``, which the parent deletes however the worker
    ends (a process that dies cannot clean up after itself). See :func:`child_setup`
    for how the worker lives and ends (``inherited``: see :func:`inherited_fds`).
    """
    child_setup(output, life, inherited, (jobs, channel))
    tempfile.tempdir = scratch
    keep_extractions(scratch)  # each FMU unpacked once per worker (the parent deletes it)
    fd = channel.fileno()

    def send(message: tuple[str, Any]) -> None:
        try:
            send_frame(fd, message)
        except OSError:  # the parent is gone (BrokenPipeError): nobody to report to
            os._exit(1)

    if checks is not None:
        passed = run_checks(checks, send)
        flush_c_stdio()  # what the FMUs printed is in the pipe before the answer
        if not passed:
            os._exit(0)  # a failed pythonfmu instance may have damaged the heap
        send(("checked", None))

    while True:
        try:
            task = jobs.recv()
        except (EOFError, OSError):  # the parent is gone
            os._exit(1)
        if task is None:
            break
        job, run_dir = task
        result = _run_in_worker(job, run_dir, send, track, pacing)
        flush_c_stdio()  # the run's output is in the pipe before its result
        send(("done", result))
        if result["status"] != "complete":
            break
    channel.close()


def _run_in_worker(job: Job, run_dir: Path, send: Callable[[tuple[str, Any]], None],
                   track: Track, pacing: Any) -> RunResult:
    """One job run in a worker (:func:`_worker`): its progress and FMU messages sent."""
    track[:] = [0.0] * len(track)
    warnings = 0

    def message(component: str, status: int, text: str) -> None:
        # errors (and the first 100 warnings) reach the parent before a crash loses them
        nonlocal warnings
        if status >= 3 or (status >= 1 and warnings < 100):
            warnings += status < 3
            send(("message", f"{component}: {' '.join(text.split())}"))

    def progress(steps: int) -> None:
        send(("progress", steps))

    try:
        return run_job(job, run_dir, progress, track, message, pacing=pacing)
    except Exception as failure:  # noqa: BLE001 - e.g. a full disk: report, no traceback
        return run_result(job, "failed", error=f"{type(failure).__name__}: {failure}")


def _ended(job: Job, run_dir: str | Path, status: str | None, how: str, track: Track,
           last_message: str | None, pacing: Any = None) -> RunResult:
    """The summary of a run whose process ended before it reported: ``how`` says what
    happened; ``track`` (shared with the process) names the component, call and time;
    ``last_message`` is the last message an FMU of the run logged (or None). ``status``
    None means ``partial`` with rows recorded, else ``failed``. A paced run's pacing
    figures up to its end are read from ``pacing`` (shared with the process)."""
    result = _ended_result(job, run_dir, status, how, track, last_message)
    if job.real_time is not None and pacing is not None:
        result["real_time"] = report_of(job.real_time, job.plan.start, pacing)
    return result


def _ended_result(job: Job, run_dir: str | Path, status: str | None, how: str,
                  track: Track, last_message: str | None) -> RunResult:
    """:func:`_ended` but for the pacing."""
    run_dir = Path(run_dir)
    csv_file = run_dir / "timeseries.csv"
    rows = count_rows(csv_file) if csv_file.is_file() else 0
    if status is None:
        status = "partial" if rows else "failed"
    if track[0] < 0:  # no FMU call yet: the process ended in its own start
        last_output = _last_output(run_dir)
        error = f"{how} before the run started" + (
            f"; its last output: {last_output}" if last_output else "")
    else:
        error = (f"{how} in {describe_track(track, list(job.plan.models))} after {rows} "
                 "recorded rows" + (f"; last FMU message: {last_message}" if last_message
                                    else ""))
    try:
        run_dir.mkdir(exist_ok=True)  # not its parents: a removed result folder stays gone
        # measured as any partial run, but for an interrupted one
        return finish_run(job, run_dir, rows, status, error,
                          measure=status != "interrupted")
    except OSError:  # the result folder is gone: the result only
        return run_result(job, status, rows=rows, error=error)


def _last_output(run_dir: Path) -> str | None:
    """The last line the run's process wrote (its output.txt), or None."""
    try:
        with open(run_dir / OUTPUT_FILE, "rb") as stream:
            stream.seek(0, os.SEEK_END)
            stream.seek(max(0, stream.tell() - 4096))
            tail = stream.read().decode("utf-8", "replace")
    except OSError:
        return None
    lines = [line.strip() for line in tail.splitlines() if line.strip()]
    return lines[-1] if lines else None


def not_run(job: Job, why: str = "not run") -> RunResult:
    """The summary of a run that never started."""
    return run_result(job, why)


def _process_end(exitcode: int | None) -> str:
    if exitcode is None:
        return "the run's process ended"
    how = f"signal {-exitcode}" if exitcode < 0 else f"exit code {exitcode}"
    return f"the run's process died ({how})"


@dataclass(eq=False)
class Worker:
    """A worker process of :func:`run_isolated` and the parent's ends of its pipes."""

    #: the worker process (the leader of its process group)
    process: BaseProcess
    #: a pidfd of the process (None without pidfd_open), closed by :meth:`release`
    pidfd: int | None
    #: what reads ready once the process ended: the pidfd, else the process's sentinel
    exited: int
    #: the writing end of the jobs pipe: ``(job, run_dir)``, or None to stop
    send: Connection
    #: the frames the worker sends (progress, messages, results)
    frames: Frames
    #: the worker's stdout and stderr, into its run's output.txt
    output: OutputLog
    #: where the worker extracts FMUs (deleted with the worker)
    scratch: str
    #: where the worker is (component, call, time), shared with it
    track: Track
    #: a paced run's figures, shared with it (:class:`~agv_cosim.execution.Pacer`)
    pacing: Any
    #: the index of the job it runs, or None
    index: int | None = None
    #: when its run (or check) must have ended [monotonic s], or None
    deadline: float | None = None
    #: when its run was handed out [monotonic s]: the wall time of a run it does not
    #: report
    started: float = 0.0
    #: True once it was told (or chose) to exit
    leaving: bool = False
    #: True while it does the initialisation check
    checking: bool = False
    #: the index of the check item under way
    checked: Any = None

    def busy(self) -> bool:
        """Whether the worker has a run, a check or its exit under way."""
        return self.index is not None or self.leaving or self.checking

    def handles(self) -> list[int]:
        """What reads ready when the worker ended or sent something."""
        found = [self.exited]
        found += [self.frames.fd] if not self.frames.closed else []
        found += [self.output.fd] if not self.output.closed else []
        return found

    def hand(self, message: Any) -> None:
        """Send ``message`` to the worker; a worker already gone is seen by its end."""
        try:
            self.send.send(message)
        except OSError:
            pass

    def release(self) -> None:
        """Close the parent's ends of the worker's pipes and its pidfd; delete its
        scratch folder (the process has ended)."""
        self.output.close()
        self.send.close()
        self.frames.close()
        if self.pidfd is not None:
            os.close(self.pidfd)
            self.pidfd = None
        shutil.rmtree(self.scratch, ignore_errors=True)


class IdleWorkers:
    """Workers that :func:`run_isolated` leaves running when it returns, for the next
    call to take (a run host's, :mod:`agv_cosim.workers.host`): each ended its last
    run ``complete`` and waits for a job. Their life pipe (see :func:`child_setup`)
    stays open with them; :meth:`close` ends them."""

    def __init__(self) -> None:
        self.workers: list[Worker] = []
        #: (reading end, writing end) of the life pipe, made by the first call
        self.life: tuple[Connection, Connection] | None = None

    def take(self) -> Worker | None:
        """A worker that is still alive (the dead ones cleaned up), or None."""
        while self.workers:
            worker = self.workers.pop()
            if worker.process.is_alive():
                return worker
            self._end(worker)
        return None

    @staticmethod
    def _end(worker: Worker) -> None:
        kill_group(worker.process)
        worker.process.join()
        worker.release()

    def close(self) -> None:
        """End the workers (their process groups killed) and close the life pipe."""
        for worker in self.workers:
            self._end(worker)
        self.workers.clear()
        if self.life is not None:
            for connection in self.life:
                connection.close()
            self.life = None


def run_isolated(jobs: list[Job], root: Path, workers: int,
                 on_progress: Callable[[int], None],
                 on_done: Callable[[], None],
                 idle: IdleWorkers | None = None,
                 checks: InitChecks | None = None,
                 meanwhile: Callable[[], None] | None = None) -> list[RunResult]:
    """Run every job in a worker process, ``workers`` processes at a time (the local
    :class:`~agv_cosim.workers.runner.Runner`).

    A worker runs one job at a time and gets the next one only if its last run ended
    ``complete`` (see :func:`_worker`); otherwise it exits and a fresh worker takes the
    next job, so a failing or crashing FMU affects its own run only. Each worker reports
    through a pipe of its own, read without blocking (one that dies mid-message, or
    whose FMU writes into the pipe, cannot block the others), and its end is seen from
    the process itself (not from the pipe, which a process the FMU forked may hold).

    A run longer than its ``job.timeout`` [s] is stopped (its process group killed) and
    reported ``timed out``; the other runs go on. On SIGINT, SIGTERM or SIGHUP the
    workers are stopped, the runs under way reported ``interrupted`` and the waiting
    ones ``not run``; a :class:`~agv_cosim.errors.RunsStopped` of the signal's kind is
    raised with those results, the termination signals ignored until its ``restore()``
    is called, so that the caller can keep what was done. A run whose process ended
    before it reported has the time from handing it out to its end as its
    ``wall_time_s``.

    With ``idle``, the workers of that :class:`IdleWorkers` take jobs first, and the
    workers whose last run ended ``complete`` are left running in it when the runs are
    done (else every worker is ended before this returns).

    With ``checks`` (:func:`~agv_cosim.workers.initcheck.plan_checks`), the first
    worker does the initialisation check before it takes a job (the other workers run
    meanwhile); an FMU's refusal, or that worker's death, broken channel or overrun of
    ``checks.limit`` per FMU during the check, stops every worker and raises the
    check's :class:`~agv_cosim.errors.ManifestError` (the runs' results are then not
    returned).

    ``meanwhile`` is called once, after the first workers started (work of this
    process that can overlap the runs, e.g. :func:`~agv_cosim.report.plots.import_drawing`).
    """
    assert checks is None or idle is None, "a run host's workers are not checked"
    return _Sweep(jobs, root, workers, on_progress, on_done, idle, checks).run(meanwhile)


#: Why a run whose worker wrote into its result channel was stopped.
_BROKEN_CHANNEL = ("the run's process wrote data that is no message of agv-cosim into its "
                   "result channel (an FMU writing into a file descriptor it does not own) "
                   "and was stopped")


class _Sweep:
    """The state of one :func:`run_isolated`: the jobs, their results, the workers."""

    def __init__(self, jobs: list[Job], root: Path, workers: int,
                 on_progress: Callable[[int], None], on_done: Callable[[], None],
                 idle: IdleWorkers | None, checks: InitChecks | None) -> None:
        self.jobs, self.root, self.workers = jobs, root, workers
        self.on_progress, self.on_done = on_progress, on_done
        self.idle, self.checks = idle, checks
        self.context = process_context()
        self.results: list[RunResult | None] = [None] * len(jobs)
        self.index_of = {job.label: i for i, job in enumerate(jobs)}
        self.last_message: list[str | None] = [None] * len(jobs)
        self.waiting = list(range(len(jobs)))
        self.pool: list[Worker] = []
        # a process a run started that outlives its worker (it left the worker's
        # group) is handed to this process, which ends it when that worker ends and at
        # the end
        self.orphans = Orphans()
        # closes when this process ends, however: each worker's guard then ends its group
        if idle is not None and idle.life is not None:
            self.life = idle.life
        else:
            self.life = self.context.Pipe(duplex=False)
            if idle is not None:
                idle.life = self.life

    def run(self, meanwhile: Callable[[], None] | None) -> list[RunResult]:
        """Run the jobs; return their results in job order."""
        try:
            if self.checks is not None:  # takes a job once its check passed
                self.start_worker(self.checks)
            while self.waiting or any(w.busy() for w in self.pool):
                self.fill()
                if meanwhile is not None:
                    overlap, meanwhile = meanwhile, None
                    overlap()
                self.wait()
                now = time.monotonic()
                for worker in list(self.pool):
                    self.look_after(worker, now)
        except (KeyboardInterrupt, Interrupted) as stop:
            raise self.stopped(stop) from stop
        finally:
            self.close()
        done = [r for r in self.results if r is not None]
        assert len(done) == len(self.results), "a run ended without a result"
        return done

    def start_worker(self, check: InitChecks | None = None) -> Worker:
        context = self.context
        job_reader, job_writer = context.Pipe(duplex=False)
        reader, writer = context.Pipe(duplex=False)
        out_reader, out_writer = context.Pipe(duplex=False)
        scratch = scratch_dir("run")
        track = context.RawArray("d", 3)  # where the worker is (master.simulate)
        track[0] = -1.0  # no component yet
        pacing = context.RawArray("d", FIGURES)  # a paced run's figures (Pacer)
        pacing[WALL] = float("nan")
        process = context.Process(target=_worker, name="agv-cosim worker",
                                  args=(job_reader, writer, out_writer, self.life[0],
                                        scratch, track, inherited_fds(context),
                                        check.items if check is not None else None,
                                        pacing))
        start_process(process, context)
        for end in (job_reader, writer, out_writer):
            end.close()
        pidfd = _exit_fd(process.pid)
        worker = Worker(process, pidfd, process.sentinel if pidfd is None else pidfd,
                        job_writer, Frames(reader), OutputLog(out_reader), scratch, track,
                        pacing, checking=check is not None)
        if check is not None:
            worker.deadline = time.monotonic() + check.limit
        self.pool.append(worker)
        return worker

    def fill(self) -> None:
        """Workers for the jobs waiting, up to ``workers`` (idle ones first)."""
        while self.waiting and len(self.pool) < self.workers:
            kept = self.idle.take() if self.idle is not None else None
            if kept is not None:
                self.pool.append(kept)
                self.give(kept)
            else:
                self.give(self.start_worker())

    def give(self, worker: Worker) -> None:
        index = self.waiting.pop(0)
        worker.index = index
        job = self.jobs[index]
        worker.started = time.monotonic()
        worker.deadline = worker.started + job.timeout if job.timeout else None
        self.output_closed(worker.output.attach(self.root / job.label))
        worker.pacing[:] = [0.0] * FIGURES  # no step paced yet
        worker.pacing[WALL] = float("nan")
        worker.hand((job, self.root / job.label))

    def wait(self) -> None:
        """Wait until a worker ended or sent something, or the next deadline."""
        now = time.monotonic()
        deadlines = [w.deadline for w in self.pool if w.deadline is not None]
        pause = min([1.0] + [max(0.0, d - now) for d in deadlines])
        wait([handle for w in self.pool for handle in w.handles()], timeout=pause)

    def look_after(self, worker: Worker, now: float) -> None:
        """Take what ``worker`` sent; end it when it died, broke its channel or
        overran its run's limit."""
        worker.output.read()
        alive = worker.process.is_alive()
        for kind, payload in worker.frames.read():  # (a dead one's last words)
            self.handle(worker, kind, payload)
        if worker.checking:
            self.check_ended(worker, alive)
        elif worker.frames.broken:
            self.end(worker, how=_BROKEN_CHANNEL)
        elif not worker.process.is_alive():
            for kind, payload in worker.frames.read():  # its last words
                self.handle(worker, kind, payload)
            self.end(worker)
        elif worker.deadline is not None and now >= worker.deadline:
            assert worker.index is not None
            job = self.jobs[worker.index]
            self.end(worker, "timed out", f"the run exceeded its wall-clock limit of "
                                          f"{job.timeout!r} s and was stopped")

    def handle(self, worker: Worker, kind: str, payload: Any) -> None:
        """One frame ``worker`` sent."""
        if worker.checking and self.checks is not None:
            self.handle_check(worker, kind, payload)
            return
        index = worker.index
        if kind == "progress":
            self.on_progress(payload)
        elif kind == "message" and index is not None:
            self.last_message[index] = payload
        elif kind == "done" and index is not None:
            worker.output.read()  # the run's output was written before its result
            self.results[index] = payload
            worker.index = worker.deadline = None
            self.on_done()
            if payload["status"] != "complete":
                worker.leaving = True
                return  # the worker exits by itself: its end retires it
            self.next_job(worker)

    def handle_check(self, worker: Worker, kind: str, payload: Any) -> None:
        """One frame of the worker doing the initialisation check."""
        checks = self.checks
        assert checks is not None
        if kind == "checking":
            worker.checked = payload
            worker.deadline = time.monotonic() + checks.limit
        elif kind == "failed":
            item, text = payload
            raise checks.error(item, text, True)
        elif kind == "checked":
            worker.output.read()  # the check's output (dropped) before any run's
            worker.checking = False
            worker.deadline = None
            self.next_job(worker)

    def check_ended(self, worker: Worker, alive: bool) -> None:
        """Raise the check's error when the checking ``worker`` went wrong."""
        checks = self.checks
        assert checks is not None
        if worker.frames.broken:
            raise checks.broken(worker.checked)
        if not alive:
            worker.process.join()
            raise checks.died(worker.checked, worker.process.exitcode)
        if worker.deadline is not None and time.monotonic() >= worker.deadline:
            raise checks.timed_out(worker.checked)

    def next_job(self, worker: Worker) -> None:
        """A worker that is free: the next job, else (no idle workers kept) its end."""
        if self.waiting:
            self.give(worker)
        elif self.idle is None:  # nothing left for it: let it exit
            worker.leaving = True
            worker.hand(None)

    def end(self, worker: Worker, status: str | None = None, how: str | None = None) -> None:
        """Stop a worker (its whole process group) and clean up after it; a run it was
        doing gets ``how`` as its reason (default: how its process ended)."""
        process = worker.process
        kill_group(process)
        process.join()
        self.orphans.sweep()
        worker.output.read()
        # output.txt whole on disk: _ended reads its last line
        self.output_closed(worker.output.detach())
        index = worker.index
        if index is not None and self.results[index] is None:
            job = self.jobs[index]
            result = _ended(job, self.root / job.label, status,
                            how or _process_end(process.exitcode), worker.track,
                            self.last_message[index], worker.pacing)
            result["wall_time_s"] = time.monotonic() - worker.started
            self.results[index] = result
            self.on_done()
        worker.release()
        if worker in self.pool:  # (an interruption may have come in the middle of an end)
            self.pool.remove(worker)

    def output_closed(self, path: Path | None) -> None:
        """A run's output.txt (``path``) closed, whole: a complete run's run.json gets
        its SHA-256 and size (:func:`~agv_cosim.report.records.record_output`), what
        ``--resume`` checks it against. (A run whose worker went on printing after its
        result has that output in the file too: it is closed when the worker's next
        run starts or the worker ends.)"""
        if path is None:
            return
        index = self.index_of.get(path.parent.name)
        result = None if index is None else self.results[index]
        if result is not None and result["status"] == "complete":
            record_output(path.parent)

    def stopped(self, stop: KeyboardInterrupt | Interrupted) -> RunsStopped:
        """After a termination signal: the workers stopped, the runs under way
        ``interrupted``, the waiting ones ``not run``; the signals ignored until the
        error's ``restore``."""
        restore = ignore_termination()
        name = stop.name if isinstance(stop, Interrupted) else "SIGINT"
        for worker in list(self.pool):
            self.end(worker, "interrupted", f"interrupted by {name}")
        results = [r if r is not None else not_run(self.jobs[i])
                   for i, r in enumerate(self.results)]
        return RunsStopped.of(stop, results, restore)

    def close(self) -> None:
        """Every worker ended, or (with idle workers kept) left in ``idle``."""
        idle = self.idle
        for worker in list(self.pool):
            if (idle is not None and worker.index is None and not worker.leaving
                    and worker.process.is_alive()):
                worker.output.read()
                # the run's output.txt is complete and closed
                self.output_closed(worker.output.detach())
                self.pool.remove(worker)
                idle.workers.append(worker)
            else:
                self.end(worker)
        if idle is None:
            for connection in self.life:
                connection.close()
        self.orphans.close()


def check_initialisation(manifest: Manifest, jobs: list[Job],
                         timeout: float | None = None) -> None:
    """Instantiate and initialise each FMU once with each run's parameters
    (``agv-cosim validate``).

    Catches what only the FMU knows (a parameter value it refuses), without running:
    the checks (:func:`~agv_cosim.workers.initcheck.plan_checks`: each distinct (FMU,
    parameter values) pair once) are made by a pool worker that runs no job
    (:func:`run_isolated`), the first refusal stops them. An FMU that takes longer than
    ``timeout`` [s] (default: the manifest's ``[simulation] timeout``, else
    :data:`~agv_cosim.workers.initcheck.INIT_TIMEOUT`) to instantiate and initialise
    is stopped.

    Raises
    ------
    ManifestError
        Naming the component, the run, the FMI call and the FMU's own message.
    """
    checks = plan_checks(manifest, jobs, timeout)
    if checks is None:
        return
    try:
        run_isolated([], Path(), 1, _ignored, _ignored, checks=checks)  # no job: no folder
    except RunsStopped as stop:
        stop.restore()  # termination signals back as they were
        raise


def _ignored(*args: Any) -> None:
    return None
