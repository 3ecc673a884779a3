"""The orchestrator functions split into named steps stay within a McCabe complexity of
15 (ruff's C901 with ``lint.mccabe.max-complexity = 15``): each is still defined where
it was, and ruff reports none of them."""

import ast
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / "orchestrator" / "agv_cosim"

#: (module of agv_cosim, function or method name) of the functions split into steps.
SPLIT = [("report/metrics.py", "compute_metrics"), ("report/metrics.py", "_stream_metrics"),
         ("system/model.py", "_parse_model"), ("system/table.py", "__init__"),
         ("tuning/setup.py", "_parameter"), ("fitting/outputerror.py", "fit")]


def ruff() -> str:
    beside = Path(sys.executable).with_name("ruff")
    found = str(beside) if beside.exists() else shutil.which("ruff")
    if found is None:
        pytest.skip("ruff is not installed")
    return found


def defined(module: str) -> set[str]:
    tree = ast.parse((PACKAGE / module).read_text(encoding="utf-8"))
    return {node.name for node in ast.walk(tree)
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)}


def test_split_functions_are_within_complexity_15() -> None:
    modules = sorted({module for module, _ in SPLIT})
    for module, function in SPLIT:
        assert function in defined(module), f"{module}: no function {function!r}"
    done = subprocess.run([ruff(), "check", "--no-cache", "--select", "C901", "--config",
                           "lint.mccabe.max-complexity=15", "--output-format", "json",
                           *(str(PACKAGE / module) for module in modules)],
                          capture_output=True, text=True, check=False)
    assert done.returncode in (0, 1), done.stderr
    found = {(Path(item["filename"]).relative_to(PACKAGE).as_posix(),
              item["message"].split("`")[1]): item["message"]
             for item in json.loads(done.stdout)}
    too_complex = {key: message for key, message in found.items() if key in SPLIT}
    assert too_complex == {}
