"""The time grid of a run is t_k = start + k step everywhere (agv_cosim.execution.grid):
the recorded time column, the communication points and step sizes each FMU is given,
the scenario events and the stop, in the reference loops and the fast path alike."""

import csv
from fractions import Fraction

import pytest

from agv_cosim import cli
from agv_cosim.execution import RowObserver, simulate
from agv_cosim.execution.grid import Grid
from agv_cosim.pipeline import prepare

EVENT = """
[components.types]
fmu = "{types}"
[events.change]
at = 0.7
set = {{ "types.ii" = 42 }}
"""


def _decimal_grid(start, step, n):
    """The doubles nearest start + k step, computed from the decimals."""
    return [float(Fraction(repr(start)) + k * Fraction(repr(step))) for k in range(n + 1)]


@pytest.mark.parametrize(("start", "stop", "step"), [
    (0.0, 0.3, 0.1), (0.0, 0.7, 0.1), (0.0, 2.3, 0.1), (0.0, 62.0, 0.01),
    (0.05, 1.05, 0.001), (-0.3, 0.3, 0.1), (1e-9, 1.000000001, 0.001)])
def test_grid_points_are_start_plus_k_step_and_steps_land_on_them(start, stop, step):
    n = round((stop - start) / step)
    grid = Grid(start, stop, n, step)
    times = [grid.time(k) for k in range(n + 1)]
    assert times == _decimal_grid(start, step, n)
    assert times[0] == start and times[-1] == stop
    for t, t_next in zip(times, times[1:]):
        h = grid.step_size(t, t_next)
        # an FMU's next communication point (t + h) is the master's, and the step is
        # the manifest's up to the rounding that makes it so
        assert t + h == t_next and abs(h - step) <= 4 * abs(t_next) * 2.0 ** -52


@pytest.mark.slow  # seconds: builds the test FMUs
@pytest.mark.parametrize("fast", [False, True], ids=["reference", "fast"])
@pytest.mark.parametrize("algorithm", ["gauss-seidel", "jacobi"])
def test_rows_events_and_fmu_clocks_are_on_the_grid(chain, fmus, fast, algorithm):
    path = chain(algorithm=algorithm, stop=2.3, step=0.1,
                 extra=EVENT.format(types=fmus["agv_test_types"]))
    _, (job,), _ = prepare(path)
    rows = []
    outcome = simulate(job.plan, [RowObserver(lambda row: rows.append(list(row)))],
                       fast=fast)
    assert outcome.ended_by is None and len(rows) == 24
    times = [row[0] for row in rows]
    assert times == _decimal_grid(0.0, 0.1, 23)
    assert times[3] == 0.3 and times[7] == 0.7 and times[-1] == 2.3
    columns = ["time", *job.plan.record]
    # the source FMU's own clock (the sum of the step sizes it was given from t = 0)
    # is the master's communication point at every row
    t_out = columns.index("src.t_out")
    assert [row[t_out] for row in rows] == times
    # the event at 0.7 s is applied at the communication point 0.7 (k = 7): its echo
    # shows from the row of 0.7 on
    echo = columns.index("types.io")
    assert [row[echo] for row in rows] == [0] * 7 + [42] * 17


@pytest.mark.slow  # seconds: runs FMUs in a process
@pytest.mark.parametrize("stop", [0.3, 0.7, 2.3])
def test_last_row_of_timeseries_is_the_stop_time(chain, tmp_path, stop):
    path = chain(stop=stop, step=0.1)
    out = tmp_path / "out"
    assert cli.main(["run", str(path), "--out", str(out), "--quiet"]) == 0
    (series,) = out.glob("*/timeseries.csv")
    with series.open(newline="") as stream:
        rows = list(csv.reader(stream))[1:]
    assert [row[0] for row in rows] == [repr(t) for t in _decimal_grid(0.0, 0.1, len(rows) - 1)]
    assert rows[-1][0] == repr(stop)
