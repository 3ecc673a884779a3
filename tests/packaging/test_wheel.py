"""A user without the repository: ``pip install`` of a wheel built from it, into a fresh venv
outside the checkout, gives a CLI that builds every FMU (FMI 2.0 and 3.0) and runs the
shipped examples with the same numbers as the repository's own run.

The wheel is built with ``pip wheel`` from a copy of the working tree (a build writes
``build/`` and ``*.egg-info`` beside the sources, never into the repository). The venv gets
the wheel with the versions of this test's own venv as constraints (so numbers can be
compared bit for bit); pip takes the wheels from its cache where it has them, and
``--no-compile`` skips byte-compiling what is never imported. Everything then runs in a
work folder outside the checkout, with the venv's ``agv-cosim``.
"""

import importlib.metadata
import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from agv_cosim.build import default_components_dir, slave_scripts
from agv_cosim.build.shipped import SHIPPED

from manifests import localise

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[2]
_NOT_SOURCES = shutil.ignore_patterns(".venv", ".git", "fmus", "results", "__pycache__",
                                      "*.egg-info", ".pytest_cache")


def NOT_SOURCES(folder, names):
    """What the copy leaves out: the checkout's own build output (``build/`` and ``dist/``
    at its top; agv_cosim/build/ is a package) and caches, venvs and results anywhere."""
    top = {"build", "dist"} if Path(folder) == REPO else set()
    return _NOT_SOURCES(folder, names) | (top & set(names))
MODELS = sorted(p.stem for p in slave_scripts(default_components_dir()))


def run(command, cwd, timeout=900):
    done = subprocess.run([str(c) for c in command], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout, env={k: v for k, v in os.environ.items()
                                                if k not in ("PYTHONPATH", "VIRTUAL_ENV")})
    assert done.returncode == 0, f"{command}: {done.stderr[-3000:]}"
    return done.stdout


@pytest.fixture(scope="module")
def user(tmp_path_factory):
    """(venv bin folder, work folder): the wheel installed in a fresh venv."""
    root = tmp_path_factory.mktemp("wheel")
    source = root / "agv-cosim"
    shutil.copytree(REPO, source, ignore=NOT_SOURCES)
    run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps",
         "--disable-pip-version-check", "-w", root / "dist", source], cwd=root)
    wheels = list((root / "dist").glob("agv_cosim-*.whl"))
    assert len(wheels) == 1, wheels
    constraints = root / "constraints.txt"
    constraints.write_text("".join(
        f"{d.metadata['Name']}=={d.version}\n" for d in importlib.metadata.distributions()
        if d.metadata["Name"] != "agv-cosim"))
    run([sys.executable, "-m", "venv", root / "venv"], cwd=root)
    bin_ = root / "venv" / "bin"
    run([bin_ / "python", "-m", "pip", "install", "--quiet", "--no-compile",
         "--disable-pip-version-check", "-c", constraints, wheels[0]], cwd=root)
    work = root / "work"
    work.mkdir()
    return bin_, work


def test_the_package_builds_without_a_deprecation_warning(tmp_path):
    """``make venv`` and ``pip wheel`` print no setuptools deprecation banner: the license
    is an SPDX expression (setuptools >= 77, the build requirement)."""
    source = tmp_path / "agv-cosim"
    shutil.copytree(REPO, source, ignore=NOT_SOURCES)
    done = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps",
                           "--disable-pip-version-check", "-w", str(tmp_path / "dist"),
                           str(source)], capture_output=True, text=True, timeout=600,
                          env={k: v for k, v in os.environ.items()
                               if k not in ("PYTHONPATH", "VIRTUAL_ENV")})
    assert done.returncode == 0, done.stderr[-3000:]
    assert "deprecat" not in (done.stdout + done.stderr).lower(), done.stderr[-3000:]
    (wheel,) = (tmp_path / "dist").glob("agv_cosim-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        metadata = archive.read("agv_cosim-0.1.0.dist-info/METADATA").decode()
    assert "License-Expression: MIT" in metadata.splitlines()


@pytest.fixture(scope="module")
def built(user):
    """``agv-cosim build`` (into fmus/) and ``--fmi 3 --out fmus3`` in the work folder."""
    bin_, work = user
    run([bin_ / "agv-cosim", "build"], cwd=work)
    run([bin_ / "agv-cosim", "build", "--fmi", "3", "--out", "fmus3"], cwd=work)
    return work


def test_the_installed_package_is_not_the_checkout(user):
    bin_, work = user
    where = json.loads(run([bin_ / "python", "-c",
                            "import json, agv_core, agv_cosim; print(json.dumps("
                            "[agv_core.__file__, agv_cosim.__file__]))"], cwd=work))
    for path in where:
        assert Path(path).is_relative_to(bin_.parent), path
    site = Path(where[1]).parent
    for kind, (folder, patterns) in SHIPPED.items():
        expected = sorted(p.name for pattern in patterns for p in (REPO / folder).glob(pattern))
        assert expected and sorted(p.name for p in (site / "shipped" / kind).iterdir()) == \
            expected, kind


def test_every_fmu_is_built_in_both_fmi_versions(built):
    for folder, version in (("fmus", "2.0"), ("fmus3", "3.0")):
        fmus = sorted((built / folder).glob("*.fmu"))
        assert len(fmus) == len(MODELS), folder
        for fmu in fmus:
            with zipfile.ZipFile(fmu) as archive:
                assert f'fmiVersion="{version}"' in archive.read("modelDescription.xml").decode()
                assert "resources/requirements.txt" in archive.namelist()


def test_a_shipped_example_runs_as_in_the_repository(user, built, component_fmus, tmp_path):
    """The main seed-000 experiment (what ``make run`` runs), to its stop time: every
    recorded number and every metric equal to the repository's run of it."""
    bin_, work = user
    run([bin_ / "agv-cosim", "examples", "examples"], cwd=work)
    shipped = sorted(p.name for p in (REPO / "experiments").glob("*.toml"))
    assert sorted(p.name for p in (work / "examples").glob("*.toml")) == shipped
    name = "seed000_models_abc"
    run([bin_ / "agv-cosim", "run", f"examples/{name}.toml", "--out", "res", "--quiet"],
        cwd=work)
    manifest = localise(REPO / "experiments" / f"{name}.toml", tmp_path, component_fmus)
    run([sys.executable, "-m", "agv_cosim.cli", "run", manifest, "--out", tmp_path / "res",
         "--quiet"], cwd=tmp_path)
    ours = sorted(p.relative_to(work / "res") for p in (work / "res").rglob("*.csv")
                  if p.name != "timings.csv")  # measured times, the one file that differs
    assert ours == sorted(p.relative_to(tmp_path / "res")
                          for p in (tmp_path / "res").rglob("*.csv")
                          if p.name != "timings.csv")
    assert len(ours) == 4  # a, b, c and the summary
    # the report page: its template travels in the wheel
    assert "<h1>seed000_models_abc</h1>" in (work / "res" / "index.html").read_text()
    for relative in ours:
        assert (work / "res" / relative).read_bytes() == \
            (tmp_path / "res" / relative).read_bytes(), relative


def test_the_fmi3_twins_run_an_example_like_the_fmi2_fmus(user, built):
    bin_, work = user
    run([bin_ / "agv-cosim", "examples", "ex3", "--fmus", "fmus3"], cwd=work)
    for folder in ("examples", "ex3"):
        if not (work / folder).exists():
            run([bin_ / "agv-cosim", "examples", folder], cwd=work)
        run([bin_ / "agv-cosim", "run", f"{folder}/example.toml", "--out", f"ex_{folder}",
             "--quiet"], cwd=work)
    runs = sorted(p.relative_to(work / "ex_examples")
                  for p in (work / "ex_examples").rglob("timeseries.csv"))
    assert len(runs) == 4  # 2 variants x 2 wheelbases
    for relative in runs:
        assert (work / "ex_ex3" / relative).read_bytes() == \
            (work / "ex_examples" / relative).read_bytes(), relative
