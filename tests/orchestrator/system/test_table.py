"""Input from a CSV time table (agv_cosim.table): interpolation, wiring, errors."""

import csv

import pytest

from agv_cosim import cli
from agv_cosim.errors import TableError
from agv_cosim.system.table import Table

TABLE = "time,a,b\n0.0,0.0,1.0\n0.2,1.0,2.0\n0.5,4.0,3.0\n"


def test_linear_and_hold_columns_analytic(tmp_path):
    path = tmp_path / "in.csv"
    path.write_text(TABLE)
    table = Table(path, {"b": "hold"})
    out = [0.0, 0.0]
    expected = {-1.0: (0.0, 1.0), 0.0: (0.0, 1.0), 0.1: (0.5, 1.0), 0.2: (1.0, 2.0),
                0.35: (2.5, 2.0), 0.5: (4.0, 3.0), 9.0: (4.0, 3.0)}
    for t, (a, b) in expected.items():
        table.values_at(t, out)
        assert out == [pytest.approx(a, abs=1e-15), b], t


@pytest.mark.parametrize("text,interp,problem", [
    ("t,a\n0,1\n", {}, "the header must be 'time,<column>,...'"),
    ("time,a\n0,1\n0,2\n", {}, "line 3: time 0.0 is not after 0.0"),
    ("time,a\n0,x\n", {}, "line 2: not a number"),
    ("time,a\n0,1\n", {"a": "cubic"}, "interpolation.a: 'cubic' is not one of linear, hold"),
    ("time,a\n0,1\n", {"c": "hold"}, "interpolation: no column 'c'"),
])
def test_bad_tables(tmp_path, text, interp, problem):
    path = tmp_path / "in.csv"
    path.write_text(text)
    with pytest.raises(TableError, match=None) as caught:
        Table(path, interp)
    assert problem in str(caught.value)


def test_table_drives_an_fmu_input(fmus, tmp_path, capsys):
    (tmp_path / "in.csv").write_text(TABLE)
    manifest = tmp_path / "t.toml"
    manifest.write_text(f"""
[simulation]
stop = 0.6
step = 0.1
[components.replay]
table = "in.csv"
interpolation = {{ b = "hold" }}
units = {{ a = "1" }}
[components.src]
fmu = "{fmus['agv_test_types']}"
[[connections]]
from = "replay.a"
to = "src.ri"
[record]
variables = ["replay.a", "replay.b", "src.ro"]
""")
    out = tmp_path / "out"
    assert cli.main(["run", str(manifest), "--out", str(out), "--jobs", "1", "--quiet"]) == 0
    with open(out / "base" / "timeseries.csv", newline="") as stream:
        rows = [[float(v) for v in row] for row in list(csv.reader(stream))[1:]]
    a = [row[1] for row in rows]
    assert a == pytest.approx([0.0, 0.5, 1.0, 2.0, 3.0, 4.0, 4.0], abs=1e-12)
    assert [row[2] for row in rows] == [1.0, 1.0, 2.0, 2.0, 2.0, 3.0, 3.0]
    assert [row[3] for row in rows] == a  # the echo of the input, same instant
    # a bad table is a one-line manifest error
    capsys.readouterr()
    (tmp_path / "in.csv").write_text("time,a,b\n0,1,1\n0,2,2\n")
    assert cli.main(["run", str(manifest), "--out", str(tmp_path / "o2"), "--jobs", "1",
                     "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "components.replay.table:" in err[0] and "line 3" in err[0]
