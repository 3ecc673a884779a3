"""Model Exchange FMUs integrated by the orchestrator (agv_cosim.execution.model_exchange).

The Reference FMUs (FMI 2.0 and 3.0) are built from ``../shared/third-party/Reference-FMUs``
once and kept in pytest's cache folder (``.pytest_cache/d/reference_fmus_me``), keyed by
the sources' sizes and times; each test copies the built FMU with its ``<CoSimulation>``
element removed, so the FMU is model-exchange-only and the orchestrator integrates it.

Tolerances (solver tolerance ``TOL`` = 1e-9 unless stated):
- closed forms: Dahlquist's exp(-k t) within 1e-7 (absolute); BouncingBall's free fall
  with restitution e (bounce times t_1 = sqrt(2 h0 / g), t_{n+1} = t_n + 2 e^n v_1 / g,
  until the speed after a bounce is below v_min = 0.1 m/s): heights within 1e-6 m,
  bounce times within 1e-5 s (CVODE and solve_ivp);
- fmpy's own Model Exchange simulation (``simulate_fmu(fmi_type="ModelExchange")``, CVODE
  at relative tolerance 1e-9, the same output points): within 1e-5;
- the Reference FMUs' ``_out.csv`` (written by ``fmusim`` through the co-simulation
  interface, forward Euler with a fixed step): Stair exactly; BouncingBall, VanDerPol and
  Dahlquist as far as fmpy's own ME result is from it (within 1e-5 of that);
  Feedthrough's outputs equal its inputs at each communication point (1e-12).
"""

import hashlib
import math
import os
import shutil
import subprocess
import zipfile
from pathlib import Path

import numpy as np
import pytest
from filelock import FileLock

from agv_cosim.errors import ModelError, SimulationError
from agv_cosim.execution import RowObserver, simulate
from agv_cosim.execution.model_exchange import (
    MAX_EVENT_ITERATIONS,
    ModelExchangeUnit,
    select_interface,
    use_model_exchange,
)
from agv_cosim.pipeline import prepare
from agv_cosim.system.model import read_model

ROOT = Path(__file__).resolve().parents[3]
SOURCES = Path(os.environ.get("AGV_REFERENCE_FMUS",
                              ROOT.parent / "shared" / "third-party" / "Reference-FMUs"))
TOL = 1e-9
VERSIONS = ["2", "3"]
SOLVERS = ["cvode", "scipy"]


def _stamp() -> str:
    digest = hashlib.sha256()
    for path in sorted(SOURCES.rglob("*")):
        if path.is_file() and "build" not in path.parts:
            st = path.stat()
            digest.update(f"{path.relative_to(SOURCES)} {st.st_size} {st.st_mtime_ns}\n"
                          .encode())
    return digest.hexdigest()[:16]


@pytest.fixture(scope="session")
def reference(request, tmp_path_factory):
    """FMI version ("2", "3") -> folder of the built Reference FMUs (cached in pytest's
    cache folder; in the session's temporary folder when the cache is off)."""
    if not (SOURCES / "CMakeLists.txt").is_file():
        pytest.skip(f"Reference FMU sources not found at {SOURCES}")
    if shutil.which("cmake") is None:
        pytest.skip("cmake is not installed (needed to build the Reference FMUs)")
    cache = getattr(request.config, "cache", None)
    base = Path(cache.mkdir("reference_fmus_me")) if cache is not None else \
        tmp_path_factory.getbasetemp()
    root = base / f"reference_me_{_stamp()}"
    root.mkdir(exist_ok=True)
    with FileLock(str(root) + ".lock"):
        if not (root / ".complete").is_file():
            for version in VERSIONS:
                build, install = root / f"build{version}", root / f"fmi{version}"
                shutil.rmtree(build, ignore_errors=True)
                build.mkdir()
                for command in (["cmake", f"-DFMI_VERSION={version}",
                                 f"-DCMAKE_INSTALL_PREFIX={install}", str(SOURCES)],
                                ["make", "-j2", "install"]):
                    done = subprocess.run(command, cwd=build, capture_output=True, text=True)
                    assert done.returncode == 0, \
                        f"{' '.join(command)} failed:\n{done.stderr[-2000:]}"
                shutil.rmtree(build, ignore_errors=True)
            (root / ".complete").touch()
    return {v: root / f"fmi{v}" for v in VERSIONS}


def _without(source: Path, target: Path, element: str, edit=None) -> Path:
    """A copy of the FMU ``source`` without its ``<element>`` (CoSimulation or
    ModelExchange) in modelDescription.xml; ``edit(text)`` changes the XML further."""
    with zipfile.ZipFile(source) as zin, zipfile.ZipFile(target, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item)
            if item.filename == "modelDescription.xml":
                text = data.decode()
                start = text.index(f"<{element}")
                close = f"</{element}>"
                end = (text.index(close, start) + len(close) if close in text
                       else text.index("/>", start) + 2)
                text = text[:start] + text[end:]
                data = (edit(text) if edit else text).encode()
            zout.writestr(item, data)
    return target


def me_only(reference, version, model, tmp_path) -> Path:
    return _without(reference[version] / f"{model}.fmu",
                    tmp_path / f"{model}{version}ME.fmu", "CoSimulation")


def run(tmp_path, fmu, stop, step, solver="cvode", tolerance=TOL, extra="", record=None,
        parameters=""):
    """Run ``fmu`` as component ``m`` (plus ``extra`` manifest text): (record names,
    rows as an array, outcome)."""
    manifest = tmp_path / "m.toml"
    manifest.write_text(f'[simulation]\nstop = {stop}\nstep = {step}\n'
                        f'[components.m]\nfmu = "{fmu}"\n{parameters}{extra}'
                        + (f"[record]\nvariables = {record!r}\n".replace("'", '"')
                           if record else ""))
    _, jobs, _ = prepare(manifest)
    system = jobs[0].plan
    system.models["m"] = use_model_exchange(system.models["m"], solver=solver,
                                            tolerance=tolerance)
    rows = []
    outcome = simulate(system, [RowObserver(lambda row: rows.append(list(row)))])
    return system.record, np.array(rows, dtype=float), outcome


def _reference_csv(model):
    import csv
    with open(SOURCES / model / f"{model}_out.csv", newline="") as stream:
        rows = list(csv.reader(stream))
    return rows[0], rows[1:]


def _column(names, rows, name):
    return rows[:, 1 + names.index(f"m.{name}")]


# closed forms -------------------------------------------------------------------------

G, E, H0, V_MIN = 9.81, 0.7, 1.0, 0.1


def _flights(e_at=lambda t: E):
    """The closed form as [(impact time, speed leaving the ground)] and the time the ball
    comes to rest; ``e_at(t)`` is the restitution at an impact at t."""
    t = math.sqrt(2 * H0 / G)
    v = G * t  # impact speed
    flights = []
    while t < 10.0:
        v *= e_at(t)  # speed leaving the ground
        if v < V_MIN:
            return flights, t
        flights.append((t, v))
        t += 2 * v / G
    return flights, None


def bounce_times(stop, e_at=lambda t: E):
    """The closed-form bounce times up to ``stop`` and the time the ball comes to rest."""
    flights, rest = _flights(e_at)
    times = [t for t, _ in flights if t <= stop]
    if rest is not None and rest <= stop:
        times.append(rest)
    return times, rest


def ball_height(t, e_at=lambda t: E):
    """h(t) of the closed form (0 once at rest)."""
    flights, rest = _flights(e_at)
    if t <= flights[0][0]:
        return H0 - G * t * t / 2
    if rest is not None and t >= rest:
        return 0.0
    start, v = [f for f in flights if f[0] <= t][-1]
    tau = t - start
    return v * tau - G * tau * tau / 2


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("version", VERSIONS)
def test_bouncing_ball_against_the_closed_form(reference, tmp_path, version, solver):
    """The recorded height follows the closed form within 1e-6 m, and each bounce time,
    found from the last row before it (free fall from the recorded h, v), matches t_n
    within 1e-5 s; the ball comes to rest when the closed form says."""
    names, rows, outcome = run(tmp_path, me_only(reference, version, "BouncingBall",
                                                 tmp_path), 3.0, 0.01, solver)
    assert outcome.ended_by is None and len(rows) == 301
    t, h, v = rows[:, 0], _column(names, rows, "h"), _column(names, rows, "v")
    expected = np.array([ball_height(x) for x in t])
    assert np.max(np.abs(h - expected)) < 1e-6, np.max(np.abs(h - expected))
    times, rest = bounce_times(3.0)
    assert rest is not None and len(times) == 11  # the 11th impact leaves v < v_min: rest
    for n, tn in enumerate(times):
        k = int(np.searchsorted(t, tn)) - 1  # the last row before the bounce
        hit = t[k] + (v[k] + math.sqrt(v[k] ** 2 + 2 * G * h[k])) / G
        assert abs(hit - tn) < 1e-5, (n, hit, tn)
    assert np.all(v[t > rest + 0.01] == 0) and np.all(h[t > rest + 0.01] < 1e-300)


@pytest.mark.parametrize("version", VERSIONS)
def test_an_event_sets_a_value_in_event_mode(reference, tmp_path, version):
    """A scenario event sets BouncingBall's restitution e (settable in a Model Exchange
    FMU in event mode only) to 0.5 at t = 1 s: the heights follow the closed form with
    e = 0.7 before and 0.5 for the impacts after, within 1e-6 m."""
    fmu = me_only(reference, version, "BouncingBall", tmp_path)
    names, rows, _ = run(tmp_path, fmu, 3.0, 0.01,
                         extra='[events.softer]\nat = 1.0\nset = { "m.e" = 0.5 }\n')
    t, h = rows[:, 0], _column(names, rows, "h")

    def e_at(when):
        return E if when < 1.0 else 0.5

    expected = np.array([ball_height(x, e_at) for x in t])
    assert np.max(np.abs(h - expected)) < 1e-6, np.max(np.abs(h - expected))
    assert np.max(np.abs(h - np.array([ball_height(x) for x in t]))) > 0.01


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("version", VERSIONS)
def test_dahlquist_against_the_exact_exponential(reference, tmp_path, version, solver):
    """x' = -k x (k = 1, x0 = 1): x(t) = exp(-t) within 1e-7 (absolute; the solver's
    absolute tolerance is 1e-9 x the state's nominal 1, restarted at every point)."""
    names, rows, _ = run(tmp_path, me_only(reference, version, "Dahlquist", tmp_path),
                         10.0, 0.1, solver)
    t, x = rows[:, 0], _column(names, rows, "x")
    assert np.allclose(x, np.exp(-t), rtol=0, atol=1e-7)


# reference outputs and fmpy -----------------------------------------------------------

#: model, stop, step as the reference CSVs were written
REFERENCE = [("BouncingBall", 3.0, 0.01), ("VanDerPol", 20.0, 0.01), ("Dahlquist", 10.0, 0.1),
             ("Stair", 10.0, 0.2)]


@pytest.mark.parametrize("model,stop,step", REFERENCE)
@pytest.mark.parametrize("version", VERSIONS)
def test_against_reference_output_and_fmpy(reference, tmp_path, version, model, stop, step):
    """Each recorded variable against fmpy's Model Exchange simulation (CVODE, the same
    relative tolerance 1e-9, the same output points, event rows left out) within 1e-5;
    against the reference CSV (rows at the same times): Stair exactly, the others as far
    as fmpy's own ME result is (within 1e-5 of fmpy's largest difference: the reference
    is forward Euler, e.g. 0.024 m in BouncingBall's h, 0.35 in VanDerPol's x0). Stair's
    FMU ends the run at t = 9 s, as the reference's last row."""
    from fmpy import simulate_fmu

    fmu = me_only(reference, version, model, tmp_path)
    names, rows, outcome = run(tmp_path, fmu, stop, step)
    header, ref = _reference_csv(model)
    ref_rows = np.array(ref, dtype=float)
    assert len(rows) == len(ref_rows)
    assert np.allclose(rows[:, 0], ref_rows[:, 0], rtol=1e-12, atol=1e-12)
    theirs = simulate_fmu(str(fmu), fmi_type="ModelExchange", stop_time=stop,
                          output_interval=step, relative_tolerance=TOL,
                          output=header[1:], solver="CVode", record_events=False)
    if model == "Stair":
        assert outcome.ended_by == "m requested stop at t=9.0 s"
    count = min(len(rows), len(theirs))
    assert count >= len(rows) - 1
    for column, name in enumerate(header[1:], start=1):
        ours, fmpy_ = _column(names, rows, name), theirs[name].astype(float)
        assert np.max(np.abs(ours[:count] - fmpy_[:count])) <= 1e-5, name
        ours_off = np.max(np.abs(ours - ref_rows[:, column]))
        if model == "Stair":
            assert ours_off == 0
        else:
            fmpy_off = np.max(np.abs(fmpy_[:count] - ref_rows[:count, column]))
            assert abs(ours_off - fmpy_off) <= 1e-5, (name, ours_off, fmpy_off)


@pytest.mark.parametrize("version", VERSIONS)
def test_feedthrough_discrete_and_continuous_inputs(reference, tmp_path, version):
    """Feedthrough fed by a table: a continuous input (set in continuous-time mode) and a
    discrete one (set in event mode, an external event) show at the outputs at the same
    communication point, as fmpy's Model Exchange simulation with the same input."""
    from fmpy import simulate_fmu

    table = tmp_path / "in.csv"
    table.write_text("time,c,d\n0,0,0\n0.5,1,2\n1,3,-1\n")
    fmu = me_only(reference, version, "Feedthrough", tmp_path)
    extra = ('[components.tab]\ntable = "' + str(table) + '"\n'
             'interpolation = { d = "hold" }\n'
             '[[connections]]\nfrom = "tab.c"\nto = "m.Float64_continuous_input"\n'
             '[[connections]]\nfrom = "tab.d"\nto = "m.Float64_discrete_input"\n')
    names, rows, _ = run(tmp_path, fmu, 1.5, 0.1, extra=extra,
                         record=["m.Float64_continuous_output", "m.Float64_discrete_output"])
    t = rows[:, 0]
    continuous = np.interp(t, [0, 0.5, 1], [0, 1, 3])
    discrete = np.where(t < 0.5 - 1e-12, 0.0, np.where(t < 1 - 1e-12, 2.0, -1.0))
    assert np.allclose(_column(names, rows, "Float64_continuous_output"), continuous,
                       rtol=0, atol=1e-12)
    assert np.array_equal(_column(names, rows, "Float64_discrete_output"), discrete)
    signals = np.array([(x, c, d) for x, c, d in zip(t, continuous, discrete, strict=True)],
                       dtype=[("time", float), ("Float64_continuous_input", float),
                              ("Float64_discrete_input", float)])
    theirs = simulate_fmu(str(fmu), fmi_type="ModelExchange", stop_time=1.5,
                          output_interval=0.1, input=signals,
                          output=["Float64_continuous_output"], record_events=False)
    assert np.allclose(_column(names, rows, "Float64_continuous_output"),
                       theirs["Float64_continuous_output"], rtol=0, atol=1e-12)


@pytest.mark.parametrize("algorithm", ["gauss-seidel", "jacobi"])
@pytest.mark.parametrize("fast", [False, True])
def test_closed_loop_with_a_co_simulation_fmu(reference, fmus, tmp_path, fast, algorithm):
    """Our co-simulation integrator (y' = u, exact for a held input) with the ME
    Feedthrough closing the loop u = y (y0 = 1, h = 0.1): Gauss-Seidel gives
    y_k = (1 + h)^k exactly; Jacobi, whose feedthrough connection adds a step of delay,
    y_{k+1} = y_k + h y_{k-1} with y_{-1} = y_0 = 1 (the reference loops and the
    generated fast path alike)."""
    fmu = me_only(reference, "2", "Feedthrough", tmp_path)
    extra = (f'[components.integ]\nfmu = "{fmus["agv_test_integrator"]}"\n'
             'parameters = { y0 = 1.0 }\n'
             '[[connections]]\nfrom = "integ.y"\nto = "m.Float64_continuous_input"\n'
             '[[connections]]\nfrom = "m.Float64_continuous_output"\nto = "integ.u"\n')
    manifest = tmp_path / "loop.toml"
    manifest.write_text(f'[simulation]\nstop = 1.0\nstep = 0.1\nalgorithm = "{algorithm}"\n'
                        f'[components.m]\nfmu = "{fmu}"\n{extra}'
                        '[record]\nvariables = ["integ.y", "m.Float64_continuous_output"]\n')
    _, jobs, _ = prepare(manifest)
    system = jobs[0].plan
    assert system.models["m"].integration is not None  # ME-only: integrated
    rows = []
    simulate(system, [RowObserver(lambda row: rows.append(list(row)))], fast=fast)
    rows = np.array(rows)
    if algorithm == "gauss-seidel":
        expected = 1.1 ** np.arange(len(rows))
        assert np.array_equal(rows[:, 2], rows[:, 1])  # the output of this instant
    else:
        expected = [1.0, 1.0]
        while len(expected) <= len(rows):
            expected.append(expected[-1] + 0.1 * expected[-2])
        expected = np.array(expected[1:])
        assert np.array_equal(rows[1:, 2], rows[:-1, 1])  # the output of the last step
    assert np.allclose(rows[:, 1], expected, rtol=1e-12, atol=0)


# the choice of interface, and bad input -----------------------------------------------

def test_interface_choice(reference, tmp_path):
    """An FMU with both interfaces runs as co-simulation unless asked; a
    model-exchange-only one is integrated with the default solver."""
    both = read_model(reference["2"] / "Dahlquist.fmu")
    assert both.interfaces == ("co-simulation", "model-exchange")
    assert both.integration is None
    chosen = use_model_exchange(both, solver="scipy", tolerance=1e-7)
    assert (chosen.integration.solver, chosen.integration.tolerance) == ("scipy", 1e-7)
    assert both.integration is None  # the shared ModelInfo is left as it was
    only = read_model(me_only(reference, "3", "Dahlquist", tmp_path))
    assert only.interfaces == ("model-exchange",)
    assert only.integration.solver == "cvode"


def test_select_interface(reference, tmp_path):
    """A component's interface / solver / tolerance: None keeps the FMU's own choice,
    "co-simulation" and "model-exchange" pick one; what cannot be honoured is one line."""
    both = read_model(reference["2"] / "Dahlquist.fmu")
    only = read_model(me_only(reference, "2", "Dahlquist", tmp_path))
    assert select_interface(both) is both
    assert select_interface(both, "co-simulation") is both
    assert select_interface(both, "model-exchange").integration.solver == "cvode"
    assert select_interface(only, solver="scipy").integration.solver == "scipy"
    assert select_interface(only, tolerance=1e-8).integration.tolerance == 1e-8
    for args, message in [((only, "co-simulation"), "has no co-simulation interface"),
                          ((both, "fmu"), "interface 'fmu' is not one of"),
                          ((both, None, "scipy"), "apply to a component integrated")]:
        with pytest.raises(ModelError) as raised:
            select_interface(*args)
        assert message in str(raised.value) and "\n" not in str(raised.value)


@pytest.mark.parametrize("case,message", [
    ("cs-only", "has no Model Exchange interface"),
    ("tool", "needsExecutionTool"),
    ("solver", "solver 'rk4' is not one of 'cvode', 'scipy'"),
    ("tolerance", "tolerance 0.0 is not a number between 0 and 1"),
])
def test_refusals_are_one_line(reference, tmp_path, case, message):
    source = reference["2"] / "Dahlquist.fmu"
    kwargs = {}
    if case == "cs-only":
        fmu = _without(source, tmp_path / "cs.fmu", "ModelExchange")
    elif case == "tool":
        fmu = _without(source, tmp_path / "tool.fmu", "CoSimulation",
                       lambda text: text.replace("<ModelExchange",
                                                 '<ModelExchange needsExecutionTool="true"'))
    else:
        fmu = source
        kwargs = {"solver": "rk4"} if case == "solver" else {"tolerance": 0.0}
    with pytest.raises(ModelError) as raised:
        use_model_exchange(read_model(fmu), **kwargs)
    text = str(raised.value)
    assert message in text and "\n" not in text and str(fmu.name) in text


def test_a_model_exchange_only_fmu_needing_its_tool_is_refused_in_one_line(
        reference, tmp_path, capsys):
    """``agv-cosim run`` of a model-exchange-only FMU with needsExecutionTool="true":
    refused before any run, one line naming the FMU and the reason, exit 2."""
    from agv_cosim import cli

    fmu = _without(reference["2"] / "Dahlquist.fmu", tmp_path / "tool.fmu", "CoSimulation",
                   lambda text: text.replace("<ModelExchange",
                                             '<ModelExchange needsExecutionTool="true"'))
    manifest = tmp_path / "tool.toml"
    manifest.write_text(f'[simulation]\nstop = 1.0\nstep = 0.1\n[components.m]\n'
                        f'fmu = "{fmu}"\n')
    code = cli.main(["run", str(manifest), "--out", str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert "a model-exchange-only FMU the orchestrator cannot integrate" in err[0]
    assert "needsExecutionTool" in err[0] and "tool.fmu" in err[0]


def test_an_fmu_that_never_leaves_event_mode_fails_in_one_line(reference, tmp_path,
                                                             monkeypatch):
    """From t = 2 s Stair's event iteration is made to ask for new discrete states
    forever: the run fails after MAX_EVENT_ITERATIONS iterations, naming the component,
    the call and the time; the rows before are kept."""
    from fmpy.fmi2 import FMU2Model

    real = FMU2Model.newDiscreteStates
    clock = {"t": 0.0}
    real_set_time = FMU2Model.setTime

    def set_time(self, time):
        clock["t"] = time
        return real_set_time(self, time)

    def stuck(self):
        answer = real(self)
        return (True, *answer[1:]) if clock["t"] >= 2.0 else answer

    monkeypatch.setattr(FMU2Model, "setTime", set_time)
    monkeypatch.setattr(FMU2Model, "newDiscreteStates", stuck)
    rows = []
    with pytest.raises(SimulationError) as raised:
        manifest = tmp_path / "s.toml"
        manifest.write_text(f'[simulation]\nstop = 10.0\nstep = 0.2\n[components.m]\n'
                            f'fmu = "{me_only(reference, "2", "Stair", tmp_path)}"\n')
        _, jobs, _ = prepare(manifest)
        simulate(jobs[0].plan, [RowObserver(lambda row: rows.append(list(row)))])
    text = str(raised.value)
    assert text == ("component 'm': the FMU did not leave event mode at t=2.0 s: "
                    "fmi2NewDiscreteStates still asked for new discrete states after "
                    f"{MAX_EVENT_ITERATIONS} event iterations")
    assert [r[0] for r in rows] == pytest.approx([0.2 * k for k in range(10)])


@pytest.mark.parametrize("solver,reason", [("cvode", "CVODE error"),
                                           ("scipy", "solve_ivp (LSODA)")])
def test_a_solver_failure_mid_run_keeps_the_rows(reference, tmp_path, monkeypatch, solver,
                                                 reason):
    """VanDerPol's derivatives turn NaN from t = 1 s: the solver fails, and the run ends
    with a SimulationError naming component, solver, time and the solver's reason; the
    rows up to the failing step are kept."""
    from ctypes import POINTER, c_double, cast

    from fmpy.fmi2 import FMU2Model

    clock = {"t": 0.0}
    real_set_time, real_dx = FMU2Model.setTime, FMU2Model.getDerivatives

    def set_time(self, time):
        clock["t"] = time
        return real_set_time(self, time)

    def derivatives(self, dx, nx):
        status = real_dx(self, dx, nx)
        if clock["t"] > 1.0:
            values = cast(dx, POINTER(c_double))
            for i in range(nx):
                values[i] = float("nan")
        return status

    monkeypatch.setattr(FMU2Model, "setTime", set_time)
    monkeypatch.setattr(FMU2Model, "getDerivatives", derivatives)
    rows = []
    manifest = tmp_path / "v.toml"
    manifest.write_text(f'[simulation]\nstop = 3.0\nstep = 0.1\n[components.m]\n'
                        f'fmu = "{me_only(reference, "2", "VanDerPol", tmp_path)}"\n')
    _, jobs, _ = prepare(manifest)
    system = jobs[0].plan
    system.models["m"] = use_model_exchange(system.models["m"], solver=solver)
    with pytest.raises(SimulationError) as raised:
        simulate(system, [RowObserver(lambda row: rows.append(list(row)))])
    text = str(raised.value)
    assert text.startswith("component 'm': the ") and "solver failed at t=" in text
    assert "(step from t=1.0 s)" in text and reason in text and "\n" not in text
    assert len(rows) == 11 and rows[-1][0] == 1.0


def test_the_unit_is_the_model_exchange_one(reference, tmp_path):
    """build_units gives a model-exchange-only FMU a ModelExchangeUnit, stepped through
    the master's Stepper like any unit (fast path too)."""
    from agv_cosim.execution.instance import FmuInstance
    from agv_cosim.execution.units import build_units

    info = read_model(me_only(reference, "3", "Dahlquist", tmp_path))
    instance = FmuInstance(info, "m")
    try:
        units = build_units({"m": info}, {"m": instance}, [], ["m.x"], [0, 0, 0],
                            ModelExchangeUnit)
        assert isinstance(units["m"], ModelExchangeUnit)
        assert units["m"].step_extra is None
    finally:
        instance.close()


def test_a_solver_failure_in_a_sweep(reference, tmp_path, capsys):
    """``agv-cosim run`` of a sweep over Dahlquist's k: k = -1000 makes x = exp(1000 t)
    overflow, CVODE gives up (its reason in the one line), that run ends partial with its
    rows up to the failing step kept, and the run with k = 1 completes."""
    import csv

    from agv_cosim import cli

    fmu = me_only(reference, "2", "Dahlquist", tmp_path)
    manifest = tmp_path / "sweep.toml"
    manifest.write_text(f'[simulation]\nstop = 2.0\nstep = 0.1\n[components.m]\n'
                        f'fmu = "{fmu}"\n[sweep]\n"m.k" = [1.0, -1000.0]\n')
    out = tmp_path / "out"
    code = cli.main(["run", str(manifest), "--out", str(out), "--jobs", "1", "--quiet"])
    assert code == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert any("component 'm': the CVODE solver failed at t=" in line
               and "mxstep steps taken" in line for line in err), err
    with open(out / "summary.csv", newline="") as stream:
        status = {row["run"]: row["status"] for row in csv.DictReader(stream)}
    assert status == {"base__m.k=1.0": "complete", "base__m.k=-1000.0": "partial"}
    with open(out / "base__m.k=-1000.0" / "timeseries.csv", newline="") as stream:
        rows = list(csv.reader(stream))[1:]
    assert len(rows) >= 5 and float(rows[-1][0]) < 1.0
    assert float(rows[1][1]) == pytest.approx(math.exp(100.0), rel=1e-2)
