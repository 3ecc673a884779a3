"""Class 3 of issue 10: every FMU's own error reason reaches the user.

fmpy's native logger proxy keeps one logger per process; before, each instance's
messages went to the instance created last. Now each message reaches its own instance,
a failed run names component, FMI call, time and the FMU's message, and `validate`
initialises each FMU once to catch values an FMU refuses.
"""

import json

from agv_cosim import cli

TWO = """
name = "two"
[simulation]
stop = 1.0
step = 0.1
[components.first]
fmu = "{fail}"
parameters = {{ fail_time = {first} }}
[components.last]
fmu = "{fail}"
parameters = {{ fail_time = {last} }}
"""


def _manifest(fmus, tmp_path, first, last):
    path = tmp_path / "two.toml"
    path.write_text(TWO.format(fail=fmus["agv_test_fail"], first=first, last=last))
    return path


def test_first_instance_reason_is_shown(fmus, tmp_path, capsys):
    """The first of two instances refuses its parameter (fail_time < 0): its own
    message is in the run's error, with component, FMI call and time (before the fix,
    the message went to the logger of the last instance created, and was lost)."""
    path = _manifest(fmus, tmp_path, -1.0, 5.0)
    assert cli.main(["run", str(path), "--quiet", "--out", str(tmp_path / "o"),
                     "--no-init"]) == 1
    info = json.loads((tmp_path / "o" / "base" / "run.json").read_text())
    error = info["error"]
    assert error.startswith("component 'first': fmi2ExitInitializationMode returned status")
    assert "at t=0.0 s" in error
    assert "AgvTestFail 'first': parameter 'fail_time': must be >= 0" in error
    assert "run base failed: component 'first'" in capsys.readouterr().err


def test_run_checks_initialisation_before_writing_any_run(fmus, tmp_path, capsys):
    """run makes validate's check first: a value the FMU refuses is the same one line,
    exit 2, and no result folder is written."""
    path = _manifest(fmus, tmp_path, 5.0, 5.0)
    bad = ["--set", "first.fail_time=-2.0"]
    assert cli.main(["validate", str(path), *bad]) == 2
    said = [line for line in capsys.readouterr().err.splitlines() if "warning" not in line]
    assert cli.main(["run", str(path), "--quiet", "--out", str(tmp_path / "o"), *bad]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if "warning" not in line]
    assert err == said and "parameter 'fail_time': must be >= 0" in err[0]
    assert not (tmp_path / "o").exists()


def test_validate_catches_a_refused_value(fmus, tmp_path, capsys):
    path = _manifest(fmus, tmp_path, 5.0, 5.0)
    assert cli.main(["validate", str(path)]) == 0
    capsys.readouterr()
    assert cli.main(["validate", str(path), "--set", "first.fail_time=-2.0"]) == 2
    err = [line for line in capsys.readouterr().err.strip().splitlines()
           if "warning" not in line]
    assert len(err) == 1
    number = path.read_text().splitlines().index("[components.first]") + 1
    assert err[0].startswith(f"agv-cosim: error: {path}:{number}: components.first: the FMU "
                             "refuses to initialise (run base): fmi2ExitInitializationMode")
    assert "parameter 'fail_time': must be >= 0" in err[0]
    assert cli.main(["validate", str(path), "--set", "first.fail_time=-2.0",
                     "--no-init"]) == 0


def _files(folder):
    return {p.relative_to(folder): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


def test_run_checks_a_sweep_in_its_first_worker(fmus, tmp_path, capsys):
    """run's check is done by the first worker, before its first run, while the other
    worker runs: a value refused in the sweep's second run is validate's one line, exit 2,
    and the earlier result folder at the target is left as it was (nothing beside it)."""
    path = _manifest(fmus, tmp_path, 5.0, 5.0)
    out = tmp_path / "o"
    assert cli.main(["run", str(path), "--quiet", "--out", str(out)]) == 0
    before = _files(out)
    sweep = tmp_path / "sweep.toml"
    sweep.write_text(path.read_text() + '[sweep]\n"first.fail_time" = [5.0, -2.0, 4.0]\n')
    capsys.readouterr()
    assert cli.main(["validate", str(sweep)]) == 2
    said = [line for line in capsys.readouterr().err.splitlines() if "warning" not in line]
    assert len(said) == 1 and "(run base__first.fail_time=-2.0)" in said[0]
    assert cli.main(["run", str(sweep), "--quiet", "--out", str(out), "--jobs", "2",
                     "--overwrite"]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if "warning" not in line]
    assert err == said
    assert _files(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o", "sweep.toml", "two.toml"]


def test_run_stops_at_an_fmu_that_kills_its_process_in_initialisation(fmus, tmp_path,
                                                                      capsys):
    """An FMU that aborts its process while it is initialised: run says what validate
    says (the process's signal, the component, the run), exit 2, no result folder."""
    path = tmp_path / "crash.toml"
    path.write_text(f'name = "crash"\n[simulation]\nstop = 0.1\nstep = 0.1\n'
                    f'[components.boom]\nfmu = "{fmus["agv_test_crash"]}"\n'
                    'parameters = { crash_time = -1.0 }\n')
    assert cli.main(["validate", str(path)]) == 2
    said = capsys.readouterr().err.strip().splitlines()
    assert cli.main(["run", str(path), "--quiet", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == said == [f"agv-cosim: error: {path}:5: components.boom: run base: the "
                           "FMU's process died (signal 6) while it was instantiated and "
                           "initialised"]
    assert not (tmp_path / "o").exists()


def test_execute_stops_a_check_past_its_limit(fmus, tmp_path):
    """execute's initialisation check gives each FMU init_limit seconds: an FMU that
    hangs in its initialisation is stopped with the check's error, no folder written."""
    import pytest

    from agv_cosim.errors import ManifestError
    from agv_cosim.pipeline import execute, prepare

    path = tmp_path / "hang.toml"
    path.write_text(f'name = "hang"\n[simulation]\nstop = 0.1\nstep = 0.1\n'
                    f'[components.h]\nfmu = "{fmus["agv_test_hang"]}"\n'
                    'parameters = { hang_time = -1.0 }\n')
    manifest, jobs, _ = prepare(path)
    with pytest.raises(ManifestError) as stop:
        execute(manifest, jobs, tmp_path / "o", quiet=True, init_limit=1.0)
    assert str(stop.value).endswith("components.h: run base: the FMU did not finish "
                                    "instantiating and initialising within 1.0 s and was "
                                    "stopped (--timeout sets the limit)")
    assert not (tmp_path / "o").exists()
