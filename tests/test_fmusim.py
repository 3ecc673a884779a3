"""Integration tier: the Reference FMUs' ``fmusim`` as a host of the FMI 2.0 FMUs and their
FMI 3.0 twins.

fmusim (Reference FMUs v0.0.39, BSD-2) is built here, into a temporary folder, from
``../shared/third-party/Reference-FMUs-v0.0.39`` (never copied into the repository) with
gcc against Debian's libxml2, minizip and sundials dev packages (``make test-deps``
installs them; ``make test`` depends on it). Its ``--final-fmu-state-file`` frees the saved
state with ``FMUState`` where ``&FMUState`` is meant (fmusim/FMIUtil.c, FMI 2.0 and 3.0);
the copy built here has that fixed.

fmusim is a C program with no Python: each FMU's loader finds the Python of this test's
virtual environment through ``VIRTUAL_ENV`` (as an activated venv exports it), no
LD_PRELOAD, no PYTHONPATH. Every FMU runs its reference experiment (the shipped input
CSV, the default experiment's stop time and step) and must reproduce its shipped reference
output within 1e-12 + 1e-9 |ref| (fmusim prints 16 significant digits) and exit with
status 0. Under valgrind, fmusim with an FMU reports no error in code that is ours or
that runs at exit. A state saved at 1 s and restored in a new process continues to the
reference.
"""

import csv
import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from agv_cosim.build import default_components_dir, slave_scripts

pytestmark = pytest.mark.interop

ROOT = Path(__file__).resolve().parent.parent
SOURCES = Path(os.environ.get("AGV_FMUSIM_SOURCES",
                              ROOT.parent / "shared" / "third-party" /
                              "Reference-FMUs-v0.0.39"))
SCRIPTS = [p.stem for p in slave_scripts(default_components_dir())]
RTOL, ATOL = 1e-9, 1e-12
REFERENCE_DIR = "extra/org.fmi-standard.fmi-ls-ref"

#: What fmusim needs from the machine (Debian packages, `make test-deps`).
LIBRARIES = ["-lxml2", "-lminizip", "-lz", "-lsundials_cvode", "-lsundials_nvecserial",
             "-lsundials_sunmatrixdense", "-lsundials_sunlinsoldense", "-ldl", "-lm"]
FMUSIM_SOURCES = ["csv.c", "FMIUtil.c", "FMIEuler.c", "FMICVode.c", "FMIModelDescription.c",
                  "FMIRecorder.c", "FMIZip.c", "FMISimulation.c", "FMIStaticInput.c",
                  "FMIBuildDescription.c", "FMI1CSSimulation.c", "FMI1MESimulation.c",
                  "FMI2CSSimulation.c", "FMI2MESimulation.c", "FMI3CSSimulation.c",
                  "FMI3MESimulation.c", "fmusim.c", "miniunzip.c", "../src/FMI.c",
                  "../src/FMI1.c", "../src/FMI2.c", "../src/FMI3.c",
                  "../src/structured_variable_name.yy.c",
                  "../src/structured_variable_name.tab.c"]
#: fmusim's host bug: the saved state is freed through its value, not its address.
STATE_BUG = [("FMI2FreeFMUstate(S, FMUState)", "FMI2FreeFMUstate(S, &FMUState)"),
             ("FMI3FreeFMUState(S, FMUState)", "FMI3FreeFMUState(S, &FMUState)")]

#: A C program's environment with this test's venv active (no Python variables otherwise).
HOST_ENV = {"PATH": "/usr/bin:/bin", "LANG": "C", "VIRTUAL_ENV": sys.prefix,
            **{k: v for k, v in os.environ.items()
               if k.startswith(("OPENBLAS_", "OMP_", "MKL_"))}}


def _unavailable(reason):
    """Skip on a developer machine; in CI (CI=true) a missing host is a failure."""
    if os.environ.get("CI"):
        pytest.fail(f"{reason} (CI must run the fmusim tests: `make test-deps`)")
    pytest.skip(reason)


@pytest.fixture(scope="module")
def fmusim(tmp_path_factory):
    """fmusim built from the shared sources, its state bug fixed in the copy."""
    if not (SOURCES / "fmusim" / "fmusim.c").is_file():
        _unavailable(f"fmusim sources not found at {SOURCES}")
    if shutil.which("gcc") is None:
        _unavailable("gcc is not installed")
    build = tmp_path_factory.mktemp("fmusim")
    for part in ("fmusim", "src", "include"):
        shutil.copytree(SOURCES / part, build / part)
    util = build / "fmusim" / "FMIUtil.c"
    text = util.read_text()
    for wrong, right in STATE_BUG:
        assert text.count(wrong) == 2, f"fmusim's FMIUtil.c changed: {wrong!r}"
        text = text.replace(wrong, right)
    util.write_text(text)
    target = build / "fmusim" / "fmusim"
    done = subprocess.run(["gcc", "-O1", "-w", "-I.", "-I../include", "-I/usr/include/libxml2",
                           "-I/usr/include/minizip", '-DFMUSIM_VERSION="0.0.39"',
                           # Debian's sundials is 6.4; fmusim calls the 7.x context API
                           "-DSUN_COMM_NULL=NULL", "-o", str(target), *FMUSIM_SOURCES,
                           *LIBRARIES], cwd=build / "fmusim", capture_output=True, text=True)
    if done.returncode != 0:
        if re.search(r"No such file|cannot find -l", done.stderr):
            _unavailable("fmusim cannot be built: libxml2/minizip/sundials dev packages "
                         "missing (`make test-deps`): " + done.stderr.strip().splitlines()[-1])
        pytest.fail(f"fmusim does not build:\n{done.stderr[-3000:]}")
    return target


def _reference(fmu, folder):
    """(input CSV or None, reference rows as a structured array) shipped in ``fmu``."""
    with zipfile.ZipFile(fmu) as archive:
        names = archive.namelist()
        out = next(n for n in names if n.startswith(REFERENCE_DIR) and n.endswith("_out.csv"))
        ins = [n for n in names if n.startswith(REFERENCE_DIR) and n.endswith("_in.csv")]
        archive.extract(out, folder)
        if ins:
            archive.extract(ins[0], folder)
    reference = np.genfromtxt(folder / out, delimiter=",", names=True)
    return (folder / ins[0] if ins else None), reference


def run_fmusim(fmusim, fmu, folder, *options, valgrind=None):
    """Run fmusim on ``fmu`` with the reference inputs; (process, output table)."""
    input_csv, reference = _reference(fmu, folder)
    output = folder / "out.csv"
    command = [str(fmusim), "--output-file", str(output), *options]
    if input_csv is not None:
        command += ["--input-file", str(input_csv)]
    command.append(str(fmu))
    done = subprocess.run([*(valgrind or []), *command], capture_output=True, text=True,
                          env=HOST_ENV, timeout=1800)
    table = None
    # under valgrind, 99 is valgrind's status for reported errors (the caller sorts them)
    if done.returncode in ((0, 99) if valgrind else (0,)) and output.is_file():
        with output.open() as handle:
            rows = list(csv.reader(handle))
        header = [h.strip('"') for h in rows[0]]
        values = np.array([[float(x) for x in row] for row in rows[1:]])
        table = {name: values[:, k] for k, name in enumerate(header)}
    return done, table, reference


def assert_matches(table, reference, since=None):
    """Every reference column equal within the tolerance (rows at or after ``since``)."""
    ref_time = reference["time"]
    keep = np.ones(len(ref_time), bool) if since is None else ref_time >= since - 1e-12
    assert np.allclose(table["time"], ref_time[keep], rtol=0, atol=1e-12)
    for name in reference.dtype.names[1:]:
        assert name in table, f"fmusim did not record {name}"
        assert np.allclose(table[name], reference[name][keep], rtol=RTOL, atol=ATOL), name


@pytest.mark.parametrize("name", SCRIPTS)
def test_fmi2_fmu_in_fmusim_matches_its_reference(fmusim, component_fmus, name, tmp_path):
    done, table, reference = run_fmusim(fmusim, component_fmus[name], tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    assert_matches(table, reference)


@pytest.mark.parametrize("name", SCRIPTS)
def test_fmi3_twin_in_fmusim_matches_its_reference(fmusim, twins, name, tmp_path):
    done, table, reference = run_fmusim(fmusim, twins[name], tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    assert_matches(table, reference)


@pytest.mark.parametrize("kind", ["fmi2", "fmi3"])
def test_a_state_saved_at_1_s_continues_to_the_reference_in_a_new_process(
        fmusim, component_fmus, twins, kind, tmp_path):
    """fmusim saves the serialised state at 1 s; a new fmusim process restores it and runs
    on to the stop time: its rows are the reference's from 1 s on. The steering actuator
    (a delay line and an integrator in its state) would start over if its state were
    lost."""
    fmu = (component_fmus if kind == "fmi2" else twins)["agv_steering_a"]
    state = tmp_path / "state.bin"
    first = tmp_path / "first"
    first.mkdir()
    done, _, _ = run_fmusim(fmusim, fmu, first, "--stop-time", "1",
                            "--final-fmu-state-file", str(state))
    assert done.returncode == 0, done.stderr[-2000:]
    assert state.stat().st_size > 0
    second = tmp_path / "second"
    second.mkdir()
    done, table, reference = run_fmusim(fmusim, fmu, second, "--start-time", "1",
                                        "--initial-fmu-state-file", str(state))
    assert done.returncode == 0, done.stderr[-2000:]
    assert_matches(table, reference, since=1.0)
    # the restored run is not the fresh one: a fresh start at 1 s departs from the reference
    fresh = tmp_path / "fresh"
    fresh.mkdir()
    done, fresh_table, _ = run_fmusim(fmusim, fmu, fresh, "--start-time", "1")
    assert done.returncode == 0, done.stderr[-2000:]
    columns = reference.dtype.names[1:]
    assert any(not np.allclose(fresh_table[c], table[c], rtol=RTOL, atol=ATOL)
               for c in columns)


#: valgrind reports in every Python process, none of them the FMUs' (see
#: benchmarks/check_exit_valgrind.py): glibc's loader reading ahead in strncmp / strlen
#: while it expands the rpaths of numpy's and scipy's extension modules.
KNOWN = re.compile(r"_dl_dst_count|_dl_dst_substitute|expand_dynamic_string_token|"
                   r"fillin_rpath|decompose_rpath|_dl_map_object|_dl_init_paths")


def _valgrind_errors(log):
    """The error records of a valgrind log that are not the known loader reports."""
    records = re.split(r"\n(?===\d+== \S)", log)
    errors = [r for r in records
              if re.search(r"Invalid (read|write|free)|uninitialised|Mismatched free|"
                           r"Syscall param|Source and destination overlap", r)]
    return [r for r in errors if not KNOWN.search(r)]


def test_fmusim_exits_clean_under_valgrind(fmusim, twins, tmp_path):
    """The FMI 3.0 fixed-gain PD crashed fmusim at exit with pythonfmu3's own binary; now
    it leaves no error (0.2 s of its experiment; one FMU, since valgrind takes a minute
    or two: benchmarks/check_exit_valgrind.py checks more)."""
    if shutil.which("valgrind") is None:
        _unavailable("valgrind is not installed (`make test-deps`)")
    fmu = twins["agv_fixed_pd"]
    log = tmp_path / "valgrind.log"
    valgrind = ["valgrind", "--error-exitcode=99", f"--log-file={log}",
                "--errors-for-leak-kinds=none"]
    done, table, _ = run_fmusim(fmusim, fmu, tmp_path, "--stop-time", "0.2",
                                valgrind=valgrind)
    text = log.read_text()
    errors = _valgrind_errors(text)
    assert not errors, "\n\n".join(errors[:3])
    assert done.returncode in (0, 99), done.stderr[-2000:]
    assert table is not None and len(table["time"]) > 1
