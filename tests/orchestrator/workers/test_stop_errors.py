"""One stop error (RunsStopped) carrying what was kept, and one exit code per error
type shared by the command line and the API."""

import signal

import pytest

from agv_cosim import api, cli
from agv_cosim.errors import (
    AgvCosimError,
    ClusterError,
    ClusterStopped,
    FolderLost,
    Interrupted,
    InterruptedRuns,
    ManifestError,
    OutputError,
    ReportError,
    RunsStopped,
    UnreadableFile,
    error_lines,
    exit_code,
    kept_summary,
)


@pytest.mark.parametrize("error, code", [
    (ManifestError("m.toml", "key", "bad"), 2), (OutputError("out"), 2),
    (UnreadableFile("f", "a FIFO"), 2), (FolderLost("gone"), 1), (ReportError("page"), 1),
    (ClusterError("--dask: gone"), 1), (OSError(28, "No space left on device"), 1),
    (KeyboardInterrupt(), 130), (Interrupted(signal.SIGTERM), 143),
    (AgvCosimError("x", exit_code=2), 2), (RuntimeError("internal"), 1)])
def test_each_error_type_carries_its_exit_code(error, code):
    assert exit_code(error) == code


def test_a_stop_is_of_the_kind_it_carries():
    results = [{"status": "complete"}, {"status": "not run"}]
    stop = RunsStopped.of(Interrupted(signal.SIGHUP), results)
    assert isinstance(stop, Interrupted) and isinstance(stop, InterruptedRuns)
    assert stop.name == "SIGHUP" and exit_code(stop) == 128 + signal.SIGHUP
    assert stop.reason == "interrupted by SIGHUP" and stop.results == results
    cluster = RunsStopped.of(ClusterError("--dask: lost the scheduler"), results,
                             reason="lost the scheduler")
    assert isinstance(cluster, ClusterError) and isinstance(cluster, ClusterStopped)
    assert str(cluster) == "--dask: lost the scheduler" and exit_code(cluster) == 1
    assert kept_summary(cluster) is None
    cluster.kept = "out"
    assert error_lines(cluster) == [
        "--dask: lost the scheduler; 1 of 2 run(s) complete kept in out (marked partial: "
        "partial.txt, summary.csv)"]
    with pytest.raises(TypeError):
        RunsStopped.of(ValueError("no stop"), results)


def test_restore_runs_once():
    calls = []
    stop = RunsStopped.of(KeyboardInterrupt(), [], lambda: calls.append(1))
    stop.restore()
    stop.restore()
    assert calls == [1]


@pytest.mark.parametrize("error", [FolderLost("the folder went away"),
                                   OutputError("out: not ours"),
                                   OSError(28, "No space left on device", "out")])
def test_the_command_and_the_api_say_the_same(error, chain, tmp_path, monkeypatch, capsys):
    """The same error raised inside ``run``: the command's exit code and line are the
    API's exit_code and message."""
    from agv_cosim import pipeline

    def fail(*args, **kwargs):
        raise error

    monkeypatch.setattr(pipeline, "execute", fail)
    path = chain()
    code = cli.main(["run", str(path), "--out", str(tmp_path / "a"), "--quiet"])
    line = capsys.readouterr().err.strip()
    with pytest.raises(AgvCosimError) as raised:
        api.run(path, out=tmp_path / "b", quiet=True)
    assert code == raised.value.exit_code == exit_code(error)
    assert line == f"agv-cosim: error: {raised.value}"
