"""--real-time at its edges and when its run is cut short: a factor whose deadlines
cannot be represented is refused with one line (CLI and API); a failure of the pacing
itself is never blamed on an FMU; a paced run stopped by its time limit or by SIGINT
keeps its pacing figures up to the stop in timings.csv; the folder an interruption
keeps has its index.html, marked partial."""

import os
import signal
import subprocess
import sys
import time

import pytest

from agv_cosim import cli
from agv_cosim.errors import OutputError, RunsStopped, SimulationError
from agv_cosim.execution import Pacer, pacing, simulate
from agv_cosim.files import MARKER
from agv_cosim.pipeline import execute, prepare
from agv_cosim.report.records import TIMINGS, read_timings
from agv_cosim.workers import pool

from processes import Collected, wait_until


@pytest.mark.parametrize("factor", ["1e-308", "1e-12", "5e-7", "2e6", "1e308"])
def test_a_factor_out_of_range_is_refused_in_one_line(chain, tmp_path, capsys, factor):
    path = chain()
    assert cli.main(["run", str(path), "--out", str(tmp_path / "o"), "--real-time",
                     factor]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"agv-cosim: error: --real-time: {float(factor)!r} must be > 0, a real-time "
        "factor from 1e-06 to 1e+06"]
    assert not (tmp_path / "o").exists()


def test_the_api_refuses_what_the_cli_refuses(chain, tmp_path):
    manifest, jobs, _ = prepare(chain())
    for factor in (1e-308, float("nan"), float("inf"), 0.0, -1.0, 2e6):
        with pytest.raises(OutputError, match="--real-time"):
            execute(manifest, jobs, tmp_path / "o", quiet=True, real_time=factor)
    # a factor in range whose paced run would last beyond what a wait can represent
    manifest, jobs, _ = prepare(chain(stop=2000.0, step=0.5, name="long.toml"))
    with pytest.raises(OutputError, match=r"--real-time: 1e-06 would pace the run's "
                                          r"2000.0 s over 2e\+09 s of wall time"):
        execute(manifest, jobs, tmp_path / "o", quiet=True, real_time=1e-6)
    assert not (tmp_path / "o").exists()
    with pytest.raises(ValueError, match="from 1e-06 to 1e\\+06"):
        Pacer(1e-308, 0.0)


def test_a_failure_of_the_pacing_is_not_an_fmus(chain, monkeypatch):
    """The wait raises (as ``time.sleep`` does for a wait it cannot represent): the run
    fails naming the pacing, not the component that stepped last."""
    def refused(seconds):
        raise OverflowError("sleep length is too large")

    monkeypatch.setattr(pacing.time, "sleep", refused)
    _, (job,), _ = prepare(chain())
    with pytest.raises(SimulationError) as caught:
        simulate(job.plan, pace=Pacer(1.0, job.plan.start))
    message = str(caught.value)
    assert message == ("real-time pacing failed at t=0.1 s: OverflowError: sleep length "
                       "is too large")
    assert "component" not in message


@pytest.mark.slow  # seconds: a paced run stopped at its limit
def test_a_paced_run_stopped_at_its_limit_keeps_its_pacing_figures(chain, tmp_path):
    path = chain(stop=100.0, step=0.1)
    out = tmp_path / "o"
    begin = time.monotonic()
    assert cli.main(["run", str(path), "--out", str(out), "--quiet", "--real-time", "10",
                     "--timeout", "2"]) == 1
    assert time.monotonic() - begin < 60  # 10 s paced at x10 was cut
    (timing,) = read_timings(out / TIMINGS).values()
    paced = timing["real_time"]
    assert paced["target"] == 10.0 and 1 <= paced["steps"] < 1000
    assert 0 < paced["wall_s"] <= timing["wall_time_s"]
    assert paced["achieved"] == pytest.approx(paced["steps"] * 0.1 / paced["wall_s"])
    assert paced["achieved"] <= 10.0 * 1.05


INTERRUPTED = """
import signal, sys
from agv_cosim import cli
# a command started from a shell: Ctrl-C's default disposition, whatever this test
# process inherited (a parent that ignores or blocks SIGINT passes that on)
signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
signal.signal(signal.SIGINT, signal.default_int_handler)
sys.exit(cli.main(["run", sys.argv[1], "--out", sys.argv[2], "--real-time", "10",
                   "--no-init"]))
"""


@pytest.mark.slow  # seconds: a paced run interrupted
def test_an_interrupted_paced_run_keeps_its_figures_and_its_page(chain, tmp_path):
    """SIGINT to the command's process group (as Ctrl-C) while its one paced run is under
    way: exit 130, the folder kept marked partial with the pacing figures up to the
    interruption in timings.csv and an index.html that says the result is partial."""
    path = chain(stop=100.0, step=0.1)
    out = tmp_path / "o"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    process = subprocess.Popen([sys.executable, "-c", INTERRUPTED, str(path), str(out)],
                               stderr=subprocess.PIPE, stdout=subprocess.DEVNULL,
                               start_new_session=True, env=env)
    err = Collected(process.stderr)
    try:
        # five paced steps are done once the temporary timeseries holds the header, the
        # row at the start and five more complete rows (a last line may still be partial)
        wait_until(lambda: any(sum(1 for _ in f.open()) > 7 for f in
                               tmp_path.glob(".o*/base/timeseries.csv")), "rows written")
        os.killpg(process.pid, signal.SIGINT)
        assert process.wait(timeout=120) == 130
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
    assert "interrupted by SIGINT" in err.text
    assert (out / MARKER).is_file() and (out / "partial.txt").is_file()
    (timing,) = read_timings(out / TIMINGS).values()
    paced = timing["real_time"]
    assert paced["target"] == 10.0 and paced["steps"] >= 5 and paced["wall_s"] > 0
    page = (out / "index.html").read_text()
    assert "partial result: interrupted by SIGINT" in page
    assert "interrupted" in page


def test_the_folder_an_interruption_keeps_has_its_page(chain, tmp_path, capsys,
                                                        monkeypatch):
    """SIGINT after the first of two runs: the kept folder has index.html, which shows
    the partial note and the run kept."""
    real = pool.run_isolated

    def first_then_interrupted(jobs, root, *args, **kwargs):
        [first] = real(jobs[:1], root, *args, **kwargs)
        raise RunsStopped.of(KeyboardInterrupt(), [first, pool.not_run(jobs[1])])

    monkeypatch.setattr(pool, "run_isolated", first_then_interrupted)
    path = chain(extra='[sweep]\n"gain.k" = [1.0, 2.0]\n')
    out = tmp_path / "out"
    assert cli.main(["run", str(path), "--out", str(out), "--quiet"]) == 130
    page = (out / "index.html").read_text()
    assert "partial result: interrupted by SIGINT; 1 of 2 run(s) complete" in page
    assert "base__gain.k=1.0" in page  # the run kept, with its files
