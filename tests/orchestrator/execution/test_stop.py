"""FMU-requested stop in the middle of a macro step (pythonfmu's False do_step)."""

import csv
import json
import os
import shutil
import subprocess
import zipfile
from pathlib import Path

import pytest

from agv_cosim import cli


@pytest.mark.parametrize("algorithm", ["gauss-seidel", "jacobi"])
def test_stop_request_mid_step_keeps_every_row_and_completes(fmus, tmp_path, algorithm):
    manifest = tmp_path / "stop.toml"
    manifest.write_text(f"""
[simulation]
stop = 1.0
step = 0.1
algorithm = "{algorithm}"
[components.d]
fmu = "{fmus['agv_test_discard']}"
parameters = {{ discard_time = 0.3 }}
[components.src]
fmu = "{fmus['agv_test_source']}"
""")
    out = tmp_path / "out"
    assert cli.main(["run", str(manifest), "--out", str(out), "--jobs", "1", "--quiet"]) == 0
    info = json.loads((out / "base" / "run.json").read_text())
    # the step 0.3 -> 0.4 was refused: the FMU's last successful time is 0.3 s, so the
    # run ends there, with the rows 0 .. 0.3 (no row at 0.4, which d never reached)
    assert info["status"] == "complete" and info["error"] is None
    assert info["ended_by"] == "d requested stop at t=0.3 s"
    with open(out / "base" / "timeseries.csv", newline="") as stream:
        rows = list(csv.reader(stream))[1:]
    assert [float(r[0]) for r in rows] == pytest.approx([0.0, 0.1, 0.2, 0.3], abs=1e-12)
    assert info["rows"] == 4


C_FMU = Path(__file__).resolve().parents[2] / "c_fmu"
#: the Reference FMUs' sources lie in the shared folder beside the checkout (as in CI)
FMI_HEADERS = Path(os.environ.get(
    "AGV_REFERENCE_FMUS",
    Path(__file__).resolve().parents[4] / "shared" / "third-party" / "Reference-FMUs")) / "include"


@pytest.fixture(scope="session")
def c_discard_fmu(tmp_path_factory):
    """tests/c_fmu (a C FMI 2.0 co-simulation FMU) compiled with gcc against the FMI
    headers of the Reference FMUs and zipped with its hand-written modelDescription.xml."""
    headers = Path(os.environ.get("AGV_FMI_HEADERS", FMI_HEADERS))
    if not (headers / "fmi2Functions.h").is_file():
        pytest.skip(f"FMI 2.0 headers not found at {headers}")
    if shutil.which("gcc") is None:
        pytest.skip("gcc is not installed (needed to compile the C test FMU)")
    out = tmp_path_factory.mktemp("c_fmu")
    library = out / "agv_test_c_discard.so"
    done = subprocess.run(["gcc", "-shared", "-fPIC", "-Wall", "-Wextra", "-Werror", "-O1",
                           f"-I{headers}", "-o", str(library),
                           str(C_FMU / "discard_fmu.c")], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    fmu = out / "agv_test_c_discard.fmu"
    with zipfile.ZipFile(fmu, "w") as archive:
        archive.write(C_FMU / "modelDescription.xml", "modelDescription.xml")
        archive.write(library, "binaries/linux64/agv_test_c_discard.so")
    return fmu


@pytest.mark.parametrize("algorithm", ["gauss-seidel", "jacobi"])
def test_discard_without_termination_is_an_error(c_discard_fmu, tmp_path, capsys,
                                                 algorithm):
    """fmi2Discard from fmi2DoStep with fmi2Terminated false is no stop request: the run
    fails with one line naming the component, the call and the time; the rows up to the
    refused step (0 .. 0.3 s) are kept and the run is marked partial."""
    manifest = tmp_path / "discard.toml"
    manifest.write_text(f"""
[simulation]
stop = 1.0
step = 0.1
algorithm = "{algorithm}"
[components.cd]
fmu = "{c_discard_fmu}"
""")
    out = tmp_path / "out"
    assert cli.main(["run", str(manifest), "--out", str(out), "--jobs", "1", "--quiet"]) == 1
    info = json.loads((out / "base" / "run.json").read_text())
    assert info["status"] == "partial" and info["partial"] is True
    assert "requested stop" not in str(info.get("ended_by"))
    error = info["error"]
    assert "\n" not in error
    assert "component 'cd'" in error and "fmi2DoStep" in error and "t=0.3" in error
    assert "returned status 2 (Discard, no stop requested)" in error
    err = capsys.readouterr().err
    assert "run base partial" in err
    with open(out / "base" / "timeseries.csv", newline="") as stream:
        rows = list(csv.reader(stream))
    assert rows[0] == ["time", "cd.y"]
    assert [float(r[0]) for r in rows[1:]] == pytest.approx([0.0, 0.1, 0.2, 0.3], abs=1e-12)
    assert [float(r[1]) for r in rows[1:]] == pytest.approx([0.0, 0.1, 0.2, 0.3], abs=1e-12)
    assert info["rows"] == 4
