"""Runs on a Dask cluster (``agv-cosim run MANIFEST --dask tcp://HOST:PORT``).

The client (the machine running ``agv-cosim``) plans and validates the runs as for a
local run, then submits one Dask task per run and writes every result itself, into the
same :class:`~agv_cosim.files.AtomicDir` and ``summary.csv`` as a local run.

What a task does on a worker (:func:`run_remote`):

1. **FMUs shipped with the job.** The client reads each distinct FMU once, scatters its
   bytes to the cluster (``Client.scatter``, keyed by SHA-256) and hands the futures to
   the tasks; a worker stores each FMU once in a cache folder of its own
   (``<tmp>/agv-cosim-dask-fmus-<uid>/<sha256>.fmu``: a 0700 folder of the worker's user,
   refused if anyone else can write it; each file written under a temporary name, its
   SHA-256 checked, then renamed) and every later run on that worker reuses it after
   checking its SHA-256 again (a changed file is replaced by the bytes sent).
   Chosen over a shared path because the cluster then needs no shared file system and a
   worker can never run an FMU other than the one the client validated: the hash in
   ``run.json`` is the hash of the bytes that ran.
2. **The same crash isolation as locally.** The run goes to a run host of the worker
   (:mod:`agv_cosim.workers.host`: an ordinary subprocess, kept for the worker's later
   tasks), which runs it through :func:`agv_cosim.workers.pool.run_isolated` in its
   worker process, kept between tasks as a local sweep keeps it between runs (replaced
   after a run that did not end ``complete``), so an FMU that aborts its process fails
   only its run, reported ``partial`` or ``failed`` with the same text as locally; the
   worker goes on. A subprocess works in a daemonic worker (the default under a nanny), where
   :mod:`multiprocessing` cannot start children, so stock workers need no setting.
3. The run's folder (``timeseries.csv``, ``run.json``, ``metrics.json``) goes back to the
   client as bytes; the client writes it, then computes the run's metrics from the
   ``timeseries.csv`` it wrote (the manifest's files, e.g. a waypoint file of a
   reference path, are on the client), with the same function as a local run.

Results are byte-identical to a local run (timeseries.csv, metrics.json, summary.csv);
``run.json`` differs only where it records the machine (package versions), and
timings.csv holds the wall times measured on the workers.

Workers need the project installed in the same Python environment as the client (same
versions of agv-cosim, numpy, scipy, pythonfmu); stock ``dask worker ADDRESS`` processes
(with a nanny or not) run the jobs. See docs/dask.md.
"""

import dataclasses
import hashlib
import json
import logging
import os
import queue
import re
import shutil
import stat
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, cast

from ..errors import ClusterError, Interrupted, RunsStopped, WorkerUnfit
from ..files import create_file
from ..lifetime import ignore_termination, scratch_dir
from ..report.records import RunResult, finish_remote_run, run_result
from ..system import Job
from .host import run_hosted
from .pool import not_run

__all__ = ["CONNECT_TIMEOUT", "LOST_TIMEOUT", "cached_fmu", "connect", "run_on_dask",
           "run_remote"]

#: How long the client waits for the scheduler to answer [s] before giving up.
CONNECT_TIMEOUT = 10.0
#: How long a cluster may go without a worker, or the client without its scheduler,
#: while runs are left [s] before the command gives up (keeping the finished runs).
LOST_TIMEOUT = 30.0


def connect(address: str, timeout: float = CONNECT_TIMEOUT) -> Any:
    """A ``distributed.Client`` on the scheduler at ``address``.

    The connection is made in a thread of its own and given up after ``timeout`` [s]
    plus a margin, whatever answers at the address (a silent TCP server, an HTTP
    server and the like make ``distributed`` wait without end).

    Raises
    ------
    ClusterError
        One line naming the address when the scheduler cannot be reached.
    """
    try:
        from distributed import Client
    except ImportError:  # pragma: no cover - a dependency of the project
        raise ClusterError("--dask: the 'distributed' package is not installed") from None
    if not isinstance(address, str) or "://" not in address:
        raise ClusterError(f"--dask: {address!r} is not a scheduler address "
                           "(e.g. tcp://HOST:8786)")
    box: dict[str, Any] = {}

    def make() -> None:
        try:
            box["client"] = Client(address, timeout=timeout)  # type: ignore[no-untyped-call]
        except BaseException as error:  # noqa: BLE001 - handed to the caller's thread
            box["error"] = error

    thread = threading.Thread(target=make, name="agv-cosim connect", daemon=True)
    thread.start()
    thread.join(timeout + 2.0)
    if thread.is_alive():  # left to end with the process (a daemon thread)
        raise ClusterError(f"--dask: cannot reach the scheduler at {address}: nothing that "
                           f"speaks Dask's protocol answered within {timeout:g} s")
    error = box.get("error")
    if isinstance(error, (OSError, TimeoutError, ValueError)):
        text = " ".join(str(error).split()) or type(error).__name__
        raise ClusterError(f"--dask: cannot reach the scheduler at {address}: "
                           f"{text}") from None
    if isinstance(error, Exception):  # e.g. an HTTP server's answer read as frames
        text = " ".join(str(error).split())[:200] or type(error).__name__
        raise ClusterError(f"--dask: {address} did not answer as a Dask scheduler "
                           f"({type(error).__name__}: {text})") from None
    if error is not None:
        raise error
    return box["client"]


def _fmu_cache() -> Path:
    """This user's FMU cache folder on a worker: created 0700; refused (WorkerUnfit)
    unless it is a folder (not a link) of this user that no one else can write."""
    folder = Path(tempfile.gettempdir()) / f"agv-cosim-dask-fmus-{os.getuid()}"
    try:
        os.mkdir(folder, 0o700)
    except FileExistsError:
        pass
    info = os.lstat(folder)
    if (not stat.S_ISDIR(info.st_mode) or info.st_uid != os.getuid()
            or info.st_mode & 0o022):
        raise WorkerUnfit(f"the FMU cache {folder} is not a folder of this user that only "
                          "it can write (a link, another user's, or group/world-writable); "
                          "refusing to run FMUs from it (remove it, or set TMPDIR)")
    return folder


def _file_sha256(path: Path) -> str | None:
    """SHA-256 of the regular file at ``path`` (not through a link), or None."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return None
    with os.fdopen(fd, "rb") as stream:
        if not stat.S_ISREG(os.fstat(stream.fileno()).st_mode):
            return None
        digest = hashlib.sha256()
        for chunk in iter(lambda: stream.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def cached_fmu(sha256: str, blob: bytes, cache: str | Path | None = None) -> Path:
    """The path of the FMU with this SHA-256 in the worker's cache.

    The cached file's SHA-256 is checked every time it is used; a file that does not
    have it (changed, planted, truncated) is replaced by ``blob``, the bytes the client
    sent, after their own hash is checked.

    Raises
    ------
    ValueError
        When ``blob`` does not have the SHA-256 the client validated.
    """
    cache = Path(cache) if cache is not None else _fmu_cache()
    path = cache / f"{sha256}.fmu"
    if _file_sha256(path) == sha256:
        return path
    if hashlib.sha256(blob).hexdigest() != sha256:
        raise ValueError(f"the FMU received does not have the SHA-256 {sha256}")
    handle, partial = tempfile.mkstemp(dir=cache, prefix=f".{sha256}.", suffix=".part")
    try:
        with os.fdopen(handle, "wb") as stream:
            stream.write(blob)
        os.replace(partial, path)  # atomic: a concurrent task sees all of it or nothing
    except BaseException:
        Path(partial).unlink(missing_ok=True)
        raise
    if _file_sha256(path) != sha256:  # replaced again meanwhile: not ours to run
        raise WorkerUnfit(f"the cached FMU {path} changed while it was written")
    return path


def run_remote(job: Job, blobs: dict[str, bytes]) -> tuple[RunResult, dict[str, bytes]]:
    """Body of a Dask task: run ``job`` isolated on this worker (in a run host, see
    :mod:`agv_cosim.workers.host`); return its folder.

    ``blobs``: SHA-256 -> FMU bytes of the job's FMUs. Returns ``(result dict, files)``,
    ``files`` mapping each file of the run's folder (relative POSIX path) to its bytes.
    Metrics are left to the client (``metrics_spec`` is dropped here).
    """
    models = {}
    for cname, info in job.plan.models.items():
        if info.table is not None:  # a time table travels in the job itself
            models[cname] = info
        else:
            models[cname] = dataclasses.replace(
                info, path=cached_fmu(info.sha256, blobs[info.sha256]))
    local = dataclasses.replace(job, plan=dataclasses.replace(job.plan, models=models),
                                metrics_spec=None)
    root = Path(scratch_dir("dask"))
    try:
        result = run_hosted(local, root)
        run_dir = root / job.label
        files = {p.relative_to(run_dir).as_posix(): p.read_bytes()
                 for p in sorted(run_dir.rglob("*")) if p.is_file()}
    finally:
        shutil.rmtree(root, ignore_errors=True)
    return result, files


def _write_back(job: Job, result: dict[str, Any], files: dict[str, bytes],
                root: Path) -> RunResult:
    """Write a run's files under ``root``; its record is finished here, the client
    (:func:`~agv_cosim.report.records.finish_remote_run`: the metrics, metrics.json,
    run.json)."""
    run_dir = Path(root) / job.label
    run_dir.mkdir(exist_ok=True)  # never its parents: a removed result folder stays gone
    written = cast(RunResult, dict(result))  # a copy
    # with metrics, run.json and metrics.json are written once, after the metrics
    measured = bool(job.metrics_spec and written["rows"] and "run.json" in files)
    for name, data in files.items():
        target = run_dir / name
        if run_dir.resolve() not in target.resolve().parents:
            raise ClusterError(f"a worker returned a file outside its run folder: {name!r}")
        if measured and name in ("run.json", "metrics.json"):
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        with create_file(target, binary=True) as stream:
            stream.write(data)
    if not measured:
        return written
    record = json.loads(files["run.json"].decode("utf-8"))
    return finish_remote_run(job, run_dir, written, record)


def _taken(arrived: "queue.SimpleQueue[Any]", timeout: float) -> list[Any]:
    """What ``arrived`` holds: waits up to ``timeout`` [s] for the first item."""
    try:
        items = [arrived.get(timeout=timeout)]
    except queue.Empty:
        return []
    while True:
        try:
            items.append(arrived.get_nowait())
        except queue.Empty:
            return items


def _failure(future: Any) -> str:
    """What a finished task raised (its message), or ''."""
    import asyncio

    try:
        future.result()
    except (Exception, asyncio.CancelledError) as error:  # noqa: BLE001 - its text only
        return str(error)
    return ""


def _worker_count(client: Any) -> int | None:
    """Workers the scheduler knows now, or None when it does not answer within
    :data:`CONNECT_TIMEOUT` (gone, or the client is no longer connected)."""
    if client.status != "running":
        return None
    try:
        info = client.sync(client.scheduler.identity, n_workers=-1,
                           callback_timeout=CONNECT_TIMEOUT)
    except Exception:  # noqa: BLE001 - any failure to answer: the scheduler is lost
        return None
    return len(info.get("workers") or {})


def _one_line(error: BaseException) -> str:
    return " ".join(str(error).split()) or type(error).__name__


def _quiet_logs() -> Callable[[], None]:
    """Silence the log output of distributed (and tornado, asyncio) on our stderr while
    the cluster is used (a lost scheduler makes it print tracebacks before our one
    line); return a function that turns logging back on."""
    logging.disable(logging.CRITICAL)

    def restore() -> None:
        logging.disable(logging.NOTSET)

    return restore


def run_on_dask(address: str, jobs: list[Job], root: Path,
                on_progress: Callable[[int], None],
                on_done: Callable[[], None]) -> list[RunResult]:
    """Run ``jobs`` on the cluster at ``address``; write each run under ``root`` (the
    Dask :class:`~agv_cosim.workers.runner.Runner`).

    Same contract as :func:`agv_cosim.workers.pool.run_isolated`: one result dict per
    job, in job order. ``on_progress`` gets each finished run's steps at once. A run
    whose task fails on the cluster (its worker died, ...) is ``failed`` with the reason
    and the others go on. When the command cannot go on (the scheduler gone, no worker left
    for :data:`LOST_TIMEOUT` s, a worker unfit to run anything, a SIGINT/SIGTERM/SIGHUP)
    once runs were submitted, a :class:`~agv_cosim.errors.RunsStopped` of the stop's
    kind carries ``results`` (the finished runs, the others ``not run``) so that the
    caller keeps them.
    """
    restore_logs = _quiet_logs()
    client = connect(address)
    runs = _DaskRuns(address, client, jobs, root, on_progress, on_done)
    try:
        runs.submit()
        runs.collect()
        done_results = [r for r in runs.results if r is not None]
        assert len(done_results) == len(runs.results), "a run ended without a result"
        return done_results
    except (KeyboardInterrupt, Interrupted) as stop:
        raise RunsStopped.of(stop, runs.so_far(), ignore_termination()) from stop
    except ClusterError as stop:
        if not runs.futures:
            raise
        raise RunsStopped.of(stop, runs.so_far(),
                             reason=str(stop).removeprefix("--dask: ")) from stop
    finally:
        runs.close()
        restore_logs()


class _DaskRuns:
    """The state of one :func:`run_on_dask`: the client, the tasks, the results."""

    def __init__(self, address: str, client: Any, jobs: list[Job], root: Path,
                 on_progress: Callable[[int], None], on_done: Callable[[], None]) -> None:
        self.address, self.client, self.jobs, self.root = address, client, jobs, root
        self.on_progress, self.on_done = on_progress, on_done
        self.results: list[RunResult | None] = [None] * len(jobs)
        #: each submitted task's future -> the index of its job
        self.futures: dict[Any, int] = {}
        self.lost_since: float | None = None

    def so_far(self) -> list[RunResult]:
        """The results, the runs not finished ``not run``."""
        return [r if r is not None else not_run(self.jobs[i])
                for i, r in enumerate(self.results)]

    def submit(self) -> None:
        """Wait for a worker; scatter each distinct FMU once; submit one task per job."""
        client = self.client
        if not client.scheduler_info().get("workers"):
            try:
                client.wait_for_workers(1, timeout=CONNECT_TIMEOUT)
            except (TimeoutError, OSError):
                raise ClusterError(f"--dask: the scheduler at {self.address} has no "
                                   "workers") from None
        shipped = {sha: client.scatter(data, hash=False, broadcast=False)
                   for sha, data in _fmu_blobs(self.jobs).items()}
        for index, job in enumerate(self.jobs):
            needed = {info.sha256: shipped[info.sha256] for info in job.plan.models.values()
                      if info.table is None}
            # pure=False: a run is not cached by Dask (two identical runs both run)
            future = client.submit(run_remote, job, needed, pure=False,
                                   key=f"agv-cosim-{os.getpid()}-{index}-{job.label}")
            self.futures[future] = index

    def collect(self) -> None:
        """Take each finished task's run as it comes, until none is pending."""
        # each finished task is put here by Dask's callback thread: the loop takes them
        # as they come (no wait over every pending task, no scheduler call per task)
        arrived: queue.SimpleQueue[Any] = queue.SimpleQueue()
        for future in self.futures:
            future.add_done_callback(arrived.put)
        pending = set(self.futures)
        while pending:
            ready = _taken(arrived, 1.0)
            quiet = not ready
            if quiet:  # nothing for a second: a completion a callback missed, if any
                ready = [f for f in pending if f.done()]
            done = [f for f in dict.fromkeys(ready) if f in pending and f.done()]
            self.check_cancelled(done, pending)
            pending.difference_update(done)
            for future in done:
                self.take(future)
            if not pending or not quiet:  # runs that finish: the cluster is there
                self.lost_since = None
                continue
            self.check_cluster(len(pending))

    def check_cancelled(self, done: list[Any], pending: set[Any]) -> None:
        """Raise ClusterError when the cluster cancelled a task of ``done``."""
        cancelled = [f for f in done if f.cancelled()]
        if not cancelled:
            return
        reasons = sorted({reason for f in cancelled
                          for reason in re.findall(r"for reason: ([^.\n]+)", _failure(f))})
        why = ", ".join(reasons) or "CancelledError"
        problem = (f"lost the scheduler at {self.address}"
                   if _worker_count(self.client) is None
                   else f"the cluster at {self.address} cancelled the runs left (a worker "
                        "holding their FMUs died)")
        raise ClusterError(f"--dask: {problem} ({why}); {len(pending)} run(s) did "
                           "not finish")

    def take(self, future: Any) -> None:
        """The run of a finished task written back (or ``failed`` with its reason)."""
        index = self.futures[future]
        job = self.jobs[index]
        try:
            result, files = future.result()
        except WorkerUnfit as error:
            raise ClusterError(f"--dask: run {job.label} could not run on the "
                               f"cluster: {_one_line(error)}") from None
        except Exception as error:  # noqa: BLE001 - this run's task failed
            self.results[index] = run_result(
                job, "failed", error=f"its Dask task failed: "
                                     f"{type(error).__name__}: {_one_line(error)}")
            self.on_done()
            return
        self.results[index] = _write_back(job, result, files, self.root)
        self.on_progress(job.plan.steps)
        self.on_done()

    def check_cluster(self, pending: int) -> None:
        """Raise ClusterError when the scheduler or every worker has been gone for
        :data:`LOST_TIMEOUT` s, ``pending`` runs left."""
        problem = None
        workers = _worker_count(self.client)
        if workers is None:
            problem = f"lost the scheduler at {self.address}"
        elif not workers:
            problem = f"the cluster at {self.address} has no worker left"
        if problem is None:
            self.lost_since = None
        elif self.lost_since is None:
            self.lost_since = time.monotonic()
        elif time.monotonic() - self.lost_since > LOST_TIMEOUT:
            raise ClusterError(f"--dask: {problem} (for {LOST_TIMEOUT:g} s); "
                               f"{pending} run(s) did not finish")

    def close(self) -> None:
        """Cancel the tasks left and close the client (the scheduler may be gone)."""
        try:
            if self.futures:
                self.client.cancel(list(self.futures), force=True)
        except Exception:  # noqa: BLE001 - the scheduler may be gone
            pass
        try:
            self.client.close(timeout=CONNECT_TIMEOUT)
        except Exception:  # noqa: BLE001 - the scheduler may be gone
            pass


def _fmu_blobs(jobs: list[Job]) -> dict[str, bytes]:
    """SHA-256 -> bytes of each distinct FMU of ``jobs``, each checked against the hash
    it was validated with."""
    blobs: dict[str, bytes] = {}
    for job in jobs:
        for info in job.plan.models.values():
            if info.table is None and info.sha256 not in blobs:
                data = Path(info.path).read_bytes()
                if hashlib.sha256(data).hexdigest() != info.sha256:
                    raise ClusterError(f"{info.path}: changed since it was validated")
                blobs[info.sha256] = data
    return blobs
