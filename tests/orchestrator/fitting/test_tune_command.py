"""agv-cosim tune (issue 34 item 4) end to end on the small test FMUs: a constant 1
through a gain k into an integrator from y0 = -a, so the lateral error is e = k t - a,
exact at every recorded step, and its mean |e| over [0, T] has a closed form:
(a^2 + (k T - a)^2) / (2 k T), least at k = sqrt(2) a / T. The tuner finds that optimum
(the mean and the worst case over runs differ), the same manifest and seed give the same
tune.json bytes (local, and on a Dask cluster), a candidate whose run fails is
infeasible and the search goes on, the page compares the original and the tuned
parameters, and each bad [tune] is one line, exit 2."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest

from agv_cosim.cli import main

#: Stop time [s]: the error is e = k t - a over [0, T].
T = 2.0

BASE = """
name = "tune_ramp"
[simulation]
stop = {stop}
step = 0.1
[components.src]
fmu = "{src}"
parameters = {{ offset = 1.0, slope = 0.0 }}
[components.gain]
fmu = "{gain}"
parameters = {{ k = 2.0 }}
{middle}
[components.int]
fmu = "{integ}"
parameters = {{ y0 = -1.0 }}
[[connections]]
from = "src.y"
to = "gain.u"
{wiring}
[record]
variables = ["int.y", "gain.y"]
"""

METRICS = """
[metrics]
lateral_error = "int.y"
control = "gain.y"
"""

DIRECT = """
[[connections]]
from = "gain.y"
to = "int.u"
"""

#: A feedthrough that fails from fail.fail_time on (a run with fail_time < T fails).
THROUGH_FAIL = """
[[connections]]
from = "gain.y"
to = "fail.u"
[[connections]]
from = "fail.y"
to = "int.u"
"""


def mean_abs_error(k: float, a: float) -> float:
    """lateral_error_mean of e = k t - a over [0, T] (k > 0): e crosses 0 when k T > a."""
    if k * T <= a:
        return a - k * T / 2.0
    return (a * a + (k * T - a) ** 2) / (2.0 * k * T)


def write(folder: Path, fmus: dict[str, Path], tune: str, *, metrics: str = METRICS,
          extra: str = "", failing: bool = False, name: str = "m.toml") -> Path:
    middle = f'[components.fail]\nfmu = "{fmus["agv_test_fail"]}"\n' \
        'parameters = { fail_time = 3.0 }' if failing else ""
    text = BASE.format(stop=T, src=fmus["agv_test_source"], gain=fmus["agv_test_gain"],
                       integ=fmus["agv_test_integrator"], middle=middle,
                       wiring=THROUGH_FAIL if failing else DIRECT)
    path = folder / name
    path.write_text(text + extra + metrics + tune)
    return path


def tune_cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(["tune", *args])
    out, err = capsys.readouterr()
    return code, out, err


def record(folder: Path) -> dict[str, Any]:
    return json.loads((folder / "tune.json").read_text())


VARIANTS = """
[variants.near]
[variants.near.components.int]
parameters = { y0 = -1.0 }
[variants.far]
[variants.far.components.int]
parameters = { y0 = -2.0 }
"""


@pytest.mark.slow
def test_worst_case_over_variants_finds_the_analytic_best(fmus, tmp_path, capsys):
    # a = 1 and a = 2: for k < 1.5 the far run is the worse one, least at k = sqrt(2)
    path = write(tmp_path, fmus, extra=VARIANTS, tune="""
[tune]
objective = "lateral_error_mean"
aggregate = "worst"
seed = 3
generations = 10
popsize = 5
[tune.parameters]
"gain.k" = { min = 0.2, max = 3.0 }
""")
    code, out, err = tune_cli([str(path), "--out", str(tmp_path / "out"), "--jobs", "2"],
                              capsys)
    assert code == 0, err
    found = record(tmp_path / "out")
    k = found["best"]["parameters"]["gain.k"]
    assert k == pytest.approx(math.sqrt(2.0), abs=0.02)
    assert found["best"]["value"] == pytest.approx(2.0 * (math.sqrt(2.0) - 1.0), abs=1e-3)
    # each run's objective is the closed form at the trial's k, to rounding
    for trial in found["history"]:
        x = trial["parameters"]["gain.k"]
        assert trial["runs"]["near"] == pytest.approx(mean_abs_error(x, 1.0), rel=1e-12)
        assert trial["runs"]["far"] == pytest.approx(mean_abs_error(x, 2.0), rel=1e-12)
        assert trial["value"] == max(trial["runs"].values())
    assert found["best"]["value"] == min(t["value"] for t in found["history"])
    assert found["start"]["parameters"] == {"gain.k": 2.0}
    assert found["history"][0]["parameters"] == {"gain.k": 2.0}
    # the tuned parameters run again on every run: the same metric as in the trial
    comparison = found["comparison"]
    assert set(comparison) == {"near", "far"}
    for run in ("near", "far"):
        assert comparison[run]["tuned"]["metrics"]["lateral_error_mean"] == \
            found["best"]["runs"][run]
        assert comparison[run]["original"]["metrics"]["lateral_error_mean"] == \
            found["start"]["runs"][run]
    assert "gain.k: 2.0 -> " in out and "objective (worst over 2 run(s))" in out
    fragment = (tmp_path / "out" / "tuned_variant.toml").read_text()
    assert f"parameters = {{ k = {k!r} }}" in fragment


@pytest.mark.slow
def test_mean_over_sweep_points_by_gradient(fmus, tmp_path, capsys):
    # mean over a = 1, 2 of the closed form: k - 1.5 + 1.25 / k, least at k = sqrt(1.25)
    path = write(tmp_path, fmus, extra='[sweep]\n"int.y0" = [-1.0, -2.0]\n', tune="""
[tune]
objective = { lateral_error_mean = 1.0 }
method = "gradient"
generations = 30
[tune.parameters]
"gain.k" = { min = 0.5, max = 3.0 }
""")
    code, _, err = tune_cli([str(path), "--out", str(tmp_path / "out"), "--quiet"], capsys)
    assert code == 0, err
    found = record(tmp_path / "out")
    assert found["method"] == "gradient" and found["converged"]
    assert found["best"]["parameters"]["gain.k"] == pytest.approx(math.sqrt(1.25),
                                                                  rel=1e-4)
    assert found["best"]["value"] == pytest.approx(2.0 * math.sqrt(1.25) - 1.5, rel=1e-8)
    assert len(found["best"]["runs"]) == 2
    assert err == ""  # --quiet: no progress lines


TUNE_SMALL = """
[tune]
objective = "lateral_error_mean"
seed = {seed}
generations = 3
popsize = 4
[tune.parameters]
"gain.k" = {{ min = 0.2, max = 3.0 }}
"""


@pytest.mark.slow
def test_same_manifest_and_seed_give_the_same_tune_json(fmus, tmp_path, capsys):
    path = write(tmp_path, fmus, tune=TUNE_SMALL.format(seed=5))
    out = tmp_path / "one"
    code, _, err = tune_cli([str(path), "--out", str(out), "--jobs", "1"], capsys)
    assert code == 0, err
    first = (out / "tune.json").read_bytes()
    # the folder replaced by the same tuning, with 2 workers: the same bytes, and the
    # user's files in it kept
    (out / "notes.txt").write_text("mine")
    (out / "mine").mkdir()
    (out / "mine" / "data.csv").write_text("1,2")
    code, _, err = tune_cli([str(path), "--out", str(out), "--jobs", "2"], capsys)
    assert code == 0, err
    assert first == (out / "tune.json").read_bytes()
    assert (out / "notes.txt").read_text() == "mine"
    assert (out / "mine" / "data.csv").read_text() == "1,2"
    assert "kept 2 file(s) not written by agv-cosim: mine, notes.txt" in err
    found = json.loads(first)
    # 4 generations of at least 5 candidates
    assert found["seed"] == 5 and len(found["history"]) == found["evaluations"] == 4 * 5
    other = write(tmp_path, fmus, tune=TUNE_SMALL.format(seed=6), name="other.toml")
    code, _, err = tune_cli([str(other), "--out", str(tmp_path / "three")], capsys)
    assert code == 0, err
    again = record(tmp_path / "three")
    assert [t["parameters"] for t in again["history"][1:]] != \
        [t["parameters"] for t in found["history"][1:]]


@pytest.mark.slow
def test_a_failing_run_makes_its_candidate_infeasible(fmus, tmp_path, capsys):
    # fail.fail_time < T: the run fails at that time; the search goes on and keeps a
    # fail_time >= T
    path = write(tmp_path, fmus, failing=True, tune="""
[tune]
objective = "lateral_error_mean"
seed = 2
generations = 5
popsize = 4
[tune.parameters]
"gain.k" = { min = 0.2, max = 3.0 }
"fail.fail_time" = { min = 0.5, max = 4.0 }
""")
    code, _, err = tune_cli([str(path), "--out", str(tmp_path / "out"), "--quiet"], capsys)
    assert code == 0, err
    found = record(tmp_path / "out")
    infeasible = [t for t in found["history"] if t["value"] is None]
    assert infeasible and found["infeasible_trials"] == len(infeasible)
    assert all(t["parameters"]["fail.fail_time"] < T + 0.1 for t in infeasible)
    assert {f["trial"] for f in found["failed_runs"]} == {t["number"] for t in infeasible}
    assert all(f["status"] in ("partial", "failed") and "deliberate failure" in f["error"]
               for f in found["failed_runs"])
    assert found["best"]["parameters"]["fail.fail_time"] >= T - 0.1
    assert found["best"]["value"] is not None
    assert "infeasible and the search went on" in err
    assert len(err.strip().splitlines()) == 1
    page = (tmp_path / "out" / "index.html").read_text()
    assert "Runs that failed during the search" in page


@pytest.mark.slow
def test_the_page_and_the_api(fmus, tmp_path):
    import agv_cosim

    path = write(tmp_path, fmus, extra=VARIANTS, tune=TUNE_SMALL.format(seed=1))
    found = agv_cosim.tune(path, out=tmp_path / "out", jobs=2)
    folder = found["folder"]
    assert folder == (tmp_path / "out").resolve() or folder == tmp_path / "out"
    names = sorted(p.name for p in folder.iterdir())
    assert names == [".agv-cosim", "index.html", "original", "tune.json",
                     "tune_history.png", "tune_run01.png", "tune_run02.png", "tuned",
                     "tuned_variant.toml"]
    for which in ("original", "tuned"):
        assert sorted(p.name for p in (folder / which).iterdir()) == ["far", "near"]
    for png in ("tune_history.png", "tune_run01.png", "tune_run02.png"):
        assert (folder / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    page = (folder / "index.html").read_text()
    for part in ("<h1>tune tune_ramp</h1>", "near <b>original</b>", "far <b>tuned</b>",
                 'src="tune_run01.png"', 'src="tune_history.png"',
                 "<code>gain.k</code>", "lateral_error_mean"):
        assert part in page, part
    assert list(found["comparison"]["which"]) == ["original", "tuned"] * 2
    assert len(found["history"]) == 20 and "gain.k" in found["history"].columns
    # a trial's runs are the runs `run --set` makes: the same metrics
    ran = agv_cosim.run(path, out=tmp_path / "check", sets={"gain.k": found["best"]["gain.k"]},
                        quiet=True)
    summary = ran.summary.set_index("run")
    for run in ("near", "far"):
        assert summary.loc[run, "lateral_error_mean"] == \
            found["record"]["best"]["runs"][run]
    # the fragment is a variant of the manifest with the tuned value
    from agv_cosim.pipeline import prepare

    fragment = (folder / "tuned_variant.toml").read_text()
    with_tuned = tmp_path / "with_tuned.toml"
    with_tuned.write_text(path.read_text() + fragment)
    _, jobs, _ = prepare(with_tuned, ["tuned"])
    assert [job.parameters["gain"]["k"] for job in jobs] == [found["best"]["gain.k"]]
    # a folder that is not ours is refused, one line, before any run
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep")
    with pytest.raises(agv_cosim.AgvCosimError) as error:
        agv_cosim.tune(path, out=tmp_path / "mine")
    assert "not a result folder of agv-cosim" in str(error.value)
    assert error.value.exit_code == 2
    assert (tmp_path / "mine" / "notes.txt").read_text() == "keep"


GOOD = """
[tune]
objective = "lateral_error_mean"
[tune.parameters]
"gain.k" = { min = 0.2, max = 3.0 }
"""

PAIR = '[components.pair]\nfmu = "{pair}"\n'


@pytest.mark.parametrize("tune, options, expected", [
    ("", {}, "tune: no [tune] table"),
    (GOOD, {"metrics": ""}, "tune.objective: the manifest has no [metrics] table"),
    (GOOD.replace('"lateral_error_mean"', '"lateral_error_maen"'), {},
     "tune.objective: 'lateral_error_maen' is not a metric of this manifest's [metrics] "
     "(did you mean 'lateral_error_mean'?)"),
    (GOOD.replace('"lateral_error_mean"', '"path_error_rms"'), {},
     "'path_error_rms' is not a metric of this manifest's [metrics]"),
    (GOOD.replace('"lateral_error_mean"', "{ lateral_error_mean = 0.0 }"), {},
     "tune.objective: weight of 'lateral_error_mean' is 0"),
    (GOOD.replace('"gain.k"', '"gian.k"'), {},
     "tune.parameters.gian.k: no component 'gian' (did you mean 'gain'?)"),
    (GOOD.replace('"gain.k"', '"gain.kk"'), {},
     "unknown parameter 'kk' of 'gain' (AgvTestGain) (did you mean 'k'?)"),
    (GOOD.replace('"gain.k"', '"int.y"'), {}, "'int.y' is output, not a parameter"),
    (GOOD.replace('"gain.k"', '"pair.n"'), {"pair": True},
     "'pair.n' is of type Integer, not Real: only Real parameters are tuned"),
    (GOOD.replace("min = 0.2, max = 3.0", "min = 3.0, max = 3.0"), {},
     "tune.parameters.gain.k: min 3.0 >= max 3.0"),
    (GOOD.replace("min = 0.2, max = 3.0", "min = 0.2, max = 1.0"), {},
     "tune.parameters.gain.k: start 2.0 (the manifest's value) is outside the bounds "
     "[0.2, 1.0]"),
    (GOOD.replace("min = 0.2", 'min = "low"'), {}, "'low' is not a number"),
    (GOOD, {"extra": '[sweep]\n"gain.k" = [1.0, 2.0]\n'},
     "tune.parameters.gain.k: is swept in [sweep]"),
    (GOOD, {"extra": "[variants.a]\n[variants.b.components.gain]\nparameters = { k = 1.5 }\n"},
     "tune.parameters.gain.k: its value differs between the runs (a: 2.0, b: 1.5)"),
    (GOOD.replace("[tune]\n", '[tune]\naggregate = "median"\n'), {},
     "tune.aggregate: 'median' is not one of mean, worst"),
    (GOOD.replace("[tune]\n", '[tune]\nmethod = "tpe"\n'), {},
     "tune.method: 'tpe' is not one of evolution, gradient"),
    (GOOD.replace("[tune]\n", "[tune]\ngenerations = 0\n"), {},
     "tune.generations: 0 must be >= 1"),
    (GOOD.replace("[tune]\n", "[tune]\nseed = -1\n"), {}, "tune.seed: -1 must be >= 0"),
    ("[tune]\nobjective = \"lateral_error_mean\"\n", {}, "tune.parameters: missing"),
    (GOOD, {"extra": '[montecarlo]\nsamples = 2\nseed = 1\n[montecarlo.parameters]\n'
                     '"gain.k" = { distribution = "uniform", low = 1.0, high = 3.0 }\n'},
     "tune.parameters.gain.k: is sampled in [montecarlo]: a parameter is tuned or "
     "sampled, not both"),
    (GOOD.replace('"gain.k"', '"tab.v"'), {"table": True},
     "tune.parameters.tab.v: 'tab' is a time table, which has no parameters"),
    (GOOD.replace('"gain.k"', '"pair.p"'),
     {"extra": '[variants.a]\n[variants.b]\n[variants.b.components.pair]\nfmu = "{pair}"\n'},
     "tune.parameters.pair.p: run 'a' has no component 'pair'"),
])
def test_bad_tune_input_is_one_line_exit_2(fmus, tmp_path, capsys, tune, options,
                                           expected):
    extra = options.get("extra", "").replace("{pair}", str(fmus["agv_test_pair"]))
    if options.get("pair"):
        extra = PAIR.format(pair=fmus["agv_test_pair"]) + extra
    if options.get("table"):
        (tmp_path / "tab.csv").write_text("time,v\n0,1\n1,2\n")
        extra = '[components.tab]\ntable = "tab.csv"\n' + extra
    path = write(tmp_path, fmus, tune=tune, extra=extra,
                 metrics=options.get("metrics", METRICS))
    code, out, err = tune_cli([str(path), "--out", str(tmp_path / "out")], capsys)
    lines = [line for line in err.splitlines() if "warning" not in line]
    assert code == 2, err
    assert len(lines) == 1 and lines[0].startswith("agv-cosim: error: "), err
    assert expected in lines[0], lines[0]
    assert str(path) in lines[0]
    assert "Traceback" not in err and out == ""
    assert not (tmp_path / "out").exists()



@pytest.mark.slow
def test_on_dask_the_same_tune_json_as_local(cluster, fmus, tmp_path,  # noqa: F811
                                             capsys):
    path = write(tmp_path, fmus, tune=TUNE_SMALL.format(seed=4))
    for out, options in (("local", []), ("dask", ["--dask", cluster])):
        code, _, err = tune_cli([str(path), "--out", str(tmp_path / out), "--quiet",
                                 *options], capsys)
        assert code == 0, err
    assert (tmp_path / "local" / "tune.json").read_bytes() == \
        (tmp_path / "dask" / "tune.json").read_bytes()
    assert sorted(p.name for p in (tmp_path / "dask" / "tuned").iterdir()) == ["base"]


@pytest.mark.parametrize("change, expected", [
    ({"variability": "constant"}, "'gain.k' is a constant parameter, not tunable"),
    ({"causality": "calculatedParameter"}, "'gain.k' is calculatedParameter, not a "
                                           "parameter"),
    ({"max": "2.5"}, "tune.parameters.gain.k: max 3.0 is outside the FMU's range (its "
                     "max is 2.5)"),
    ({"min": "0.5"}, "tune.parameters.gain.k: min 0.2 is outside the FMU's range (its "
                     "min is 0.5)"),
])
def test_what_the_fmu_declares_is_checked(fmus, tmp_path, change, expected):
    # the test FMUs declare no range and no constant: the model description read is
    # changed as such an FMU's would read
    import copy
    from dataclasses import replace

    from agv_cosim.errors import ManifestError
    from agv_cosim.pipeline import prepare
    from agv_cosim.tuning import check_tune

    manifest, jobs, _ = prepare(write(tmp_path, fmus, tune=GOOD))
    check_tune(manifest, jobs)  # as declared: fine
    for job in jobs:
        info = copy.copy(job.plan.models["gain"])
        info.variables = dict(info.variables)
        info.variables["k"] = replace(info.variables["k"], **change)
        job.plan.models["gain"] = info
    with pytest.raises(ManifestError) as error:
        check_tune(manifest, jobs)
    text = str(error.value)
    assert expected in text and "\n" not in text, text
