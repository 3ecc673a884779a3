"""Runs on a Dask cluster that goes away: a scheduler and one worker (no nanny) started
for each test, then the scheduler or the worker SIGKILLed mid-sweep. A file of its own so
that pytest-xdist can run it beside test_dask.py."""

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from dask_cluster import DASK, _die_with_parent, _stop

pytestmark = pytest.mark.slow


HANG = """
name = "hangdask"
[simulation]
stop = 0.5
step = 0.01
[components.h]
fmu = "{hang}"
[sweep]
"h.hang_time" = [10.0, 20.0, 0.1, 0.2]
"""


def _mini_cluster(folder):
    """A scheduler and one worker without a nanny (so killing it leaves none); returns
    (address, scheduler process, worker process)."""
    scheduler_file = folder / "scheduler.json"
    env = dict(os.environ, TMPDIR=str(folder))
    log = open(folder / "cluster.log", "w")

    def start(*args):
        return subprocess.Popen([str(DASK), *args], env=env, stdout=log,
                                stderr=subprocess.STDOUT, cwd=folder,
                                start_new_session=True, preexec_fn=_die_with_parent)

    scheduler = start("scheduler", "--scheduler-file", str(scheduler_file), "--host",
                      "127.0.0.1", "--port", "0", "--no-dashboard")
    deadline = time.monotonic() + 60
    while not scheduler_file.is_file():
        assert time.monotonic() < deadline and scheduler.poll() is None
        time.sleep(0.2)
    worker = start("worker", "--scheduler-file", str(scheduler_file), "--nthreads", "1",
                   "--no-dashboard", "--no-nanny", "--local-directory", str(folder))
    address = json.loads(scheduler_file.read_text())["address"]
    from distributed import Client

    with Client(address, timeout=30) as client:
        client.wait_for_workers(1, timeout=90)
    return address, scheduler, worker


@pytest.mark.parametrize("victim", ["scheduler", "worker"])
def test_finished_runs_are_kept_when_the_cluster_goes_away(fmus, tmp_path, victim):
    """Two runs finish, the next hangs; then the scheduler, or the only worker, is
    killed (SIGKILL): the command ends with one line of ours last on stderr (no
    traceback of distributed's), exit 1, the two runs kept complete in a folder marked
    partial, the others 'not run'."""
    # short: the worker's fork server puts a socket in its TMPDIR (at most 107 bytes)
    folder = Path(tempfile.mkdtemp(prefix="agvdask", dir="/tmp"))
    address, scheduler, worker = _mini_cluster(folder)
    try:
        path = tmp_path / "hangdask.toml"
        path.write_text(HANG.format(hang=fmus["agv_test_hang"]))
        out = tmp_path / "out"
        command = subprocess.Popen(
            [sys.executable, "-m", "agv_cosim.cli", "run", str(path), "--out", str(out),
             "--dask", address], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 180
        while len(list(tmp_path.glob(".out.incomplete-*/*/run.json"))) < 2:
            assert time.monotonic() < deadline, "the first runs did not finish"
            assert command.poll() is None, command.communicate()
            time.sleep(0.2)
        time.sleep(1.0)  # the third run is under way
        os.kill((scheduler if victim == "scheduler" else worker).pid, signal.SIGKILL)
        _, err = command.communicate(timeout=180)
        assert command.returncode == 1, err
        lines = [line for line in err.replace("\r", "\n").splitlines() if line.strip()]
        assert "Traceback" not in err
        assert lines[-1].startswith("agv-cosim: error: --dask: ")
        assert lines[-1].endswith(f"2 of 4 run(s) complete kept in {out} (marked partial: "
                                  "partial.txt, summary.csv)")
        with open(out / "summary.csv", newline="") as stream:
            statuses = [row["status"] for row in csv.DictReader(stream)]
        assert statuses == ["complete", "complete", "not run", "not run"]
        assert json.loads((out / ".agv-cosim").read_text())["complete"] is False
    finally:
        _stop(worker)
        _stop(scheduler)
        shutil.rmtree(folder, ignore_errors=True)
