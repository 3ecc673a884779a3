"""Integration tier: the Reference FMUs' ``fmusim`` as a host of the FMI 2.0 FMUs and their
FMI 3.0 twins.

fmusim is built here, into a temporary folder, from the shared Reference FMU sources, its
state-file bug fixed in the copy (tests/interop/fmusim_host.py, the ``fmusim`` fixture).

fmusim is a C program with no Python: each FMU's loader finds the Python of this test's
virtual environment through ``VIRTUAL_ENV`` (as an activated venv exports it), no
LD_PRELOAD, no PYTHONPATH. Every FMU runs its reference experiment (the shipped input
CSV, the default experiment's stop time and step) and must reproduce its shipped reference
output within 1e-12 + 1e-9 |ref| (fmusim prints 16 significant digits) and exit with
status 0. Under valgrind, fmusim with an FMU reports no error in code that is ours or
that runs at exit. A state saved at 1 s and restored in a new process continues to the
reference.
"""

import re
import shutil

import numpy as np
import pytest

from agv_cosim.build import default_components_dir, slave_scripts

from fmusim_host import ATOL, RTOL, assert_matches, run_fmusim, unavailable

pytestmark = pytest.mark.interop

SCRIPTS = [p.stem for p in slave_scripts(default_components_dir())]


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
        unavailable("valgrind is not installed (`make test-deps`)")
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
