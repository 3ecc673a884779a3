"""Every FMU runs in a Python that has nothing installed but its ``resources/requirements.txt``.

The build derives each FMU's requirement list from the imports of its code
(agv_cosim/build/bundle.py). Here every component FMU, FMI 2.0 and FMI 3.0 twin, is run in a
fresh venv into which exactly its pinned list was installed with ``pip install --no-deps``
(one venv per distinct list, shared by the FMUs that declare the same; an FMU and its FMI
3.0 twin declare the same list), through a host that imports nothing but the standard
library (fmu_driver.py, run by that venv's interpreter). Each runs its default experiment
with its reference inputs held, and must give bit for bit what the same driver gives in the
test's own venv (everything installed), and the reference result shipped in the FMU within
the band 1e-12 + 1e-9 |ref| (fmpy, which computed it, interpolates between the input table's
rows, so a held input may be off by an ulp: 0.19999999999999998 for 0.2). An FMU whose
Python lacks a package of its list fails with the module's name in an FMI error message
(checked by uninstalling one package from a venv).

pip installs from its cache where it can (the versions are those of the test's own venv);
``--no-compile`` skips byte-compiling what the runs never import.
"""

import csv
import hashlib
import json
import subprocess
import sys
import zipfile
from pathlib import Path

import fmpy
import pytest

from agv_cosim.build import REFERENCE_DIR, reference_experiment

DRIVER = Path(__file__).parent / "fmu_driver.py"


def requirements(fmu):
    with zipfile.ZipFile(fmu) as archive:
        return archive.read("resources/requirements.txt").decode()


def pins(text):
    return sorted(line for line in text.splitlines() if line and not line.startswith("#"))


def make_venv(folder, pinned):
    """A venv at ``folder`` holding exactly the distributions ``pinned`` (name==version)."""
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(folder)], check=True,
                   capture_output=True, timeout=300)
    python = folder / "bin" / "python"
    if pinned:
        done = subprocess.run([sys.executable, "-m", "pip", "--python", str(python),
                               "install", "--quiet", "--no-deps", "--no-compile",
                               "--disable-pip-version-check", *pinned],
                              capture_output=True, text=True, timeout=900)
        assert done.returncode == 0, done.stderr[-2000:]
    return python


def installed(python):
    code = ("import importlib.metadata as md, json; print(json.dumps(sorted("
            "f\"{d.metadata['Name']}=={d.version}\" for d in md.distributions())))")
    done = subprocess.run([str(python), "-I", "-c", code], capture_output=True, text=True,
                          check=True, timeout=120)
    return json.loads(done.stdout)


def job_of(fmu, folder):
    """The driver's job for the FMU's default experiment, and its shipped reference rows."""
    md = fmpy.read_model_description(str(fmu))
    with zipfile.ZipFile(fmu) as archive:
        experiment = reference_experiment(archive.read("modelDescription.xml"))
        archive.extractall(folder)
    by_name = {v.name: v for v in md.modelVariables}
    outputs = [v for v in md.modelVariables
               if v.causality == "output" and v.type in ("Real", "Float64")]
    job = {"folder": str(folder), "identifier": md.coSimulation.modelIdentifier,
           "token": md.guid, "fmi": int(md.fmiVersion[0]), "start": experiment["start"],
           "stop": experiment["stop"], "step": experiment["step"],
           "inputs": {by_name[n].valueReference: points
                      for n, points in experiment["inputs"].items()},
           "outputs": [v.valueReference for v in outputs]}
    with open(folder / REFERENCE_DIR / f"{md.modelName}_out.csv", newline="") as handle:
        table = list(csv.reader(handle))
    assert table[0] == ["time", *(v.name for v in outputs)]
    return job, [[float(x) for x in row] for row in table[1:]]


def drive(python, job, folder):
    path = folder / "job.json"
    path.write_text(json.dumps(job))
    done = subprocess.run([str(python), "-I", str(DRIVER), str(path)], capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def every_fmu(component_fmus, twins):
    """(label, FMU) of every component FMU and FMI 3.0 twin."""
    return ([(f"{stem} (FMI 2.0)", fmu) for stem, fmu in sorted(component_fmus.items())]
            + [(f"{stem} (FMI 3.0)", fmu) for stem, fmu in sorted(twins.items())])


@pytest.fixture(scope="module")
def venvs(every_fmu, tmp_path_factory):
    """requirement list (sorted pins) -> venv interpreter holding exactly those."""
    root = tmp_path_factory.mktemp("requirement_venvs")
    made = {}
    for _, fmu in every_fmu:
        key = tuple(pins(requirements(fmu)))
        if key not in made:
            name = hashlib.sha256("\n".join(key).encode()).hexdigest()[:12]
            made[key] = make_venv(root / name, list(key))
    return made


def test_the_lists_name_what_the_code_imports(component_fmus, twins):
    """Spot checks of the derived lists: the packages a component's code imports, the
    packages those import undeclared (scikit-fuzzy 0.5 declares no dependency but
    imports networkx and packaging), the wrapper that the FMU carries itself left out."""
    def names(fmu):
        return {line.partition("==")[0] for line in pins(requirements(fmu))}

    assert "control" in names(component_fmus["agv_preview_lq"])
    assert {"scikit-fuzzy", "packaging", "networkx"} <= names(component_fmus["agv_fuzzy_pd"])
    assert "osqp" in names(component_fmus["agv_ltv_mpc"])
    assert names(component_fmus["agv_vehicle"]) == set()  # math only; pythonfmu is shipped
    assert names(component_fmus["agv_train"]) == {"scipy", "numpy"}
    for fmu in [*component_fmus.values(), *twins.values()]:
        assert not names(fmu) & {"pythonfmu", "pythonfmu3", "fmpy", "agv-cosim"}, fmu.name


def within_band(rows, reference):
    return len(rows) == len(reference) and all(
        len(a) == len(b) and all(abs(x - y) <= 1e-12 + 1e-9 * abs(y) for x, y in zip(a, b))
        for a, b in zip(rows, reference))


def test_every_fmu_runs_with_only_its_requirements(every_fmu, venvs, tmp_path):
    """Each venv holds exactly its list; each FMU runs there as in the full venv.

    The FMUs that declare one list run one after the other in one process of their venv
    (whatever one loads is in the list of the next), and all of them in one process of the
    test's venv for the comparison."""
    for key, python in venvs.items():
        assert sorted(installed(python)) == sorted(key)
    jobs = {}  # label -> (job, reference, key)
    for k, (label, fmu) in enumerate(every_fmu):
        job, reference = job_of(fmu, tmp_path / f"fmu{k}")
        jobs[label] = (job, reference, tuple(pins(requirements(fmu))))
    results = {}
    for key, python in venvs.items():
        labels = [label for label, (_, _, own) in jobs.items() if own == key]
        results.update(zip(labels, drive(python, [jobs[n][0] for n in labels], tmp_path)))
    labels = list(jobs)
    full = dict(zip(labels, drive(sys.executable, [jobs[n][0] for n in labels], tmp_path)))
    failures = []
    for label, (_, reference, _) in jobs.items():
        result, everything = results[label], full[label]
        if result["failed"]:
            failures.append(f"{label}: {result['failed']}: {result['messages'][-3:]}")
        elif everything["failed"] or result["rows"] != everything["rows"]:
            failures.append(f"{label}: differs from the run with everything installed")
        elif not within_band(result["rows"], reference):
            failures.append(f"{label}: differs from its shipped reference")
    assert not failures, "\n".join(failures)


@pytest.mark.parametrize("stem, package, module", [
    ("agv_preview_lq", "control", "control"),          # imported when the core is made
    ("agv_fuzzy_pd", "packaging", "packaging"),        # imported by scikit-fuzzy
    ("agv_vision_sensor", "numpy", "numpy"),           # imported when the slave loads
])
def test_a_missing_package_is_an_fmi_error_naming_it(component_fmus, twins, venvs, tmp_path,
                                                      stem, package, module):
    """The FMU's venv with one package of its list uninstalled (and reinstalled after)."""
    key = tuple(pins(requirements(component_fmus[stem])))
    assert tuple(pins(requirements(twins[stem]))) == key
    python = venvs[key]
    pinned = [p for p in key if p.startswith(f"{package}==")]
    assert len(pinned) == 1, key

    def pip(*args):
        done = subprocess.run([sys.executable, "-m", "pip", "--python", str(python), *args,
                               "--quiet", "--disable-pip-version-check"],
                              capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr[-2000:]

    pip("uninstall", "--yes", package)
    try:
        assert not [p for p in installed(python) if p.startswith(f"{package}==")]
        for version, fmu in (("2", component_fmus[stem]), ("3", twins[stem])):
            folder = tmp_path / f"fmu{version}"
            job, _ = job_of(fmu, folder)
            result = drive(python, job, folder)
            assert result["failed"], f"FMI {version}: ran without {package}"
            errors = [m for status, _, m in result["messages"] if status >= 3]
            assert any(f"No module named '{module}'" in m for m in errors), \
                (version, result["messages"])
    finally:
        pip("install", "--no-deps", "--no-compile", *pinned)


@pytest.mark.parametrize("version", ["3", "2"])
def test_a_host_that_turned_logging_off_still_hears_why(component_fmus, twins, tmp_path,
                                                        version):
    """The vision sensor (numpy at import) in an empty venv, instantiated with loggingOn
    false: the error that ends it must still reach the host's logger (the bridge passes
    warnings and errors on whatever loggingOn says, agv_fmu_bridge.c)."""
    fmu = (component_fmus if version == "2" else twins)["agv_vision_sensor"]
    python = make_venv(tmp_path / "empty", [])
    job, _ = job_of(fmu, tmp_path / "fmu")
    result = drive(python, {**job, "logging": False}, tmp_path)
    assert result["failed"]
    errors = [m for status, _, m in result["messages"] if status >= 3]
    assert any("No module named 'numpy'" in m for m in errors), result["messages"]

