"""Scenario events: time-triggered sets of tunable parameters or unconnected inputs."""

import csv
import json

import pytest

from agv_cosim import cli

BASE = """
[simulation]
stop = 0.6
step = 0.1
algorithm = "{algorithm}"
[components.src]
fmu = "{types}"
[record]
variables = ["src.io", "src.so", "src.ro"]
"""


def _run(tmp_path, text, args=(), expect=0, name="events"):
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    out = tmp_path / f"out_{name}"
    assert cli.main(["run", str(path), "--out", str(out), "--jobs", "1", "--quiet",
                     *args]) == expect
    return out


def _columns(run_dir):
    with open(run_dir / "timeseries.csv", newline="") as stream:
        rows = list(csv.reader(stream))
    return {name: [row[i] for row in rows[1:]] for i, name in enumerate(rows[0])}


@pytest.mark.parametrize("algorithm", ["gauss-seidel", "jacobi"])
def test_event_applies_exactly_at_its_communication_point(fmus, tmp_path, algorithm):
    text = BASE.format(types=fmus["agv_test_types"], algorithm=algorithm) + """
[events.change]
at = 0.3
set = { "src.ii" = 42, "src.si" = "a, \\"b\\"" }
[events.later]
at = 0.5
set = { "src.ri" = 2.5 }
"""
    out = _run(tmp_path, text)
    col = _columns(out / "base")
    assert [float(t) for t in col["time"]] == pytest.approx([0.1 * k for k in range(7)],
                                                            abs=1e-12)
    # the row of t = 0.3 s already shows the value (an echo is direct feedthrough)
    assert col["src.io"] == ["0", "0", "0", "42", "42", "42", "42"]
    assert col["src.so"] == ["", "", "", 'a, "b"', 'a, "b"', 'a, "b"', 'a, "b"']
    assert col["src.ro"] == ["0.0"] * 5 + ["2.5", "2.5"]
    info = json.loads((out / "base" / "run.json").read_text())
    assert info["events"] == [{"name": "change", "at": 0.3,
                               "set": {"src.ii": 42, "src.si": 'a, "b"'}},
                              {"name": "later", "at": 0.5, "set": {"src.ri": 2.5}}]


def test_event_time_swept_and_changed_by_variant_and_set(fmus, tmp_path):
    text = BASE.format(types=fmus["agv_test_types"], algorithm="gauss-seidel") + """
[events.change]
at = 0.3
set = { "src.ii" = 7 }
[sweep]
"events.change.at" = [0.1, 0.4]
"""
    out = _run(tmp_path, text)
    runs = sorted(p.name for p in out.iterdir() if p.is_dir())
    assert len(runs) == 2
    firsts = []
    for run in runs:
        col = _columns(out / run)
        firsts.append(col["src.io"].index("7"))
    assert sorted(firsts) == [1, 4]
    # a variant moves the event and changes its value; --set moves it again
    text2 = BASE.format(types=fmus["agv_test_types"], algorithm="gauss-seidel") + """
[events.change]
at = 0.3
set = { "src.ii" = 7 }
[variants.late.events.change]
at = 0.5
set = { "src.ii" = 9 }
"""
    out = _run(tmp_path, text2, name="variant")
    assert _columns(out / "late")["src.io"] == ["0"] * 5 + ["9", "9"]
    out = _run(tmp_path, text2, ["--set", "events.change.at=0.2"], name="set")
    assert _columns(out / "late")["src.io"] == ["0"] * 2 + ["9"] * 5


@pytest.mark.parametrize("event,problem", [
    ('at = 0.25\nset = { "src.ii" = 1 }', "events.e.at: 0.25 s is not a communication point"),
    ('at = 0.9\nset = { "src.ii" = 1 }', "events.e.at: 0.9 s is outside the run"),
    ('at = 0.2\nset = { "src.ii" = 1.5 }', "events.e.set.src.ii: 'src.ii' is Integer, got 1.5"),
    ('at = 0.2\nset = { "src.io" = 1 }', "'src.io' is an output (an event sets a tunable"),
    ('at = 0.2\nset = { "gain.k" = 1.0 }', "'gain.k' is a fixed parameter (an event can "
                                           "change only a tunable one)"),
    ('at = 0.2\nset = { "gain.u" = 1.0 }', "input 'gain.u' is driven by connections[0]"),
    ('at = 0.2', "events.e.set: must be a non-empty table"),
])
def test_bad_events_are_one_line_errors(fmus, tmp_path, capsys, event, problem):
    text = BASE.format(types=fmus["agv_test_types"], algorithm="gauss-seidel") + f"""
[components.gain]
fmu = "{fmus['agv_test_gain']}"
[[connections]]
from = "src.r"
to = "gain.u"
[events.e]
{event}
"""
    _run(tmp_path, text, expect=2)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and problem in err[0], err


def test_event_values_swept_and_set(fmus, tmp_path):
    """``events.<name>.set.<component>.<variable>`` changes (or adds) a value an event
    sets, from --set or [sweep]; the checks are those of a value written in the event."""
    text = BASE.format(types=fmus["agv_test_types"], algorithm="gauss-seidel") + """
[events.change]
at = 0.3
set = { "src.ii" = 7 }
"""
    out = _run(tmp_path, text, ["--set", "events.change.set.src.ii=11",
                                "--set", 'events.change.set.src.si="new"'], name="set")
    col = _columns(out / "base")
    assert col["src.io"] == ["0"] * 3 + ["11"] * 4
    assert col["src.so"] == [""] * 3 + ["new"] * 4
    info = json.loads((out / "base" / "run.json").read_text())
    assert info["events"] == [{"name": "change", "at": 0.3,
                               "set": {"src.ii": 11, "src.si": "new"}}]
    swept = text + '[sweep]\n"events.change.set.src.ii" = [-3, 5]\n'
    out = _run(tmp_path, swept, name="sweep")
    found = sorted(_columns(out / run.name)["src.io"][-1] for run in out.iterdir()
                   if run.is_dir())
    assert found == ["-3", "5"]


@pytest.mark.parametrize("setting,problem", [
    ("events.change.set.src.ii=1.5", "events.change.set.src.ii: 'src.ii' is Integer, got 1.5"),
    ("events.change.set.src.io=1", "'src.io' is an output (an event sets a tunable"),
    ("events.change.set.src=1", "'events.change.set.src': an event's time or one of its "
                                "values can be swept or set"),
    ("events.nope.set.src.ii=1", "unknown event 'nope' in 'events.nope.set.src.ii'"),
])
def test_bad_event_value_sets_are_one_line_errors(fmus, tmp_path, capsys, setting, problem):
    text = BASE.format(types=fmus["agv_test_types"], algorithm="gauss-seidel") + """
[events.change]
at = 0.3
set = { "src.ii" = 7 }
"""
    _run(tmp_path, text, ["--set", setting], expect=2)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and problem in err[0], err
