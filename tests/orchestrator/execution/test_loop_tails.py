"""The tail the single-rate and the multirate loop share (agv_cosim.execution.stretch.Tail):
the recorded rows, the progress reports and the end a stop request gives, on its own
(fake record, progress and algorithm) and through both loops, with the stop request
inside a compiled stretch and in the Python loop."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from agv_cosim.execution import Observer, compiled, multirate, simulate, simulation
from agv_cosim.execution.stretch import Tail
from agv_cosim.pipeline import prepare

ROOT = Path(__file__).resolve().parents[3]


class Calls:
    """Every call the tail makes, in order: ("row", t), ("steps", n), ("last", t, names)."""

    def __init__(self) -> None:
        self.seen: list[tuple[object, ...]] = []

    def record(self, t: float) -> None:
        self.seen.append(("row", t))

    def steps(self, count: int) -> None:
        self.seen.append(("steps", count))

    def algorithm_at(self, k: int) -> "Calls":
        self.seen.append(("at", k))
        return self

    def last(self, t: float, stopped: set[str]) -> None:
        self.seen.append(("last", t, sorted(stopped)))


def _tail(calls: Calls, *, steps: int = 10, every: int = 3, progress_every: int = 4,
          requests: list[tuple[str, float | None]] | None = None,
          progress: bool = True) -> Tail:
    return Tail(steps, every, calls.record, [calls.steps] if progress else [],
                progress_every, [] if requests is None else requests, calls.algorithm_at)


def _run(tail: Tail, points: list[int]) -> None:
    """A loop reaching each k of ``points`` in turn (a stretch or one macro step each),
    calling the tail where its bound says."""
    for k in points:
        assert k <= tail.bound  # a stretch never runs past the bound
        if k >= tail.bound:
            tail.point(k, k / 10)


def test_the_tail_records_every_recording_point_and_the_last():
    calls = Calls()
    tail = _tail(calls, progress=False)
    assert tail.bound == 3
    _run(tail, list(range(1, 11)))
    assert calls.seen == [("row", 0.3), ("row", 0.6), ("row", 0.9), ("row", 1.0)]
    assert tail.bound == 10  # the last step: nothing after it


def test_the_tail_reports_the_progress_when_due_and_the_rest_at_the_end():
    """Stretches to 3 and 4 make a report of 4; the 2 after it are told at the end."""
    calls = Calls()
    tail = _tail(calls, every=100, steps=100)
    assert tail.bound == 4
    _run(tail, [3, 4])
    assert calls.seen == [("steps", 4)] and tail.bound == 8
    _run(tail, [6])
    tail.finish(6)
    assert calls.seen == [("steps", 4), ("steps", 2)]
    tail.finish(6)  # nothing left to tell
    assert calls.seen == [("steps", 4), ("steps", 2)]


def test_the_row_comes_before_the_report_of_the_same_point():
    calls = Calls()
    tail = _tail(calls, every=4, progress_every=4)
    _run(tail, [1, 2, 3, 4])
    assert calls.seen == [("row", 0.4), ("steps", 4)]


def test_without_progress_observers_nothing_is_counted_or_told():
    calls = Calls()
    tail = _tail(calls, every=100, steps=100, progress=False)
    assert tail.bound == 100
    _run(tail, [50])
    tail.finish(50)
    assert calls.seen == []


def test_a_stop_request_reached_at_the_point_ends_with_the_last_exchange_and_row():
    """6 macro steps completed, the 7th (to 0.7 s) brought the request of d and e, both
    at 0.7 s: the last exchange is the algorithm's at t_7."""
    calls = Calls()
    tail = _tail(calls, every=100, steps=100, requests=[("d", 0.7), ("e", 0.7)])
    tail.stop(6, 0.7)
    assert (tail.ended_by, tail.stop_time) == ("d requested stop at t=0.7 s", 0.7)
    assert calls.seen == [("at", 7), ("last", 0.7, ["d", "e"]), ("row", 0.7)]
    tail.finish(6)  # the 6 macro steps completed before it are told
    assert calls.seen[-1] == ("steps", 6)


def test_a_stop_request_before_the_point_ends_without_a_row():
    calls = Calls()
    tail = _tail(calls, every=100, steps=100, requests=[("d", 0.6)], progress=False)
    tail.stop(6, 0.7)
    tail.finish(6)
    assert (tail.ended_by, tail.stop_time) == ("d requested stop at t=0.6 s", 0.6)
    assert calls.seen == []


def test_the_bound_is_the_next_row_or_report_or_the_last_step():
    tail = _tail(Calls(), steps=100, every=10, progress_every=25)
    expected = {10: 20, 20: 25, 25: 30, 30: 40, 40: 50, 50: 60}
    for k, bound in expected.items():
        tail.point(k, k / 10)
        assert tail.bound == bound, k
    tail = _tail(Calls(), steps=95, every=10, progress=False)
    tail.point(90, 9.0)
    assert tail.bound == 95


STOP = """
[simulation]
stop = 3.0
step = 0.001
algorithm = "{algorithm}"
[components.d]
fmu = "{discard}"
parameters = {{ discard_time = 2.5024 }}
[components.src]
fmu = "{source}"
[components.plant]
fmu = "{lag}"
{plant_step}
[[connections]]
from = "src.y"
to = "plant.u"
[record]
variables = ["plant.x", "d.y"]
interval = 0.01
"""


class Seen(Observer):
    def __init__(self) -> None:
        self.calls: list[tuple[str, object]] = []

    def row(self, row):
        self.calls.append(("row", tuple(row)))

    def steps(self, count):
        self.calls.append(("steps", count))


@pytest.mark.parametrize("algorithm", ["gauss-seidel", "jacobi"])
@pytest.mark.parametrize("plant_step", [None, 0.005], ids=["single-rate", "multirate"])
def test_a_stop_request_inside_a_compiled_stretch_ends_as_in_the_python_loop(
        fmus, tmp_path, monkeypatch, algorithm, plant_step):
    """d refuses its step from 2.503 s (k = 2503), in the middle of a stretch of macro
    steps run in C (single-rate: 2500 .. 2509, to the row of 2.51 s; multirate, the plant
    at 5 ms: 2501 .. 2503, between the plant's points): the stretch returns 3 (2)
    completed steps, and the run ends as the Python loop ends it: the rows to 2.50 s,
    the progress 1000, 1000 and the 503 completed steps, ended by d at 2.503 s."""
    if not compiled.available():
        pytest.skip(f"no compiled call path here: {compiled.why_not()}")
    path = tmp_path / "stop.toml"
    path.write_text(STOP.format(algorithm=algorithm, discard=fmus["agv_test_discard"],
                                source=fmus["agv_test_source"], lag=fmus["agv_test_lag"],
                                plant_step="" if plant_step is None
                                else f"step = {plant_step}"))
    _, jobs, _ = prepare(path)
    system = jobs[0].plan
    module = simulation if plant_step is None else multirate
    original = module.compiled_stretch
    short: list[tuple[int, int, int]] = []  # stretches cut short by a stop request

    def counted(*args, **kwargs):
        run = original(*args, **kwargs)
        if run is None:  # the reference loop (fast=False): every step in Python
            return None

        def counting(k0: int, k1: int) -> int:
            ran: int = run(k0, k1)
            if ran < k1 - k0:
                short.append((k0, k1, ran))
            return ran
        return counting

    monkeypatch.setattr(module, "compiled_stretch", counted)
    results = {}
    for fast in (False, True):
        seen = Seen()
        outcome = simulate(system, [seen], fast=fast)
        results[fast] = (seen.calls, outcome)
    assert short == ([(2500, 2510, 3)] if plant_step is None else [(2501, 2504, 2)])
    calls, outcome = results[True]
    assert calls == results[False][0]
    assert (outcome.rows, outcome.ended_by, outcome.stop_time) == \
        (251, "d requested stop at t=2.503 s", 2.503)
    assert [c for c in calls if c[0] == "steps"] == [("steps", 1000), ("steps", 1000),
                                                     ("steps", 503)]
    rows = [c[1] for c in calls if c[0] == "row"]
    assert [r[0] for r in rows] == pytest.approx([i / 100 for i in range(251)], abs=1e-12)


def test_the_loops_are_within_the_complexity_limit():
    """The single-rate loop, the multirate loop and the Model Exchange step stay at a
    McCabe complexity of 15 or less (ruff's C901)."""
    ruff = shutil.which("ruff", path=str(Path(sys.executable).parent)) or shutil.which("ruff")
    if ruff is None:
        pytest.skip("ruff is not installed")
    execution = ROOT / "orchestrator" / "agv_cosim" / "execution"
    done = subprocess.run(
        [ruff, "check", "--isolated", "--select", "C901", "--output-format", "json",
         "--config", "lint.mccabe.max-complexity = 15",
         *(str(execution / f) for f in ("simulation.py", "multirate.py",
                                        "model_exchange.py"))],
        capture_output=True, text=True, check=False)
    found = json.loads(done.stdout)
    assert [f["message"] for f in found] == []
