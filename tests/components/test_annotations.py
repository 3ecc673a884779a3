"""Type hints on agv_core: every public function and method of a public class (slave
scripts included) has every parameter (but self / cls) and its return annotated
(``__init__``'s return may be left out), as tests/orchestrator/test_layering.py asks of
agv_cosim. Read from the source (ast).
"""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2] / "components" / "agv_core"


def bare_signatures(path):
    """``name: parameters...`` of each public function of ``path`` missing annotations."""
    missing = []

    def visit(body, owner, public):
        for node in body:
            if isinstance(node, ast.ClassDef):
                visit(node.body, node.name, public and not node.name.startswith("_"))
            elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                dunder = node.name.startswith("__") and node.name.endswith("__")
                if not public or (node.name.startswith("_") and not dunder):
                    continue
                args = node.args.posonlyargs + node.args.args + node.args.kwonlyargs
                if owner and args and args[0].arg in ("self", "cls"):
                    args = args[1:]
                args += [a for a in (node.args.vararg, node.args.kwarg) if a]
                bare = [a.arg for a in args if a.annotation is None]
                if node.returns is None and node.name != "__init__":
                    bare.append("return")
                if bare:
                    missing.append(f"{node.lineno} {node.name}: {', '.join(bare)}")

    visit(ast.parse(path.read_text()).body, "", True)
    return missing


def modules():
    return {p.relative_to(ROOT).as_posix(): p for p in sorted(ROOT.rglob("*.py"))}


def test_the_check_finds_a_bare_signature(tmp_path):
    source = tmp_path / "m.py"
    source.write_text("def f(a: int, b) -> int:\n    return a\n\n"
                      "class C:\n    def g(self, x: float):\n        return x\n\n"
                      "def _private(a):\n    return a\n")
    assert bare_signatures(source) == ["1 f: b", "5 g: return"]


def test_every_public_function_of_agv_core_is_annotated():
    missing = [f"{name}:{line}" for name, path in modules().items()
               for line in bare_signatures(path)]
    assert missing == []
