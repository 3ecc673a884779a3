"""``agv-cosim run --resume``: the complete runs of an earlier result folder whose inputs
are unchanged are kept, the others run again, and the folder is the one a run from
scratch writes.

"The same folder" is checked file by file: every file, same names, same bytes, but for
timings.csv, the one file of measured times (a reused run keeps its row of it).
"""

import csv
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import pytest

from agv_cosim import cli
from agv_cosim.pipeline import execute, prepare
from agv_cosim.report.records import TIMING_COLUMNS, TIMINGS, read_timings, write_timings

from processes import GUARD, Collected, wait_until
from result_folders import assert_same_folder

#: two variants (the second with its own copy of the gain FMU) x two sweep points
VARIANTS = """
[variants.lo.components.gain]
parameters = {{ k = 1.0 }}
[variants.hi.components.gain]
fmu = "{copy}"
parameters = {{ k = 5.0 }}
[sweep]
"gain2.k" = [0.5, 1.0]
[plots]
signals = ["int.y", "gain.y"]
"""


#: a sweep of three runs with metrics, the figures and a Monte Carlo-free summary
CLEAN = """
[sweep]
"gain.k" = [1.0, 2.0, 4.0]
[metrics]
lateral_error = "int.y"
[plots]
signals = ["int.y", "gain.y"]
"""


def test_two_clean_runs_differ_only_in_timings_csv(chain, tmp_path, capsys):
    """No file of a result folder but timings.csv holds a time: two runs of the same
    manifest write the same bytes; timings.csv has one row per run, its wall time."""
    path = chain(extra=CLEAN, step=0.01)
    first, second = tmp_path / "first", tmp_path / "second"
    for out in (first, second):
        assert cli.main(["run", str(path), "--out", str(out), "--quiet", "--jobs", "2",
                         "--no-init"]) == 0
    count = assert_same_folder(first, second)
    runs = sorted(p.parent.name for p in first.glob("*/run.json"))
    assert len(runs) == 3
    # 3 x (timeseries, metrics, run) + summary.csv, .agv-cosim, index.html, its record
    assert count == 3 * 3 + 4 + len(list(first.glob("*.png")))
    page = (first / "index.html").read_text()
    assert f'href="{TIMINGS}"' in page and "<th>wall time" not in page
    for out in (first, second):
        with open(out / TIMINGS, newline="") as stream:
            rows = list(csv.DictReader(stream))
        assert tuple(rows[0]) == TIMING_COLUMNS
        assert sorted(row["run"] for row in rows) == runs
        for row in rows:
            wall = float(row["wall_time_s"])
            assert math.isfinite(wall) and wall >= 0, row
            assert not any(row[k] for k in TIMING_COLUMNS[2:]), row  # not paced
        assert "wall_time_s" not in (out / runs[0] / "run.json").read_text()


def test_timings_csv_reads_back_as_written(tmp_path):
    """A reused run's row of timings.csv is written again as it was read."""
    paced = {"target": 2.0, "achieved": 1.9993, "overruns": 3, "max_lateness_s": 0.0125,
             "steps": 200, "wall_s": 1.0003}
    results = [{"label": "a", "wall_time_s": 0.1 + 0.2},
               {"label": "b,\"c", "wall_time_s": 1.5, "real_time": paced},
               {"label": "d"}]
    write_timings(tmp_path / "one.csv", results)
    read = read_timings(tmp_path / "one.csv")
    assert read == {"a": {"wall_time_s": 0.1 + 0.2},
                    "b,\"c": {"wall_time_s": 1.5, "real_time": paced},
                    "d": {"wall_time_s": None}}
    write_timings(tmp_path / "two.csv", [{"label": k, **v} for k, v in read.items()])
    assert (tmp_path / "two.csv").read_bytes() == (tmp_path / "one.csv").read_bytes()
    assert read_timings(tmp_path / "missing.csv") == {}


def _run(path, out, resume=True):
    manifest, jobs, _ = prepare(path)
    target, results = execute(manifest, jobs, out, workers=2, quiet=True, resume=resume)
    assert all(r["status"] == "complete" for r in results), results
    return {r["label"]: r.get("reused", False) for r in results}


@pytest.fixture
def variants(chain, fmus, tmp_path):
    copy = tmp_path / "gain_copy.fmu"
    shutil.copyfile(fmus["agv_test_gain"], copy)
    return chain(extra=VARIANTS.format(copy=copy), step=0.01), copy


@pytest.mark.slow  # seconds: runs FMUs in processes
def test_resume_reruns_only_the_runs_a_change_affects(variants, tmp_path):
    path, copy = variants
    out = tmp_path / "out"
    first = _run(path, out, resume=False)
    assert len(first) == 4 and not any(first.values())
    # nothing changed: every run kept, the folder as it was, timings.csv included
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert all(_run(path, out).values())
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before

    # a parameter of variant hi changed: its two runs run again, lo's are kept
    path.write_text(path.read_text().replace("k = 5.0", "k = 6.0"))
    reused = _run(path, out)
    assert {label for label, kept in reused.items() if kept} == {
        label for label in reused if label.startswith("lo")} and len(reused) == 4
    assert_same_folder(out, _clean(path, tmp_path / "clean1"))

    # the FMU variant hi uses changed (its hash): its runs run again, lo's are kept
    with zipfile.ZipFile(copy, "a") as fmu:
        fmu.writestr("documentation/changed.txt", "another build\n")
    reused = _run(path, out)
    assert {label for label, kept in reused.items() if kept} == {
        label for label in reused if label.startswith("lo")}
    assert_same_folder(out, _clean(path, tmp_path / "clean2"))


def _clean(path, out):
    assert not any(_run(path, out, resume=False).values())
    return out


def test_resume_refusals(chain, tmp_path, capsys):
    path = chain(stop=0.2)
    other = tmp_path / "mine"
    other.mkdir()
    (other / "notes.txt").write_text("mine\n")
    assert cli.main(["run", str(path), "--out", str(other), "--resume", "--no-init"]) == 2
    assert capsys.readouterr().err.strip() == (
        f"agv-cosim: error: {other}: not a result folder of agv-cosim; refusing to "
        "resume from it")
    assert (other / "notes.txt").read_text() == "mine\n"

    assert cli.main(["run", str(path), "--out", str(tmp_path / "r"), "--resume",
                     "--overwrite", "--no-init"]) == 2
    assert capsys.readouterr().err.strip().startswith(
        "agv-cosim: error: --resume and --overwrite exclude each other")

    # a folder of another manifest (name)
    assert cli.main(["run", str(path), "--out", str(tmp_path / "r"), "--quiet",
                     "--no-init"]) == 0
    renamed = tmp_path / "renamed.toml"
    renamed.write_text(path.read_text().replace('name = "chain"', 'name = "other"'))
    assert cli.main(["run", str(renamed), "--out", str(tmp_path / "r"), "--resume",
                     "--no-init"]) == 2
    assert capsys.readouterr().err.strip() == (
        f"agv-cosim: error: {tmp_path / 'r'}: written for manifest 'chain', not 'other'; "
        "refusing to resume from it (choose another --out)")


#: four runs, --jobs 1: two of them sleep 0.4 s in each of their last five steps
KILLED = """
[components.h]
fmu = "{hang}"
parameters = {{ hang_time = 0.95 }}
[sweep]
"h.hang_seconds" = [0.0, 0.4]
"gain.k" = [1.0, 2.0]
[plots]
signals = ["int.y", "h.t_out"]
"""


@pytest.mark.slow  # seconds: runs FMUs in processes, one of them killed
def test_sweep_killed_by_sigterm_then_resumed_equals_a_clean_run(chain, fmus, tmp_path):
    path = chain(stop=1.0, step=0.01, extra=KILLED.format(hang=fmus["agv_test_hang"]))
    tmp = Path(tempfile.mkdtemp(prefix="agvres", dir="/tmp"))  # short: socket paths
    env = dict(os.environ, TMPDIR=str(tmp))
    out = tmp_path / "out"
    command = [sys.executable, "-m", "agv_cosim.cli", "run", str(path), "--out", str(out),
               "--jobs", "1", "--no-init"]
    process = subprocess.Popen(command, env=env, start_new_session=True,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    stderr = Collected(process.stderr)
    try:
        def hanging():  # a run is complete, a run that hangs is in its hang
            if process.poll() is not None:
                raise AssertionError(f"the command ended: {stderr.rest()}")
            done = list(tmp_path.glob(".out.incomplete-*/*/run.json"))
            csvs = list(tmp_path.glob(".out.incomplete-*/*/timeseries.csv"))
            return done and any(p.read_bytes().count(b"\n") >= 96 for p in csvs
                                if not (p.parent / "run.json").exists())

        wait_until(hanging, "the second run in its hang")
        os.kill(process.pid, signal.SIGTERM)
        assert process.wait(timeout=GUARD) == 128 + signal.SIGTERM
        process.stdout.read()
        stderr.rest()
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    assert (out / "partial.txt").is_file()
    statuses = [line.split(",")[2] for line in
                (out / "summary.csv").read_text().splitlines()[1:]]
    complete = statuses.count("complete")
    assert 1 <= complete < 4 and "interrupted" in statuses, statuses
    kept = next(p.parent for p in out.glob("*/run.json")
                if json.loads(p.read_text())["status"] == "complete")
    partial_timings = read_timings(out / TIMINGS)
    kept_timing = partial_timings[kept.name]
    assert kept_timing["wall_time_s"] >= 0
    # the run under way has the time until it was stopped; a run not started, none
    walls = [partial_timings[line.split(",")[0]]["wall_time_s"]
             for line in (out / "summary.csv").read_text().splitlines()[1:]]
    assert [w is not None for w in walls] == [s != "not run" for s in statuses], walls

    resumed = subprocess.run(command + ["--resume"], env=env, capture_output=True,
                             text=True, timeout=GUARD)
    assert resumed.returncode == 0, resumed.stderr
    assert (f"agv-cosim: resume: reused {complete} of 4 run(s) of {out}; running "
            f"{4 - complete}") in resumed.stderr
    assert not (out / "partial.txt").exists()
    timings = read_timings(out / TIMINGS)
    assert timings[kept.name] == kept_timing  # the time it was measured with
    assert sorted(timings) == sorted(p.parent.name for p in out.glob("*/run.json"))

    clean = tmp_path / "clean"
    finished = subprocess.run([*command[:6], str(clean), *command[7:]], env=env,
                              capture_output=True, text=True, timeout=GUARD)
    assert finished.returncode == 0, finished.stderr
    count = assert_same_folder(out, clean)
    figures = len(list(clean.glob("*.png")))
    assert figures >= 1
    # 4 x (timeseries, metrics, run) + summary.csv, the marker .agv-cosim, index.html
    # and its record .agv-cosim-report.json, the figures
    assert count == 4 * 3 + 4 + figures
    shutil.rmtree(tmp, ignore_errors=True)


def test_an_interrupted_resume_keeps_the_reused_runs(chain, tmp_path, monkeypatch):
    """A resumed sweep interrupted before its own runs end commits the folder marked
    partial with the reused runs complete in it; resuming again reuses them."""
    from agv_cosim.errors import Interrupted, RunsStopped
    from agv_cosim.workers import pool

    path = chain(extra='[sweep]\n"gain.k" = [1.0, 2.0]\n')
    out = tmp_path / "out"
    assert not any(_run(path, out, resume=False).values())
    path.write_text(path.read_text().replace("[1.0, 2.0]", "[1.0, 3.0]"))

    def interrupted(jobs, *args, **kwargs):
        raise RunsStopped.of(Interrupted(signal.SIGTERM), [pool.not_run(job) for job in jobs])

    monkeypatch.setattr(pool, "run_isolated", interrupted)
    manifest, jobs, _ = prepare(path)
    with pytest.raises(Interrupted):
        execute(manifest, jobs, out, quiet=True, resume=True)
    assert (out / "partial.txt").read_text().startswith(
        "partial result: interrupted by SIGTERM; 1 of 2 run(s) complete")
    statuses = [line.split(",")[:3] for line in
                (out / "summary.csv").read_text().splitlines()[1:]]
    assert [s[2] for s in statuses] == ["complete", "not run"]
    assert (out / statuses[0][0] / "timeseries.csv").is_file()
    monkeypatch.undo()
    assert _run(path, out) == {statuses[0][0]: True, statuses[1][0]: False}
    assert_same_folder(out, _clean(path, tmp_path / "clean"))
