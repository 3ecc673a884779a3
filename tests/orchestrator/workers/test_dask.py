"""Runs on a real Dask cluster (issue 16): a scheduler and two workers started as
processes with the venv's ``dask`` command, the results compared file by file with a
local run, one run with an FMU that aborts its process."""

import json
from pathlib import Path

import pytest

from agv_cosim.cli import main
from agv_cosim.errors import ClusterError
from agv_cosim.workers.distributed import cached_fmu, connect

pytestmark = pytest.mark.slow

MANIFEST = """
name = "daskcmp"
[simulation]
stop = 0.5
step = 0.01
[components.src]
fmu = "{src}"
parameters = {{ offset = 1.0, slope = 2.0 }}
[components.gain]
fmu = "{gain}"
[components.int]
fmu = "{integ}"
[components.crashdut]
fmu = "{crash}"
parameters = {{ crash_time = 10.0 }}
[[connections]]
from = "src.y"
to = "gain.u"
[[connections]]
from = "gain.y"
to = "int.u"
[variants.one]
[variants.one.components.gain]
parameters = {{ k = 1.0 }}
[variants.crashing]
[variants.crashing.components.crashdut]
parameters = {{ crash_time = 0.25 }}
[sweep]
"src.slope" = [1.0, -2.0]
[metrics]
lateral_error = "int.y"
"""


def _files(root):
    """The CSV and JSON files of a result folder but timings.csv (the wall times)."""
    assert (Path(root) / "timings.csv").is_file()
    return {path.relative_to(root).as_posix(): path.read_bytes()
            for path in sorted(Path(root).rglob("*"))
            if path.is_file() and path.suffix in (".csv", ".json")
            and path.name != "timings.csv"}


def test_a_dask_run_gives_the_local_results_and_isolates_a_crash(cluster, fmus, tmp_path):
    path = tmp_path / "daskcmp.toml"
    path.write_text(MANIFEST.format(src=fmus["agv_test_source"],
                                    gain=fmus["agv_test_gain"],
                                    integ=fmus["agv_test_integrator"],
                                    crash=fmus["agv_test_crash"]))
    local, remote = tmp_path / "local", tmp_path / "remote"
    assert main(["run", str(path), "--out", str(local), "--quiet"]) == 1
    assert main(["run", str(path), "--out", str(remote), "--quiet", "--dask", cluster]) == 1
    mine, theirs = _files(local), _files(remote)
    # summary.csv + (timeseries, metrics, run) x 4 runs + the report's record of its files
    assert len(mine) == 1 + 4 * 3 + 1 and ".agv-cosim-report.json" in mine
    assert mine == theirs
    crashed = json.loads((remote / "crashing__src.slope=1.0" / "run.json").read_text())
    assert crashed["status"] == "partial"  # every row before the crash is kept
    assert crashed["rows"] == 26  # t = 0 .. 0.25 s
    assert "process died (signal 6)" in crashed["error"]
    ok = json.loads((remote / "one__src.slope=1.0" / "metrics.json").read_text())
    assert ok["lateral_error_max"] > 0.0  # metrics computed (on the client)


def test_stock_workers_run_every_run_isolated(cluster, fmus, tmp_path):
    """Both stock workers (the daemonic one under a nanny, and the one without) run
    runs in processes of their own: each is given a complete run and a run whose FMU
    aborts its process, which ends partial while the worker goes on."""
    from distributed import Client

    from agv_cosim.pipeline import prepare
    from agv_cosim.workers.distributed import run_remote

    with Client(cluster, timeout=30) as client:
        daemonic = client.run(  # a lambda: sent by value (this module is not on workers)
            lambda: __import__("multiprocessing").current_process().daemon)
        assert sorted(daemonic.values()) == [False, True], daemonic
        path = tmp_path / "daskcmp.toml"
        path.write_text(MANIFEST.format(src=fmus["agv_test_source"],
                                        gain=fmus["agv_test_gain"],
                                        integ=fmus["agv_test_integrator"],
                                        crash=fmus["agv_test_crash"]))
        _, jobs, _ = prepare(path)
        jobs = [job for job in jobs if job.label.endswith("slope=1.0")]
        assert len(jobs) == 2
        for worker in daemonic:
            for job in jobs:
                blobs = {info.sha256: Path(info.path).read_bytes()
                         for info in job.plan.models.values() if info.table is None}
                result, files = client.submit(run_remote, job, blobs, pure=False,
                                              workers=[worker]).result(timeout=120)
                crashing = "crashing" in job.label
                assert result["status"] == ("partial" if crashing else "complete"), result
                assert ("process died (signal 6)" in (result["error"] or "")) == crashing
                assert "timeseries.csv" in files and "run.json" in files


def test_an_unreachable_scheduler_is_one_line_and_nonzero(chain, capsys):
    with pytest.raises(ClusterError, match="cannot reach the scheduler at tcp://127.0.0.1:9"):
        connect("tcp://127.0.0.1:9", timeout=1.0)
    assert main(["run", str(chain()), "--quiet", "--dask", "127.0.0.1:8786"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["agv-cosim: error: --dask: '127.0.0.1:8786' is not a scheduler address "
                   "(e.g. tcp://HOST:8786)"]


def test_the_fmu_cache_checks_the_hash(tmp_path):
    import hashlib

    blob = b"not really an FMU"
    sha = hashlib.sha256(blob).hexdigest()
    with pytest.raises(ValueError, match="does not have the SHA-256"):
        cached_fmu(sha, b"tampered", tmp_path)
    path = cached_fmu(sha, blob, tmp_path)
    assert path.read_bytes() == blob and path.name == f"{sha}.fmu"
    assert cached_fmu(sha, blob, tmp_path) == path  # written once
    assert [p.name for p in tmp_path.iterdir()] == [path.name]  # no partial file left

