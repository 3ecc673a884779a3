"""``run --check-step``: the step refinement study (agv_cosim.pipeline.stepcheck).

The closed form: an integrator y' = u fed back through a gain u = -a y. Gauss-Seidel
steps the integrator (no feedthrough) with u held at -a y_k, so the co-simulation is
explicit Euler, y_k = y0 (1 - a h)^k, against the exact y0 exp(-a t): a coupling error
of order 1 in the step, whose size at every recorded time is known.
"""

import json
import math

import pytest

from agv_cosim import cli
from agv_cosim.pipeline.stepcheck import ATOL, MIN_ORDER, RTOL, assess

LOOP = """
name = "loop"
[simulation]
stop = {stop}
step = {step}
[components.int]
fmu = "{integ}"
parameters = {{ y0 = 1.0 }}
[components.fb]
fmu = "{gain}"
parameters = {{ k = -{a} }}
[[connections]]
from = "int.y"
to = "fb.u"
[[connections]]
from = "fb.y"
to = "int.u"
[metrics]
lateral_error = "int.y"
{extra}
"""


def _run(fmus, tmp_path, *, step, stop=2.0, a=1.0, extra="", args=("--check-step",),
         name="loop"):
    path = tmp_path / f"{name}.toml"
    path.write_text(LOOP.format(step=step, stop=stop, a=a, extra=extra,
                                integ=fmus["agv_test_integrator"],
                                gain=fmus["agv_test_gain"]))
    out = tmp_path / f"out_{name}"
    code = cli.main(["run", str(path), "--out", str(out), "--jobs", "1", "--quiet",
                     *args])
    return out, code


def _euler_max_error(step, stop, a):
    n = round(stop / step)
    return max(abs((1 - a * step) ** k - math.exp(-a * k * stop / n)) for k in range(n + 1))


def test_euler_coupling_has_order_one_and_richardson_finds_its_error(fmus, tmp_path):
    step, stop, a = 0.1, 2.0, 1.0
    out, code = _run(fmus, tmp_path, step=step, stop=stop, a=a)
    assert code == 0
    data = json.loads((out / "step_check.json").read_text())
    assert data["error"] is None and data["factors"] == [1, 2, 4]
    (run,) = data["runs"]
    assert run["status"] == "checked" and run["steps"] == [0.1, 0.05, 0.025]
    signal = run["signals"]["int.y"]
    # the differences of explicit Euler halve with the step: p -> 1 as h -> 0
    assert signal["order"] == pytest.approx(1.0, abs=0.1)
    true_error = _euler_max_error(step, stop, a)
    assert signal["estimate"] == pytest.approx(true_error, rel=0.1)
    assert signal["flag"] == "not converged"
    assert "int.y" in run["not_converged"]
    # a metric: the time-weighted mean of |y| (y > 0: the integral of y over [0, T])
    mean = run["metrics"]["lateral_error_mean"]
    assert mean["order"] == pytest.approx(1.0, abs=0.15)
    exact = (1 - math.exp(-a * stop)) / (a * stop)
    assert mean["estimate"] == pytest.approx(abs(mean["values"][0] - exact), rel=0.15)
    assert mean["change"] == pytest.approx(mean["values"][1] - mean["values"][0])
    # a metric the step does not change: no order, no error, converged
    duration = run["metrics"]["duration"]
    assert duration == {"values": [stop, stop, stop], "change": 0.0, "change_fine": 0.0,
                        "order": None, "estimate": 0.0, "tolerance": RTOL * stop + ATOL,
                        "flag": "converged"}


def test_a_small_enough_step_is_flagged_converged(fmus, tmp_path):
    out, code = _run(fmus, tmp_path, step=0.001, stop=1.0)
    assert code == 0
    (run,) = json.loads((out / "step_check.json").read_text())["runs"]
    signal = run["signals"]["int.y"]
    assert signal["order"] == pytest.approx(1.0, abs=0.05)
    assert signal["estimate"] == pytest.approx(_euler_max_error(0.001, 1.0, 1.0), rel=0.05)
    assert signal["estimate"] < signal["tolerance"] and signal["flag"] == "converged"
    assert "int.y" not in run["not_converged"]


def test_the_base_results_are_the_same_bytes_with_and_without_the_check(fmus, tmp_path):
    checked, _ = _run(fmus, tmp_path, step=0.1, name="checked")
    plain, _ = _run(fmus, tmp_path, step=0.1, args=(), name="plain")
    for name in ("timeseries.csv", "metrics.json"):
        assert (checked / "base" / name).read_bytes() == (plain / "base" / name).read_bytes()
    assert (checked / "summary.csv").read_bytes() == (plain / "summary.csv").read_bytes()
    assert not (plain / "step_check.json").exists()
    # the refined runs' folders are gone: the findings are in step_check.json
    assert sorted(p.name for p in checked.iterdir() if p.is_dir()) == ["base"]


def test_events_stay_at_their_time_in_the_refined_runs(fmus, tmp_path):
    # a ramp started at t = 1 by an event on an unconnected input: exact at any step
    # (y = t - 1 from t = 1 on), so unchanged by the refinements only if each applies
    # the event at t = 1
    extra = (f'[components.ramp]\nfmu = "{fmus["agv_test_integrator"]}"\n'
             '[events.go]\nat = 1.0\nset = { "ramp.u" = 1.0 }\n')
    out, code = _run(fmus, tmp_path, step=0.1, extra=extra)
    assert code == 0
    (run,) = json.loads((out / "step_check.json").read_text())["runs"]
    ramp = run["signals"]["ramp.y"]
    assert max(ramp["change"], ramp["change_fine"]) < 1e-12  # rounding of the sums
    assert ramp["flag"] == "converged"
    assert run["signals"]["int.y"]["order"] == pytest.approx(1.0, abs=0.1)


@pytest.mark.parametrize("d1, d2, scale, order, estimate, flag", [
    (0.0, 0.0, 1.0, None, 0.0, "converged"),          # the step changes nothing
    (4e-3, 2e-3, 1.0, 1.0, 8e-3, "not converged"),     # first order: E = 2 d1
    (4e-3, 1e-3, 10.0, 2.0, 4e-3 * 4 / 3, "converged"),  # second order, tol 1e-2
    (1e-2, 0.0, 1.0, None, 1e-2, "not converged"),     # finer runs agree: E = d1
    (0.0, 1e-2, 1.0, None, None, "order unusable"),    # the change starts at h/2
    (1e-2, 1e-2, 1.0, 0.0, None, "order unusable"),    # p = 0 < MIN_ORDER: no estimate
    (1e-2, 2e-2, 1.0, -1.0, None, "order unusable"),   # the change grows
    (1e-4, 1e-4, 1.0, 0.0, None, "converged"),         # p unusable, changes < 1e-3
    (1e-12, 1e-12, 1.0, 0.0, None, "converged"),       # p unusable, changes within tol
])
def test_flag_rules(d1, d2, scale, order, estimate, flag):
    found = assess(d1, d2, scale)
    assert found["flag"] == flag
    assert found["order"] == (None if order is None else pytest.approx(order))
    assert found["estimate"] == (None if estimate is None else pytest.approx(estimate))
    assert found["tolerance"] == RTOL * scale + ATOL
    assert MIN_ORDER == 0.5


def test_a_failed_refinement_is_said_and_the_base_stays_complete(fmus, tmp_path, capsys):
    # fails once t >= 0.95: the base (last step from 0.9) completes, step/2 (a step
    # from 0.95) and step/4 do not
    extra = (f'[components.f]\nfmu = "{fmus["agv_test_fail"]}"\n'
             "parameters = { fail_time = 0.95 }\n"
             '[[connections]]\nfrom = "int.y"\nto = "f.u"\n')
    out, code = _run(fmus, tmp_path, step=0.1, stop=1.0, extra=extra)
    assert code == 0
    summary = (out / "summary.csv").read_text().splitlines()
    assert summary[1].startswith("base,,complete,")
    data = json.loads((out / "step_check.json").read_text())
    (run,) = data["runs"]
    assert run["status"] == "failed"
    assert run["error"].startswith("the run at step/2 (0.05 s) is partial: ")
    assert "deliberate failure at t=0.95" in run["error"]
    assert run["metrics"] == {} and run["signals"] == {}
    page = (out / "index.html").read_text()
    assert "base: failed: the run at step/2 (0.05 s) is partial" in page
    assert "No run was checked." in page and "not converged in the step" not in page
    assert json.loads((out / "base" / "metrics.json").read_text())["lateral_error_max"] == 1.0


def test_the_page_shows_the_step_check_table_with_its_flags(fmus, tmp_path):
    out, _ = _run(fmus, tmp_path, step=0.1)
    page = (out / "index.html").read_text()
    assert '<h2 id=step-check>Step check</h2>' in page
    assert '<a href="#step-check">step check</a>' in page
    assert '<a href="step_check.json">step_check.json</a>' in page
    section = page.split("<h2 id=step-check>")[1].split("<h2")[0]
    data = json.loads((out / "step_check.json").read_text())
    bad = len(data["runs"][0]["not_converged"])
    assert bad > 0 and f"{bad} quantities not converged in the step (1 run(s) checked)" in section
    # the not-converged rows come first, each flagged
    first = section.split("<tbody>")[1].split("</tr>")[0]
    assert '<td class="flag not-converged">not converged</td>' in first
    assert '<td class="flag converged">converged</td>' in section
    assert "<code>int.y</code>" in section and "<code>lateral_error_mean</code>" in section


def test_refined_divides_the_step_and_tolerances_and_keeps_component_rates():
    """The step and a Model Exchange tolerance are divided; a multirate component's own
    step is its rate (part of the model) and stays, a multiple of the finer step."""
    from pathlib import Path

    from agv_cosim.execution.multirate import multiples
    from agv_cosim.pipeline.stepcheck import refined
    from agv_cosim.system import Event, Job, System
    from agv_cosim.system.model import Integration, ModelInfo

    me = ModelInfo(path=Path("m.fmu"), sha256="0", model_name="m", identifier="m",
                   guid="g", description="", integration=Integration("cvode", 1e-6))
    cs = ModelInfo(path=Path("c.fmu"), sha256="1", model_name="c", identifier="c",
                   guid="h", description="")
    plan = System(models={"me": me, "cs": cs}, parameters={}, connections=[],
                     order=["me", "cs"], record=[], start=0.0, stop=1.0, step=0.1,
                     algorithm="gauss-seidel", record_every=2, steps=10,
                     events=[Event(k=3, at=0.3, name="e", sets=())],
                     component_steps={"cs": 0.3})
    job = Job(label="r", variant=None, point={}, plan=plan, parameters={}, fmu_sha256={},
              manifest_path="m.toml", manifest_sha256="0", metrics_spec=None,
              fmu_paths={}, real_time=1.0)
    finer = refined(job, 4).plan
    assert (finer.step, finer.steps, finer.record_every) == (0.025, 40, 8)
    assert [(e.k, e.at) for e in finer.events] == [(12, 0.3)]
    assert finer.component_steps == {"cs": 0.3}
    assert multiples(plan)["cs"] == 3 and multiples(finer)["cs"] == 12
    assert finer.models["me"].integration == Integration("cvode", 2.5e-7)
    assert finer.models["cs"].integration is None
    assert refined(job, 4).real_time is None and job.plan.step == 0.1


def test_the_api_runs_the_check_too(fmus, tmp_path):
    import agv_cosim

    path = tmp_path / "loop.toml"
    path.write_text(LOOP.format(step=0.1, stop=1.0, a=1.0, extra="",
                                integ=fmus["agv_test_integrator"],
                                gain=fmus["agv_test_gain"]))
    results = agv_cosim.run(path, out=tmp_path / "api", jobs=1, quiet=True,
                            check_step=True)
    data = json.loads((results.folder / "step_check.json").read_text())
    assert [run["status"] for run in data["runs"]] == ["checked"]
    assert data["runs"][0]["signals"]["int.y"]["order"] == pytest.approx(1.0, abs=0.1)
    plain = agv_cosim.run(path, out=tmp_path / "plain", jobs=1, quiet=True)
    assert not (plain.folder / "step_check.json").exists()
