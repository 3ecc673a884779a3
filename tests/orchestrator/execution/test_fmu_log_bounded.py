"""An FMU that logs without end: what the host holds of its log stays bounded (the last
error and fatal message, counts), however many messages come."""

import pytest

from agv_cosim.errors import SimulationError
from agv_cosim.execution import simulate
from agv_cosim.execution.instance import MAX_MESSAGE, _route
from agv_cosim.pipeline import prepare

ROGUE = """
name = "chatty"
[simulation]
stop = {stop}
step = 0.01
[components.r]
fmu = "{fmu}"
parameters = {parameters}
"""


def _rss():
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    raise AssertionError("no VmRSS")


@pytest.mark.slow  # seconds: a million messages through the FMI logger
def test_a_million_messages_are_not_held(fmus, tmp_path):
    """20 000 messages a step for 50 steps: they all reach the host (counted), and the
    process's memory at the last of them has not grown with them (held, a million
    messages of ~30 characters are over 100 MB)."""
    path = tmp_path / "chatty.toml"
    path.write_text(ROGUE.format(stop=0.5, fmu=fmus["agv_test_rogue"],
                                 parameters="{ log_count = 20000 }"))
    _, (job,), _ = prepare(path)
    seen = [0, 0]
    growth = []
    before = _rss()

    def message(component, status, text):
        seen[0] += 1
        seen[1] += status == 1
        if seen[0] == 20000 * 50:  # the last one: whatever the run holds is held now
            growth.append(_rss() - before)

    outcome = simulate(job.plan, on_message=message)
    assert outcome.ended_by is None
    assert seen == [20000 * 50, 50]
    assert growth and growth[0] < 40 * 2 ** 20, f"grew {growth[0] / 2 ** 20:.0f} MiB"


@pytest.mark.slow  # seconds: builds the test FMUs
def test_the_last_error_is_kept_among_many_messages(fmus, tmp_path):
    """The run's error ends with the FMU's own error message, which came after 1000
    other messages of each step."""
    path = tmp_path / "fails.toml"
    path.write_text(ROGUE.format(stop=0.1, fmu=fmus["agv_test_rogue"],
                                 parameters='{ message = "boom", fail_time = 0.05, '
                                            "log_count = 1000 }"))
    _, (job,), _ = prepare(path)
    with pytest.raises(SimulationError) as caught:
        simulate(job.plan)
    error = str(caught.value)
    assert error.startswith("component 'r': fmi2DoStep returned status")
    assert error.endswith("boom")


def test_a_message_is_cut_before_it_is_decoded():
    got = []
    from agv_cosim.execution import instance

    instance._ROUTES["cut-test"] = lambda status, text: got.append((status, text))
    try:
        _route(None, b"cut-test", 1, b"logAll", b"\xc3\xa9" * MAX_MESSAGE)
    finally:
        del instance._ROUTES["cut-test"]
    [(status, text)] = got
    assert status == 1
    assert text == "\u00e9" * (MAX_MESSAGE // 2) + f" [... {MAX_MESSAGE} more bytes]"
