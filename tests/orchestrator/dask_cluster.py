"""A real Dask cluster for the tests that run on one (tests/orchestrator/workers/,
fitting/): a scheduler and two stock one-thread workers started as processes with the
venv's ``dask`` command, torn down with their sessions."""

import ctypes
import ctypes.util
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

DASK = Path(sys.executable).with_name("dask")
_LIBC = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")


def _die_with_parent():
    """preexec_fn: the kernel kills the process (SIGKILL) when this test process ends
    (prctl PR_SET_PDEATHSIG; libc is loaded beforehand, nothing here may fork)."""
    _LIBC.prctl(1, int(signal.SIGKILL), 0, 0, 0)


def _stop(process):
    """End a process and its session (a worker's nanny and its worker) for sure."""
    if process.poll() is None:
        try:
            os.killpg(process.pid, signal.SIGTERM)
        except ProcessLookupError:
            pass
        try:
            process.wait(timeout=15)
        except subprocess.TimeoutExpired:
            pass
    try:  # whatever is left of the session (SIGTERM ignored, or children)
        os.killpg(process.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    process.wait()


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """The address of a scheduler with two stock one-thread workers (no DASK_* setting):
    one under a nanny (a daemonic process), one without (``--no-nanny``)."""
    from distributed import Client

    folder = tmp_path_factory.mktemp("dask")
    scheduler_file = folder / "scheduler.json"
    # TMPDIR: the workers' FMU cache and run folders stay in this test's folder
    env = {name: value for name, value in os.environ.items()
           if not name.startswith("DASK_")}
    env["TMPDIR"] = str(folder)
    processes = []
    log = open(folder / "cluster.log", "w")

    def start(*args):
        # a session of its own (torn down as a group); killed by the kernel if this
        # test process dies (_die_with_parent), and the workers end 60 s after losing
        # the scheduler (--death-timeout)
        processes.append(subprocess.Popen([str(DASK), *args], env=env, stdout=log,
                                          stderr=subprocess.STDOUT, cwd=folder,
                                          start_new_session=True,
                                          preexec_fn=_die_with_parent))

    try:
        start("scheduler", "--scheduler-file", str(scheduler_file), "--host", "127.0.0.1",
              "--port", "0", "--no-dashboard")
        deadline = time.monotonic() + 60
        while not scheduler_file.is_file():
            assert time.monotonic() < deadline, "the scheduler did not start"
            assert processes[0].poll() is None, "the scheduler ended"
            time.sleep(0.2)
        for nanny in (["--nanny"], ["--no-nanny"]):
            start("worker", "--scheduler-file", str(scheduler_file), "--nthreads", "1",
                  "--no-dashboard", "--local-directory", str(folder),
                  "--death-timeout", "60", *nanny)
        with Client(scheduler_file=str(scheduler_file), timeout=30) as client:
            client.wait_for_workers(2, timeout=90)
            address = client.scheduler.address
        yield address
    finally:
        for process in reversed(processes):
            _stop(process)
        log.close()
