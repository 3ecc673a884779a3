"""docs/fit.md's worked example (issue 34): run as the page gives it, its output
compared with what the page shows, and the known values recovered within 3 standard
errors."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from agv_cosim.build import build_one

from docs_examples import assert_prints_what_the_page_shows, example_env

pytestmark = pytest.mark.slow  # builds AgvSteeringA and runs it tens of times

ROOT = Path(__file__).resolve().parents[3]
DOC = ROOT / "docs" / "fit.md"


def test_docs_worked_example_prints_what_the_page_shows(tmp_path: Path) -> None:
    (tmp_path / "fmus").mkdir()
    built = build_one(ROOT / "components" / "agv_core" / "steering" / "agv_steering_a.py",
                      tmp_path / "build")
    shutil.copy(built.fmu, tmp_path / "fmus" / "AgvSteeringA.fmu")
    assert_prints_what_the_page_shows(DOC, tmp_path, timeout=600)
    result = json.loads((tmp_path / "fitted" / "fit.json").read_text())
    for name, true in (("act.K", 0.45), ("act.tau", 0.08)):
        entry = result["parameters"][name]
        assert abs(entry["value"] - true) <= 3 * entry["stderr"], (name, entry)
    # the page's shell lines: the fitted variant pasted into the manifest runs
    fragment = (tmp_path / "fitted" / "fit_variant.toml").read_text()
    with open(tmp_path / "act_fit.toml", "a") as manifest:
        manifest.write(fragment)
    ran = subprocess.run([sys.executable, "-m", "agv_cosim.cli", "run", "act_fit.toml",
                          "--variant", "fitted", "--out", "fitted_run", "--quiet"],
                         capture_output=True, text=True, cwd=tmp_path, timeout=300,
                         env=example_env())
    assert ran.returncode == 0, ran.stderr
    run = json.loads((tmp_path / "fitted_run" / "fitted" / "run.json").read_text())
    assert run["parameters"]["act"]["K"] == result["parameters"]["act.K"]["value"]
