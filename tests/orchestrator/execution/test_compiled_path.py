"""The compiled call path (agv_cosim/execution/_fmicall.c, built by
agv_cosim.execution.compiled): the same bytes as the ctypes path, stretches of macro steps
in C, the ctypes path when the extension is switched off or cannot be built, and failures
inside a stretch reported as before, with the rows recorded before them."""

import ctypes
import shutil
from multiprocessing.sharedctypes import RawArray
from pathlib import Path

import pytest

from agv_cosim.execution import compiled, simulate
from agv_cosim.execution.algorithm import Stepper
from agv_cosim.pipeline import prepare
from agv_cosim.workers.job import run_job

pytestmark = pytest.mark.slow  # seconds: builds the test FMUs

from test_fastpath import STOP, SYSTEM  # noqa: E402

FAILING = """
name = "failing"
[simulation]
stop = 1.0
step = 0.01
algorithm = "{algorithm}"
[components.src]
fmu = "{fmus[agv_test_source]}"
parameters = {{ slope = 1.0 }}
[components.f]
fmu = "{fmus[agv_test_fail]}"
parameters = {{ fail_time = 0.337 }}
[components.n]
fmu = "{fmus[agv_test_nan]}"
parameters = {{ nan_time = {nan_time} }}
[components.gain]
fmu = "{fmus[agv_test_gain]}"
[[connections]]
from = "src.y"
to = "f.u"
[[connections]]
from = "n.y"
to = "gain.u"
[record]
interval = 0.1
"""


def _manifest(tmp_path, text, fmus, algorithm, **extra):
    table = tmp_path / "replay.csv"
    table.write_text("time,a\n0,0\n1,4\n2,-1\n")
    path = tmp_path / f"{algorithm}.toml"
    path.write_text(text.format(algorithm=algorithm, fmus=fmus, table=table, **extra))
    (job,) = prepare(path)[1]
    return job


@pytest.fixture
def stretches(monkeypatch):
    """Counts the macro steps the compiled loop ran (stretch calls, steps)."""
    module = compiled.module()
    if module is None:
        pytest.fail(f"the compiled call path is not available: {compiled.why_not()}")
    count = [0, 0]
    real = module.run_stretch

    def counting(*args):
        ran = real(*args)
        count[0] += 1
        count[1] += ran
        return ran

    monkeypatch.setattr(module, "run_stretch", counting)
    return count


def _run(job, folder, monkeypatch, off, track=None):
    """run_job into ``folder`` with the compiled path on or off; (result, csv bytes)."""
    with monkeypatch.context() as patch:
        if off:
            patch.setenv(compiled.DISABLE, "1")
        else:
            patch.delenv(compiled.DISABLE, raising=False)
        result = run_job(job, folder, track=track)
    return result, (folder / "timeseries.csv").read_bytes()


@pytest.mark.parametrize("text", [SYSTEM, STOP], ids=["paths", "stop"])
@pytest.mark.parametrize("algorithm", ["gauss-seidel", "jacobi"])
@pytest.mark.parametrize("shared_track", [False, True], ids=["list", "shared"])
def test_compiled_and_ctypes_paths_write_the_same_bytes(fmus, tmp_path, monkeypatch,
                                                        stretches, text, algorithm,
                                                        shared_track):
    job = _manifest(tmp_path, text, fmus, algorithm)
    track = RawArray("d", 3) if shared_track else None
    plain, plain_csv = _run(job, tmp_path / "ctypes", monkeypatch, off=True, track=track)
    plain_track = list(track) if shared_track else None
    assert stretches == [0, 0]
    fast, fast_csv = _run(job, tmp_path / "compiled", monkeypatch, off=False, track=track)
    assert plain["status"] == fast["status"] == "complete"
    assert fast_csv == plain_csv and fast["rows"] == plain["rows"] > 3
    # most macro steps ran in C: all but those of an event (paths: 2) and the one that
    # brought the stop request (stop: its row is read in Python)
    steps = round(job.plan.stop / job.plan.step)
    assert stretches[0] > 3
    if text is STOP:
        assert fast["rows"] == 4 and stretches[1] == 3  # d stops after the step to 0.3
    else:
        assert stretches[1] == steps - 2
    if shared_track:  # the C code wrote the shared doubles as the Python code does
        assert list(track) == plain_track
        assert track[2] == (0.4 if text is STOP else job.plan.stop)


def test_the_units_run_as_compiled_programs(fmus, tmp_path):
    job = _manifest(tmp_path, SYSTEM, fmus, "gauss-seidel")
    made = []
    original = Stepper.__init__

    def spy(self, *args, **kwargs):
        original(self, *args, **kwargs)
        made.append(self)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(Stepper, "__init__", spy)
        simulate(job.plan, fast=True)
        patch.setenv(compiled.DISABLE, "1")
        simulate(job.plan, fast=True)
    assert type(made[0].step).__name__ == "Program" and made[0].compiled is made[0].step
    assert made[1].compiled is None and type(made[1].step).__name__ == "function"


def test_without_the_extension_the_ctypes_path_runs(fmus, tmp_path, monkeypatch):
    job = _manifest(tmp_path, SYSTEM, fmus, "gauss-seidel")
    _, expected = _run(job, tmp_path / "compiled", monkeypatch, off=False)
    # switched off by the environment
    monkeypatch.setenv(compiled.DISABLE, "1")
    assert compiled.module() is None and not compiled.available()
    assert compiled.why_not() == f"switched off by {compiled.DISABLE}"
    monkeypatch.delenv(compiled.DISABLE)
    # cannot be built: no compiler, nothing cached
    monkeypatch.setattr(compiled, "_LOADED", [])
    monkeypatch.setattr(compiled, "_REASON", [])
    monkeypatch.setenv("AGV_COSIM_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(shutil, "which", lambda name: None)
    assert compiled.module() is None
    assert compiled.why_not() == "RuntimeError: no C compiler (gcc) on PATH"
    result = run_job(job, tmp_path / "fallback")
    assert result["status"] == "complete"
    assert (tmp_path / "fallback" / "timeseries.csv").read_bytes() == expected


def test_the_extension_is_built_into_the_cache_once(tmp_path, monkeypatch):
    monkeypatch.setattr(compiled, "_LOADED", [])
    monkeypatch.setattr(compiled, "_REASON", [])
    monkeypatch.setenv("AGV_COSIM_CACHE", str(tmp_path / "cache"))
    module = compiled.module()
    assert module is not None, compiled.why_not()
    (built,) = (tmp_path / "cache").iterdir()  # nothing but the extension is left
    assert built.name.startswith("_fmicall-")
    monkeypatch.setattr(compiled, "_LOADED", [])
    monkeypatch.setattr(shutil, "which", lambda name: None)  # no rebuild: no compiler
    assert compiled.module() is not None


@pytest.mark.parametrize("algorithm", ["gauss-seidel", "jacobi"])
@pytest.mark.parametrize("nan_time", [2.0, 0.253], ids=["fails", "nan"])
def test_a_failure_inside_a_stretch_keeps_its_rows_and_reason(fmus, tmp_path, monkeypatch,
                                                              stretches, algorithm,
                                                              nan_time):
    job = _manifest(tmp_path, FAILING, fmus, algorithm, nan_time=nan_time)
    plain, plain_csv = _run(job, tmp_path / "ctypes", monkeypatch, off=True)
    fast, fast_csv = _run(job, tmp_path / "compiled", monkeypatch, off=False)
    assert stretches[1] >= 20  # two stretches of 10 steps returned, the third raised
    assert fast["status"] == plain["status"] == "partial"
    assert fast["error"] == plain["error"] and "\n" not in fast["error"]
    assert fast_csv == plain_csv
    if nan_time == 2.0:  # rows 0 .. 0.3 s, then the doStep from 0.34 s fails
        assert fast["rows"] == 4
        assert fast["error"].startswith("component 'f': fmi2DoStep returned status 4 "
                                        "(Fatal) during doStep at t=0.34 s")
        assert "deliberate failure" in fast["error"]
    else:  # rows 0 .. 0.2 s, then n's output read at 0.26 s is NaN
        assert fast["rows"] == 3
        assert fast["error"] == "component 'n': output 'y' is nan at t=0.26 s"


def test_a_program_refuses_malformed_operations():
    module = compiled.module()
    assert module is not None, compiled.why_not()
    args = ([], None, [0.0, 0.0, 0.0], None, None, [], ())
    with pytest.raises(ValueError, match="bad operation"):
        module.Program([(99, 0, 0.0, None, None, None, 0, None, 0, None, 0, 0, None, None,
                         "", None, None)], *args[1:])
    with pytest.raises(ValueError, match="without a function"):
        module.Program([(3, 0, 0.0, None, None, None, 0, None, 0, None, 0, 0, None, None,
                         "", None, None)], *args[1:])
    buf = (ctypes.c_double * 1)(1.0)
    copy = module.Program([(2, 0, 0.0, None, None, None, 0, ctypes.addressof(buf), 0, None,
                            0, 8, ctypes.addressof(buf), None, "", None, None)], *args[1:])
    copy(0.0)  # a copy onto itself: nothing changes
    assert buf[0] == 1.0


#: the test FMUs built as FMI 3.0 twins (source and types are FMI 2.0 only)
FMI3_TWINS = ("agv_test_gain", "agv_test_integrator", "agv_test_pair", "agv_test_fail",
              "agv_test_nan")


@pytest.fixture(scope="module")
def mixed(fmus, tmp_path_factory):
    """The test FMUs with FMI 3.0 twins where they have one (FMI 2.0 otherwise)."""
    from agv_cosim.build import build_one

    sources = Path(__file__).resolve().parents[2] / "fmu_src"
    out = tmp_path_factory.mktemp("fmi3_twins")
    return dict(fmus, **{stem: build_one(sources / f"{stem}.py", out,
                                         fmi_version=3).fmu for stem in FMI3_TWINS})


@pytest.mark.parametrize("text", [SYSTEM, FAILING], ids=["paths", "failing"])
@pytest.mark.parametrize("algorithm", ["gauss-seidel", "jacobi"])
def test_fmi3_units_run_compiled_with_the_same_bytes(mixed, tmp_path, monkeypatch,
                                                    stretches, text, algorithm):
    job = _manifest(tmp_path, text, mixed, algorithm, nan_time=0.253)
    assert {m.fmi_version for m in job.plan.models.values() if m.table is None} == \
        {"2.0", "3.0"}
    plain, plain_csv = _run(job, tmp_path / "ctypes", monkeypatch, off=True)
    fast, fast_csv = _run(job, tmp_path / "compiled", monkeypatch, off=False)
    assert stretches[1] >= 20
    assert fast_csv == plain_csv
    assert (fast["status"], fast["error"], fast["rows"]) == \
        (plain["status"], plain["error"], plain["rows"])
    if text is FAILING:
        assert fast["error"] == "component 'n': output 'y' is nan at t=0.26 s"
