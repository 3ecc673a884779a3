"""The workers package: the local pool and Dask keep one Runner contract; a stopped
pool raises a RunsStopped of the signal's kind carrying what was done."""

import signal

import pytest

from agv_cosim.errors import KeyboardInterruptedRuns, RunsStopped
from agv_cosim.pipeline import prepare
from agv_cosim.workers import pool
from agv_cosim.workers.runner import DaskRunner, LocalRunner, Runner

SWEEP = '[sweep]\n"gain.k" = [1.0, 2.0]\n'


def test_the_local_pool_and_dask_are_runners():
    assert isinstance(LocalRunner(2), Runner)
    assert isinstance(DaskRunner("tcp://127.0.0.1:8786"), Runner)


def test_the_local_runner_gives_one_result_per_job_in_job_order(chain, tmp_path):
    _, jobs, _ = prepare(chain(extra=SWEEP))
    steps, ended = [], []
    results = LocalRunner(2).run(jobs, tmp_path, steps.append, lambda: ended.append(1))
    assert [r["label"] for r in results] == [job.label for job in jobs]
    assert [r["status"] for r in results] == ["complete", "complete"]
    assert sum(steps) == sum(job.plan.steps for job in jobs) and len(ended) == 2
    assert all((tmp_path / job.label / "run.json").is_file() for job in jobs)


def test_an_interrupted_pool_raises_runs_stopped_with_what_was_done(chain, tmp_path):
    """SIGINT (a KeyboardInterrupt) once the first of two runs ended, one worker: a
    RunsStopped that is a KeyboardInterrupt, with the first run complete, the other
    'not run', the termination signals ignored until its restore()."""
    _, jobs, _ = prepare(chain(extra=SWEEP))
    before = signal.getsignal(signal.SIGTERM)

    def first_done():
        raise KeyboardInterrupt

    with pytest.raises(RunsStopped) as raised:
        pool.run_isolated(jobs, tmp_path, 1, lambda steps: None, first_done)
    stop = raised.value
    try:
        assert isinstance(stop, KeyboardInterrupt)
        assert isinstance(stop, KeyboardInterruptedRuns)
        assert [r["status"] for r in stop.results] == ["complete", "not run"]
        assert stop.reason == "interrupted by SIGINT" and stop.kept is None
        assert signal.getsignal(signal.SIGTERM) == signal.SIG_IGN
    finally:
        stop.restore()
    assert signal.getsignal(signal.SIGTERM) == before


def test_the_idle_workers_are_typed(chain, tmp_path):
    _, [job], _ = prepare(chain())
    idle = pool.IdleWorkers()
    try:
        [result] = pool.run_isolated([job], tmp_path, 1, lambda s: None, lambda: None, idle)
        assert result["status"] == "complete"
        [worker] = idle.workers
        assert isinstance(worker, pool.Worker)
        assert worker.index is None and not worker.busy() and worker.process.is_alive()
    finally:
        idle.close()
    assert not worker.process.is_alive() and worker.pidfd is None
