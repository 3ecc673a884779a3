"""fit's bad input (issue 34 item 6): measured data that are not CSV, non-numeric, NaN
or infinite, time not increasing, a missing column, data outside the simulated
interval; a fit set up with min >= max, a start outside its bounds, a bad weight, a
signal the simulation does not have or that is not finite. Each is one line (an
AgvCosimError subclass, exit code 2) naming the culprit and the reason."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from agv_cosim.errors import AgvCosimError, FitDataError, FitError
from agv_cosim.fitting import Parameter, check_interval, fit, measured_data, read_data

from fitting_models import SECOND_PARAMETERS, SECOND_TRUE, TIME, data_of, second_order


def one_line(error: pytest.ExceptionInfo[AgvCosimError], *parts: str) -> None:
    text = str(error.value)
    assert "\n" not in text and error.value.exit_code == 2
    for part in parts:
        assert part in text, (part, text)


def write(tmp_path: Path, text: str, name: str = "measured.csv") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


GOOD = "time,yaw_rate,a_y\n0.0,0.1,1.0\n0.1,0.2,1.1\n0.2,0.3,1.3\n"


def test_read_data_reads_the_columns(tmp_path: Path) -> None:
    data = read_data(write(tmp_path, "\ufeff" + GOOD), ["a_y", "yaw_rate"])
    assert data.time.tolist() == [0.0, 0.1, 0.2]
    assert data.columns["yaw_rate"].tolist() == [0.1, 0.2, 0.3]
    assert list(data.columns) == ["a_y", "yaw_rate"] and data.lines == (2, 3, 4)


@pytest.mark.parametrize("text, parts", [
    (GOOD.replace("0.2,1.1", "abc,1.1"), ["line 3, column 'yaw_rate'", "'abc' is not a number"]),
    (GOOD.replace("0.2,1.1", ",1.1"), ["line 3, column 'yaw_rate'", "'' is not a number"]),
    (GOOD.replace("0.2,1.1", "nan,1.1"), ["line 3, column 'yaw_rate'", "'nan' is not a finite"]),
    (GOOD.replace("1.3", "inf"), ["line 4, column 'a_y'", "'inf' is not a finite number"]),
    (GOOD.replace("0.2,0.3", "0.1,0.3"), ["line 4, column 'time'", "time not increasing",
                                         "(0.1 after 0.1)"]),
    (GOOD.replace("0.2,0.3", "0.05,0.3"), ["line 4", "time not increasing",
                                          "(0.05 after 0.1)"]),
    (GOOD.replace("time", "t"), ["no column 'time'", "(columns: t, yaw_rate, a_y)"]),
    (GOOD.replace("yaw_rate", "yawrate"), ["no column 'yaw_rate'", "did you mean"]),
    ("time,yaw_rate,a_y\n0.0,0.1,1.0\n", ["1 sample(s); at least 2 needed"]),
    ("", ["empty, not a CSV file"]),
    (GOOD + "0.3,0.4\n", ["line 5: 2 field(s), the header has 3"]),
    ("time,yaw_rate,a_y\n\0\0", ["binary data"]),
])
def test_bad_data_is_one_line(tmp_path: Path, text: str, parts: list[str]) -> None:
    path = write(tmp_path, text)
    with pytest.raises(FitDataError) as error:
        read_data(path, ["yaw_rate", "a_y"])
    one_line(error, str(path), *parts)


def test_unreadable_data_files(tmp_path: Path) -> None:
    with pytest.raises(FitDataError) as error:
        read_data(tmp_path / "missing.csv", ["y"])
    one_line(error, "missing.csv: not found")
    with pytest.raises(FitDataError) as error:
        read_data(tmp_path, ["y"])
    one_line(error, str(tmp_path), "a folder, not a regular file")
    latin = tmp_path / "latin.csv"
    latin.write_bytes(b"time,y\n0,\xe9\n")
    with pytest.raises(FitDataError) as error:
        read_data(latin, ["y"])
    one_line(error, "latin.csv", "not UTF-8")


def test_arrays_are_checked_as_files_are() -> None:
    with pytest.raises(FitDataError) as error:
        measured_data([0.0, 1.0, 2.0], {"y": [0.0, float("nan"), 1.0]})
    one_line(error, "sample 2, column 'y'", "nan is not a finite number")
    with pytest.raises(FitDataError) as error:
        measured_data([0.0, 1.0, 1.0], {"y": [0.0, 1.0, 2.0]})
    one_line(error, "sample 3, column 'time'", "time not increasing")
    with pytest.raises(FitDataError) as error:
        measured_data([0.0, 1.0], {"y": [0.0, 1.0, 2.0]})
    one_line(error, "column 'y': 3 value(s), time has 2")


def test_data_outside_the_simulated_interval(tmp_path: Path) -> None:
    data = read_data(write(tmp_path, GOOD), ["yaw_rate"])
    check_interval(data, 0.0, 0.2)  # the data's own interval is fine
    with pytest.raises(FitDataError) as error:
        check_interval(data, 0.0, 0.15)
    one_line(error, "line 4, column 'time': 0.2 s is after the simulated interval "
             "[0.0, 0.15] s")
    with pytest.raises(FitDataError) as error:
        check_interval(data, 0.05, 1.0)
    one_line(error, "line 2", "0.0 s is before the simulated interval [0.05, 1.0] s")


def simulate(batch):  # type: ignore[no-untyped-def]
    return [second_order(x) for x in batch]


DATA = data_of(second_order, SECOND_TRUE)
K, WN, ZETA = SECOND_PARAMETERS


@pytest.mark.parametrize("parameters, parts", [
    ((), ["fit: no parameter to vary"]),
    ((Parameter("K", 1.0, 2.0, 2.0), WN), ["parameter 'K': min 2.0 >= max 2.0"]),
    ((Parameter("K", 1.0, 3.0, 2.0), WN), ["parameter 'K': min 3.0 >= max 2.0"]),
    ((Parameter("K", 6.0, 0.1, 5.0), WN), ["parameter 'K': start 6.0 is outside its "
                                           "bounds [0.1, 5.0]"]),
    ((Parameter("K", 1.0, float("nan"), 5.0),), ["parameter 'K': min nan is not a "
                                                 "finite number"]),
    ((Parameter("K", 1.0, 0.0, float("inf")),), ["max inf is not a finite number"]),
    ((Parameter("K", "1", 0.0, 2.0),), ["start '1' is not a finite number"]),  # type: ignore[arg-type]
    ((K, Parameter("K", 1.0, 0.0, 2.0)), ["parameter 'K' given twice"]),
])
def test_bad_parameters(parameters: tuple[Parameter, ...], parts: list[str]) -> None:
    with pytest.raises(FitError) as error:
        fit(simulate, DATA, {"y": "y"}, parameters)
    one_line(error, *parts)


@pytest.mark.parametrize("signals, weights, parts", [
    ({}, None, ["fit: no signal to fit"]),
    ({"y": "yaw"}, None, ["signal 'y': data has no column 'yaw' (columns: y)"]),
    ({"y": "y"}, {"y": 0.0}, ["weight of 'y': 0.0 is not a positive number"]),
    ({"y": "y"}, {"y": -1.0}, ["weight of 'y': -1.0 is not a positive number"]),
    ({"y": "y"}, {"y": float("nan")}, ["weight of 'y': nan is not a positive number"]),
    ({"y": "y"}, {"x": 1.0}, ["weight for 'x', which is not a fitted signal"]),
])
def test_bad_signals_and_weights(signals: dict[str, str], weights: dict[str, float] | None,
                                 parts: list[str]) -> None:
    with pytest.raises(FitError) as error:
        fit(simulate, DATA, signals, SECOND_PARAMETERS, weights=weights)
    one_line(error, *parts)


def test_a_constant_column_needs_a_weight() -> None:
    data = measured_data(TIME, {"y": np.ones_like(TIME)})
    with pytest.raises(FitError) as error:
        fit(simulate, data, {"y": "y"}, SECOND_PARAMETERS)
    one_line(error, "signal 'y': measured column 'y' is constant (1.0)", "give it a weight")
    fit(simulate, data, {"y": "y"}, SECOND_PARAMETERS, weights={"y": 1.0}, max_nfev=2)


def test_bad_simulations() -> None:
    def missing(batch):  # type: ignore[no-untyped-def]
        return [{"x": second_order(x)["y"]} for x in batch]

    with pytest.raises(FitError) as error:
        fit(missing, DATA, {"y": "y"}, SECOND_PARAMETERS)
    one_line(error, "the simulation has no signal 'y' (signals: x)")

    def diverging(batch):  # type: ignore[no-untyped-def]
        return [{"y": (TIME, np.full(TIME.size, np.inf))} for _ in batch]

    with pytest.raises(FitError) as error:
        fit(diverging, DATA, {"y": "y"}, SECOND_PARAMETERS)
    one_line(error, "simulated signal 'y' is not finite at K = 1, wn = 20, zeta = 0.7")

    def short(batch):  # type: ignore[no-untyped-def]
        return [second_order(x, TIME[:200]) for x in batch]

    with pytest.raises(FitError) as error:
        fit(short, DATA, {"y": "y"}, SECOND_PARAMETERS)
    one_line(error, "data from 0.0 to 4.0 s are outside simulated signal 'y' (0.0 to "
             "1.99 s)")

    def too_few(batch):  # type: ignore[no-untyped-def]
        return []

    with pytest.raises(FitError) as error:
        fit(too_few, DATA, {"y": "y"}, SECOND_PARAMETERS)
    one_line(error, "returned 0 result(s) for 1 parameter point(s)")


def test_bad_solver_settings() -> None:
    with pytest.raises(FitError) as error:
        fit(simulate, DATA, {"y": "y"}, SECOND_PARAMETERS, max_nfev=0)
    one_line(error, "max_nfev 0: must be a positive whole number")
    with pytest.raises(FitError) as error:
        fit(simulate, DATA, {"y": "y"}, SECOND_PARAMETERS, relative_step=0.0)
    one_line(error, "relative_step 0.0: must be in (0, 0.1)")
