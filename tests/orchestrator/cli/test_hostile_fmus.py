"""Hostile round three, misbehaving FMUs: a hang has a wall-clock limit, finished runs
survive an interruption, an FMU's output and messages stay out of our stdout and cannot
drive the terminal, garbage in our pipes and forked helpers end with their run, and a
modelIdentifier is a name, never a path."""

import csv
import dataclasses
import json
import os
import time
import zipfile
from pathlib import Path

import pytest

from agv_cosim import cli
from agv_cosim import pipeline as runner
from agv_cosim.errors import RunsStopped
from agv_cosim.files import MARKER
from agv_cosim.workers import channels, initcheck, pool

from processes import ended

HANG = """
name = "hang"
[simulation]
stop = 1.0
step = 0.01
{timeout}
[components.h]
fmu = "{fmu}"
parameters = {{ hang_time = {hang_time} }}
{extra}
"""

ROGUE = """
name = "rogue"
[simulation]
stop = 0.1
step = 0.01
[components.r]
fmu = "{fmu}"
parameters = {parameters}
"""


def _hang(fmus, tmp_path, hang_time=0.2, timeout="", extra="", name="hang.toml"):
    path = tmp_path / name
    path.write_text(HANG.format(fmu=fmus["agv_test_hang"], hang_time=hang_time,
                                timeout=timeout, extra=extra))
    return path


def _rogue(fmus, tmp_path, parameters, extra="", name="rogue.toml"):
    path = tmp_path / name
    path.write_text(ROGUE.format(fmu=fmus["agv_test_rogue"], parameters=parameters) + extra)
    return path


def _statuses(folder):
    with open(Path(folder) / "summary.csv", newline="") as stream:
        return {row["run"]: row["status"] for row in csv.DictReader(stream)}


# ---------------------------------------------------------------- hangs and time limits

@pytest.mark.slow  # waits out its limit, 10 s
def test_a_hung_run_is_stopped_at_its_limit_and_the_sweep_goes_on(fmus, tmp_path):
    """Runs that hang in fmi2DoStep (blocked in a sleep, or busy in a loop) are stopped
    at their wall-clock limit and reported 'timed out' with the rows they recorded;
    the runs around them complete. Only the hanging runs have a limit here, so a loaded
    machine cannot make a sound run time out; the limit (it counts from the start of the
    run's process) is ten times what a loaded machine needs to reach the hang at t = 0.2 s
    (under 1 s at a load average of 16 on 2 cores), so the rows recorded are all 21."""
    limit = 10.0
    extra = '[sweep]\n"h.hang_time" = [10.0, 0.2]\n"h.busy" = [false, true]\n'
    _, jobs, _ = runner.prepare(_hang(fmus, tmp_path, extra=extra))
    jobs = [dataclasses.replace(job, timeout=limit) if job.point["h.hang_time"] == 0.2
            else job for job in jobs]
    root = tmp_path / "root"
    root.mkdir()
    begin = time.monotonic()
    results = pool.run_isolated(jobs, root, 2, lambda steps: None, lambda: None)
    assert time.monotonic() - begin < 600  # not the hour the FMU would hang
    by_label = {r["label"]: r for r in results}
    for job in jobs:
        result = by_label[job.label]
        if job.timeout is None:
            assert result["status"] == "complete", result
            continue
        assert result["status"] == "timed out"
        assert result["error"].startswith("the run exceeded its wall-clock limit of 10.0 s "
                                          "and was stopped in component 'h' during doStep "
                                          "at t=0.2 s after 21 recorded rows")
        info = json.loads((root / job.label / "run.json").read_text())
        assert info["status"] == "timed out" and info["rows"] == 21
        assert info["timeout_s"] == limit


def test_the_limit_comes_from_the_cli_or_the_manifest(fmus, tmp_path, capsys):
    """--timeout, or [simulation] timeout when it is not given; --timeout wins."""
    path = _hang(fmus, tmp_path, timeout="timeout = 1.0")
    assert cli.main(["run", str(path), "--out", str(tmp_path / "a"), "--quiet"]) == 1
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert line.startswith("agv-cosim: run base timed out: the run exceeded its "
                           "wall-clock limit of 1.0 s")
    assert _statuses(tmp_path / "a") == {"base": "timed out"}
    path = _hang(fmus, tmp_path, timeout="timeout = 3600.0", name="long.toml")
    assert cli.main(["run", str(path), "--out", str(tmp_path / "b"), "--quiet",
                     "--timeout", "1.5"]) == 1
    assert "wall-clock limit of 1.5 s" in capsys.readouterr().err


@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf", "soon"])
def test_a_bad_timeout_is_refused(chain, capsys, value):
    with pytest.raises(SystemExit) as stop:
        cli.main(["run", str(chain()), "--timeout", value])
    assert stop.value.code == 2
    assert "--timeout" in capsys.readouterr().err


def test_validate_stops_an_fmu_that_hangs_in_initialisation(fmus, tmp_path, capsys):
    path = _hang(fmus, tmp_path, hang_time=-1.0)
    assert cli.main(["validate", str(path), "--timeout", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    number = path.read_text().splitlines().index("[components.h]") + 1
    assert err == [f"agv-cosim: error: {path}:{number}: components.h: run base: the FMU did not "
                   "finish instantiating and initialising within 1.0 s and was stopped "
                   "(--timeout sets the limit)"]
    timed = _hang(fmus, tmp_path, hang_time=-1.0, timeout="timeout = 1.0",
                  name="timed.toml")
    assert cli.main(["validate", str(timed)]) == 2  # the manifest's limit
    assert "within 1.0 s" in capsys.readouterr().err
    assert initcheck.INIT_TIMEOUT == 60.0  # the default stated in validate --help


# ---------------------------------------------------------------- interruptions

def test_an_interruption_keeps_the_finished_runs_marked_partial(chain, tmp_path, capsys,
                                                                monkeypatch):
    """SIGINT after the first of two runs: the folder is committed with that run
    complete, the other 'not run', the marker and partial.txt saying so; exit 130."""
    real = pool.run_isolated

    def first_then_interrupted(jobs, root, *args, **kwargs):
        [first] = real(jobs[:1], root, *args, **kwargs)
        raise RunsStopped.of(KeyboardInterrupt(), [first, pool.not_run(jobs[1])])

    monkeypatch.setattr(pool, "run_isolated", first_then_interrupted)
    path = chain(extra='[sweep]\n"gain.k" = [1.0, 2.0]\n')
    out = tmp_path / "out"
    assert cli.main(["run", str(path), "--out", str(out), "--quiet"]) == 130
    assert capsys.readouterr().err.strip().splitlines() == [
        f"agv-cosim: interrupted by SIGINT; 1 of 2 run(s) complete kept in {out} (marked "
        "partial: partial.txt, summary.csv)"]
    assert _statuses(out) == {"base__gain.k=1.0": "complete", "base__gain.k=2.0": "not run"}
    marker = json.loads((out / MARKER).read_text())
    assert marker["complete"] is False and marker["runs_complete"] == 1
    assert (out / "partial.txt").read_text().startswith("partial result: interrupted by "
                                                        "SIGINT; 1 of 2 run(s) complete")
    assert json.loads((out / "base__gain.k=1.0" / "run.json").read_text())["status"] == \
        "complete"
    assert not (out / "base__gain.k=2.0").exists()


def test_run_json_records_what_a_resume_needs(chain, tmp_path):
    """run.json holds the run's inputs and their hash: equal for the same manifest and
    values, different when a parameter changes."""
    assert cli.main(["run", str(chain()), "--out", str(tmp_path / "a"), "--quiet"]) == 0
    assert cli.main(["run", str(chain()), "--out", str(tmp_path / "b"), "--quiet"]) == 0
    assert cli.main(["run", str(chain()), "--out", str(tmp_path / "c"), "--quiet",
                     "--set", "gain.k=4.0"]) == 0
    a, b, c = (json.loads((tmp_path / x / "base" / "run.json").read_text()) for x in "abc")
    assert a["inputs_sha256"] == b["inputs_sha256"] != c["inputs_sha256"]
    inputs = a["inputs"]
    assert inputs["parameters"]["gain"]["k"] == 3.0 and inputs["versions"]["agv_cosim"]
    assert set(inputs["fmu_sha256"]) == {"src", "gain", "gain2", "int"}
    assert inputs["simulation"]["step"] == 0.1 and inputs["manifest_sha256"]


# ---------------------------------------------------------------- output and messages

def test_an_fmus_stdout_goes_to_its_run_folder_bounded(fmus, tmp_path, capfd):
    """An FMU writing 400 kB a step to fds 1 and 2 (4 MB in all): our stdout has our
    summary line only, the run's output.txt keeps 1 MiB and says how much was not kept;
    a quiet FMU's run has no output.txt."""
    path = _rogue(fmus, tmp_path, "{ stdout_bytes = 200000 }",
                  extra="[variants.loud]\n[variants.quiet.components.r]\n"
                        "parameters = { stdout_bytes = 0 }\n")
    out = tmp_path / "out"
    assert cli.main(["run", str(path), "--out", str(out)]) == 0
    captured = capfd.readouterr()
    assert captured.out == f"{out}: 2/2 run(s) complete\n"
    assert "FMU output" not in captured.err
    text = (out / "loud" / channels.OUTPUT_FILE).read_bytes()
    kept, note = text[:channels.MAX_OUTPUT], text[channels.MAX_OUTPUT:].decode()
    assert kept.startswith(b"FMU output") and len(kept) == channels.MAX_OUTPUT
    dropped = 10 * 2 * 200000 - channels.MAX_OUTPUT  # the prints' lines come on top
    assert note.startswith("\n[agv-cosim: ") and int(note.split()[1]) > dropped
    assert not (out / "quiet" / channels.OUTPUT_FILE).exists()


def test_an_fmus_escape_sequences_never_reach_the_terminal(fmus, tmp_path, capfd):
    """The FMU fails with a message that clears the screen and sets the window title:
    the line we print shows the escapes as text; run.json keeps the message as it was."""
    message = "\x1b[2J\x1b]0;pwned\x07 gone\nwrong"
    path = _rogue(fmus, tmp_path, json.dumps({"message": message, "fail_time": 0.05})
                  .replace('": ', '" = ').replace("{", "{ ").replace("}", " }"))
    assert cli.main(["run", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 1
    err = capfd.readouterr().err
    assert "\x1b" not in err and "\x07" not in err
    [line] = [line for line in err.splitlines() if "run base" in line]
    assert "\\x1b[2J\\x1b]0;pwned\\x07 gone" in line
    info = json.loads((tmp_path / "out" / "base" / "run.json").read_text())
    assert "\x1b[2J" in info["error"]


def test_garbage_written_into_our_pipes_fails_that_run_only(fmus, tmp_path, capfd):
    """An FMU writes garbage into every pipe it inherited: its run is stopped and
    reported with the reason, the next runs (fresh workers, the same fork server)
    complete, and no helper of ours prints a traceback."""
    path = _rogue(fmus, tmp_path, "{ garbage_time = -1.0 }",
                  extra="[variants.garbage.components.r]\n"
                        "parameters = { garbage_time = 0.05 }\n[variants.after]\n"
                        "[variants.again.components.r]\nparameters = { stdout_bytes = 1 }\n")
    out = tmp_path / "out"
    assert cli.main(["run", str(path), "--out", str(out), "--quiet", "--jobs", "1"]) == 1
    err = capfd.readouterr().err
    assert "Traceback" not in err
    lines = [line for line in err.strip().splitlines()]
    assert len(lines) == 1 and lines[0].startswith("agv-cosim: run garbage ")
    assert "wrote data that is no message of agv-cosim into its result channel" in lines[0]
    assert _statuses(out)["after"] == _statuses(out)["again"] == "complete"
    assert _statuses(out)["garbage"] in ("partial", "failed")


def test_a_forked_helper_ends_with_its_run(fmus, tmp_path):
    """The FMU forks a helper that would sleep 5 minutes holding our pipes: the command
    ends when the run does, the helper is ended, no scratch folder is left."""
    path = _rogue(fmus, tmp_path, "{ fork_seconds = 300.0 }")
    before = time.monotonic()
    assert cli.main(["run", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    assert time.monotonic() - before < 120
    with open(tmp_path / "out" / "base" / "timeseries.csv", newline="") as stream:
        helper = int(next(iter(csv.DictReader(stream)))["r.helper"])
    assert helper > 0 and ended(helper)
    import tempfile

    mine = list(Path(tempfile.gettempdir()).glob(f"agv-cosim-{os.getpid()}-run-*"))
    assert mine == []


# ---------------------------------------------------------------- modelIdentifier

def _rewrite(src, dest, edit_xml=None, drop=None):
    with zipfile.ZipFile(src) as old, zipfile.ZipFile(dest, "w",
                                                      zipfile.ZIP_DEFLATED) as new:
        for info in old.infolist():
            if drop and info.filename.startswith(drop):
                continue
            data = old.read(info)
            if info.filename == "modelDescription.xml" and edit_xml:
                data = edit_xml(data.decode()).encode()
            new.writestr(info, data)
    return dest


@pytest.mark.parametrize("identifier", ["../../outside/lib", "/tmp/outside/lib", "a.b"])
def test_a_model_identifier_that_is_a_path_is_refused(chain, fmus, tmp_path, capsys,
                                                      identifier):
    fmu = _rewrite(fmus["agv_test_gain"], tmp_path / "Path.fmu",
                   lambda xml: xml.replace('modelIdentifier="AgvTestGain"',
                                           f'modelIdentifier="{identifier}"'))
    path = chain()
    path.write_text(path.read_text().replace(str(fmus["agv_test_gain"]), str(fmu)))
    assert cli.main(["validate", str(path), "--no-init"]) == 2
    [line] = capsys.readouterr().err.strip().splitlines()
    number = next(i for i, text in enumerate(path.read_text().splitlines(), 1)
                  if str(fmu) in text)
    assert line.startswith(f"agv-cosim: error: {path}:{number}: components.gain.fmu: broken FMU "
                           f"(modelIdentifier {identifier!r} is not a name")


def test_an_fmu_without_its_binary_is_named(chain, fmus, tmp_path, capsys):
    """No binaries/linux64/<id>.so in the FMU: validate names what is missing, a run
    fails with the same reason (never a library from elsewhere)."""
    fmu = _rewrite(fmus["agv_test_gain"], tmp_path / "NoBinary.fmu", drop="binaries/")
    path = chain()
    path.write_text(path.read_text().replace(str(fmus["agv_test_gain"]), str(fmu)))
    assert cli.main(["validate", str(path)]) == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert "the FMU has no binary for this platform (binaries/linux64/AgvTestGain.so)" \
        in line and "components.gain" in line
    assert cli.main(["run", str(path), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    assert not (tmp_path / "o").exists()  # refused by the check before any run
    capsys.readouterr()
    assert cli.main(["run", str(path), "--out", str(tmp_path / "o"), "--quiet",
                     "--no-init"]) == 1
    info = json.loads((tmp_path / "o" / "base" / "run.json").read_text())
    assert info["status"] == "failed"
    assert "no binary for this platform" in info["error"]


def test_the_helper_channels_dropped_in_a_worker_still_exist():
    """lifetime.drop_helper_channels closes multiprocessing's private descriptors of
    the fork server and the resource tracker in each worker; this pins their names (a
    Python that renames them makes the garbage test above fail, and this one say why)."""
    from multiprocessing import forkserver, resource_tracker

    assert hasattr(forkserver._forkserver, "_forkserver_alive_fd")
    assert hasattr(resource_tracker._resource_tracker, "_fd")
