"""docs/fit.md's worked example (issue 34): run as the page gives it, its output
compared with what the page shows, and the known values recovered within 3 standard
errors."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from agv_cosim.build import build_one

pytestmark = pytest.mark.slow  # builds AgvSteeringA and runs it tens of times

ROOT = Path(__file__).resolve().parents[3]
DOC = ROOT / "docs" / "fit.md"
NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:e[-+]?\d+)?")


def _block(text: str, language: str) -> str:
    found = re.search(rf"^```{language}\n(.*?)^```$", text, flags=re.M | re.S)
    assert found, f"no ```{language} block"
    return found.group(1)


def _shape(line: str) -> tuple[str, list[float]]:
    return NUMBER.sub("#", line), [float(n) for n in NUMBER.findall(line)]


def test_docs_worked_example_prints_what_the_page_shows(tmp_path: Path) -> None:
    text = DOC.read_text()
    code, shown = _block(text, "python"), _block(text, "text")
    (tmp_path / "fmus").mkdir()
    built = build_one(ROOT / "components" / "agv_core" / "steering" / "agv_steering_a.py",
                      tmp_path / "build")
    shutil.copy(built.fmu, tmp_path / "fmus" / "AgvSteeringA.fmu")
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=tmp_path, timeout=600, env=env)
    assert done.returncode == 0, done.stderr
    printed, expected = done.stdout.splitlines(), shown.splitlines()
    assert len(printed) == len(expected), done.stdout
    for got, want in zip(printed, expected):
        (got_text, got_numbers), (want_text, want_numbers) = _shape(got), _shape(want)
        assert got_text == want_text, (got, want)
        assert got_numbers == pytest.approx(want_numbers, rel=1e-3, abs=1e-12), (got, want)
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
                         capture_output=True, text=True, cwd=tmp_path, timeout=300, env=env)
    assert ran.returncode == 0, ran.stderr
    run = json.loads((tmp_path / "fitted_run" / "fitted" / "run.json").read_text())
    assert run["parameters"]["act"]["K"] == result["parameters"]["act.K"]["value"]
