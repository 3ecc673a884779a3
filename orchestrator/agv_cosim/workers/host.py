"""Run hosts: Python processes of their own that run jobs for a Dask worker.

A Dask worker under a nanny is a daemonic process, which :mod:`multiprocessing` forbids
to have children, so it cannot run :func:`agv_cosim.workers.pool.run_isolated` itself.
It can start an ordinary subprocess: a run host (``python -m agv_cosim.workers.host``),
which reads ``(job, root)`` requests from its stdin and runs each through
:func:`~agv_cosim.workers.pool.run_isolated` (the run in a worker process of its own,
exactly as locally), then writes the run's result to its stdout (pickles, one per
request). A host lives as long as its Dask worker: it ends when its stdin closes or its
parent process is gone (the kernel kills it then, ``PR_SET_PDEATHSIG``).

The host keeps its worker process between requests, as a local sweep does between runs
(:class:`~agv_cosim.workers.pool.IdleWorkers`): a worker whose run ended ``complete``
takes the next request's run with its FMUs' cores already imported and its FMUs already
extracted; after any other ending it exits and the next run gets a fresh worker, forked
from the host (which runs a single thread, see
:func:`~agv_cosim.workers.channels.process_context`). A run that crashes its worker is a
result, as locally; the host goes on.

The worker side (:func:`run_hosted`) keeps its idle hosts for the next task, one host per
task running at once; a host that dies or answers nonsense is dropped and the next task
starts a new one.
"""

import os
import pickle
import subprocess
import sys
import threading
from pathlib import Path
from typing import IO, cast

from ..lifetime import die_with_parent
from ..report.records import RunResult
from ..system import Job
from .pool import IdleWorkers, run_isolated

__all__ = ["HOST_MODULE", "main", "run_hosted", "serve"]

#: The module a run host runs (``python -m``).
HOST_MODULE = __name__

_idle: list[subprocess.Popen[bytes]] = []
_idle_lock = threading.Lock()


def serve(requests: IO[bytes], replies: IO[bytes]) -> None:
    """Run each ``(job, root)`` request read from ``requests`` (pickles) until it ends;
    write ``("done", result)`` or ``("error", one line)`` for each to ``replies``. The
    worker of a complete run waits for the next request; all end with ``requests``."""
    idle = IdleWorkers()
    try:
        while True:
            try:
                job, root = pickle.load(requests)
            except EOFError:
                return
            try:
                [result] = run_isolated([job], Path(root), 1, lambda steps: None,
                                        lambda: None, idle)
                reply: tuple[str, object] = ("done", result)
            except Exception as failure:  # noqa: BLE001 - reported to the task, one line
                reply = ("error", " ".join(f"{type(failure).__name__}: {failure}".split()))
            pickle.dump(reply, replies, protocol=pickle.HIGHEST_PROTOCOL)
            replies.flush()
    finally:
        idle.close()


def main() -> None:
    """Body of a run host: requests on stdin, replies on the original stdout; anything
    else printed goes to stderr. Killed by the kernel when its parent (the Dask worker)
    ends; its workers then end with it (their guard sees the life pipe close)."""
    replies = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)
    die_with_parent()
    serve(sys.stdin.buffer, replies)
    replies.flush()
    os._exit(0)  # the workers are ended and the replies flushed: nothing left to finalise


def _start_host() -> subprocess.Popen[bytes]:
    # a session of its own: a terminal's SIGINT to the worker does not reach the runs;
    # the host ends with its worker (stdin closed, or its parent gone)
    return subprocess.Popen([sys.executable, "-m", HOST_MODULE], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, start_new_session=True)


def _drop(host: subprocess.Popen[bytes]) -> None:
    for stream in (host.stdin, host.stdout):
        try:
            if stream is not None:
                stream.close()
        except OSError:
            pass
    try:
        host.kill()
    except OSError:
        pass
    host.wait()


def run_hosted(job: Job, root: Path) -> RunResult:
    """Run ``job`` under ``root`` in a run host of this process (an idle one, else a new
    one) and return its result.

    Raises
    ------
    RuntimeError
        One line, when the host died or failed outside the run (the run itself failing
        is a result, as locally).
    """
    with _idle_lock:
        host = None
        while _idle and host is None:
            candidate = _idle.pop()
            if candidate.poll() is None:
                host = candidate
            else:
                _drop(candidate)
    if host is None:
        host = _start_host()
    assert host.stdin is not None and host.stdout is not None
    try:
        pickle.dump((job, str(root)), host.stdin, protocol=pickle.HIGHEST_PROTOCOL)
        host.stdin.flush()
        kind, payload = pickle.load(host.stdout)
    except BaseException as error:
        _drop(host)
        if isinstance(error, (EOFError, OSError, pickle.UnpicklingError, ValueError)):
            how = (f"exit code {host.returncode}" if host.returncode >= 0
                   else f"signal {-host.returncode}")
            raise RuntimeError(f"the run host process ended ({how}) before the run "
                               "ended") from None
        raise
    if kind != "done" or not isinstance(payload, dict):
        _drop(host)
        raise RuntimeError(f"the run host failed: {payload}")
    with _idle_lock:
        _idle.append(host)
    return cast(RunResult, payload)


if __name__ == "__main__":
    main()
