"""The package layout of agv_cosim: its imports point down the pipeline, form no cycle,
take no private name from another module; every error type lives in agv_cosim.errors;
every package declares its public names.

The import graph is read from the source (ast: every import statement, at module level
or inside a function), so an import that only runs later counts too.
"""

import ast
import graphlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2] / "orchestrator" / "agv_cosim"
PACKAGE = "agv_cosim"

#: Layer of each top-level part: a module may import only from its own layer or below.
#: The foundation (0) serves every stage; the stages follow the pipeline (manifest ->
#: plan -> system -> execution -> report); the workers run the jobs (local processes or
#: Dask); the pipeline composes a command from the stages and the workers; the tools sit
#: on top.
LAYERS = {
    "errors": 0, "version": 0, "fmitypes": 0, "lifetime": 0, "files": 0, "timeseries": 0,
    "csvcolumns": 0, "archive": 0,
    "manifest": 1, "plan": 2, "system": 3, "execution": 4, "report": 5, "workers": 6,
    "pipeline": 7,
    "ssp": 8, "build": 8, "identification": 8, "fitting": 8, "tuning": 8, "manifest_fit": 8,
    "cli": 9, "api": 9, "": 10,
}

#: Inside the build package (agv_cosim.build, the FMU build wing): its modules in layers of
#: their own; the package as a whole stands on the foundation (layer 0) only.
BUILD_LAYERS = {"shipped": 0, "bundle": 0, "standalone": 1, "examples": 1, "fmus": 2, "": 3}


def module_name(path):
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join([PACKAGE] + parts)


def modules():
    return {module_name(p): p for p in sorted(ROOT.rglob("*.py"))}


def imports(name, path, known):
    """``(imported module, names taken from it, line)`` of every import in ``path``."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(a.name, [], node.lineno) for a in node.names
                      if a.name.split(".")[0] == PACKAGE]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] != PACKAGE:
                continue
            names = [a.name for a in node.names]
            submodules = [f"{target}.{n}" for n in names if f"{target}.{n}" in known]
            found += [(s, [], node.lineno) for s in submodules]
            taken = [n for n in names if f"{target}.{n}" not in known]
            if taken or not submodules:
                found.append((target, taken, node.lineno))
    return found


def graph():
    known = modules()
    edges = {name: {} for name in known}
    for name, path in known.items():
        for target, names, line in imports(name, path, known):
            assert target in known, f"{name}:{line}: imports unknown module {target}"
            edges[name].setdefault(target, []).append((names, line))
    return edges


def find_cycle(edges):
    """A cycle of ``edges`` (module -> imported modules), or None."""
    try:
        graphlib.TopologicalSorter({m: set(t) - {m} for m, t in edges.items()}).prepare()
    except graphlib.CycleError as error:
        return error.args[1]
    return None


def layer(name):
    part = name.split(".")[1] if "." in name else ""
    return LAYERS[part]


def test_the_cycle_finder_finds_a_cycle():
    assert find_cycle({"a": {"b": []}, "b": {"c": []}, "c": {"a": []}}) is not None
    assert find_cycle({"a": {"b": []}, "b": {"c": []}, "c": {}}) is None


def test_no_import_cycle():
    assert find_cycle(graph()) is None


def test_every_module_has_a_layer():
    assert [m for m in modules() if (m.split(".")[1] if "." in m else "") not in LAYERS] == []


def test_imports_point_down_the_pipeline():
    upward = [f"{m} ({layer(m)}) imports {t} ({layer(t)}) at line {uses[0][1]}"
              for m, targets in graph().items() for t, uses in targets.items()
              if layer(t) > layer(m)]
    assert upward == []


def build_layer(name):
    parts = name.split(".")
    return BUILD_LAYERS[parts[2] if len(parts) > 2 else ""]


def test_every_build_module_has_a_layer():
    assert [m for m in modules() if m.startswith(f"{PACKAGE}.build.")
            and m.split(".")[2] not in BUILD_LAYERS] == []


def test_the_build_package_stands_on_the_foundation_only():
    above = [f"{m} imports {t} at line {uses[0][1]}" for m, targets in graph().items()
             if layer(m) == LAYERS["build"] and m.split(".")[1] == "build"
             for t, uses in targets.items()
             if t.split(".")[1] != "build" and layer(t) > 0]
    assert above == []


def test_imports_point_down_inside_the_build_package():
    upward = [f"{m} imports {t} at line {uses[0][1]}" for m, targets in graph().items()
              if m.split(".")[1:2] == ["build"] for t, uses in targets.items()
              if t.split(".")[1:2] == ["build"] and build_layer(t) > build_layer(m)]
    assert upward == []


def test_no_private_name_is_taken_from_another_module():
    taken = [f"{m}:{line} takes {n} from {t}" for m, targets in graph().items()
             for t, uses in targets.items() if t != m
             for names, line in uses for n in names if n.startswith("_")
             and n != "__version__"]
    assert taken == []


def test_every_error_type_is_in_the_errors_module():
    bases = {"Exception", "BaseException", "ValueError", "RuntimeError"}
    elsewhere = []
    for name, path in modules().items():
        if name == f"{PACKAGE}.errors":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ClassDef) and not node.name.startswith("_") and any(
                    isinstance(b, ast.Name) and (b.id in bases or b.id.endswith("Error"))
                    for b in node.bases):
                elsewhere.append(f"{name}.{node.name}")
    assert elsewhere == []


@pytest.mark.parametrize("name", sorted(n for n, p in modules().items()
                                        if p.name == "__init__.py"))
def test_every_package_declares_its_public_names(name):
    import importlib

    package = importlib.import_module(name)
    assert isinstance(package.__all__, list) and package.__all__
    assert [n for n in package.__all__ if not hasattr(package, n)] == []


def test_every_public_function_is_annotated():
    """Public functions and methods of public classes: every parameter (but self / cls)
    and the return annotated (``__init__``'s return may be left out)."""
    missing = []
    for name, path in modules().items():
        def visit(body, owner, public, name=name):
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
                        missing.append(f"{name}:{node.lineno} {node.name}: {', '.join(bare)}")

        visit(ast.parse(path.read_text()).body, "", True)
    assert missing == []
