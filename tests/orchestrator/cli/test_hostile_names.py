"""Hostile round three, names: FMI variable names of any legal form (dots, brackets,
quotes, commas, line breaks) work wherever a name is used, and timeseries.csv is written
and read with the csv module, so its columns read back exactly."""

import csv
import json

import numpy as np
import pytest

from agv_cosim import cli, files, fmitypes
from agv_cosim import timeseries as results

NAMES = """
name = "names"
[simulation]
stop = 0.5
step = 0.1
[components.src]
fmu = "{src}"
parameters = {{ offset = 1.0, slope = 2.0 }}
[components.n]
fmu = "{names}"
parameters = {{ "gain.k" = 2.0 }}
[[connections]]
from = "src.y"
to = "n.in.u[1]"
[metrics]
lateral_error = "n.body.frame_a.r_0[1]"
[plots]
signals = ["n.body.frame_a.r_0[1]", "n.a,b", 'n.say "hi"']
"""

ODD = ["n.body.frame_a.r_0[1]", "n.a,b", 'n.say "hi"', "n.x'[2,3]", "n.echo.y"]


@pytest.fixture
def names(fmus, tmp_path):
    path = tmp_path / "names.toml"
    path.write_text(NAMES.format(src=fmus["agv_test_source"], names=fmus["agv_test_names"]))
    return path


def test_odd_names_run_and_read_back_exactly(names, tmp_path):
    """A Modelica-style output (body.frame_a.r_0[1]) feeds metrics and plots, an input
    named in.u[1] is connected, a parameter named gain.k is set; the CSV header holds
    every name exactly (quoted where needed) and each column reads back."""
    out = tmp_path / "out"
    assert cli.main(["run", str(names), "--out", str(out), "--quiet"]) == 0
    csv_file = out / "base" / "timeseries.csv"
    with open(csv_file, newline="") as stream:
        header = next(csv.reader(stream))
    assert header[0] == "time" and header[-len(ODD):] == ODD
    assert results.timeseries_columns(csv_file) == header[1:]
    t, columns = results.read_timeseries(csv_file, ODD)
    k = np.arange(len(t))
    for name, factor in zip(ODD[:4], (1.0, 2.0, 3.0, 4.0)):
        assert columns[name].tolist() == (2.0 * factor * k).tolist()  # gain.k = 2
    source = results.read_timeseries(csv_file, ["src.y"])[1]["src.y"]
    assert columns["n.echo.y"].tolist() == source.tolist()  # in.u[1] connected
    assert results.count_rows(csv_file) == len(t) == 6
    metrics = json.loads((out / "base" / "metrics.json").read_text())
    assert metrics["lateral_error_max"] == pytest.approx(2.0 * 5)
    assert (out / "signals.png").is_file()


def test_odd_names_in_set_sweep_and_record(names, tmp_path):
    text = names.read_text() + '[sweep]\n"n.gain.k" = [1.0, 3.0]\n' \
        '[record]\nvariables = ["n.a,b", "n.body.frame_a.r_0[1]"]\n'
    text = text.replace('parameters = { "gain.k" = 2.0 }', "")
    text = text.replace("[plots]", "[plots]\n# only recorded signals").replace(
        'signals = ["n.body.frame_a.r_0[1]", "n.a,b", \'n.say "hi"\']',
        'signals = ["n.body.frame_a.r_0[1]", "n.a,b"]')
    names.write_text(text)
    out = tmp_path / "out"
    assert cli.main(["run", str(names), "--out", str(out), "--quiet"]) == 0
    with open(out / "summary.csv", newline="") as stream:
        rows = list(csv.DictReader(stream))
    assert [row["n.gain.k"] for row in rows] == ["1.0", "3.0"]
    csv_file = out / "base__n.gain.k=3.0" / "timeseries.csv"
    assert results.timeseries_columns(csv_file) == ["n.a,b", "n.body.frame_a.r_0[1]"]
    assert results.read_timeseries(csv_file)[1]["n.a,b"][-1] == 3.0 * 2.0 * 5
    assert cli.main(["validate", str(names), "--no-init", "--set", "src.slope=4.0"]) == 0


def test_csv_names_with_line_breaks_commas_and_quotes_round_trip(tmp_path):
    """Column names with a line break, a comma, quotes; a String column whose values
    hold line breaks and commas: the header reads back exactly, every row counts once,
    the numeric columns read back bit for bit, in any chunk size."""
    names = ["a.two\nlines", "b.x,y", 'c.say "hi"', "d.s"]
    string = fmitypes.lookup("2.0", "String")
    real = fmitypes.lookup("2.0", "Real")
    formats = [fmitypes.record_format(real)] * 3 + [fmitypes.record_format(string)]
    path = tmp_path / "timeseries.csv"
    sink = results.CsvSink(path, names, formats)
    rows = [(0.1 * i, i / 3.0, -i * 1e-300, 2.0 ** i, f'line {i}\nnext, "q"')
            for i in range(7)]
    for row in rows:
        sink.write(row)
    sink.close()
    assert sink.bytes == path.stat().st_size
    assert results.timeseries_columns(path) == names
    assert results.count_rows(path) == 7
    for chunk in (1, 2, 7, 100):
        t, columns = results.read_timeseries(path, names[:3]) if chunk == 100 else (
            np.concatenate([c[0] for c in results.iter_timeseries(path, names[:3], chunk)]),
            {n: np.concatenate([c[1][n] for c in results.iter_timeseries(path, names[:3],
                                                                          chunk)])
             for n in names[:3]})
        assert t.tolist() == [r[0] for r in rows]
        for j, name in enumerate(names[:3], start=1):
            assert columns[name].tolist() == [r[j] for r in rows]
    with open(path, newline="") as stream:
        back = list(csv.reader(stream))
    assert back[0] == ["time"] + names and [r[4] for r in back[1:]] == [r[4] for r in rows]


def test_plain_names_keep_the_header_bytes_of_before(tmp_path):
    """Names that need no quoting are written as before (a plain comma-joined line)."""
    sink = results.CsvSink(tmp_path / "t.csv", ["a.y", "b.z[1]"])
    sink.write((0.0, 1.0, 2.0))
    sink.close()
    assert (tmp_path / "t.csv").read_text() == "time,a.y,b.z[1]\n0.0,1.0,2.0\n"


def test_terminal_text_is_escaped():
    assert files.printable("plain é ok") == "plain é ok"
    assert files.printable("a\x1b[2Jb\nc\x07\u202ed\x9b") == \
        "a\\x1b[2Jb\\nc\\x07\\u202ed\\x9b"
