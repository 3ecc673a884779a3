"""Integration tier: the FMUs run in hosts that are not Python, and every host exits cleanly.

A small FMI 2.0 host in C (tests/interop/c_host/fmi2_host.c, compiled here with gcc against fmpy's
FMI headers) loads each FMU's binary with dlopen, no LD_PRELOAD, and a minimal
environment. The FMU's loader (components/fmu_loader) must find a Python on this machine
the way its C source documents (here: the virtual environment named in VIRTUAL_ENV, as
activating it does; AGV_COSIM_PYTHON; PATH), report a missing Python as fmi2Error, and let
the host exit with status 0.
"""

import math
import re
import os
import shutil
import subprocess
import sys
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu

from agv_cosim.build import default_components_dir, host_python, slave_scripts

pytestmark = pytest.mark.interop

SCRIPTS = [p.stem for p in slave_scripts(default_components_dir())]
HOST_SOURCE = Path(__file__).parent / "c_host" / "fmi2_host.c"
THREADS_SOURCE = Path(__file__).parent / "c_host" / "fmi2_threads.c"

#: What a plain C program started from a service or a desktop launcher has: no Python
#: variables, no venv on PATH, no preloaded libpython. The BLAS settings are kept: they
#: pick OpenBLAS's kernels (OPENBLAS_CORETYPE), and another kernel changes the last bit
#: of scipy's Riccati solution (measured: 1.1e-16 in the preview controller's alpha_ref).
BARE_ENV = {"PATH": "/usr/bin:/bin", "LANG": "C",
            **{k: v for k, v in os.environ.items()
               if k.startswith(("OPENBLAS_", "OMP_", "MKL_"))}}
#: The same with this test's virtual environment active (what `activate` exports, less PATH).
VENV_ENV = {**BARE_ENV, "VIRTUAL_ENV": sys.prefix}


@pytest.fixture(scope="module")
def c_host(tmp_path_factory):
    """The C host, compiled into a temp folder."""
    if not Path(host_python()["libpython"]).is_file():
        pytest.skip(f"this Python has no shared library ({host_python()['libpython']}): "
                    "a C host cannot start it (a Python built with --enable-shared can)")
    out = tmp_path_factory.mktemp("c_host") / "fmi2_host"
    headers = Path(fmpy.__file__).parent / "c-code"
    subprocess.run(["gcc", "-O1", "-Wall", "-Werror", f"-I{headers}", "-o", str(out),
                    str(HOST_SOURCE), "-ldl"], check=True, capture_output=True, text=True)
    return out


@pytest.fixture(scope="module")
def threads_host(tmp_path_factory):
    """The threaded C host (c_host/fmi2_threads.c), compiled into a temp folder."""
    if not Path(host_python()["libpython"]).is_file():
        pytest.skip(f"this Python has no shared library ({host_python()['libpython']})")
    out = tmp_path_factory.mktemp("threads_host") / "fmi2_threads"
    headers = Path(fmpy.__file__).parent / "c-code"
    subprocess.run(["gcc", "-O1", "-Wall", "-Werror", f"-I{headers}", "-o", str(out),
                    str(THREADS_SOURCE), "-ldl", "-lpthread"], check=True,
                   capture_output=True, text=True)
    return out


@pytest.fixture(scope="module")
def unzipped(component_fmus, tmp_path_factory):
    """Every component FMU extracted once: name -> (folder, model description)."""
    root = tmp_path_factory.mktemp("unzipped")
    return {name: (fmpy.extract(str(fmu), unzipdir=str(root / name)),
                   read_model_description(str(fmu)))
            for name, fmu in component_fmus.items()}


def _inputs(md):
    """Each Real input set to a distinct non-zero value (the slave must really use them)."""
    inputs = [v for v in md.modelVariables if v.causality == "input" and v.type == "Real"]
    return {v.name: 0.05 * (k + 1) for k, v in enumerate(inputs)}


def run_c_host(c_host, folder, md, stop, step, start_values, env=None, timeout=120):
    """Run the C host on an extracted FMU; (completed process, {output name: array})."""
    outputs = [v for v in md.modelVariables if v.causality == "output" and v.type == "Real"]
    by_name = {v.name: v for v in md.modelVariables}
    settings = [f"{by_name[n].valueReference}={value!r}" for n, value in start_values.items()]
    command = [str(c_host), str(folder), md.coSimulation.modelIdentifier, md.guid,
               repr(stop), repr(step), ",".join(str(v.valueReference) for v in outputs),
               *settings]
    done = subprocess.run(command, capture_output=True, text=True, timeout=timeout,
                          env=VENV_ENV if env is None else env)
    table = {}
    if done.returncode == 0:
        rows = np.array([[float(x) for x in line.split()] for line in done.stdout.splitlines()])
        table = {"time": rows[:, 0]}
        table.update({v.name: rows[:, k + 1] for k, v in enumerate(outputs)})
    return done, table


@pytest.mark.parametrize("name", SCRIPTS)
def test_every_fmu_runs_in_a_plain_c_host_like_in_fmpy(c_host, unzipped, component_fmus, name):
    """Same outputs, bit for bit, from the C host (no Python of its own) and from fmpy."""
    folder, md = unzipped[name]
    stop, step = 0.5, 0.01
    start_values = _inputs(md)
    done, ours = run_c_host(c_host, folder, md, stop, step, start_values)
    assert done.returncode == 0, done.stderr[-2000:]
    reference = simulate_fmu(str(component_fmus[name]), stop_time=stop, step_size=step,
                             output_interval=step, start_values=start_values,
                             output=[n for n in ours if n != "time"])
    assert len(ours["time"]) == len(reference) == 51
    for column in reference.dtype.names:
        assert np.array_equal(ours[column], reference[column]), column


def test_vehicle_in_the_c_host_exits_cleanly_every_time(c_host, unzipped):
    """Ten processes, each loads, runs, frees and unloads the vehicle: exit status 0 each,
    and the turn is the exact arc (alpha = 0.2 rad, v = v0 + dv = 1.5 m/s, L = 1 m: yaw
    rate v tan(alpha) / L; 1e-12 rad: the integration is exact)."""
    folder, md = unzipped["agv_vehicle"]
    for k in range(10):
        done, table = run_c_host(c_host, folder, md, 1.0, 0.1, {"alpha": 0.2, "dv": 0.5})
        assert done.returncode == 0, f"run {k}: {done.returncode} {done.stderr[-1000:]}"
        assert table["heading"][-1] == pytest.approx(1.5 * math.tan(0.2), abs=1e-12)


def test_a_drive_beyond_its_friction_is_an_fmi2_error_in_the_c_host(c_host, unzipped):
    """AgvDynamicVehicle (four wheels, rear drive, cg 0.6 m high) at 4 m/s with the wheel
    held at 0.45 rad: the step from t = 0.12 s needs more drive force than the rear
    wheels' friction; fmi2DoStep returns fmi2Error (a modelling limit, not Fatal) and its
    one-line reason reaches the host's logger; the host exits through its own error
    path."""
    folder, md = unzipped["agv_dynamic_vehicle"]
    done, _ = run_c_host(c_host, folder, md, 1.0, 0.01,
                         {"v0": 4.0, "cg_height": 0.6, "alpha": 0.45})
    assert done.returncode == 1, done.stderr[-2000:]
    assert "fmi2DoStep(c, t, (k + 1) * step - t, fmi2True) returned status 3" in done.stderr
    logged = [line for line in done.stderr.splitlines()
              if line.startswith("[host] status 3 logStatusError: ")]
    assert len(logged) == 1, done.stderr[-2000:]
    assert ("AgvDynamicVehicle 'host': step at t=0.12 s failed: DriveLimitError: the rear "
            "axle's drive needs") in logged[0]
    assert "status 4" not in done.stderr


def test_missing_python_is_an_fmi2_error_not_a_dead_host(c_host, unzipped):
    folder, md = unzipped["agv_vehicle"]
    env = {**BARE_ENV, "AGV_COSIM_PYTHON": "/nonexistent/bin/python3"}
    done, _ = run_c_host(c_host, folder, md, 0.1, 0.1, {}, env=env)
    assert done.returncode == 1, done.stderr  # the host's own error exit, not a signal
    assert "status 3 logStatusError" in done.stderr  # fmi2Error through the host's logger
    assert "/nonexistent/bin/python3" in done.stderr and "AGV_COSIM_PYTHON" in done.stderr
    assert "fmi2Instantiate failed" in done.stderr


def test_host_python_variables_do_not_break_the_fmu(c_host, unzipped):
    """A bad PYTHONHOME used to kill the host inside fmi2Instantiate; the FMU's
    interpreter is isolated from the host's Python variables."""
    folder, md = unzipped["agv_vehicle"]
    env = {**VENV_ENV, "PYTHONHOME": "/nonexistent", "PYTHONPATH": "/nonexistent"}
    done, table = run_c_host(c_host, folder, md, 0.2, 0.1, {"alpha": 0.1}, env=env)
    assert done.returncode == 0, done.stderr[-2000:]
    assert table["heading"][-1] > 0.0


def test_the_python_can_be_named_and_is_then_used(c_host, unzipped, tmp_path):
    """AGV_COSIM_PYTHON wins over an active venv (here a bare one that would fail)."""
    bare = tmp_path / "bare"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(bare)], check=True)
    folder, md = unzipped["agv_vehicle"]
    env = {**BARE_ENV, "AGV_COSIM_PYTHON": sys.executable, "VIRTUAL_ENV": str(bare)}
    done, table = run_c_host(c_host, folder, md, 0.2, 0.1, {"alpha": 0.1}, env=env)
    assert done.returncode == 0, done.stderr[-2000:]
    assert f"started Python 3.{sys.version_info.minor}" in done.stderr
    assert "(named by AGV_COSIM_PYTHON)" in done.stderr


def test_without_a_named_python_the_one_on_path_is_used(c_host, unzipped):
    """No AGV_COSIM_PYTHON, no VIRTUAL_ENV: python3.<minor> on PATH (here the venv's bin
    first on PATH, as activating it does), with that venv's packages."""
    folder, md = unzipped["agv_vehicle"]
    env = {**BARE_ENV, "PATH": f"{Path(sys.executable).parent}:/usr/bin:/bin"}
    done, table = run_c_host(c_host, folder, md, 0.2, 0.1, {"alpha": 0.1}, env=env)
    assert done.returncode == 0, done.stderr[-2000:]
    assert f"(python3.{sys.version_info.minor} on PATH)" in done.stderr
    assert table["heading"][-1] > 0.0


def test_a_python_without_the_packages_is_reported(c_host, unzipped, tmp_path):
    """A named Python that lacks numpy/scipy: fmi2Instantiate fails with the import error
    in the log; the host survives and exits with its own status."""
    venv = tmp_path / "bare"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    folder, md = unzipped["agv_preview_lq"]
    env = {**BARE_ENV, "AGV_COSIM_PYTHON": str(venv / "bin" / "python")}
    done, _ = run_c_host(c_host, folder, md, 0.1, 0.1, {}, env=env)
    assert done.returncode == 1, done.stderr[-2000:]
    assert "No module named" in done.stderr
    assert "fmi2Instantiate failed" in done.stderr
    # and what to do about it: the FMU's requirement list, the Python, the variable
    assert f"{folder}/resources/requirements.txt" in done.stderr, done.stderr[-2000:]
    assert f"({venv / 'bin' / 'python'})" in done.stderr
    assert "AGV_COSIM_PYTHON" in done.stderr


def test_a_python_on_path_without_the_packages_names_the_requirements(c_host, unzipped,
                                                                      tmp_path):
    """A clean environment whose first python3 on PATH lacks the FMU's packages (a venv
    without any): fmi2Instantiate fails with the import error, then one message naming
    that Python, the FMU's resources/requirements.txt and AGV_COSIM_PYTHON."""
    venv = tmp_path / "bare"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    folder, md = unzipped["agv_preview_lq"]
    env = {**BARE_ENV, "PATH": f"{venv / 'bin'}:/usr/bin:/bin"}
    done, _ = run_c_host(c_host, folder, md, 0.1, 0.1, {}, env=env)
    assert done.returncode == 1, done.stderr[-2000:]
    assert "on PATH)" in done.stderr  # the rule that chose the Python (loggingOn)
    assert "ModuleNotFoundError: No module named" in done.stderr
    hint = next((line for line in done.stderr.splitlines() if "requirements.txt" in line),
                None)
    assert hint is not None, done.stderr[-2000:]
    assert f"{folder}/resources/requirements.txt" in hint
    assert f"({venv / 'bin' / f'python3.{sys.version_info.minor}'})" in hint
    assert "AGV_COSIM_PYTHON" in hint
    assert "status 4 logStatusFatal" in hint  # fmi2Fatal, as the import error itself


PYTHON_HOST = """
import sys
import fmpy
result = fmpy.simulate_fmu(sys.argv[1], stop_time=0.2, step_size=0.01,
                           start_values={"alpha": 0.2})
print(repr(float(result["heading"][-1])))
"""


def test_python_hosts_that_exit_normally_never_abort(component_fmus, tmp_path):
    """pythonfmu 0.7 alone aborts a Python host at exit now and then (a shared_ptr released
    twice); with the loader 30 processes that load, run, free and exit normally all
    return 0 with the same result."""
    script = tmp_path / "host.py"
    script.write_text(PYTHON_HOST)
    fmu = str(component_fmus["agv_vehicle"])
    codes, answers = [], set()
    for _ in range(30):
        done = subprocess.run([sys.executable, str(script), fmu], capture_output=True,
                              text=True, timeout=120)
        codes.append(done.returncode)
        answers.add(done.stdout.strip())
    assert codes == [0] * 30, codes
    assert len(answers) == 1


DOCS = Path(__file__).resolve().parents[2] / "docs" / "using-the-fmus.md"


def _doc_recipe():
    """The shell lines of docs/using-the-fmus.md's "A C host, in full"."""
    text = DOCS.read_text()
    section = text[text.index("### A C host, in full"):]
    start = section.index("```sh\n") + len("```sh\n")
    return section[start:section.index("```", start)]


def test_the_docs_c_host_recipe_runs_as_written(component_fmus, tmp_path):
    """The recipe's value references are those `agv-cosim list` shows, and its lines,
    run in a folder laid out like the checkout (.venv, tests/, fmus/), build the host,
    run the vehicle one second with alpha = 0.2 and print x, y, heading per step."""
    from agv_cosim.system.model import describe, read_model

    recipe = _doc_recipe()
    listing = describe(read_model(component_fmus["agv_vehicle"]))
    vr = {name: vr for vr, name in re.findall(r"vr=(\d+)\s+\S+\s+(\w+)", listing)}
    said = re.search(r"# value references: alpha = (\d+), x/y/heading = (\d+),(\d+),(\d+) "
                     r"\(`agv-cosim list fmus/AgvVehicle.fmu`", recipe)
    assert said is not None, recipe
    assert said.groups() == (vr["alpha"], vr["x"], vr["y"], vr["heading"])
    assert f" {vr['x']},{vr['y']},{vr['heading']} {vr['alpha']}=0.2" in recipe
    (tmp_path / ".venv").symlink_to(sys.prefix)
    (tmp_path / "tests").symlink_to(Path(__file__).resolve().parents[1])
    (tmp_path / "fmus").mkdir()
    shutil.copy2(component_fmus["agv_vehicle"], tmp_path / "fmus" / "AgvVehicle.fmu")
    done = subprocess.run(["bash", "-e", "-c", recipe], cwd=tmp_path, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    rows = [[float(x) for x in line.split()] for line in done.stdout.splitlines()
            if line.strip()]
    assert len(rows) >= 10 and {len(r) for r in rows} == {4}
    assert rows[-1][0] == pytest.approx(1.0) and rows[-1][3] > 0.0  # turned left


def run_threads_host(threads_host, folder, md, stop, step, start_values, instances, threads,
                     mode):
    """Run the threaded C host; (completed process, {instance: {output name: array}})."""
    outputs = [v for v in md.modelVariables if v.causality == "output" and v.type == "Real"]
    by_name = {v.name: v for v in md.modelVariables}
    settings = [f"{by_name[n].valueReference}={value!r}" for n, value in start_values.items()]
    command = [str(threads_host), str(folder), md.coSimulation.modelIdentifier, md.guid,
               repr(stop), repr(step), ",".join(str(v.valueReference) for v in outputs),
               str(instances), str(threads), mode, *settings]
    done = subprocess.run(command, capture_output=True, text=True, timeout=120, env=VENV_ENV)
    tables = {}
    if done.returncode == 0:
        rows = np.array([[float(x) for x in line.split()] for line in done.stdout.splitlines()])
        for k in range(instances):
            mine = rows[rows[:, 0] == k]
            tables[k] = {"time": mine[:, 1]}
            tables[k].update({v.name: mine[:, i + 2] for i, v in enumerate(outputs)})
    return done, tables


@pytest.mark.parametrize("name", SCRIPTS)
def test_fmus_stepped_from_a_thread_pool_match_a_single_thread(c_host, threads_host, unzipped,
                                                               name):
    """Three instances stepped by two worker threads in turn (each instance moves from
    thread to thread every step, two run at once; instantiated on one worker and freed on
    the other, or freed by the main thread after the workers have exited) give, bit for
    bit, what the single-threaded C host gives for each instance's inputs."""
    folder, md = unzipped[name]
    stop, step, instances = 0.3, 0.01, 3
    inputs = _inputs(md)
    expected = {}
    for k in range(instances):
        done, expected[k] = run_c_host(c_host, folder, md, stop, step,
                                       {n: v * (1 + 0.1 * k) for n, v in inputs.items()})
        assert done.returncode == 0, done.stderr[-2000:]
    for mode in ("pool", "exit-first"):
        done, tables = run_threads_host(threads_host, folder, md, stop, step, inputs,
                                        instances, 2, mode)
        assert done.returncode == 0, f"{mode}: {done.returncode} {done.stderr[-2000:]}"
        for k in range(instances):
            assert len(tables[k]["time"]) == 31
            for column, values in expected[k].items():
                assert np.array_equal(tables[k][column], values), (mode, k, column)


def test_a_pool_thread_keeps_its_python_thread_state(threads_host, unzipped):
    """After the first step, an FMI call on a host's worker thread takes the GIL with the
    thread state the bridge made for that thread: no thread state (and no frame stack
    mapped for it) per call. Measured: about one page fault per 4 calls when every call
    made and deleted a thread state, 0-1 per 100 calls with one per thread."""
    folder, md = unzipped["agv_vehicle"]
    done, _ = run_threads_host(threads_host, folder, md, 1.0, 0.01, {"alpha": 0.2}, 3, 2,
                               "pool")
    assert done.returncode == 0, done.stderr[-2000:]
    faults, calls = map(int, re.search(r"worker page faults (\d+) in (\d+) FMI calls",
                                       done.stderr).groups())
    assert calls == 3 * 99 * 2
    assert faults < calls / 20, f"{faults} page faults in {calls} calls"
