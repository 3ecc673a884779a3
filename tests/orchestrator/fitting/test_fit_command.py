"""``agv-cosim fit`` end to end (issue 34 items 3 and 6): the parameters of seed 000's
actuator model a recovered through the command from data generated with known values;
the fitted variant runs; each bad input one line, exit 2; a fit that does not converge
kept and marked; a run that fails stops the fit; the output folder's safety."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from fit_manifests import TRUE, manifest, measured

from agv_cosim import cli
from agv_cosim.build import build_one
from agv_cosim.files import marker_data
from agv_cosim.timeseries import read_timeseries

pytestmark = pytest.mark.slow  # builds AgvSteeringA and runs it tens of times

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def steering_a(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The AgvSteeringA FMU built from this tree."""
    folder = tmp_path_factory.mktemp("fmu")
    script = ROOT / "components" / "agv_core" / "steering" / "agv_steering_a.py"
    return Path(build_one(script, folder).fmu)


def fit_cli(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    code = cli.main(["fit", *args])
    out, err = capsys.readouterr()
    return code, out, err


def test_fit_recovers_noise_free_parameters_and_writes_the_folder(
        tmp_path: Path, steering_a: Path, capsys: pytest.CaptureFixture[str]) -> None:
    measured(tmp_path)
    path = manifest(tmp_path, steering_a)
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "notes.txt").write_text("mine")  # an empty-but-for-this folder
    code, out, err = fit_cli(capsys, str(path), "--out", str(tmp_path / "out"), "--jobs",
                             "2")
    # a folder with a user's file that is not ours is refused before any run
    assert code == 2 and "not a result folder of agv-cosim" in err, err
    assert (tmp_path / "out" / "notes.txt").read_text() == "mine"
    out_dir = tmp_path / "fitted"
    code, out, err = fit_cli(capsys, str(path), "--out", str(out_dir), "--jobs", "2")
    assert code == 0, err
    result = json.loads((out_dir / "fit.json").read_text())
    assert result["converged"] is True
    for name, true in TRUE.items():
        value = result["parameters"][name]["value"]
        assert abs(value - true) <= 1e-6 * true, (name, value)
        assert f"{name} = " in out
    # the runs: the engine's batches plus the run at the fitted values
    record = json.loads((out_dir / "fit_run.json").read_text())
    assert record["runs"] == result["runs"] + 1 and result["runs"] >= 3 * result["iterations"]
    assert record["signals"] == {"act.alpha": "alpha"}
    assert record["parameters"]["act.K"] == {"start": 0.6, "min": 0.1, "max": 2.0,
                                             "unit": "rad/(V.s)"}
    # the run at the fitted values, as run writes it; no scratch runs left
    run = json.loads((out_dir / "fitted" / "run.json").read_text())
    assert run["status"] == "complete"
    assert run["parameters"]["act"]["K"] == result["parameters"]["act.K"]["value"]
    assert not (out_dir / ".trials").exists()
    page = (out_dir / "index.html").read_text()
    assert "act.tau" in page and 'src="fit.png"' in page and "Not converged" not in page
    assert (out_dir / "fit.png").read_bytes()[:4] == b"\x89PNG"
    assert marker_data(out_dir) is not None and marker_data(out_dir).get("complete") is None
    # fit again into the same folder: it is ours, replaced, and a user's file kept
    (out_dir / "my_notes.txt").write_text("keep me")
    code, out, err = fit_cli(capsys, str(path), "--out", str(out_dir), "--jobs", "1")
    assert code == 0, err
    assert (out_dir / "my_notes.txt").read_text() == "keep me"
    assert json.loads((out_dir / "fit.json").read_text())["parameters"] == \
        result["parameters"]


def test_the_fitted_variant_runs_the_fitted_model(
        tmp_path: Path, steering_a: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = measured(tmp_path)
    path = manifest(tmp_path, steering_a)
    code, _, err = fit_cli(capsys, str(path), "--out", str(tmp_path / "fitted"))
    assert code == 0, err
    fragment = (tmp_path / "fitted" / "fit_variant.toml").read_text()
    assert "[variants.fitted.components.act]" in fragment
    # into another manifest of the same folder: the experiment without [fit], with
    # the fitted variant pasted at its end
    other = tmp_path / "experiment.toml"
    other.write_text(path.read_text().split("[fit]")[0].replace('"act_fit"', '"other"')
                     + "\n" + fragment)
    assert cli.main(["run", str(other), "--variant", "fitted", "--out",
                     str(tmp_path / "run"), "--quiet"]) == 0, capsys.readouterr().err
    run = json.loads((tmp_path / "run" / "fitted" / "run.json").read_text())
    fitted = json.loads((tmp_path / "fitted" / "fit.json").read_text())["parameters"]
    assert run["parameters"]["act"]["K"] == fitted["act.K"]["value"]
    assert run["parameters"]["act"]["tau"] == fitted["act.tau"]["value"]
    time, columns = read_timeseries(tmp_path / "run" / "fitted" / "timeseries.csv",
                                    ["act.alpha"])
    import numpy as np

    measured_alpha = np.loadtxt(data, delimiter=",", skiprows=1)[:, 2]
    assert np.max(np.abs(columns["act.alpha"] - measured_alpha)) < 1e-6


@pytest.mark.parametrize("case, parts", [
    ({"replace": (('"act.alpha" = "alpha"', '"act.alpha" = "alpha_x"'),)},
     ["measured.csv: no column 'alpha_x'"]),
    ({"replace": (('"act.K" = {', '"act.Kx" = {'),)},
     ["fit.parameters.act.Kx", "'act' has no parameter 'Kx'"]),
    ({"replace": (('"act.K" = {', '"act.alpha" = {'),)},
     ["fit.parameters.act.alpha", "not a tunable parameter (causality output"]),
    ({"replace": (('"act.K" = { min = 0.1, max = 2.0 }',
                   '"act.mode" = { min = 0.1, max = 2.0 }'),)},
     ["fit.parameters.act.mode", "of type String, not a Real scalar"]),
    ({"replace": (('"act.K" = {', '"cmd.u" = {'),)},
     ["fit.parameters.cmd.u", "'cmd' is a time table"]),
    ({"replace": (("min = 0.1, max = 2.0", "min = 2.0, max = 2.0"),)},
     ["fit.parameters.act.K", "min 2.0 >= max 2.0"]),
    ({"replace": (("min = 0.1, max = 2.0", "min = 0.7, max = 2.0"),)},
     ["fit.parameters.act.K", "start 0.6 (the run's value) is outside the bounds [0.7, 2.0]"]),
    ({"stop": 2.0}, ["measured.csv: line 302, column 'time': 3.0 s is after the simulated "
                     "interval [0.0, 2.0] s"]),
    ({"replace": (('"act.alpha" = "alpha"', '"act.u" = "alpha"'),)},
     ["fit.signals.act.u", "'act.u' is not an output of 'act'"]),
    ({"replace": (('signals = { "act.alpha" = "alpha" }',
                   'signals = { "act.alpha" = "alpha" }\nweights = { "act.x" = 2.0 }'),)},
     ["fit.weights.act.x", "not a fitted signal"]),
    ({"extra": '[sweep]\n"act.alpha0" = [0.0, 0.1]'},
     ["fit:", "the manifest has 2 runs", "a fit needs one"]),
])
def test_bad_manifest_input_is_one_line_exit_2(
        tmp_path: Path, steering_a: Path, capsys: pytest.CaptureFixture[str],
        case: dict[str, object], parts: list[str]) -> None:
    measured(tmp_path)
    path = manifest(tmp_path, steering_a, **case)  # type: ignore[arg-type]
    code, out, err = fit_cli(capsys, str(path), "--out", str(tmp_path / "out"))
    assert code == 2 and err.count("\n") == 1 and err.startswith("agv-cosim: error: "), err
    for part in parts:
        assert part in err, (part, err)
    assert "Traceback" not in err and not (tmp_path / "out").exists()


@pytest.mark.parametrize("field, value, parts", [
    (2, "abc", ["line 52, column 'alpha'", "'abc' is not a number"]),
    (2, "nan", ["line 52, column 'alpha'", "'nan' is not a finite number"]),
    (0, "0.49", ["line 52, column 'time'", "time not increasing (0.49 after 0.49)"]),
])
def test_bad_data_is_one_line_exit_2(tmp_path: Path, steering_a: Path,
                                     capsys: pytest.CaptureFixture[str], field: int,
                                     value: str, parts: list[str]) -> None:
    lines = measured(tmp_path).read_text().splitlines()
    # line 52 of the file is the sample at 0.5 s; the fit reads a copy with it made bad
    # (the table component reads the good file)
    cells = lines[51].split(",")
    cells[field] = value
    lines[51] = ",".join(cells)
    (tmp_path / "bad.csv").write_text("\n".join(lines) + "\n")
    path = manifest(tmp_path, steering_a, replace=(('data = "measured.csv"',
                                                    'data = "bad.csv"'),))
    code, out, err = fit_cli(capsys, str(path), "--out", str(tmp_path / "out"))
    assert code == 2 and err.count("\n") == 1, err
    for part in ["bad.csv", *parts]:
        assert part in err, (part, err)


def test_a_fit_that_does_not_converge_is_kept_marked_exit_2(
        tmp_path: Path, steering_a: Path, capsys: pytest.CaptureFixture[str]) -> None:
    measured(tmp_path, noise=0.002)
    path = manifest(tmp_path, steering_a)
    out_dir = tmp_path / "fitted"
    code, out, err = fit_cli(capsys, str(path), "--out", str(out_dir),
                             "--max-evaluations", "2")
    assert code == 2 and err.count("\n") == 1, err
    assert "not converged" in err and str(out_dir) in err
    result = json.loads((out_dir / "fit.json").read_text())
    assert result["converged"] is False
    assert all(p["stderr"] is None for p in result["parameters"].values())
    marker = marker_data(out_dir)
    assert marker is not None and marker["complete"] is False
    assert "not converged" in marker["reason"]
    assert "not converged" in (out_dir / "not_converged.txt").read_text()
    assert "Not converged" in (out_dir / "index.html").read_text()
    assert "NOT CONVERGED" in (out_dir / "fit_variant.toml").read_text()


def test_a_run_that_fails_stops_the_fit_exit_1(
        tmp_path: Path, fmus: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "measured.csv").write_text(
        "time,u,y\n" + "".join(f"{k / 10},{k},{k}\n" for k in range(11)))
    path = tmp_path / "fail.toml"
    path.write_text(f"""name = "fail_fit"
[simulation]
stop = 1.0
step = 0.1
[components.cmd]
table = "measured.csv"
[components.f]
fmu = "{fmus['agv_test_fail']}"
parameters = {{ fail_time = 0.5 }}
[[connections]]
from = "cmd.u"
to = "f.u"
[fit]
data = "measured.csv"
signals = {{ "f.y" = "y" }}
[fit.parameters]
"f.fail_time" = {{ min = 0.2, max = 10.0 }}
""")
    code, out, err = fit_cli(capsys, str(path), "--out", str(tmp_path / "out"))
    assert code == 1 and err.count("\n") == 1, err
    assert "error: fit: run at f.fail_time = 0.5 partial: component 'f'" in err
    assert "deliberate failure at t=0.5" in err
    assert not (tmp_path / "out").exists()
    assert not list(tmp_path.glob(".out.*"))


def test_the_api_raises_not_converged_with_the_folder_kept(
        tmp_path: Path, steering_a: Path) -> None:
    import agv_cosim
    from agv_cosim.errors import FitNotConverged

    measured(tmp_path, noise=0.002)
    path = manifest(tmp_path, steering_a)
    with pytest.raises(FitNotConverged) as error:
        agv_cosim.fit(path, out=tmp_path / "fitted", jobs=1, max_evaluations=1)
    assert error.value.exit_code == 2 and "not converged" in str(error.value)
    assert error.value.kept == tmp_path / "fitted"
    assert error.value.result.converged is False
    assert json.loads((tmp_path / "fitted" / "fit.json").read_text())["converged"] is False
    # without out: no folder, the result as a dict
    found = agv_cosim.fit(path, jobs=1)
    assert found["folder"] is None and found["fit"]["converged"] is True
    assert list(found["parameters"]["parameter"]) == ["act.K", "act.tau"]
    assert list(found["signals"].columns) == ["act.alpha measured", "act.alpha fitted",
                                              "act.alpha residual"]
    assert found["runs"] == found["fit"]["runs"] + 1


def test_an_unreachable_cluster_is_one_line_exit_1(
        tmp_path: Path, steering_a: Path, capsys: pytest.CaptureFixture[str]) -> None:
    measured(tmp_path)
    path = manifest(tmp_path, steering_a)
    code, out, err = fit_cli(capsys, str(path), "--out", str(tmp_path / "out"), "--dask",
                             "tcp://127.0.0.1:9")
    assert code == 1 and err.count("\n") == 1, err
    assert "--dask: cannot reach the scheduler at tcp://127.0.0.1:9" in err
    assert not (tmp_path / "out").exists()


def test_weights_of_the_manifest_are_used(tmp_path: Path, steering_a: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    measured(tmp_path, noise=0.002)
    path = manifest(tmp_path, steering_a, replace=((
        'signals = { "act.alpha" = "alpha" }',
        'signals = { "act.alpha" = "alpha" }\nweights = { "act.alpha" = 500.0 }'),))
    code, out, err = fit_cli(capsys, str(path), "--out", str(tmp_path / "fitted"))
    assert code == 0, err
    result = json.loads((tmp_path / "fitted" / "fit.json").read_text())
    assert result["weights"] == {"act.alpha": 500.0}
    # the cost is half the sum of the squared weighted residuals
    rms = result["rms"]["act.alpha"]
    assert result["cost"] == pytest.approx(0.5 * 301 * (500.0 * rms) ** 2, rel=1e-9)
    for name, true in TRUE.items():
        entry = result["parameters"][name]
        assert abs(entry["value"] - true) <= 3 * entry["stderr"], (name, entry)
