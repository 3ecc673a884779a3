"""The result folder's figures drawn in concurrent forked processes
(agv_cosim.pipeline.pool.call_concurrently, used by pipeline.run after the runs)."""

import os
from functools import partial

import pytest
from test_resume import folder_contents

from agv_cosim import cli
from agv_cosim.pipeline.pool import call_concurrently
from agv_cosim.report import plots

SWEEP_PLOTS = """
[sweep]
"gain.k" = [1.0, 2.0, 3.0]
[metrics]
lateral_error = "int.y"
[plots]
signals = ["int.y", "gain.y"]
"""


def _pid(index: int) -> tuple[int, int]:
    return index, os.getpid()


def _raise() -> None:
    raise ValueError("boom")


def _die() -> None:
    os._exit(3)


def _said(failure: BaseException) -> str:
    return f"{type(failure).__name__}: {failure}"


def test_tasks_run_in_forked_processes_in_order():
    tasks = [partial(_pid, i) for i in range(3)]
    results = call_concurrently(tasks, 2, _said)
    assert [index for index, _ in results] == [0, 1, 2]
    assert all(pid != os.getpid() for _, pid in results)
    # one worker, or one task: here, one after the other
    assert call_concurrently(tasks, 1, _said) == [(i, os.getpid()) for i in range(3)]
    assert call_concurrently(tasks[:1], 4, _said) == [(0, os.getpid())]


def test_a_failing_task_gives_its_failure():
    assert call_concurrently([partial(_pid, 0), _raise], 2, _said)[1] == "ValueError: boom"
    assert call_concurrently([_raise, partial(_pid, 1)], 1, _said)[0] == "ValueError: boom"
    # a process that dies: its task (at least) says so, nothing raises here
    died = call_concurrently([_die, partial(_pid, 1)], 2, _said)[0]
    assert isinstance(died, str) and died.startswith("BrokenProcessPool")


@pytest.mark.slow  # seconds: runs FMUs in processes
def test_figures_drawn_concurrently_are_the_serial_bytes(chain, tmp_path):
    path = chain(extra=SWEEP_PLOTS)
    for jobs, out in (("1", "s"), ("2", "p")):
        assert cli.main(["run", str(path), "--out", str(tmp_path / out), "--jobs", jobs,
                         "--quiet"]) == 0
    serial, parallel = folder_contents(tmp_path / "s"), folder_contents(tmp_path / "p")
    assert {plots.SIGNALS_FILE, plots.SWEEP_FILE, "index.html"} <= set(serial)
    assert serial == parallel
    page = serial["index.html"].decode()
    assert plots.SIGNALS_FILE in page and plots.SWEEP_FILE in page


@pytest.mark.slow  # seconds: runs FMUs in processes
def test_a_plot_failing_in_its_process_is_reported(chain, tmp_path, monkeypatch, capsys):
    def broken(*args, **kwargs):
        raise RuntimeError("no ink")

    # the drawing processes are forked from this one: they draw with the broken function
    monkeypatch.setattr(plots, "plot_runs", broken)
    path = chain(extra=SWEEP_PLOTS)
    out = tmp_path / "o"
    assert cli.main(["run", str(path), "--out", str(out), "--jobs", "2", "--quiet"]) == 0
    assert (out / "plots_error.txt").read_text() == "RuntimeError: no ink\n"
    assert "warning" in capsys.readouterr().err
    assert not (out / plots.SIGNALS_FILE).exists()
    # the page's own figure, drawn beside it, and the page (which names the failure)
    assert (out / plots.SWEEP_FILE).is_file()
    assert "plots_error.txt" in (out / "index.html").read_text()


INTERRUPTED = """
import os, signal, sys, time
from functools import partial
from agv_cosim.pipeline.pool import call_concurrently

def task(seconds):
    time.sleep(seconds)
    return os.getpid()

signal.signal(signal.SIGALRM, lambda *_: os.killpg(0, signal.SIGINT))  # as Ctrl-C does
signal.setitimer(signal.ITIMER_REAL, 0.5)
try:
    call_concurrently([partial(task, 0.1), partial(task, 2.0)], 2, repr)
except KeyboardInterrupt:
    print("interrupted", file=sys.stderr)
"""


def test_an_interruption_reaches_the_command_only():
    """Ctrl-C goes to the whole process group: the figure processes, the busy one and
    the one waiting for a task, leave it to the command (no traceback of theirs), which
    gets its KeyboardInterrupt."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", INTERRUPTED], capture_output=True,
                          text=True, timeout=60, start_new_session=True)
    assert done.stderr.strip() == "interrupted", done.stderr
    assert done.returncode == 0
