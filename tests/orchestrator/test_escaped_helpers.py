"""A process an FMU starts ends with the command, also when it left the run's process
group and session (``setsid()``), and also when its own parent is already gone (a
daemon's double fork): the run's process is a child subreaper, killed with everything
below it, and the command ends what is handed to it (agv_cosim.lifetime)."""

import csv
import os
import signal
import time

import pytest

from agv_cosim import cli
from agv_cosim.lifetime import Orphans, descendants

from processes import ended

ROGUE = """
name = "helpers"
[simulation]
stop = 0.1
step = 0.01
[components.r]
fmu = "{rogue}"
parameters = {{ fork_seconds = 300.0, leave = {leave} }}
{extra}
"""
HANG = """
[components.h]
fmu = "{hang}"
parameters = {{ hang_time = 0.05 }}
"""


def _helper(out):
    with open(out / "base" / "timeseries.csv", newline="") as stream:
        return int(next(iter(csv.DictReader(stream)))["r.helper"])


def _kill_if_alive(pid):
    try:
        os.kill(pid, signal.SIGKILL)
    except OSError:
        pass


@pytest.mark.parametrize("leave", [1, 2], ids=["setsid", "double-fork"])
def test_a_helper_that_left_the_group_ends_with_its_run(fmus, tmp_path, leave):
    path = tmp_path / "helpers.toml"
    path.write_text(ROGUE.format(rogue=fmus["agv_test_rogue"], leave=leave, extra=""))
    out = tmp_path / "out"
    assert cli.main(["run", str(path), "--out", str(out), "--quiet", "--no-init"]) == 0
    helper = _helper(out)
    try:
        assert helper > 0
        assert os.getsid(0) != _sid(helper)  # it did leave our session
        assert ended(helper, guard=30)
    finally:
        _kill_if_alive(helper)


def _sid(pid):
    try:
        return os.getsid(pid)
    except OSError:
        return None  # already gone: not ours either


@pytest.mark.slow  # seconds: a run stopped at its limit
@pytest.mark.parametrize("leave", [1, 2], ids=["setsid", "double-fork"])
def test_a_helper_that_left_the_group_ends_with_a_stopped_run(fmus, tmp_path, leave):
    """The run hangs and is stopped at its wall-clock limit while its worker lives: the
    helper, outside the worker's group, is killed with it."""
    path = tmp_path / "helpers.toml"
    path.write_text(ROGUE.format(rogue=fmus["agv_test_rogue"], leave=leave,
                                 extra=HANG.format(hang=fmus["agv_test_hang"])))
    out = tmp_path / "out"
    assert cli.main(["run", str(path), "--out", str(out), "--quiet", "--no-init",
                     "--timeout", "5"]) == 1
    helper = _helper(out)
    try:
        assert helper > 0
        assert ended(helper, guard=30)
    finally:
        _kill_if_alive(helper)


def test_orphans_handed_to_the_command_are_ended_and_the_others_spared():
    """A child that was there before is spared; a grandchild whose parent exited is
    handed to this process and ended by the sweep; the setting is put back."""
    before = os.fork()
    if before == 0:
        time.sleep(60)
        os._exit(0)
    reader, writer = os.pipe()
    try:
        orphans = Orphans()
        others = set(descendants(os.getpid()))  # e.g. a fork server of earlier tests
        middle = os.fork()
        if middle == 0:
            if os.fork() == 0:
                os.setsid()
                time.sleep(60)
                os._exit(0)
            os._exit(0)
        os.waitpid(middle, 0)
        # the grandchild is now a child of this process
        adopted = [p for p in descendants(os.getpid()) if p not in others]
        assert len(adopted) == 1
        assert orphans.sweep() == adopted
        assert ended(adopted[0], guard=10)
        orphans.close()
        assert not ended(before, guard=0.2)
    finally:
        os.close(reader)
        os.close(writer)
        os.kill(before, signal.SIGKILL)
        os.waitpid(before, 0)


@pytest.mark.slow  # seconds: a command SIGKILLed while its run hangs
def test_a_helper_that_left_the_group_ends_with_a_sigkilled_command(fmus, tmp_path):
    """The command is SIGKILLed while its run hangs: the worker dies with it (and may go
    before its guard looks), and the setsid() helper, outside every group of ours, is
    ended by the guard from what it saw below the worker."""
    import subprocess
    import sys

    from processes import wait_until

    path = tmp_path / "helpers.toml"
    path.write_text(ROGUE.format(rogue=fmus["agv_test_rogue"], leave=1,
                                 extra=HANG.format(hang=fmus["agv_test_hang"])))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    process = subprocess.Popen([sys.executable, "-m", "agv_cosim.cli", "run", str(path),
                                "--out", str(tmp_path / "out"), "--quiet", "--no-init"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                               start_new_session=True, env=env)
    helper = 0
    try:
        def helper_started():
            if process.poll() is not None:
                raise AssertionError("the command ended")
            for series in tmp_path.glob(".out.incomplete-*/base/timeseries.csv"):
                rows = series.read_text().split("\n")
                if len(rows) > 2:
                    return int(rows[1].split(",")[rows[0].split(",").index("r.helper")])
            return 0

        helper = wait_until(helper_started, "the FMU's helper started")
        assert os.getsid(helper) == helper  # it left our session
        time.sleep(1.5)  # the guard looks below the worker every 0.5 s
        process.kill()
        process.wait()
        assert ended(helper, guard=30), "the helper outlived a SIGKILLed command"
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        if helper:
            _kill_if_alive(helper)
