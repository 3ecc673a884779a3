"""Multirate stepping (agv_cosim.execution.multirate): a component's own ``step``.

The closed forms: a sampled proportional controller (the gain FMU, u = k x) at
T = m h driving a first-order lag (tau x' = u - x, exact for a held input) stepped at h.
Over one controller period the lag sees u held, and m exact steps of h compose into the
exact step of T: the zero-order-hold discretisation a = exp(-T / tau),

    x_{j+1} = a x_j + (1 - a) u_j,

with u_j = k x_j under Gauss-Seidel (the controller sees this instant's x) and, under
Jacobi (libcosim's), u_0 = k x_0 and u_j = k x_{j-1} (the controller's output is read
before its input is set: one controller period of delay). Between controller points
the lag follows x_j's exponential towards the held u_j, and the controller's output
holds. Tolerance 1e-12 (m roundings of the composed exponential).
"""

import filecmp
import json
import math
import zipfile
from pathlib import Path

import pytest

# the built Reference FMUs (session fixture) of the Model Exchange tests beside this file
from test_model_exchange import reference  # noqa: F401

from agv_cosim.errors import ManifestError
from agv_cosim.execution import RowObserver, simulate
from agv_cosim.execution.multirate import multiples
from agv_cosim.manifest import load_manifest
from agv_cosim.pipeline import execute, prepare

TAU, K, X0 = 0.5, -2.0, 1.0

LOOP = """
name = "sampled"
[simulation]
stop = {stop}
step = {step}
algorithm = "{algorithm}"
[components.plant]
fmu = "{lag}"
parameters = {{ tau = {tau}, x0 = {x0} }}
[components.ctrl]
fmu = "{gain}"
parameters = {{ k = {k} }}
{ctrl_step}
[[connections]]
from = "plant.x"
to = "ctrl.u"
[[connections]]
from = "ctrl.y"
to = "plant.u"
[record]
variables = ["plant.x", "ctrl.y"]
{extra}
"""


def _write(tmp_path: Path, fmus: dict[str, Path], *, stop: float = 1.0,
           step: float = 0.01, algorithm: str = "gauss-seidel",
           ctrl_step: float | None = 0.1, extra: str = "",
           name: str = "sampled.toml") -> Path:
    path = tmp_path / name
    path.write_text(LOOP.format(stop=stop, step=step, algorithm=algorithm,
                                lag=fmus["agv_test_lag"], gain=fmus["agv_test_gain"],
                                tau=TAU, x0=X0, k=K, extra=extra,
                                ctrl_step="" if ctrl_step is None else
                                f"step = {ctrl_step}"))
    return path


def _rows(manifest: Path, fast: bool = False) -> list[list[float]]:
    _, jobs, _ = prepare(manifest)
    rows: list[list[float]] = []
    simulate(jobs[0].plan, [RowObserver(lambda row: rows.append(list(row)))], fast=fast)
    return rows


def _zoh(periods: int, T: float, jacobi: bool) -> tuple[list[float], list[float]]:
    """x_j at the controller points and the u_j held over [t_j, t_{j+1})."""
    a = math.exp(-T / TAU)
    xs, us = [X0], []
    for j in range(periods):
        u = K * (xs[j - 1] if jacobi and j > 0 else xs[j])
        us.append(u)
        xs.append(a * xs[j] + (1 - a) * u)
    return xs, us


@pytest.mark.parametrize("fast", [False, True])
@pytest.mark.parametrize("algorithm", ["gauss-seidel", "jacobi"])
def test_sampled_controller_is_the_exact_zero_order_hold(fmus, tmp_path, algorithm,
                                                        fast):
    h, m = 0.01, 10
    rows = _rows(_write(tmp_path, fmus, algorithm=algorithm), fast)
    assert len(rows) == 101
    xs, us = _zoh(10, m * h, algorithm == "jacobi")
    for i, (t, x, _) in enumerate(rows):
        j, r = divmod(i, m)
        assert t == pytest.approx(i * h, abs=1e-15)
        if r == 0:
            assert x == pytest.approx(xs[j], abs=1e-12), (t, x, xs[j])
        if j < len(us):
            # between points the lag follows the held u_j from x_j exactly
            expected = us[j] + (xs[j] - us[j]) * math.exp(-r * h / TAU)
            assert x == pytest.approx(expected, abs=1e-12), t
    # the controller's output holds between its points: what it showed at t_j
    shown = [row[2] for row in rows]
    for j in range(10):
        held = shown[j * m:(j + 1) * m]
        assert held == [held[0]] * m
        # Gauss-Seidel's row of t_j shows u_j = k x_j; Jacobi's is read before the
        # sets of t_j: the output for the input set at t_{j-1}, k x_{j-1} (k x_0 at
        # the start, from the initialisation's exchanges)
        if algorithm == "gauss-seidel":
            assert held[0] == pytest.approx(us[j], abs=1e-12)
        else:
            assert held[0] == pytest.approx(K * xs[j - 1] if j else K * X0, abs=1e-12)


def test_the_sampled_loop_differs_from_the_single_rate_one(fmus, tmp_path):
    multirate = _rows(_write(tmp_path, fmus))
    single = _rows(_write(tmp_path, fmus, ctrl_step=None, name="single.toml"))
    # the single-rate loop is the exact discretisation at h, not at T
    a = math.exp(-0.01 / TAU)
    assert single[10][1] == pytest.approx(X0 * (a + (1 - a) * K) ** 10, abs=1e-12)
    assert abs(multirate[10][1] - single[10][1]) > 1e-2


def test_a_slow_component_is_stepped_only_at_its_points(fmus, tmp_path):
    """The ramp source at 0.25 s counts its doSteps: 4 over one second (its last step
    shorter when the stop is not on its grid: 0.9 s is 3 steps and one of 0.15 s)."""
    manifest = tmp_path / "ramp.toml"
    manifest.write_text(f"""
[simulation]
stop = 0.9
step = 0.05
[components.src]
fmu = "{fmus['agv_test_source']}"
step = 0.25
[components.int]
fmu = "{fmus['agv_test_integrator']}"
[[connections]]
from = "src.y"
to = "int.u"
[record]
variables = ["src.count", "src.t_out", "int.y"]
""")
    rows = _rows(manifest)
    by_time = {round(r[0], 9): r for r in rows}
    assert by_time[0.2][1:3] == [0, 0.0]
    assert by_time[0.25][1:3] == [1, 0.25]
    assert by_time[0.7][1:3] == [2, 0.5]
    assert by_time[0.75][1:3] == [3, 0.75]
    assert by_time[0.9][1:3] == [4, pytest.approx(0.9, abs=1e-15)]
    # the integrator (at 0.05 s) integrates the source's held output y = t_j
    assert by_time[0.5][3] == pytest.approx(0.25 * 0.25, abs=1e-12)


def test_a_step_that_is_not_a_whole_multiple_is_refused(fmus, tmp_path):
    with pytest.raises(ManifestError) as raised:
        load_manifest(_write(tmp_path, fmus, ctrl_step=0.015))
    text = str(raised.value)
    assert "components.ctrl.step" in text
    assert "0.015 s is not a whole multiple of the simulation step (0.01 s)" in text
    assert "\n" not in text


def test_the_multiple_is_exact_in_decimals(fmus, tmp_path):
    """0.3 / 0.1 is 2.9999999999999996 in doubles: in decimals it is 3."""
    manifest = load_manifest(_write(tmp_path, fmus, step=0.1, stop=0.9, ctrl_step=0.3))
    assert manifest.components["ctrl"].step == 0.3
    _, jobs, _ = prepare(manifest)
    assert multiples(jobs[0].plan)["ctrl"] == 3


def test_a_variant_gives_its_own_step(fmus, tmp_path):
    path = _write(tmp_path, fmus, extra="""
[variants.fast]
components.ctrl.step = 0.01
[variants.bad]
components.ctrl.step = 0.025
""")
    with pytest.raises(ManifestError, match=r"variants\.bad\.components\.ctrl\.step: "
                       r"0\.025 s is not a whole multiple"):
        load_manifest(path)
    path = _write(tmp_path, fmus, extra="""
[variants.sampled]
description = "the base's controller step"
[variants.fast]
components.ctrl.step = 0.01
""")
    _, jobs, _ = prepare(path)
    plans = {job.variant: job.plan for job in jobs}
    assert plans["sampled"].component_steps == {"ctrl": 0.1}
    assert plans["fast"].component_steps == {}


def test_an_event_off_a_slow_components_grid_is_refused(fmus, tmp_path):
    def probe(at: float, step: str) -> str:
        # a second lag whose input only the event drives
        return (f'[components.probe]\nfmu = "{fmus["agv_test_lag"]}"\n{step}\n'
                f'[events.kick]\nat = {at}\nset = {{ "probe.u" = 1.0 }}\n')

    prepare(_write(tmp_path, fmus, extra=probe(0.3, "step = 0.1")))  # one of its points
    prepare(_write(tmp_path, fmus, extra=probe(1.0, "step = 0.3")))  # the stop time
    with pytest.raises(ManifestError) as raised:
        prepare(_write(tmp_path, fmus, extra=probe(0.35, "step = 0.1")))
    assert str(raised.value).endswith(
        "events.kick.at: 0.35 s is not a communication point of component 'probe' (its "
        "step is 0.1 s), whose 'u' the event sets")
    # at the simulation's step, any base point
    prepare(_write(tmp_path, fmus, extra=probe(0.35, "")))


def test_a_step_equal_to_the_simulations_is_the_same_run(fmus, tmp_path):
    """Every result file but timings.csv is the same, byte for byte."""
    path = _write(tmp_path, fmus, ctrl_step=0.01)
    given = load_manifest(path)
    assert given.components["ctrl"].step == 0.01
    none = load_manifest(path)
    none.components["ctrl"].step = None
    outs = []
    for i, manifest in enumerate((given, none)):
        out = tmp_path / f"out{i}"
        _, jobs, _ = prepare(manifest)
        execute(manifest, jobs, out, 1, True)
        outs.append(out)
    files = sorted(p.relative_to(outs[0]) for p in outs[0].rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(outs[1]) for p in outs[1].rglob("*")
                           if p.is_file())
    compared = [f for f in files if f.name != "timings.csv"]
    assert any(f.name == "timeseries.csv" for f in compared)
    for name in compared:
        assert filecmp.cmp(outs[0] / name, outs[1] / name, shallow=False), name


def _reused(path: Path, out: Path, resume: bool = True) -> dict[str, bool]:
    manifest, jobs, _ = prepare(path)
    _, results = execute(manifest, jobs, out, workers=1, quiet=True, resume=resume)
    assert all(r["status"] == "complete" for r in results), results
    return {r["label"]: bool(r.get("reused", False)) for r in results}


def test_the_step_is_an_input_of_a_run_for_resume(fmus, tmp_path):
    """run.json records the component's step; a changed step runs the run again, the
    same one keeps it."""
    path = _write(tmp_path, fmus, extra="""
[variants.sampled]
description = "the controller at the base's step"
[variants.other]
components.plant.parameters = { tau = 0.25 }
""")
    out = tmp_path / "out"
    assert _reused(path, out, resume=False) == {"sampled": False, "other": False}
    record = json.loads((out / "sampled" / "run.json").read_text())
    assert record["component_steps"] == {"ctrl": 0.1}
    assert record["inputs"]["simulation"]["component_steps"] == {"ctrl": 0.1}
    assert _reused(path, out) == {"sampled": True, "other": True}
    path.write_text(path.read_text().replace(
        '[variants.other]\n', '[variants.other]\ncomponents.ctrl.step = 0.05\n'))
    assert _reused(path, out) == {"sampled": True, "other": False}
    record = json.loads((out / "other" / "run.json").read_text())
    assert record["component_steps"] == {"ctrl": 0.05}
    # a single-rate run's run.json has no such key (its inputs are as before)
    path.write_text(path.read_text().replace("step = 0.1\n", "").replace(
        "components.ctrl.step = 0.05\n", ""))
    assert _reused(path, out) == {"sampled": False, "other": False}
    assert "component_steps" not in json.loads((out / "sampled" / "run.json").read_text())


def test_ssp_export_keeps_the_step_in_an_annotation_our_import_reads(fmus, tmp_path):
    from xml.etree import ElementTree

    from agv_cosim.ssp import common as ssp
    from agv_cosim.ssp import exporter, importer

    path = _write(tmp_path, fmus)
    package = tmp_path / "sampled.ssp"
    exporter.export_ssp(path, package)
    with zipfile.ZipFile(package) as archive:
        root = ElementTree.fromstring(archive.read("SystemStructure.ssd"))
    ns = ssp.NS
    ctrl = root.find("ssd:System/ssd:Elements/ssd:Component[@name='ctrl']", ns)
    notes = {note.get("type"): note
             for note in ctrl.findall("ssd:Annotations/ssc:Annotation", ns)}
    assert notes[ssp.AGV_ANNOTATION].find("agv:Component", ns).get("stepSize") == "0.1"
    # libcosim's own hint (its decimation factor)
    assert notes[ssp.OSP_ANNOTATION].find("osp:StepSizeHint", ns).get("value") == "0.1"
    plant = root.find("ssd:System/ssd:Elements/ssd:Component[@name='plant']", ns)
    assert plant.find("ssd:Annotations", ns) is None
    again = importer.load_ssp(package, tmp_path / "unpacked")
    assert again.components["ctrl"].step == 0.1
    assert again.components["plant"].step is None
    # the imported package runs the same sampled loop, row for row (the algorithm,
    # Gauss-Seidel, travels in our annotation too)
    _, jobs, _ = prepare(again)
    rows: list[list[float]] = []
    simulate(jobs[0].plan, [RowObserver(lambda row: rows.append(list(row)))])
    assert rows == _rows(path)


@pytest.mark.parametrize("algorithm", ["gauss-seidel", "jacobi"])
def test_the_compiled_stretches_give_the_python_loops_rows(fmus, tmp_path, monkeypatch,
                                                           algorithm):
    """With the compiled call path, the macro steps between the controller's points run
    in C stretches: the rows are those of the reference loop, bit for bit."""
    from agv_cosim.execution import compiled, multirate

    if not compiled.available():
        pytest.skip(f"no compiled call path here: {compiled.why_not()}")
    stretched: list[tuple[int, int]] = []
    original = multirate.compiled_stretch

    def counted(*args, **kwargs):
        run = original(*args, **kwargs)
        if run is None:
            return None

        def counting(k0: int, k1: int) -> int:
            stretched.append((k0, k1))
            return run(k0, k1)
        return counting

    monkeypatch.setattr(multirate, "compiled_stretch", counted)
    # a base-rate probe (a second lag) whose input an event sets at 0.55 s, between
    # the controller's points
    path = _write(tmp_path, fmus, algorithm=algorithm, extra=f"""
[components.probe]
fmu = "{fmus['agv_test_lag']}"
[events.kick]
at = 0.55
set = {{ "probe.u" = 1.0 }}
""")
    python_rows = _rows(path, fast=False)
    assert not stretched
    fast = _rows(path, fast=True)
    assert fast == python_rows
    # the macro steps from a controller point (k = 10 j) and to one (k = 10 j + 9), and
    # the one to the event's point (k = 54), are made in Python; the 79 others in C
    assert stretched and all(k0 % 10 not in (0, 9) and (k1 - 1) % 10 not in (0, 9)
                             for k0, k1 in stretched)
    assert sum(k1 - k0 for k0, k1 in stretched) == 79
    assert not any(k0 <= 54 < k1 for k0, k1 in stretched)
    monkeypatch.setenv(compiled.DISABLE, "1")
    assert _rows(path, fast=True) == python_rows


@pytest.mark.parametrize("version", ["2", "3"])
def test_a_model_exchange_component_at_its_own_step(reference, tmp_path,  # noqa: F811
                                                    version):
    """Dahlquist (x' = -x, x0 = 1) integrated as Model Exchange at 0.1 s in a run at
    0.01 s (solver tolerance 1e-9): exp(-t) at its points within 1e-7, held between them."""
    from test_model_exchange import me_only

    from agv_cosim.execution.model_exchange import use_model_exchange

    fmu = me_only(reference, version, "Dahlquist", tmp_path)
    path = tmp_path / "me.toml"
    # a model-exchange-only FMU: integrated by the orchestrator
    path.write_text(f'[simulation]\nstop = 1.0\nstep = 0.01\n[components.m]\nfmu = "{fmu}"\n'
                    'step = 0.1\n[record]\nvariables = ["m.x"]\n')
    _, jobs, _ = prepare(path)
    system = jobs[0].plan
    assert system.component_steps == {"m": 0.1}
    system.models["m"] = use_model_exchange(system.models["m"], tolerance=1e-9)
    rows: list[list[float]] = []
    simulate(system, [RowObserver(lambda row: rows.append(list(row)))])
    assert len(rows) == 101
    for i, (t, x) in enumerate(rows):
        point = 0.1 * (i // 10)
        assert x == pytest.approx(math.exp(-point), abs=1e-7), t


def test_the_command_refuses_a_non_multiple_in_one_line(fmus, tmp_path, capsys):
    from agv_cosim import cli

    path = _write(tmp_path, fmus, ctrl_step=0.025)
    code = cli.main(["validate", str(path)])
    err = capsys.readouterr().err
    assert code != 0
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "components.ctrl.step: 0.025 s is not a whole multiple of the simulation " \
           "step (0.01 s)" in lines[0]
    assert "Traceback" not in err


def test_libcosim_steps_the_exported_package_as_our_jacobi_does(fmus, tmp_path):
    """The reference: libcosim (libcosimpy) runs the exported package with the
    controller's decimation factor from ``osp:StepSizeHint``; the lag's state at every
    base step equals our Jacobi's (libcosim's observer samples a simulator only at its
    own steps: the fast lag is the one compared)."""
    pytest.importorskip("libcosimpy")
    from agv_cosim.ssp import exporter

    from libcosim_runner import run_libcosim

    path = _write(tmp_path, fmus, algorithm="jacobi")
    package = tmp_path / "sampled.ssp"
    exporter.export_ssp(path, package)
    times, series = run_libcosim(package, ["plant.x"])
    ours = _rows(path)
    assert [row[0] for row in ours] == list(times)
    theirs = series["plant.x"]
    assert max(abs(row[1] - x) for row, x in zip(ours, theirs)) < 1e-12
    # and it is the sampled loop, not the single-rate one
    single = _rows(_write(tmp_path, fmus, algorithm="jacobi", ctrl_step=None,
                          name="single.toml"))
    assert max(abs(row[1] - x) for row, x in zip(single, theirs)) > 1e-3


def test_a_paced_multirate_run_gives_the_same_rows(fmus, tmp_path):
    """Pacing (``--real-time``) waits after each base step; the rows are unchanged."""
    from agv_cosim.execution import Pacer

    path = _write(tmp_path, fmus, stop=0.2)
    _, jobs, _ = prepare(path)
    rows: list[list[float]] = []
    pacer = Pacer(20.0, 0.0)
    simulate(jobs[0].plan, [RowObserver(lambda row: rows.append(list(row)))], fast=True,
             pace=pacer)
    assert rows == _rows(path)
    assert pacer.figures[3] == pytest.approx(0.2)  # the last base step it paced ended there


def test_the_step_check_refines_a_multirate_component_alike(fmus, tmp_path):
    """--check-step on the sampled loop: the refined runs halve the controller's own
    step with the simulation's (it stays a whole multiple), so the sampled loop is
    refined as a sampled loop: every refinement completes, and the plant's state at the
    controller's points moves by less than the plant's own hold error (the controller
    still samples every 0.1 s, so the discretisation in time barely changes)."""
    import json

    from agv_cosim.cli import main

    path = _write(tmp_path, fmus, ctrl_step=0.1)
    out = tmp_path / "checked"
    assert main(["run", str(path), "--out", str(out), "--check-step", "--quiet",
                 "--no-init"]) == 0
    check = json.loads((out / "step_check.json").read_text())
    (run,) = check["runs"].values() if isinstance(check["runs"], dict) else check["runs"]
    text = json.dumps(run)
    assert "failed" not in {run.get("status"), run.get("check")}, text
    # the sampled controller at 0.1 s: refining the base step only refines the plant's
    # integration between samples, which the exact lag does not need
    for name in ("plant.x", "ctrl.y"):
        entry = run["signals"][name]
        assert entry["change"] is not None and abs(entry["change"]) < 1e-9, text
        assert entry["change_fine"] is not None and abs(entry["change_fine"]) < 1e-9, text
