"""A run host's worker kept between runs (pool.IdleWorkers), and the Dask run host
serving request after request with it."""

import io
import pickle
from pathlib import Path

import pytest

from agv_cosim import pipeline as runner
from agv_cosim.pipeline import host, pool

ROGUE = """
name = "rogue"
[simulation]
stop = 0.1
step = 0.01
[components.r]
fmu = "{fmu}"
parameters = {{ garbage_time = 0.05 }}
"""


def _noop(*args):
    return None


@pytest.mark.slow  # seconds: runs FMUs in processes
def test_a_complete_runs_worker_takes_the_next_call_and_ends_with_close(chain, tmp_path):
    _, [job], _ = runner.prepare(chain())
    idle = pool.IdleWorkers()
    try:
        (tmp_path / "a").mkdir()
        [first] = pool.run_isolated([job], tmp_path / "a", 1, _noop, _noop, idle)
        assert first["status"] == "complete"
        [worker] = idle.workers
        pid, scratch = worker["process"].pid, Path(worker["scratch"])
        assert worker["process"].is_alive() and scratch.is_dir()
        (tmp_path / "b").mkdir()
        [second] = pool.run_isolated([job], tmp_path / "b", 1, _noop, _noop, idle)
        assert second["status"] == "complete"
        assert [w["process"].pid for w in idle.workers] == [pid]  # the same process
        assert ((tmp_path / "a" / job.label / "timeseries.csv").read_bytes()
                == (tmp_path / "b" / job.label / "timeseries.csv").read_bytes())
        process = idle.workers[0]["process"]
    finally:
        idle.close()
    assert not process.is_alive() and not scratch.exists() and idle.workers == []


@pytest.mark.slow  # seconds: runs FMUs in processes
def test_a_failed_runs_worker_is_not_kept_and_the_host_serves_on(chain, fmus, tmp_path):
    """Requests to a run host: a complete run, a run whose FMU writes garbage into our
    pipes (failed or partial, its worker gone), then a complete run again in a fresh
    worker; every reply is a result."""
    rogue = tmp_path / "rogue.toml"
    rogue.write_text(ROGUE.format(fmu=fmus["agv_test_rogue"]))
    _, [good], _ = runner.prepare(chain())
    _, [bad], _ = runner.prepare(rogue)
    requests = io.BytesIO()
    for index, job in enumerate((good, bad, good)):
        (tmp_path / str(index)).mkdir()
        pickle.dump((job, str(tmp_path / str(index))), requests)
    requests.seek(0)
    replies = io.BytesIO()
    host.serve(requests, replies)
    replies.seek(0)
    answers = [pickle.load(replies) for _ in range(3)]
    assert [kind for kind, _ in answers] == ["done"] * 3
    statuses = [result["status"] for _, result in answers]
    assert statuses[0] == statuses[2] == "complete" and statuses[1] in ("failed", "partial")
    assert "no message of agv-cosim" in answers[1][1]["error"]
