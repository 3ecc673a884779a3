"""Memory independent of run length, by structure: the parent reads a run's file only in
chunks into decimated lines, and the run's metrics are streamed from its file."""

import numpy as np
import pytest

from agv_cosim import pipeline as runner
from agv_cosim import timeseries as results
from agv_cosim.report import metrics, plots

PLOTS = """
[metrics]
lateral_error = "int.y"
control = "gain.y"
settle_band = 0.5
[plots]
signals = ["int.y", "gain.y"]
trajectory = { x = "src.y", y = "int.y" }
dpi = 10
"""
CHUNK = 64


@pytest.mark.slow  # seconds: builds or runs FMUs in processes
def test_parent_reads_runs_in_chunks_into_bounded_lines(chain, tmp_path, monkeypatch):
    manifest, jobs, _ = runner.prepare(chain(stop=20.0, step=0.01, extra=PLOTS))
    read, drawn = [], []

    def full_read(*args, **kwargs):
        raise AssertionError("the parent read a whole time series")

    def chunks(path, columns=None, chunk_rows=results.CHUNK_ROWS):
        for t, signals in results.iter_timeseries(path, columns, chunk_rows):
            read.append(t.size)
            yield t, signals

    real_plot_runs = plots.plot_runs

    def plot_runs(runs, *args, **kwargs):
        drawn.extend(runs)
        return real_plot_runs(runs, *args, **kwargs)

    monkeypatch.setattr(results, "read_timeseries", full_read)
    monkeypatch.setattr(np, "loadtxt", _only_lists(np.loadtxt))
    monkeypatch.setattr(plots, "iter_timeseries", chunks)
    monkeypatch.setattr(plots, "CHUNK_ROWS", CHUNK)
    monkeypatch.setattr(plots, "plot_runs", plot_runs)
    out, done = runner.execute(manifest, jobs, tmp_path / "out", workers=1, quiet=True)
    rows = done[0]["rows"]
    assert rows == 2001 and not (out / "plots_error.txt").exists()
    assert (out / "signals.png").is_file() and (out / "trajectory.png").is_file()
    # 3 lines read in one pass of chunks of at most CHUNK rows, covering the file
    assert max(read) <= CHUNK and sum(read) == rows
    (run,) = drawn
    assert run.time.size == 0 and not run.signals
    # dpi 10: a signal line keeps at most 4 points in each of 160 buckets (< rows)
    for (x, _), (xs, ys) in run.lines.items():
        bound = 4 * 160 if x == "time" else rows
        assert xs.size == ys.size <= bound
    assert run.lines[("time", "int.y")][0].size < rows
    # the result the child sent holds numbers only, no time series
    assert all(not isinstance(v, (list, np.ndarray)) for v in done[0]["metrics"].values())


def _only_lists(loadtxt):
    """np.loadtxt that refuses a file (a whole-file read) and parses lists of lines."""

    def guarded(source, *args, **kwargs):
        if not isinstance(source, list):
            raise AssertionError(f"np.loadtxt on a whole file: {source!r}")
        return loadtxt(source, *args, **kwargs)

    return guarded


def test_run_job_streams_its_metrics(chain, tmp_path, monkeypatch):
    """run_job (the body of a run's process) computes metrics from chunks of its file,
    equal to the in-memory computation on the whole file."""
    _, jobs, _ = runner.prepare(chain(stop=20.0, step=0.01, extra=PLOTS))
    whole = results.read_timeseries
    monkeypatch.setattr(results, "read_timeseries", lambda *a, **k: 1 / 0)
    monkeypatch.setattr(results, "CHUNK_ROWS", CHUNK)
    sizes = []
    real = results.iter_timeseries

    def chunks(*args, **kwargs):
        for t, signals in real(*args, **kwargs):
            sizes.append(t.size)
            yield t, signals

    monkeypatch.setattr(results, "iter_timeseries", chunks)
    summary = runner.run_job(jobs[0], tmp_path / "run")
    assert summary["metrics_error"] is None and max(sizes) == CHUNK
    t, signals = whole(tmp_path / "run" / "timeseries.csv")
    assert summary["metrics"] == metrics.compute_metrics(t, signals, jobs[0].metrics_spec)
    assert summary["metrics"]["lateral_error_max"] > 0
