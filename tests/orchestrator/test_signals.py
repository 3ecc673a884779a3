"""Class 2 of issue 10: a termination signal ends the whole run cleanly.

The CLI runs as a real process in a session of its own (so its process group holds
exactly its processes) with a private temp folder; a long run is interrupted once its
children are computing. Each case costs a few seconds.
"""

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

SWEEP = '[sweep]\n"gain.k" = [1.0, 2.0]\n'  # two runs, each in a child process


def _group(pgid):
    """Pids of the live (not zombie) processes in process group ``pgid``."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":
            found.append(int(entry.name))
    return found


def _wait_gone(pgid, seconds):
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if not _group(pgid):
            return True
        time.sleep(0.05)
    return not _group(pgid)


@pytest.fixture
def long_run(chain, tmp_path):
    path = chain(stop=10000.0, step=0.01, extra=SWEEP, name="long.toml")
    tmp = Path(tempfile.mkdtemp(prefix="agvsig", dir="/tmp"))  # short: socket paths
    env = dict(os.environ, TMPDIR=str(tmp))
    started = []

    def start(out="out", stale=()):
        process = subprocess.Popen(
            [sys.executable, "-m", "agv_cosim.cli", "run", str(path), "--quiet", "--out",
             str(tmp_path / out), "--jobs", "2"], env=env, start_new_session=True,
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        started.append(process)
        # wait until both runs' children have recorded rows (header + at least one row)
        end = time.monotonic() + 60
        while time.monotonic() < end:
            csvs = [p for p in tmp_path.glob(f".{out}.incomplete-*/*/timeseries.csv")
                    if p.parent.parent not in stale]
            if len(csvs) == 2 and all(p.read_bytes().count(b"\n") >= 2 for p in csvs):
                break
            time.sleep(0.05)
        else:
            process.kill()
            raise AssertionError(f"the runs did not start: {process.communicate()}")
        return process

    yield start, tmp, tmp_path
    for process in started:  # never leave a process of this test behind
        for pid in _group(process.pid):
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        process.wait()
    shutil.rmtree(tmp, ignore_errors=True)


def _kept_partial(folder, statuses):
    """``folder`` is a committed result folder marked partial, with these run statuses."""
    marker = json.loads((folder / ".agv-cosim").read_text())
    assert marker["complete"] is False and marker["runs"] == len(statuses)
    assert (folder / "partial.txt").read_text().startswith("partial result: interrupted by")
    with open(folder / "summary.csv", newline="") as stream:
        assert [row["status"] for row in csv.DictReader(stream)] == statuses
    for run in (p for p in folder.iterdir() if p.is_dir()):
        info = json.loads((run / "run.json").read_text())
        assert info["status"] == "interrupted" and info["rows"] >= 1


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
@pytest.mark.slow  # seconds: builds or runs FMUs in processes
def test_signal_to_the_parent_ends_everything(long_run, sig):
    """The parent alone gets the signal: it stops its children, keeps the rows they
    recorded in a folder marked partial (both runs 'interrupted'), and leaves no process
    and no temporary folder."""
    start, tmp, root = long_run
    process = start()
    os.kill(process.pid, sig)  # the parent only: it must stop its children itself
    _, err = process.communicate(timeout=30)
    assert process.returncode == 128 + sig
    assert err.strip().splitlines()[-1] == (
        f"agv-cosim: interrupted by {signal.Signals(sig).name}; 0 of 2 run(s) complete "
        f"kept in {root / 'out'} (marked partial: partial.txt, summary.csv)")
    assert _wait_gone(process.pid, 3.0), "processes of the run are left"
    assert list(tmp.iterdir()) == []  # scratch, extraction and multiprocessing folders
    assert sorted(p.name for p in root.iterdir()) == ["long.toml", "out"]
    _kept_partial(root / "out", ["interrupted", "interrupted"])


@pytest.mark.slow  # seconds: builds or runs FMUs in processes
def test_sigkilled_parent_children_stop_and_next_run_cleans(long_run):
    start, tmp, root = long_run
    process = start()
    os.kill(process.pid, signal.SIGKILL)
    process.wait()
    assert _wait_gone(process.pid, 5.0), "children outlived a SIGKILLed parent"
    stale = set(root.glob(".out.incomplete-*"))
    assert len(stale) == 1 and list(tmp.iterdir())  # left behind by the killed run
    second = start(stale=stale)  # the next run to the same place cleans what was left
    assert not any(p.exists() for p in stale)
    assert [p for p in tmp.iterdir() if f"-{process.pid}-" in p.name] == []
    os.kill(second.pid, signal.SIGTERM)
    second.communicate(timeout=30)
    assert second.returncode == 128 + signal.SIGTERM
    assert _wait_gone(second.pid, 3.0)
    assert sorted(p.name for p in root.iterdir()) == ["long.toml", "out"]
    _kept_partial(root / "out", ["interrupted", "interrupted"])
    assert list(tmp.iterdir()) == []


@pytest.mark.slow  # seconds: builds or runs FMUs in processes
def test_no_process_left_after_a_normal_exit(chain, tmp_path):
    path = chain(extra=SWEEP, name="short.toml")
    tmp = Path(tempfile.mkdtemp(prefix="agvsig", dir="/tmp"))
    process = subprocess.Popen([sys.executable, "-m", "agv_cosim.cli", "run", str(path),
                                "--quiet", "--out", str(tmp_path / "o")],
                               env=dict(os.environ, TMPDIR=str(tmp)),
                               start_new_session=True)
    assert process.wait(timeout=60) == 0
    try:
        assert _group(process.pid) == []  # at once: nothing of ours outlives the command
        assert list(tmp.iterdir()) == []
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
