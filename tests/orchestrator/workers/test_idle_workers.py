"""A run host's worker kept between runs (pool.IdleWorkers), and the Dask run host
serving request after request with it."""

import io
import pickle
from pathlib import Path

import pytest

from agv_cosim import pipeline as runner
from agv_cosim.workers import host, pool

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
        pid, scratch = worker.process.pid, Path(worker.scratch)
        assert worker.process.is_alive() and scratch.is_dir()
        (tmp_path / "b").mkdir()
        [second] = pool.run_isolated([job], tmp_path / "b", 1, _noop, _noop, idle)
        assert second["status"] == "complete"
        assert [w.process.pid for w in idle.workers] == [pid]  # the same process
        assert ((tmp_path / "a" / job.label / "timeseries.csv").read_bytes()
                == (tmp_path / "b" / job.label / "timeseries.csv").read_bytes())
        process = idle.workers[0].process
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


@pytest.mark.slow  # seconds: runs FMUs in processes
def test_the_checking_worker_runs_after_its_check_and_meanwhile_overlaps(chain, tmp_path):
    """run_isolated with checks and one worker: that worker checks, then runs both jobs
    (one process in all); ``meanwhile`` is called once, before any run ended; the
    folders hold what runs without the check write."""
    from agv_cosim.workers import initcheck

    manifest, jobs, _ = runner.prepare(chain(extra='[sweep]\n"gain.k" = [1.0, 2.0]\n'))
    checks = initcheck.plan_checks(manifest, jobs, 30.0)
    assert checks is not None and len(checks.items) == 5  # gain checked with k = 1 and 2
    events: list[str] = []
    started: list[int] = []
    real_start = pool.start_process

    def counted(process, context):
        real_start(process, context)
        started.append(process.pid)

    pool.start_process, saved = counted, pool.start_process
    try:
        (tmp_path / "a").mkdir()
        checked = pool.run_isolated(jobs, tmp_path / "a", 1, _noop,
                                    lambda: events.append("done"), checks=checks,
                                    meanwhile=lambda: events.append("meanwhile"))
    finally:
        pool.start_process = saved
    assert events == ["meanwhile", "done", "done"]
    assert len(started) == 1
    (tmp_path / "b").mkdir()
    plain = pool.run_isolated(jobs, tmp_path / "b", 1, _noop, _noop)
    assert [r["status"] for r in checked] == [r["status"] for r in plain] == ["complete"] * 2
    for job in jobs:
        assert ((tmp_path / "a" / job.label / "timeseries.csv").read_bytes()
                == (tmp_path / "b" / job.label / "timeseries.csv").read_bytes())
