"""The component layout (components/README.md): one folder per component, the FMI boundary,
the committed reference results and the documented parameter tables.

- No core or numerics module imports pythonfmu / pythonfmu3 or the ``agv_core.fmi`` package
  (the imports are read with ``ast``, not run).
- Every component folder has a README.md, at least one slave script, and for each slave
  script the reference result ``<Model>_ref.csv``, the output of the default experiment
  that the built FMU ships (``extra/org.fmi-standard.fmi-ls-ref``), computed where the
  committed file was made. The FMU built here computes its own on this machine, so the two
  are compared within ``REFERENCE_TOLERANCE`` (see there), not byte for byte: the header,
  the number of rows and the time column exactly, every output within the band.
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


#: Band of a committed reference result against the one built here, as a fraction of
#: each column's largest magnitude (at least 1 in the column's unit). A reference result
#: depends on the machine that computed it: OpenBLAS (scipy's and numpy's LAPACK/BLAS) is
#: built with DYNAMIC_ARCH and picks its kernel by CPU (Haswell, SkylakeX, ...), and numpy
#: picks its SIMD loops for tan, arctan, exp by CPU (AVX2, AVX-512), so the last bits of a
#: Riccati solution or a matrix exponential move with the machine. Measured by re-running
#: every default experiment here under OPENBLAS_CORETYPE=Haswell/SkylakeX/Prescott with
#: and without NPY_DISABLE_CPU_FEATURES="X86_V4 AVX512_ICL AVX512_SPR": at most 1.1e-15
#: of the column (AgvPreviewLq alpha_ref, AgvSteeringC alpha_rate, AgvLtvMpc domega), the
#: other models bit for bit. 1e-12 leaves a factor of about 1000 and is far below any
#: modelled effect; a re-run on one machine is checked bit for bit (test_fmu_reference.py).
REFERENCE_TOLERANCE = 1e-12


def _table(data):
    """(header, rows as lists of floats) of a reference CSV."""
    lines = data.decode().splitlines()
    return lines[0].split(","), [[float(x) for x in line.split(",")] for line in lines[1:]]


def reference_differences(committed, shipped, tolerance=REFERENCE_TOLERANCE):
    """Where two reference CSVs (bytes) differ beyond ``tolerance``: one line per column
    (its worst row), the header, row count and time column compared exactly."""
    head_c, rows_c = _table(committed)
    head_s, rows_s = _table(shipped)
    if head_c != head_s:
        return [f"columns {head_c} != {head_s}"]
    if len(rows_c) != len(rows_s):
        return [f"{len(rows_c)} rows != {len(rows_s)}"]
    found = []
    for j, name in enumerate(head_c):
        column_c = [row[j] for row in rows_c]
        column_s = [row[j] for row in rows_s]
        band = 0.0 if j == 0 else tolerance * max(1.0, *map(abs, column_c))
        worst = max(range(len(column_c)), key=lambda i: abs(column_s[i] - column_c[i]))
        if not abs(column_s[worst] - column_c[worst]) <= band:
            found.append(f"{name}: row {worst + 1}: {column_c[worst]!r} committed, "
                         f"{column_s[worst]!r} built (band {band:.3g})")
    return found


def test_reference_comparison_sees_a_difference_beyond_the_band():
    committed = b"time,x,y\n0.0,1.0,100.0\n0.1,2.0,-200.0\n"
    assert reference_differences(committed, committed) == []
    assert reference_differences(committed, b"time,x,y\n0.0,1.0,100.0\n0.1,2.0,"
                                            b"-200.00000000000003\n") == []  # 1 ulp
    assert reference_differences(committed, b"time,x,y\n0.0,1.0000000001,100.0\n"
                                            b"0.1,2.0,-200.0\n") == [
        "x: row 1: 1.0 committed, 1.0000000001 built (band 2e-12)"]
    assert reference_differences(committed, b"time,x,y\n0.0,1.0,100.0\n"
                                            b"0.10000000000000002,2.0,-200.0\n") == [
        "time: row 2: 0.1 committed, 0.10000000000000002 built (band 0)"]
    assert reference_differences(committed, b"time,y,x\n0.0,1.0,100.0\n") == [
        "columns ['time', 'x', 'y'] != ['time', 'y', 'x']"]
    assert reference_differences(committed, b"time,x,y\n0.0,1.0,100.0\n") == [
        "2 rows != 1"]


@pytest.mark.parametrize("model", sorted(MODELS))
def test_committed_reference_result_is_the_one_the_fmu_ships(component_fmus, model):
    script = MODELS[model]
    with zipfile.ZipFile(component_fmus[script.stem]) as archive:
        shipped = archive.read(f"{REFERENCE_DIR}/{model}_out.csv")
    committed = (script.parent / f"{model}_ref.csv").read_bytes()
    differences = reference_differences(committed, shipped)
    assert not differences, (f"{model}: the built FMU's reference output differs from "
                             f"{script.parent.name}/{model}_ref.csv: "
                             + "; ".join(differences))


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
