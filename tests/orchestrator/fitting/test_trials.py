"""agv_cosim.pipeline.trials, what fit and tune share: the varied parameters checked
against a manifest's runs, a run at a parameter vector, batches of runs through the
local worker pool with the signals or the results read back."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from agv_cosim.errors import ManifestError, TrialFailed
from agv_cosim.pipeline import prepare
from agv_cosim.pipeline.trials import KeptLocalRunner, Trials, at_point, tunable
from agv_cosim.report.records import RunResult, run_result
from agv_cosim.system import Job


def _manifest(tmp_path: Path, fmus: dict[str, Path]) -> Path:
    path = tmp_path / "gain.toml"
    path.write_text(f"""name = "gain"
[simulation]
stop = 1.0
step = 0.1
[components.src]
fmu = "{fmus['agv_test_source']}"
parameters = {{ offset = 1.0, slope = 2.0 }}
[components.gain]
fmu = "{fmus['agv_test_gain']}"
parameters = {{ k = 3.0 }}
[[connections]]
from = "src.y"
to = "gain.u"
[record]
variables = ["src.y", "gain.y"]
interval = 0.5
""")
    return path


def test_runs_at_parameter_vectors_through_the_pool(tmp_path: Path,
                                                    fmus: dict[str, Path]) -> None:
    manifest, jobs, _ = prepare(_manifest(tmp_path, fmus))
    parameters = tunable(manifest, jobs, ["gain.k", "src.slope"], "fit.parameters")
    assert [(p.name, p.start) for p in parameters] == [("gain.k", 3.0), ("src.slope", 2.0)]
    points = [[1.0, 1.0], [2.0, 0.5]]
    runs = [at_point(jobs[0], parameters, x, f"p{i}", record=["gain.y"], metrics=False)
            for i, x in enumerate(points)]
    assert runs[0].plan.record == ["gain.y"] and runs[0].plan.record_every == 1
    assert runs[1].parameters["gain"]["k"] == 2.0 and runs[1].point["src.slope"] == 0.5
    assert jobs[0].parameters["gain"]["k"] == 3.0  # the prepared run is left as it was
    runner = KeptLocalRunner(2)
    try:
        trials = Trials(runner, tmp_path / "scratch")
        signals = trials.run(runs, parameters, points, ["gain.y"])
        for (k, slope), out in zip(points, signals):
            t, y = out["gain.y"]
            assert t.tolist() == pytest.approx(np.arange(11) * 0.1)  # every step
            assert y == pytest.approx(k * (1.0 + slope * t))
        results = trials.results([at_point(jobs[0], parameters, [1.0, 1.0], "r")])
        assert results[0]["status"] == "complete" and results[0]["point"]["gain.k"] == 1.0
        assert trials.runs == 3 and not any((tmp_path / "scratch").iterdir())
    finally:
        runner.close()


def test_a_failed_run_names_its_point(tmp_path: Path, fmus: dict[str, Path]) -> None:
    path = _manifest(tmp_path, fmus)
    path.write_text(path.read_text().replace(
        f'fmu = "{fmus["agv_test_gain"]}"\nparameters = {{ k = 3.0 }}',
        f'fmu = "{fmus["agv_test_fail"]}"\nparameters = {{ fail_time = 0.5 }}'))
    manifest, jobs, _ = prepare(path)
    parameters = tunable(manifest, jobs, ["gain.fail_time"], "tune.parameters")
    runner = KeptLocalRunner(1)
    try:
        trials = Trials(runner, tmp_path / "scratch", what="tune")
        with pytest.raises(TrialFailed) as error:
            trials.run([at_point(jobs[0], parameters, [0.3], "x", record=["gain.y"])],
                       parameters, [[0.3]], ["gain.y"])
        assert str(error.value).startswith("tune: run at gain.fail_time = 0.3 partial: ")
        assert error.value.exit_code == 1
    finally:
        runner.close()


class _NamingRunner:
    """A runner whose runs fail naming their own folder (in error and metrics_error)
    and one path elsewhere."""

    def run(self, jobs: list[Job], root: Path, on_progress: object,
            on_done: object) -> list[RunResult]:
        return [run_result(job, "failed", error=f"cannot read {root / job.label}/x.csv",
                           metrics_error=f"{root / job.label}/metrics.json: empty; "
                                         f"see /elsewhere/{job.label}")
                for job in jobs]


def test_results_name_a_removed_run_folder_neutrally(tmp_path: Path,
                                                     fmus: dict[str, Path]) -> None:
    # the batch's folders are removed before results returns: a path into one names
    # nothing, so it reads <run folder> (tune.json's failed_runs keep it so)
    manifest, jobs, _ = prepare(_manifest(tmp_path, fmus))
    parameters = tunable(manifest, jobs, ["gain.k"], "tune.parameters")
    trials = Trials(_NamingRunner(), tmp_path / "scratch", what="tune")
    results = trials.results([at_point(jobs[0], parameters, [x], f"c{i}__base")
                              for i, x in enumerate([1.0, 2.0])])
    assert [r["error"] for r in results] == ["cannot read <run folder>/x.csv"] * 2
    assert [r["metrics_error"] for r in results] == [
        "<run folder>/metrics.json: empty; see /elsewhere/c0__base",
        "<run folder>/metrics.json: empty; see /elsewhere/c1__base"]
    assert not any((tmp_path / "scratch").iterdir())


@pytest.mark.parametrize("name, problem", [
    ("nope.k", "unknown component 'nope'"),
    ("gain.kk", "'gain' has no parameter 'kk' (did you mean 'k'?)"),
    ("gain.y", "'gain.y' is not a tunable parameter (causality output"),
])
def test_parameters_that_cannot_vary(tmp_path: Path, fmus: dict[str, Path], name: str,
                                     problem: str) -> None:
    manifest, jobs, _ = prepare(_manifest(tmp_path, fmus))
    with pytest.raises(ManifestError) as error:
        tunable(manifest, jobs, [name], "tune.parameters")
    assert f"tune.parameters.{name}: {problem}" in str(error.value)
