"""Shared fixtures and the test tiers (see tests/README.md).

The component FMUs are built once per test session into a temp folder; under pytest-xdist
once for all workers (a file lock in the session's base temp folder, which the workers'
own temp folders sit in).

Tiers: every test not marked ``slow`` is the fast tier (``make test-fast``, ``-m "not
slow"``). A test is slow when it is marked so where it is written (``@pytest.mark.slow``, or
a file's ``pytestmark``: the seed reproductions are ``seed``, the interop cross-checks
``interop``), or when it uses a fixture in ``BUILDING_FIXTURES`` (building every component
FMU takes tens of seconds); ``seed`` and ``interop`` imply ``slow``.
"""

import json
import os
import shutil
from pathlib import Path

import pytest
from filelock import FileLock

from agv_cosim.build import build_fmus, build_one, default_components_dir, slave_scripts

#: fixtures that build every component FMU (FMI 2.0 or the FMI 3.0 twins): tens of seconds
BUILDING_FIXTURES = {"component_fmus", "twins"}


def pytest_collection_modifyitems(config, items):
    for item in items:
        if (item.get_closest_marker("seed") or item.get_closest_marker("interop")
                or BUILDING_FIXTURES & set(getattr(item, "fixturenames", ()))):
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


@pytest.fixture(scope="session")
def twins(tmp_path_factory):
    """Every component built as an FMI 3.0 twin; map script stem -> FMU path."""
    def make(folder):
        results = build_fmus(folder, slave_scripts(default_components_dir()), fmi_version=3)
        (folder / "fmus.json").write_text(json.dumps(
            {result.script.stem: result.fmu.name for result in results}))

    out = session_folder(tmp_path_factory, "component_fmus3", make)
    return {stem: out / name for stem, name in
            json.loads((out / "fmus.json").read_text()).items()}


#: the small test FMUs' sources (tests/fmu_src/agv_test_*.py)
TEST_FMU_SOURCES = Path(__file__).resolve().parent / "fmu_src"


@pytest.fixture(scope="session")
def fmus(tmp_path_factory):
    """Script stem -> path of the small test FMUs of fmu_src/ (agv_test_source,
    agv_test_gain, ...), built once per session for every worker: they declare no default
    experiment, so a build is a zip of a few files (no reference run)."""
    def make(folder):
        (folder / "fmus.json").write_text(json.dumps(
            {p.stem: build_one(p, folder).fmu.name
             for p in sorted(TEST_FMU_SOURCES.glob("agv_test_*.py"))}))

    out = session_folder(tmp_path_factory, "test_fmus", make)
    return {stem: out / name for stem, name in
            json.loads((out / "fmus.json").read_text()).items()}
