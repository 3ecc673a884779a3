"""agv_cosim.fitting is numerics on callables: it imports, of agv_cosim, only the
foundation it needs (errors, files, csvcolumns) and itself, never the manifest, plan,
pipeline or worker code that the command wraps it with; importing it loads none of
them."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import agv_cosim.fitting

FOLDER = Path(agv_cosim.fitting.__file__).parent
ALLOWED = {"agv_cosim.errors", "agv_cosim.files", "agv_cosim.csvcolumns"}


def test_fitting_imports_only_the_foundation() -> None:
    found = set()
    for path in sorted(FOLDER.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.level == 2:
                found.add(f"agv_cosim.{node.module}")
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and \
                    (node.module or "").startswith("agv_cosim"):
                found.add(node.module or "")
            elif isinstance(node, ast.Import):
                found |= {a.name for a in node.names if a.name.startswith("agv_cosim")}
    assert found and found <= ALLOWED, found - ALLOWED


def test_importing_fitting_loads_no_pipeline_stage() -> None:
    code = ("import sys, agv_cosim.fitting; print(sorted(m for m in sys.modules "
            "if m.split('.')[:2][-1] in ('manifest', 'plan', 'pipeline', 'workers', "
            "'system', 'execution', 'report')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "[]", out.stdout
