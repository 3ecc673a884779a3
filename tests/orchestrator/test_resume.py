"""``agv-cosim run --resume``: the complete runs of an earlier result folder whose inputs
are unchanged are kept, the others run again, and the folder is the one a run from
scratch writes.

"The same folder" is checked file by file (every file, same names, same bytes) except
the wall times, which differ between any two runs: ``wall_time_s`` of each run.json
(a reused run keeps the one it was measured with) and the wall-time column of
index.html's run table.
"""

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import pytest
from processes import GUARD, Collected, wait_until

from agv_cosim import cli
from agv_cosim.pipeline import execute, prepare

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

#: index.html's wall-time cell (the one before the run's links)
WALL_CELL = re.compile(r"<td[^>]*>[^<]*</td>(?=<td class=files>)")


def folder_contents(root):
    """Relative path -> content of every file under ``root``, wall times left out."""
    root = Path(root)
    found = {}
    for path in sorted(root.rglob("*")):
        if path.is_dir():
            continue
        data = path.read_bytes()
        if path.name == "run.json":
            record = json.loads(data)
            assert isinstance(record.pop("wall_time_s"), (float, type(None)))
            data = json.dumps(record, sort_keys=True).encode()
        elif path.name == "index.html":
            data, cells = WALL_CELL.subn("", data.decode())
            assert cells == sum(1 for p in root.iterdir() if (p / "run.json").is_file())
        found[str(path.relative_to(root))] = data
    return found


def assert_same_folder(resumed, clean):
    mine, theirs = folder_contents(resumed), folder_contents(clean)
    assert sorted(mine) == sorted(theirs)
    for name in theirs:
        assert mine[name] == theirs[name], name
    return len(theirs)


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
    # nothing changed: every run kept, the folder as it was (but for index.html's
    # wall times, now the same as before, and run.json: the same bytes)
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
    kept_json = (kept / "run.json").read_bytes()

    resumed = subprocess.run(command + ["--resume"], env=env, capture_output=True,
                             text=True, timeout=GUARD)
    assert resumed.returncode == 0, resumed.stderr
    assert (f"agv-cosim: resume: reused {complete} of 4 run(s) of {out}; running "
            f"{4 - complete}") in resumed.stderr
    assert not (out / "partial.txt").exists()
    assert (kept / "run.json").read_bytes() == kept_json  # its wall time too

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
    from agv_cosim.errors import Interrupted
    from agv_cosim.pipeline import pool, run

    path = chain(extra='[sweep]\n"gain.k" = [1.0, 2.0]\n')
    out = tmp_path / "out"
    assert not any(_run(path, out, resume=False).values())
    path.write_text(path.read_text().replace("[1.0, 2.0]", "[1.0, 3.0]"))

    def interrupted(jobs, *args):
        stop = Interrupted(signal.SIGTERM)
        stop.results = [pool.not_run(job) for job in jobs]
        raise stop

    monkeypatch.setattr(run, "run_isolated", interrupted)
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
