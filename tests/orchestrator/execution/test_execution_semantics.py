"""Execution semantics: Gauss-Seidel vs Jacobi (closed form), failures, NaN, cleanup."""

import json
import os
import tempfile
from pathlib import Path

import numpy as np
import pytest

from agv_cosim import cli
from agv_cosim.timeseries import read_timeseries

A, B, K, H, N = 1.0, 2.0, 1.5, 0.1, 10  # src offset, slope; gain * gain2; step; steps


def _run(path, out, *extra):
    return cli.main(["run", str(path), "--out", str(out), "--quiet", *extra])


def test_gauss_seidel_vs_jacobi_closed_form(chain, tmp_path):
    """src (a + b t) -> gain 3 -> gain2 0.5 -> integrator, inputs held over each step.

    Gauss-Seidel: int.u(t_k) = K (a + b t_k), so y_n = h K (a n + b h n (n - 1) / 2).
    Jacobi (libcosim's semantics): the exchanges in initialisation mode make t0
    consistent, then each feedthrough hop lags one step: with two hops
    int.u(t_k) = K (a + b t_max(k-2, 0)); the final values differ by h^2 K b (2N - 3).
    Tolerance 1e-12: a handful of double additions of O(1) numbers.
    """
    assert _run(chain("gauss-seidel"), tmp_path / "gs") == 0
    assert _run(chain("jacobi", name="j.toml"), tmp_path / "j") == 0
    t, gs = read_timeseries(tmp_path / "gs" / "base" / "timeseries.csv")
    _, jc = read_timeseries(tmp_path / "j" / "base" / "timeseries.csv")
    n = np.arange(N + 1)
    np.testing.assert_allclose(t, n * H, rtol=0, atol=1e-15)
    np.testing.assert_allclose(gs["gain2.y"], K * (A + B * n * H), rtol=0, atol=1e-12)
    jacobi_u = K * (A + B * np.maximum(n - 2, 0) * H)
    np.testing.assert_allclose(jc["gain2.y"], jacobi_u, rtol=0, atol=1e-12)
    y_gs = H * K * (A * n + B * H * n * (n - 1) / 2)
    np.testing.assert_allclose(gs["int.y"], y_gs, rtol=0, atol=1e-12)
    np.testing.assert_allclose(jc["int.y"], H * np.concatenate([[0.0], np.cumsum(jacobi_u[:-1])]),
                               rtol=0, atol=1e-12)
    # the difference is not zero: two steps of lag on the ramp of slope K b
    assert jc["int.y"][-1] == pytest.approx(y_gs[-1] - H * H * K * B * (2 * N - 3), abs=1e-12)
    # default record = every numeric output (Integer too), in manifest order
    assert list(gs) == ["src.y", "src.t_out", "src.count", "gain.y", "gain2.y", "int.y"]


def test_record_interval(chain, tmp_path):
    """record.interval = 0.3 with h = 0.1: rows at 0, 0.3, 0.6, 0.9 and the stop 1.0."""
    path = chain(extra='[record]\nvariables = ["int.y"]\ninterval = 0.3\n')
    assert _run(path, tmp_path / "r") == 0
    t, sig = read_timeseries(tmp_path / "r" / "base" / "timeseries.csv")
    np.testing.assert_allclose(t, [0.0, 0.3, 0.6, 0.9, 1.0], atol=1e-12)
    assert list(sig) == ["int.y"]


def _fail_manifest(fmus, tmp_path, comp, param, when):
    text = f"""
name = "fails"
[simulation]
stop = 1.0
step = 0.1
[components.src]
fmu = "{fmus['agv_test_source']}"
[components.bad]
fmu = "{fmus[comp]}"
parameters = {{ {param} = {when} }}
"""
    if comp == "agv_test_fail":
        text += '[[connections]]\nfrom = "src.y"\nto = "bad.u"\n'
    path = tmp_path / f"{comp}.toml"
    path.write_text(text)
    return path


def test_failing_fmu_leaves_partial_results(fmus, tmp_path, capsys):
    """doStep from t = 0.5 fails: rows t = 0 .. 0.5 (6) are kept, status partial, exit 1,
    and every extraction folder is gone afterwards (the run happens in a child process:
    its folders, agv_cosim_<instance>_* inside agv-cosim-<pid>-run-*, are looked for in
    the temp folder)."""
    def leftovers():
        # this test's runs only: other tests (other pytest-xdist workers) may run an
        # instance of the same name meanwhile. The run folders are made by this process
        # (agv-cosim-<our pid>-run-*); a folder straight in the temp folder counts only if
        # it was not there before the run.
        root = Path(tempfile.gettempdir())
        return sorted(set(root.glob("agv_cosim_bad_*")) - before) + list(
            root.glob(f"agv-cosim-{os.getpid()}-run-*/agv_cosim_bad_*"))

    before = set(Path(tempfile.gettempdir()).glob("agv_cosim_bad_*"))

    path = _fail_manifest(fmus, tmp_path, "agv_test_fail", "fail_time", 0.5)
    assert _run(path, tmp_path / "out") == 1
    err = capsys.readouterr().err
    run_dir = tmp_path / "out" / "base"
    info = json.loads((run_dir / "run.json").read_text())
    assert info["status"] == "partial" and info["partial"] is True
    assert "component 'bad'" in info["error"] and "fmi2DoStep" in info["error"]
    assert "t=0.5 s" in info["error"] and "deliberate failure" in info["error"]
    assert "run base partial" in err
    t, sig = read_timeseries(run_dir / "timeseries.csv")
    np.testing.assert_allclose(t, np.arange(6) * 0.1, atol=1e-12)
    np.testing.assert_allclose(sig["bad.y"], np.arange(6) * 0.1, atol=1e-12)  # y = u = t
    assert leftovers() == []


def test_nan_names_component_variable_time(fmus, tmp_path):
    """y becomes NaN once t >= 0.25, first seen at the communication point t = 0.3."""
    path = _fail_manifest(fmus, tmp_path, "agv_test_nan", "nan_time", 0.25)
    assert _run(path, tmp_path / "out") == 1
    info = json.loads((tmp_path / "out" / "base" / "run.json").read_text())
    assert info["status"] == "partial"
    assert info["error"].startswith("component 'bad': output 'y' is nan at t=0.3")
    t, _ = read_timeseries(tmp_path / "out" / "base" / "timeseries.csv")
    assert len(t) == 3  # 0, 0.1, 0.2 recorded; 0.3 is not


def test_bad_parameter_value_fails_run(fmus, tmp_path):
    """A ParameterError at initialisation: nothing recorded, status failed, exit 1 (the
    check before the runs skipped: it refuses such a value, test_one_line_errors)."""
    path = _fail_manifest(fmus, tmp_path, "agv_test_fail", "fail_time", -1.0)
    assert _run(path, tmp_path / "out", "--no-init") == 1
    info = json.loads((tmp_path / "out" / "base" / "run.json").read_text())
    assert info["status"] == "failed"
    assert "fail_time" in info["error"] and "initialisation" in info["error"]


def test_interrupted_run_leaves_no_complete_folder(chain, tmp_path, monkeypatch):
    from agv_cosim.workers import pool as runner

    def boom(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(runner, "run_isolated", boom)
    assert _run(chain(), tmp_path / "out") == 130
    assert not (tmp_path / "out").exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".out")] == []


def test_a_crashing_fmu_fails_its_run_only(fmus, tmp_path, capsys):
    """An FMU that kills its host at t = 2.5 s (step 1 ms): the run, in its own process,
    is reported partial with every row it recorded (t = 0 .. 2.5 s: 2501 rows, each
    written unbuffered), the other run completes, exit code 1, and no extraction folder
    is left behind."""
    def leftovers():
        # this test's runs only: other tests (other pytest-xdist workers) may run an
        # instance of the same name meanwhile. The run folders are made by this process
        # (agv-cosim-<our pid>-run-*); a folder straight in the temp folder counts only if
        # it was not there before the run.
        root = Path(tempfile.gettempdir())
        return sorted(set(root.glob("agv_cosim_crashdut_*")) - before) + list(
            root.glob(f"agv-cosim-{os.getpid()}-run-*/agv_cosim_crashdut_*"))

    before = set(Path(tempfile.gettempdir()).glob("agv_cosim_crashdut_*"))

    path = tmp_path / "crash.toml"
    path.write_text(f"""
name = "crash"
[simulation]
stop = 3.0
step = 0.001
[components.crashdut]
fmu = "{fmus['agv_test_crash']}"
[sweep]
"crashdut.crash_time" = [2.5, 10.0]
""")
    assert _run(path, tmp_path / "out") == 1
    runs = sorted(p for p in (tmp_path / "out").iterdir() if p.is_dir())
    infos = [json.loads((run / "run.json").read_text()) for run in runs]
    crashed = [i for i in infos if i["status"] != "complete"]
    assert len(crashed) == 1 and len(infos) == 2
    assert crashed[0]["status"] == "partial"
    assert "process died (signal 6)" in crashed[0]["error"]
    # the child's shared track names the component, the call and the time it died in
    assert "in component 'crashdut' during doStep at t=2.5" in crashed[0]["error"]
    assert crashed[0]["rows"] == 2501 and "after 2501 recorded rows" in crashed[0]["error"]
    csv_rows = (tmp_path / "out" / crashed[0]["label"] / "timeseries.csv").read_text()
    assert csv_rows.splitlines()[-1].split(",")[0] == "2.5"  # the last row is t = 2.5 s
    assert leftovers() == []
