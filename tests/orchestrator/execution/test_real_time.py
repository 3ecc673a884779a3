"""``agv-cosim run --real-time FACTOR``: one run paced at FACTOR x wall time, with the
same results as unpaced (the same folder, byte for byte, but timings.csv); the target
and achieved factor, the overruns and the worst lateness recorded in timings.csv and
printed.

The timing assertions cannot flake: a paced run never ends before its last deadline
(so its stepping lasts at least stop / factor and its achieved factor is at most the
target, up to rounding); on a loaded machine it may fall behind, which then shows as
overruns.
"""

import json
import time

import pytest

from agv_cosim import cli
from agv_cosim.execution import Pacer
from agv_cosim.pipeline import execute, prepare
from agv_cosim.report.records import REAL_TIME_FIELDS, TIMINGS, read_timings

from result_folders import folder_contents

SWEEP = '[sweep]\n"gain.k" = [1.0, 2.0]\n'


@pytest.mark.slow  # seconds: runs FMUs in processes, one of them paced
def test_paced_run_keeps_its_factor_and_its_results(chain, tmp_path, capsys):
    path = chain(stop=2.0, step=0.01)
    assert cli.main(["run", str(path), "--out", str(tmp_path / "plain"), "--quiet"]) == 0
    begin = time.monotonic()
    assert cli.main(["run", str(path), "--out", str(tmp_path / "paced"), "--real-time",
                     "4"]) == 0
    assert time.monotonic() - begin >= 2.0 / 4
    printed = capsys.readouterr().out.splitlines()[-1]
    (run,) = (tmp_path / "paced").glob("*/run.json")
    (timing,) = read_timings(tmp_path / "paced" / TIMINGS).values()
    paced = timing["real_time"]
    assert timing["wall_time_s"] >= paced["wall_s"] > 0
    assert paced["target"] == 4.0 and paced["steps"] == 200
    assert paced["wall_s"] >= 2.0 / 4
    assert paced["achieved"] <= 4.0 * 1.05
    assert paced["achieved"] >= 3.0 or paced["overruns"] > 0
    assert paced["overruns"] == 0 or paced["max_lateness_s"] > 0
    assert printed.startswith(f"real time: target x4, achieved x{paced['achieved']:.5g} "
                              f"over 200 step(s); {paced['overruns']} overrun(s)")
    # the pacing changes no file but timings.csv, and an unpaced run records none
    assert folder_contents(tmp_path / "paced") == folder_contents(tmp_path / "plain")
    assert "real_time" not in json.loads(run.read_text())
    (plain,) = read_timings(tmp_path / "plain" / TIMINGS).values()
    assert "real_time" not in plain and plain["wall_time_s"] > 0


def test_pacer_deadlines_are_absolute():
    """A slow step is an overrun with its lateness; the later steps keep their own
    deadlines (from the start), and the stepping ends no earlier than the last one."""
    pacer = Pacer(1.0, start=0.0)
    done = []

    def step(t, h):
        done.append(t)
        if len(done) == 3:
            time.sleep(0.3)  # this step's deadline is 0.15 s after the start

    paced = pacer.wrap(step)
    for k in range(10):
        paced(k * 0.05, 0.05)
    report = pacer.report()
    assert tuple(report) == REAL_TIME_FIELDS  # timings.csv's columns
    assert done == [k * 0.05 for k in range(10)]
    assert report["steps"] == 10 and report["overruns"] >= 1
    assert report["max_lateness_s"] >= 0.15
    assert report["wall_s"] >= 0.5 and report["achieved"] <= 1.0 + 1e-9


def test_real_time_refusals(chain, tmp_path, capsys):
    with pytest.raises(ValueError, match="must be > 0"):
        Pacer(0.0, 0.0)
    sweep = chain(extra=SWEEP)
    assert cli.main(["run", str(sweep), "--out", str(tmp_path / "o"), "--real-time",
                     "1"]) == 2
    assert capsys.readouterr().err.strip() == (
        "agv-cosim: error: --real-time: paces one run; the manifest has 2 (choose one "
        "with --variant, or a manifest without a sweep)")
    single = chain(name="single.toml")
    for extra, error in ((["--dask", "tcp://127.0.0.1:1"],
                          "--real-time: runs on this machine, not with --dask"),
                         (["--resume"], "--real-time and --resume exclude each other")):
        assert cli.main(["run", str(single), "--out", str(tmp_path / "o"), "--real-time",
                         "1", *extra]) == 2
        assert capsys.readouterr().err.strip() == f"agv-cosim: error: {error}"
    with pytest.raises(SystemExit) as exit_:
        cli.main(["run", str(single), "--real-time", "0"])
    assert exit_.value.code == 2
    assert "must be a positive, finite factor" in capsys.readouterr().err
    manifest, jobs, _ = prepare(single)
    assert not (tmp_path / "o").exists()
    with pytest.raises(Exception, match="paces one run"):
        execute(manifest, jobs * 2, tmp_path / "o", real_time=2.0)
