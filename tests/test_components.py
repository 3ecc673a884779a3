"""The component layout (components/README.md): one folder per component, the FMI boundary,
the committed reference results and the documented parameter tables.

- No core or numerics module imports pythonfmu / pythonfmu3 or the ``agv_core.fmi`` package
  (the imports are read with ``ast``, not run).
- Every component folder has a README.md, at least one slave script, and for each slave
  script the reference result ``<Model>_ref.csv`` equal to the byte to the output of the
  default experiment the built FMU ships (``extra/org.fmi-standard.fmi-ls-ref``). Exact:
  the build writes both from the same simulation with ``repr`` floats, so any difference
  is a change of behaviour.
- Each component README's parameter tables (name, unit, default) match the built FMUs'
  modelDescription.xml both ways: no undocumented parameter, no stale row.
"""

import ast
import re
import zipfile

import fmpy
import pytest

from agv_cosim.build import REFERENCE_DIR, default_components_dir, slave_class_name, slave_scripts

CORE = default_components_dir() / "agv_core"
SCRIPTS = slave_scripts(default_components_dir())
MODELS = {slave_class_name(s): s for s in SCRIPTS}
FORBIDDEN = ("pythonfmu", "pythonfmu3", "agv_core.fmi")


def _is_slave_script(path):
    return path.name.startswith("agv_")


def _core_modules():
    """Every module of agv_core outside fmi/ that is not a slave script."""
    return sorted(p for p in CORE.rglob("*.py")
                  if "__pycache__" not in p.parts and p.relative_to(CORE).parts[0] != "fmi"
                  and not _is_slave_script(p))


def _imports(path, source=None):
    """Absolute names of the modules ``path`` imports (relative ones resolved).

    ``source``: the text to read instead of the file's (for the walker's own test).
    """
    package = ["agv_core", *path.relative_to(CORE).parent.parts]
    text = path.read_text() if source is None else source
    names = []
    for node in ast.walk(ast.parse(text, filename=str(path))):
        if isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            module = ".".join(base + ([node.module] if node.module else []))
            names.append(module)
            names += [f"{module}.{alias.name}" for alias in node.names]
    return names


def test_the_import_walker_resolves_relative_imports():
    """The boundary test below can fail: the walker sees every way of importing the FMI side."""
    source = ("from ..fmi import fmi_slave\nfrom ..fmi.slave_base import SlaveLogic\n"
              "import pythonfmu3.enums\nfrom . import vehicle\nfrom ..numerics.arc import sinc\n")
    names = _imports(CORE / "vehicle" / "probe.py", source)
    assert "agv_core.fmi" in names and "agv_core.fmi.fmi_slave" in names
    assert "agv_core.fmi.slave_base" in names and "pythonfmu3.enums" in names
    assert "agv_core.vehicle.vehicle" in names and "agv_core.numerics.arc.sinc" in names
    assert _imports(CORE / "numerics" / "probe.py", "from .paths import x\n")[0] == \
        "agv_core.numerics.paths"


@pytest.mark.parametrize("module", _core_modules(), ids=lambda p: str(p.relative_to(CORE)))
def test_cores_and_numerics_never_import_the_fmi_side(module):
    bad = [n for n in _imports(module)
           if any(n == f or n.startswith(f + ".") for f in FORBIDDEN)]
    assert not bad, f"{module.relative_to(CORE)} imports {bad}"


def _component_folders():
    return sorted(p for p in CORE.iterdir()
                  if p.is_dir() and p.name not in ("fmi", "numerics", "__pycache__"))


@pytest.mark.parametrize("folder", _component_folders(), ids=lambda p: p.name)
def test_every_component_folder_is_complete(folder):
    assert (folder / "__init__.py").is_file()
    assert (folder / "README.md").is_file()
    scripts = [s for s in SCRIPTS if s.parent == folder]
    assert scripts, f"{folder.name}/ has no slave script"
    for script in scripts:
        model = slave_class_name(script)
        assert (folder / f"{model}_ref.csv").is_file(), f"{folder.name}/{model}_ref.csv missing"
        assert f"`{model}`" in (folder / "README.md").read_text()
    cores = [p for p in folder.glob("*.py") if not _is_slave_script(p) and p.name != "__init__.py"]
    assert cores, f"{folder.name}/ has no core module"


@pytest.mark.parametrize("model", sorted(MODELS))
def test_committed_reference_result_is_the_one_the_fmu_ships(component_fmus, model):
    script = MODELS[model]
    with zipfile.ZipFile(component_fmus[script.stem]) as archive:
        shipped = archive.read(f"{REFERENCE_DIR}/{model}_out.csv")
    committed = (script.parent / f"{model}_ref.csv").read_bytes()
    assert committed == shipped, (f"{model}: the built FMU's reference output differs from "
                                  f"{script.parent.name}/{model}_ref.csv")


_TABLE_HEAD = re.compile(r"^Parameters of `(\w+)`")


def _documented_tables():
    """model -> (README path, [(name, unit, default text), ...]) from every component README."""
    tables = {}
    for readme in sorted(CORE.glob("*/README.md")):
        lines = readme.read_text().splitlines()
        for i, line in enumerate(lines):
            match = _TABLE_HEAD.match(line)
            if not match:
                continue
            j = i + 1
            while j < len(lines) and not lines[j].startswith("|"):
                j += 1
            rows = []
            for row in lines[j + 2:]:
                if not row.startswith("|"):
                    break
                cells = [c.strip() for c in row.strip().strip("|").split("|")]
                rows.append((cells[0].strip("`"), cells[1], cells[2].strip("`")))
            assert match[1] not in tables, f"{match[1]}: two parameter tables"
            tables[match[1]] = (readme, rows)
    return tables


def _same_default(text, variable):
    start = variable.start
    if variable.type in ("Real", "Float64"):
        return float(text) == float(start)
    if variable.type in ("Integer", "Int32"):
        return int(text) == int(start)
    if variable.type == "Boolean":
        return text.lower() == str(start).lower()
    return text == start


def test_every_fmu_has_one_documented_parameter_table_and_no_table_is_stale():
    assert set(_documented_tables()) == set(MODELS)


@pytest.mark.parametrize("model", sorted(MODELS))
def test_documented_parameters_match_the_model_description(component_fmus, model):
    readme, rows = _documented_tables()[model]
    assert readme.parent == MODELS[model].parent, f"{model} documented in {readme}"
    md = fmpy.read_model_description(str(component_fmus[MODELS[model].stem]))
    parameters = {v.name: v for v in md.modelVariables if v.causality == "parameter"}
    documented = {name: (unit, default) for name, unit, default in rows}
    assert len(documented) == len(rows), f"{model}: a parameter documented twice"
    assert sorted(documented) == sorted(parameters), (
        f"{model}: undocumented {sorted(set(parameters) - set(documented))}, "
        f"stale {sorted(set(documented) - set(parameters))}")
    for name, (unit, default) in documented.items():
        variable = parameters[name]
        assert unit == (variable.unit or "-"), f"{model}.{name}: unit {unit} != {variable.unit}"
        assert _same_default(default, variable), (
            f"{model}.{name}: documented default {default} != {variable.start}")
