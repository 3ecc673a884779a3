"""Shared fixtures and the test tiers (see tests/README.md).

The component FMUs are built once per test session into a temp folder; under pytest-xdist
once for all workers (a file lock in the session's base temp folder, which the workers'
own temp folders sit in).

Tiers: every test not marked ``slow`` is the fast tier (``make test-fast``, ``-m "not
slow"``). A test is slow when it is decorated so, when its file is listed in ``TIERS``
below (whole files: the seed reproductions, the interop cross-checks), when its id is in
``SLOW``, or when it uses the ``component_fmus`` fixture (building every component FMU
takes tens of seconds); ``seed`` and ``interop`` imply ``slow``.
"""

import json
import os
import shutil
from pathlib import Path

import pytest
from filelock import FileLock

from agv_cosim.build import build_fmus, default_components_dir, slave_scripts

#: test file -> markers of every test in it
TIERS = {
    "test_seed000.py": ("seed",),
    "test_seed001.py": ("seed",),
    "test_seed002.py": ("seed",),
    "test_seed003.py": ("seed",),
    "test_seed004.py": ("seed",),
    "test_fmu_conformance.py": ("interop",),   # libcosim, fmpy validation
    "test_fmu_hosts.py": ("interop",),         # a C host compiled here
    "test_reference_fmus.py": ("interop",),    # Reference FMUs built with cmake
}

#: single slow tests in otherwise fast files (file relative to tests/ :: test name, without
#: parameters). Each took 4-11 s in a serial run on a loaded 2-core machine.
SLOW = {
    "orchestrator/test_runner.py::test_sweep_serial_equals_parallel",
    "orchestrator/test_signals.py::test_sigkilled_parent_children_stop_and_next_run_cleans",
    "orchestrator/test_signals.py::test_signal_to_the_parent_ends_everything",
    "orchestrator/test_signals.py::test_no_process_left_after_a_normal_exit",
    "orchestrator/test_bounded_memory.py::test_parent_reads_runs_in_chunks_into_bounded_lines",
    "test_actuator.py::test_fmus_declare_truthful_dependencies",
    "test_actuator.py::test_fmu_a_delay_and_c_step_through_fmpy",
    "test_build.py::test_failing_runs_do_not_corrupt_the_orchestrator",
    "test_preview_lq.py::test_fmu_matches_the_core",
    "test_preview_lq.py::test_literal_eq12_needs_a_lagging_actuator",
    "test_metrics_streaming.py::test_streamed_equals_reference_at_every_chunk_boundary",
}


def pytest_collection_modifyitems(config, items):
    tests_dir = Path(__file__).resolve().parent
    for item in items:
        path = Path(str(item.path)).resolve()
        for name in TIERS.get(path.name, ()):
            item.add_marker(name)
        rel = path.relative_to(tests_dir).as_posix() if path.is_relative_to(tests_dir) else ""
        if f"{rel}::{item.originalname}" in SLOW:
            item.add_marker("slow")
        if (item.get_closest_marker("seed") or item.get_closest_marker("interop")
                or "component_fmus" in getattr(item, "fixturenames", ())):
            item.add_marker("slow")


def session_folder(tmp_path_factory, name, make):
    """``make(folder)`` run once per test session, for every xdist worker; returns folder.

    The folder sits in the folder every worker's base temp folder is in (the session's
    base temp folder when not under xdist); a file lock lets the first caller make it and
    the others wait for it. ``make`` that raises leaves no completion mark: the next
    caller tries again (and fails the same way, with its own traceback).
    """
    base = tmp_path_factory.getbasetemp()
    root = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    folder = root / name
    with FileLock(str(folder) + ".lock"):
        done = folder / ".complete"
        if not done.is_file():
            shutil.rmtree(folder, ignore_errors=True)
            folder.mkdir()
            make(folder)
            done.touch()
    return folder


@pytest.fixture(scope="session")
def component_fmus(tmp_path_factory):
    """Build every component FMU into a session temp folder; map script stem -> FMU path."""
    def make(folder):
        results = build_fmus(folder, slave_scripts(default_components_dir()))
        (folder / "fmus.json").write_text(json.dumps(
            {result.script.stem: result.fmu.name for result in results}))

    out = session_folder(tmp_path_factory, "component_fmus", make)
    return {stem: out / name for stem, name in
            json.loads((out / "fmus.json").read_text()).items()}
