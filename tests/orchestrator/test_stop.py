"""FMU-requested stop in the middle of a macro step (pythonfmu's False do_step)."""

import csv
import json

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
    assert info["ended_by"] == "d requested stop at t=0.30000000000000004 s"
    with open(out / "base" / "timeseries.csv", newline="") as stream:
        rows = list(csv.reader(stream))[1:]
    assert [float(r[0]) for r in rows] == pytest.approx([0.0, 0.1, 0.2, 0.3], abs=1e-12)
    assert info["rows"] == 4
