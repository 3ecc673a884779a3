"""A run's record (metrics.json, run.json, the metrics' error) is finished in one place,
report/records.py, for a local run, a run ended by its process and a Dask run."""

import json
from multiprocessing import get_context

from agv_cosim.pipeline import prepare
from agv_cosim.report import records
from agv_cosim.workers import pool
from agv_cosim.workers.job import run_job

METRICS = '[metrics]\nlateral_error = "int.y"\n'


def _failing_metrics(monkeypatch):
    def fail(*args, **kwargs):
        raise ValueError("no such column")

    monkeypatch.setattr(records.metrics, "compute_metrics_csv", fail)


def test_a_metrics_error_is_recorded_by_the_records(chain, tmp_path, monkeypatch):
    _, [job], _ = prepare(chain(extra=METRICS))
    _failing_metrics(monkeypatch)
    result = run_job(job, tmp_path / job.label)
    info = json.loads((tmp_path / job.label / "run.json").read_text())
    assert result["status"] == "complete"
    assert result["metrics_error"] == info["metrics_error"] == "ValueError: no such column"
    assert json.loads((tmp_path / job.label / "metrics.json").read_text()) == {}


def test_finish_run_measures_only_when_asked(chain, tmp_path, monkeypatch):
    _, [job], _ = prepare(chain(extra=METRICS))
    run_job(job, tmp_path / job.label)
    measured = json.loads((tmp_path / job.label / "metrics.json").read_text())
    assert "lateral_error_max" in measured
    run_dir = tmp_path / job.label
    rows = json.loads((run_dir / "run.json").read_text())["rows"]
    result = records.finish_run(job, run_dir, rows, "interrupted", "stopped",
                                measure=False)
    assert result["metrics"] == {} and result["metrics_error"] is None
    assert json.loads((run_dir / "metrics.json").read_text()) == {}
    info = json.loads((run_dir / "run.json").read_text())
    assert info["status"] == "interrupted" and info["error"] == "stopped"
    again = records.finish_run(job, run_dir, rows, "partial", "failed late")
    assert again["metrics"] == measured


def test_a_remote_run_is_finished_with_the_workers_record(chain, tmp_path, monkeypatch):
    """A Dask run: the worker's run.json kept as it is (its FMU copies, its versions)
    but for the metrics' error; metrics.json computed here."""
    _, [job], _ = prepare(chain(extra=METRICS))
    run_dir = tmp_path / job.label
    run_job(job, run_dir)
    record = json.loads((run_dir / "run.json").read_text())
    record["fmus"] = {"src": "/elsewhere/src.fmu"}
    (run_dir / "run.json").unlink()
    (run_dir / "metrics.json").unlink()
    _failing_metrics(monkeypatch)
    result = records.run_result(job, "complete", rows=record["rows"])
    done = records.finish_remote_run(job, run_dir, result, record)
    info = json.loads((run_dir / "run.json").read_text())
    assert info["fmus"] == {"src": "/elsewhere/src.fmu"}
    assert info["metrics_error"] == done["metrics_error"] == "ValueError: no such column"
    assert json.loads((run_dir / "metrics.json").read_text()) == {}


def test_a_run_whose_process_died_is_recorded_by_the_records(chain, tmp_path,
                                                             monkeypatch):
    """A worker that dies mid-run: its run is partial, and its record (with the metrics'
    error text of records.run_metrics) is written by the parent."""
    _, [job], _ = prepare(chain(extra=METRICS, stop=2.0, step=0.001))
    _failing_metrics(monkeypatch)
    real = records.finish_run

    def die_after_rows(job, run_dir, rows, status, *args, **kwargs):
        import os
        if status == "complete":  # in the worker: its process dies before reporting
            os._exit(3)
        return real(job, run_dir, rows, status, *args, **kwargs)

    monkeypatch.setattr(pool, "finish_run", die_after_rows)
    monkeypatch.setattr("agv_cosim.workers.job.finish_run", die_after_rows)
    # the worker forked from this process, so that the patches above are in it: a thread
    # an earlier test left here (a Dask client's) would make the pool start its workers
    # from the fork server, which has the modules unpatched
    monkeypatch.setattr(pool, "process_context", lambda: get_context("fork"))
    [result] = pool.run_isolated([job], tmp_path, 1, lambda s: None, lambda: None)
    info = json.loads((tmp_path / job.label / "run.json").read_text())
    assert result["status"] == "partial" and "exit code 3" in result["error"]
    assert info["status"] == "partial"
    assert result["metrics_error"] == info["metrics_error"] == "ValueError: no such column"
