"""A termination signal ends the whole run cleanly and keeps what was computed.

The CLI runs as a real process in a session of its own (so its session holds exactly
its processes: the workers lead process groups of their own inside it) with a private
temp folder; a long run is interrupted once its children are computing. Each case costs
a few seconds. Every wait is on a condition (rows recorded, a line printed, a process
gone), bounded only by ``processes.GUARD`` against a case that never gets there.
"""

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from processes import GUARD, Collected, ended, wait_until

SWEEP = '[sweep]\n"gain.k" = [1.0, 2.0]\n'  # two runs, each in a child process


def _group(sid):
    """Pids of the live (not zombie) processes in session ``sid`` (the command's: it
    was started in a session of its own; its workers lead process groups of their own
    in that session)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[3]) == sid and fields[0] != "Z":
            found.append(int(entry.name))
    return found


def _wait_gone(sid):
    """True once session ``sid`` holds no live process (False after ``GUARD``)."""
    try:
        wait_until(lambda: not _group(sid), f"session {sid} empty")
    except AssertionError:
        return False
    return True


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

        def recording():  # both runs' children have recorded rows (header + a row)
            if process.poll() is not None:
                raise AssertionError(f"the command ended: {process.communicate()}")
            csvs = [p for p in tmp_path.glob(f".{out}.incomplete-*/*/timeseries.csv")
                    if p.parent.parent not in stale]
            return len(csvs) == 2 and all(p.read_bytes().count(b"\n") >= 2 for p in csvs)

        wait_until(recording, "both runs recording rows")
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
    _, err = process.communicate(timeout=GUARD)
    assert process.returncode == 128 + sig
    assert err.strip().splitlines()[-1] == (
        f"agv-cosim: interrupted by {signal.Signals(sig).name}; 0 of 2 run(s) complete "
        f"kept in {root / 'out'} (marked partial: partial.txt, summary.csv)")
    assert _wait_gone(process.pid), "processes of the run are left"
    assert list(tmp.iterdir()) == []  # scratch, extraction and multiprocessing folders
    assert sorted(p.name for p in root.iterdir()) == ["long.toml", "out"]
    _kept_partial(root / "out", ["interrupted", "interrupted"])


@pytest.mark.slow  # seconds: builds or runs FMUs in processes
def test_sigkilled_parent_children_stop_and_next_run_cleans(long_run):
    start, tmp, root = long_run
    process = start()
    os.kill(process.pid, signal.SIGKILL)
    process.wait()
    assert _wait_gone(process.pid), "children outlived a SIGKILLed parent"
    stale = set(root.glob(".out.incomplete-*"))
    assert len(stale) == 1 and list(tmp.iterdir())  # left behind by the killed run
    second = start(stale=stale)  # the next run to the same place cleans what was left
    assert not any(p.exists() for p in stale)
    assert [p for p in tmp.iterdir() if f"-{process.pid}-" in p.name] == []
    os.kill(second.pid, signal.SIGTERM)
    second.communicate(timeout=GUARD)
    assert second.returncode == 128 + signal.SIGTERM
    assert _wait_gone(second.pid)
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
    assert process.wait(timeout=GUARD) == 0
    try:
        assert _group(process.pid) == []  # at once: nothing of ours outlives the command
        assert list(tmp.iterdir()) == []
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _cli(args, tmp):
    return subprocess.Popen([sys.executable, "-m", "agv_cosim.cli", *args],
                            env=dict(os.environ, TMPDIR=str(tmp)), start_new_session=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.slow  # seconds: runs FMUs in processes
def test_sigterm_during_a_hung_run_keeps_the_finished_one(fmus, tmp_path):
    """--jobs 1: the first run completes, the second hangs in doStep (no time limit)
    while an FMU of it has forked a helper; SIGTERM keeps the first complete, the second
    'interrupted' with its rows, the others 'not run', ends every process (the helper
    too), and our line is the last on stderr, on a line of its own (the progress bar is
    not drawn after it).

    The bar shows from the first progress after its 2 s delay: the first run pauses
    2.5 s in its last step (hang_time 0.99 s, hang_seconds 2.5), so that progress comes
    after the delay on any machine, and the test waits for the bar on stderr."""
    path = tmp_path / "hang.toml"
    path.write_text(f"""
name = "hang"
[simulation]
stop = 1.0
step = 0.01
[components.h]
fmu = "{fmus['agv_test_hang']}"
[components.r]
fmu = "{fmus['agv_test_rogue']}"
parameters = {{ fork_seconds = 300.0 }}
[sweep]
"h.hang_time" = [0.99, 0.3]
"h.hang_seconds" = [2.5, 3600.0]
""")
    hung_label = "base__h.hang_time=0.99__h.hang_seconds=3600.0"
    tmp = Path(tempfile.mkdtemp(prefix="agvsig", dir="/tmp"))
    out = tmp_path / "out"
    process = _cli(["run", str(path), "--out", str(out), "--jobs", "1"], tmp)
    stdout, stderr = Collected(process.stdout), Collected(process.stderr)
    try:
        def hung():  # the second run has recorded t = 0.99 s (100 rows) and hangs
            if process.poll() is not None:
                raise AssertionError(f"the command ended: {stderr.rest()}")
            found = next(iter(tmp_path.glob(f".out.incomplete-*/{hung_label}/"
                                            "timeseries.csv")), None)
            return found if found and found.read_bytes().count(b"\n") >= 100 else None

        hung_csv = wait_until(hung, "the hang reached")
        wait_until(lambda: "hang:" in stderr.text, "the progress bar drawn")
        rows = hung_csv.read_text().splitlines()
        helper = int(rows[1].split(",")[rows[0].split(",").index("r.helper")])
        assert Path(f"/proc/{helper}").exists()
        os.kill(process.pid, signal.SIGTERM)
        assert process.wait(timeout=GUARD) == 128 + signal.SIGTERM
        err = stderr.rest()
        stdout.rest()
        assert err.replace("\r", "\n").strip().splitlines()[-1] == (
            f"agv-cosim: interrupted by SIGTERM; 1 of 4 run(s) complete kept in {out} "
            "(marked partial: partial.txt, summary.csv)")
        assert _wait_gone(process.pid), "processes of the run are left"
        assert ended(helper), "the FMU's helper outlived the run"
        with open(out / "summary.csv", newline="") as stream:
            assert [r["status"] for r in csv.DictReader(stream)] == \
                ["complete", "interrupted", "not run", "not run"]
        info = json.loads((out / hung_label / "run.json").read_text())
        assert info["rows"] == 100 and "during doStep at t=0.99 s" in info["error"]
        assert list(tmp.iterdir()) == []
    finally:
        for pid in _group(process.pid):
            os.kill(pid, signal.SIGKILL)
        process.wait()
        shutil.rmtree(tmp, ignore_errors=True)


@pytest.mark.slow  # seconds: runs FMUs in processes
def test_a_forked_helper_dies_with_a_sigkilled_command(fmus, tmp_path):
    """The FMU forks a helper that would sleep 5 minutes, then the command is killed
    with SIGKILL while its run hangs: the worker, the helper and the fork server end
    (the helper was in the worker's group, which its guard kills); the next command
    removes the scratch folders left."""
    path = tmp_path / "fork.toml"
    path.write_text(f"""
name = "fork"
[simulation]
stop = 1.0
step = 0.01
[components.r]
fmu = "{fmus['agv_test_rogue']}"
parameters = {{ fork_seconds = 300.0 }}
[components.h]
fmu = "{fmus['agv_test_hang']}"
parameters = {{ hang_time = 0.1 }}
""")
    tmp = Path(tempfile.mkdtemp(prefix="agvsig", dir="/tmp"))
    process = _cli(["run", str(path), "--out", str(tmp_path / "out"), "--quiet"], tmp)
    try:
        def helper_started():  # the helper's pid, once the run has recorded a row
            if process.poll() is not None:
                raise AssertionError(f"the command ended: {process.communicate()}")
            for csv_file in tmp_path.glob(".out.incomplete-*/base/timeseries.csv"):
                rows = csv_file.read_text().split("\n")
                if len(rows) > 2:  # the header and a whole row
                    return int(rows[1].split(",")[rows[0].split(",").index("r.helper")])
            return 0

        helper = wait_until(helper_started, "the FMU's helper started")
        assert Path(f"/proc/{helper}").exists()
        os.kill(process.pid, signal.SIGKILL)
        process.wait()
        assert _wait_gone(process.pid), "processes outlived a SIGKILLed command"
        assert ended(helper), "the FMU's helper outlived it"
        assert [p.name for p in tmp.iterdir() if f"-{process.pid}-" in p.name]
        cleaner = _cli(["validate", str(path), "--no-init"], tmp)
        cleaner.communicate(timeout=GUARD)
        assert cleaner.returncode == 0
        assert [p.name for p in tmp.iterdir() if f"-{process.pid}-" in p.name] == []
    finally:
        for pid in _group(process.pid):
            os.kill(pid, signal.SIGKILL)
        shutil.rmtree(tmp, ignore_errors=True)
