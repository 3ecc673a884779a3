"""The result folder's figures drawn in concurrent forked processes
(agv_cosim.workers.pool.call_concurrently, used by pipeline.run after the runs)."""

import os
import subprocess
import sys

import pytest

from agv_cosim import cli
from agv_cosim.report import plots
from agv_cosim.workers.pool import call_concurrently

from result_folders import folder_contents

SWEEP_PLOTS = """
[sweep]
"gain.k" = [1.0, 2.0, 3.0]
[metrics]
lateral_error = "int.y"
[plots]
signals = ["int.y", "gain.y"]
"""


#: call_concurrently forks only from a single-threaded process, which a pytest-xdist
#: worker is not (execnet's threads): these checks run in a fresh interpreter
FORKED = """
import os
from functools import partial
from agv_cosim.workers.pool import call_concurrently

def pid(index):
    return index, os.getpid()

def fail():
    raise ValueError("boom")

def die():
    os._exit(3)

def said(failure):
    return f"{type(failure).__name__}: {failure}"

tasks = [partial(pid, i) for i in range(3)]
results = call_concurrently(tasks, 2, said)
assert [index for index, _ in results] == [0, 1, 2], results
assert all(child != os.getpid() for _, child in results), results
# one worker, or one task: here, one after the other
assert call_concurrently(tasks, 1, said) == [(i, os.getpid()) for i in range(3)]
assert call_concurrently(tasks[:1], 4, said) == [(0, os.getpid())]
# a task that raises gives its failure, forked or not
assert call_concurrently([partial(pid, 0), fail], 2, said)[1] == "ValueError: boom"
assert call_concurrently([fail, partial(pid, 1)], 1, said)[0] == "ValueError: boom"
# a process that dies: its task (at least) says so, nothing raises here
died = call_concurrently([die, partial(pid, 1)], 2, said)[0]
assert isinstance(died, str) and died.startswith("BrokenProcessPool"), died
print("ok")
"""


def test_tasks_run_in_forked_processes_in_order_and_fail_alone():
    done = subprocess.run([sys.executable, "-c", FORKED], capture_output=True, text=True,
                          timeout=120)
    assert (done.returncode, done.stdout.strip()) == (0, "ok"), done.stderr


def test_a_threaded_caller_calls_the_tasks_here():
    """With other threads (a pytest-xdist worker, a Jupyter kernel) nothing is forked."""
    import threading

    stop = threading.Event()
    helper = threading.Thread(target=stop.wait)
    helper.start()
    try:
        got = call_concurrently([os.getpid, os.getpid], 2, repr)
    finally:
        stop.set()
        helper.join()
    assert got == [os.getpid(), os.getpid()]


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
from agv_cosim.workers.pool import call_concurrently

def task(seconds):
    time.sleep(seconds)
    return os.getpid()

# a command started from a shell: Ctrl-C's default disposition, whatever this test
# process inherited (a parent that ignores or blocks SIGINT passes that on)
signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
signal.signal(signal.SIGINT, signal.default_int_handler)
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
    done = subprocess.run([sys.executable, "-c", INTERRUPTED], capture_output=True,
                          text=True, timeout=60, start_new_session=True)
    assert done.stderr.strip() == "interrupted", done.stderr
    assert done.returncode == 0
