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
