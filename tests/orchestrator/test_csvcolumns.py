"""agv_cosim.csvcolumns: the one checked reader of measured-data CSV tables, which fit
(fitting/data.py) and identify (identification/data.py) both read through: the columns
asked, each problem one line raised as the caller's error class; both commands report a
bad table with the same line."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from agv_cosim.csvcolumns import read_columns
from agv_cosim.errors import AgvCosimError, FitDataError, IdentifyError
from agv_cosim.fitting import read_data
from agv_cosim.identification.data import read_columns as identify_columns

PACKAGE = Path(__file__).resolve().parents[2] / "orchestrator" / "agv_cosim"
GOOD = "time,yaw_rate,a_y\n0.0,0.1,1.0\n\n , ,\n0.1, 0.2 ,1.1\n0.2,0.3,1.3\n"


def test_the_columns_asked_each_once_in_order_with_their_lines() -> None:
    read = read_columns(GOOD, "m.csv", ["a_y", "time", "a_y"], FitDataError)
    assert list(read.values) == ["a_y", "time"]
    assert read.values["time"].tolist() == [0.0, 0.1, 0.2]
    assert read.values["a_y"].tolist() == [1.0, 1.1, 1.3]
    assert all(v.dtype == np.float64 for v in read.values.values())
    assert read.lines == (2, 5, 6)  # lines 3 (empty) and 4 (blank fields) skipped


def test_a_header_only_table_has_no_sample() -> None:
    read = read_columns("time,y\n", "m.csv", ["time", "y"], FitDataError)
    assert read.lines == () and read.values["y"].tolist() == []


BAD = [
    ("", "m.csv: empty, not a CSV file with a header row"),
    ("t" * 200_000 + ",y\n0,1\n", "m.csv: not a CSV file (field larger than field limit "
                                   "(131072))"),
    (GOOD.replace("time", "t"), "m.csv: no column 'time' (columns: t, yaw_rate, a_y)"),
    (GOOD + "0.3,0.4," + "5" * 200_000 + "\n", "m.csv: line 7: not a CSV file (field "
                                              "larger than field limit (131072))"),
    (GOOD.replace("yaw_rate", "yawrate"),
     "m.csv: no column 'yaw_rate' (did you mean 'yawrate'?) (columns: time, yawrate, a_y)"),
    (GOOD + "0.3,0.4\n", "m.csv: line 7: 2 field(s), the header has 3: not a CSV table"),
    (GOOD.replace(" 0.2 ", "abc"), "m.csv: line 5, column 'yaw_rate': 'abc' is not a "
                                   "number"),
    (GOOD.replace(" 0.2 ", ""), "m.csv: line 5, column 'yaw_rate': '' is not a number"),
    (GOOD.replace("1.3", "-inf"), "m.csv: line 6, column 'a_y': '-inf' is not a finite "
                                  "number"),
    (GOOD.replace("1.3", "nan"), "m.csv: line 6, column 'a_y': 'nan' is not a finite "
                                 "number"),
]
IDS = ["empty", "not-csv", "no-column", "not-csv-row", "did-you-mean", "ragged", "text",
       "blank", "inf", "nan"]


@pytest.mark.parametrize("error", [FitDataError, IdentifyError])
@pytest.mark.parametrize("text, message", BAD, ids=IDS)
def test_each_problem_is_one_line_of_the_callers_class(
        text: str, message: str, error: type[AgvCosimError]) -> None:
    with pytest.raises(AgvCosimError) as raised:
        read_columns(text, "m.csv", ["time", "yaw_rate", "a_y"], error)
    assert type(raised.value) is error
    assert str(raised.value) == message and raised.value.exit_code == 2


def test_a_header_of_too_few_fields() -> None:
    text = "time;u;alpha\n0;1;2\n"
    with pytest.raises(IdentifyError) as raised:
        read_columns(text, "m.csv", ["time", "u"], IdentifyError, min_fields=2)
    assert str(raised.value) == ("m.csv: not a CSV file with a header row of column names "
                                 "(line 1 holds 1 field)")
    with pytest.raises(IdentifyError) as raised:  # without min_fields: the column missing
        read_columns(text, "m.csv", ["time", "u"], IdentifyError)
    assert str(raised.value).startswith("m.csv: no column 'time'")


@pytest.mark.parametrize("text, message", BAD[1:], ids=IDS[1:])
def test_fit_and_identify_report_a_bad_table_alike(tmp_path: Path, text: str,
                                                    message: str) -> None:
    path = tmp_path / "m.csv"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(FitDataError) as fit:
        read_data(path, ["yaw_rate", "a_y"])
    with pytest.raises(IdentifyError) as identify:
        identify_columns(path, ["time", "yaw_rate", "a_y"])
    assert str(fit.value) == str(identify.value) == message.replace("m.csv", str(path))


@pytest.mark.parametrize("reader", ["fitting/data.py", "identification/data.py"])
def test_the_commands_have_no_csv_loop_of_their_own(reader: str) -> None:
    tree = ast.parse((PACKAGE / reader).read_text(encoding="utf-8"))
    imported = {a.name for node in ast.walk(tree) if isinstance(node, ast.Import)
                for a in node.names}
    assert "csv" not in imported
