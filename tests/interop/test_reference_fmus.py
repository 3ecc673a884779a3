"""Third-party FMU tier: the FMI standard's Reference FMUs run through ``agv-cosim run``.

The FMUs are built once per session from the C sources in
``../shared/third-party/Reference-FMUs`` (``cmake -DFMI_VERSION=2`` and ``3``, then
``make install``) into a temporary folder; the tier is skipped, with the reason, only when
that folder or cmake is missing. Each model's ``<Model>_out.csv`` (written by the
standard's own ``fmusim``) is the reference.

Tolerance: rtol 1e-9, atol 1e-12. The models use a fixed internal solver step that the
communication step (the reference's output interval) is a multiple of, so the only
expected difference is the decimal printing of the reference CSV (16-17 significant
digits); 1e-9 leaves room for that and would still catch any solver or exchange
difference (a different step or a one-step lag moves these values by 1e-4 or more).
"""

import csv
import json
import os
import shutil
import subprocess
import zipfile
from pathlib import Path

import numpy as np
import pytest

from agv_cosim import cli
from agv_cosim.build import build_one

pytestmark = pytest.mark.interop

ROOT = Path(__file__).resolve().parents[2]
SOURCES = Path(os.environ.get("AGV_REFERENCE_FMUS",
                              ROOT.parent / "shared" / "third-party" / "Reference-FMUs"))
RTOL, ATOL = 1e-9, 1e-12
#: (model, communication step [s], stop [s]) as the reference CSVs were written
MODELS = [("BouncingBall", 0.01, 3.0), ("Dahlquist", 0.1, 10.0), ("VanDerPol", 0.01, 20.0),
          ("Stair", 0.2, 10.0), ("Resource", 1.0, 1.0)]


@pytest.fixture(scope="session")
def reference_fmus(tmp_path_factory):
    """FMI version ("2", "3") -> folder of the built Reference FMUs."""
    if not (SOURCES / "CMakeLists.txt").is_file():
        pytest.skip(f"Reference FMU sources not found at {SOURCES}")
    if shutil.which("cmake") is None:
        pytest.skip("cmake is not installed (needed to build the Reference FMUs)")
    root = tmp_path_factory.mktemp("reference_fmus")
    folders = {}
    for version in ("2", "3"):
        build, install = root / f"build{version}", root / f"fmi{version}"
        build.mkdir()
        for command in (["cmake", f"-DFMI_VERSION={version}",
                         f"-DCMAKE_INSTALL_PREFIX={install}", str(SOURCES)],
                        ["make", "-j2", "install"]):
            done = subprocess.run(command, cwd=build, capture_output=True, text=True)
            assert done.returncode == 0, f"{' '.join(command)} failed:\n{done.stderr[-2000:]}"
        folders[version] = install
    return folders


@pytest.fixture(scope="session")
def types_fmu(tmp_path_factory):
    out = tmp_path_factory.mktemp("types_fmu")
    return build_one(ROOT / "tests" / "fmu_src" / "agv_test_types.py", out).fmu


def _run(tmp_path, text, name="m", expect=0):
    manifest = tmp_path / f"{name}.toml"
    manifest.write_text(text)
    out = tmp_path / f"out_{name}"
    code = cli.main(["run", str(manifest), "--out", str(out), "--jobs", "1", "--quiet"])
    assert code == expect
    return out / "base"


def _reference(model):
    with open(SOURCES / model / f"{model}_out.csv", newline="") as stream:
        rows = list(csv.reader(stream))
    return rows[0], np.array(rows[1:], dtype=float)


def _ours(run_dir):
    with open(run_dir / "timeseries.csv", newline="") as stream:
        rows = list(csv.reader(stream))
    return rows[0], rows[1:]


@pytest.mark.parametrize("version", ["2", "3"])
@pytest.mark.parametrize("model,step,stop", MODELS)
def test_reference_output(reference_fmus, tmp_path, version, model, step, stop):
    fmu = reference_fmus[version] / f"{model}.fmu"
    run = _run(tmp_path, f'[simulation]\nstop = {stop}\nstep = {step}\n'
                         f'[components.m]\nfmu = "{fmu}"\n')
    info = json.loads((run / "run.json").read_text())
    assert info["status"] == "complete"
    header, rows = _ours(run)
    ref_header, ref = _reference(model)
    assert header == ["time"] + [f"m.{c}" for c in ref_header[1:]]
    ours = np.array(rows, dtype=float)
    assert ours.shape == ref.shape
    np.testing.assert_allclose(ours, ref, rtol=RTOL, atol=ATOL)
    if model == "Stair":
        # the FMU asks to stop when its counter reaches 10 (t = 9 s): the run ends there,
        # complete, with every row
        assert info["ended_by"] == "m requested stop at t=9.0 s"
        assert ours[-1].tolist() == [9.0, 10.0]
        assert rows[-1] == ["9.0", "10"]  # Integer recorded as an integer
    else:
        assert info["ended_by"] == "stop time"


def test_feedthrough_every_fmi2_type(reference_fmus, types_fmu, tmp_path):
    """Our typed source drives FMI 2.0 and FMI 3.0 Feedthrough; every type passes."""
    ft2, ft3 = (reference_fmus[v] / "Feedthrough.fmu" for v in ("2", "3"))
    text = (f'[simulation]\nstop = 0.5\nstep = 0.1\n'
            f'[components.src]\nfmu = "{types_fmu}"\n'
            f'[components.ft2]\nfmu = "{ft2}"\n[components.ft3]\nfmu = "{ft3}"\n'
            f'[components.ft3b]\nfmu = "{ft3}"\n'
            '[record]\nvariables = ["src.r", "src.i", "src.b", "src.s", '
            '"ft2.Float64_continuous_output", "ft2.Int32_output", "ft2.Boolean_output", '
            '"ft2.String_output", "ft2.Enumeration_output", '
            '"ft3.Float64_continuous_output", "ft3.Int32_output", "ft3.Boolean_output", '
            '"ft3.String_output", "ft3b.Float32_continuous_output", "ft3b.Int8_output", '
            '"ft3b.UInt64_output", "ft3b.Enumeration_output", "src.ro", "src.io", '
            '"src.bo", "src.so"]\n')
    for src, dst in [("src.r", "ft2.Float64_continuous_input"), ("src.i", "ft2.Int32_input"),
                     ("src.b", "ft2.Boolean_input"), ("src.s", "ft2.String_input"),
                     ("src.r", "ft3.Float64_continuous_input"), ("src.i", "ft3.Int32_input"),
                     ("src.b", "ft3.Boolean_input"), ("src.s", "ft3.String_input"),
                     ("ft3.Float32_continuous_output", "ft3b.Float32_continuous_input"),
                     ("ft3.Int8_output", "ft3b.Int8_input"),
                     ("ft3.UInt64_output", "ft3b.UInt64_input"),
                     ("ft3.Enumeration_output", "ft3b.Enumeration_input"),
                     ("ft3.Float64_continuous_output", "src.ri"),
                     ("ft3.Int32_output", "src.ii"), ("ft3.Boolean_output", "src.bi"),
                     ("ft2.String_output", "src.si")]:
        text += f'[[connections]]\nfrom = "{src}"\nto = "{dst}"\n'
    run = _run(tmp_path, text)
    assert json.loads((run / "run.json").read_text())["status"] == "complete"
    header, rows = _ours(run)
    assert len(rows) == 6
    col = {name: [row[i] for row in rows] for i, name in enumerate(header)}
    k = np.arange(6)
    np.testing.assert_array_equal(np.array(col["src.r"], dtype=float), 0.5 * k)
    assert col["src.i"] == [str(3 * j - 7) for j in k]
    assert col["src.b"] == [str(j % 2) for j in k]
    assert col["src.s"] == [f'step {j}, "q"' for j in k]  # comma and quotes round-trip
    for ft in ("ft2", "ft3"):  # each type arrives unchanged, in the same instant (GS)
        assert col[f"{ft}.Float64_continuous_output"] == col["src.r"]
        assert col[f"{ft}.Int32_output"] == col["src.i"]
        assert col[f"{ft}.Boolean_output"] == col["src.b"]
        assert col[f"{ft}.String_output"] == col["src.s"]
    # and back into the FMI 2.0 source's echo inputs
    assert col["src.ro"] == col["src.r"] and col["src.io"] == col["src.i"]
    assert col["src.bo"] == col["src.b"] and col["src.so"] == col["src.s"]
    assert col["ft2.Enumeration_output"] == ["1"] * 6
    assert col["ft3b.Enumeration_output"] == ["1"] * 6
    assert col["ft3b.Int8_output"] == ["0"] * 6 and col["ft3b.UInt64_output"] == ["0"] * 6


@pytest.mark.parametrize("src,dst", [("src.i", "ft.Float64_continuous_input"),
                                     ("src.r", "ft.Int32_input"),
                                     ("src.b", "ft.Int32_input")])
def test_no_implicit_type_conversion(reference_fmus, types_fmu, tmp_path, capsys, src, dst):
    ft = reference_fmus["3"] / "Feedthrough.fmu"
    _run(tmp_path, f'[simulation]\nstop = 0.2\nstep = 0.1\n'
                   f'[components.src]\nfmu = "{types_fmu}"\n[components.ft]\nfmu = "{ft}"\n'
                   f'[[connections]]\nfrom = "{src}"\nto = "{dst}"\n', expect=2)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "connections[0]: type mismatch" in err[0]
    assert "no implicit conversion" in err[0]


def test_parameter_types_checked(reference_fmus, tmp_path, capsys):
    ft = reference_fmus["3"] / "Feedthrough.fmu"
    base = f'[simulation]\nstop = 0.2\nstep = 0.1\n[components.ft]\nfmu = "{ft}"\n'
    run = _run(tmp_path, base + "parameters = { Float64_tunable_parameter = 2 }\n", "ok")
    info = json.loads((run / "run.json").read_text())
    assert info["parameters"]["ft"]["Float64_tunable_parameter"] == 2.0
    _run(tmp_path, base + "parameters = { Float64_tunable_parameter = true }\n", "bad",
         expect=2)
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].endswith("type mismatch: 'ft.Float64_tunable_parameter' is Float64, "
                            "got True")


def _state_space_reference():
    """StateSpace_out.csv: one ``y`` column holding the vector as space-separated text."""
    header, rows = None, []
    with open(SOURCES / "StateSpace" / "StateSpace_out.csv", newline="") as stream:
        for row in csv.reader(stream):
            if header is None:
                header = row
                continue
            rows.append([float(row[0])] + [float(x) for x in row[1].split()])
    assert header == ["time", "y"]
    return np.array(rows)


def test_state_space_arrays(reference_fmus, tmp_path):
    """StateSpace (FMI 3.0 only: the sources build it only for FMI_VERSION 3) has array
    variables. Its output vector y is recorded element by element as ``m.y[1]`` ..
    ``m.y[3]`` (1-based, row-major) and matches the reference within the tier tolerance."""
    fmu = reference_fmus["3"] / "StateSpace.fmu"
    assert not (reference_fmus["2"] / "StateSpace.fmu").exists()
    run = _run(tmp_path, f'[simulation]\nstop = 10.0\nstep = 1.0\n'
                         f'[components.m]\nfmu = "{fmu}"\n')
    info = json.loads((run / "run.json").read_text())
    assert info["status"] == "complete" and info["ended_by"] == "stop time"
    header, rows = _ours(run)
    assert header == ["time", "m.y[1]", "m.y[2]", "m.y[3]"]
    ref = _state_space_reference()
    ours = np.array(rows, dtype=float)
    assert ours.shape == ref.shape == (11, 4)
    np.testing.assert_allclose(ours, ref, rtol=RTOL, atol=ATOL)


def test_state_space_array_parameters(reference_fmus, tmp_path):
    """Whole arrays set as parameters (flat lists, row-major). With D = 0 and B having
    its only 1 in row 3, column 1: x1 = x2 = 0 and x3' = x3 + u1, which is the reference
    run's x1 (x1' = x1 + u1), so y = (0, 0, y1_ref - u1). Column-major order would put
    the 1 at row 1, column 3 (x1' = x1 + u3) and give (y3_ref - 3, 0, 0) instead."""
    fmu = reference_fmus["3"] / "StateSpace.fmu"
    run = _run(tmp_path, f'[simulation]\nstop = 3.0\nstep = 1.0\n'
                         f'[components.m]\nfmu = "{fmu}"\n'
                         'parameters = { D = [0, 0, 0, 0, 0, 0, 0, 0, 0], '
                         'B = [0, 0, 0, 0, 0, 0, 1, 0, 0] }\n'
                         '[record]\nvariables = ["m.y[3]", "m.y[1]", "m.y[2]"]\n')
    info = json.loads((run / "run.json").read_text())
    assert info["parameters"]["m"]["B"] == [0.0] * 6 + [1.0, 0.0, 0.0]
    header, rows = _ours(run)
    assert header == ["time", "m.y[3]", "m.y[1]", "m.y[2]"]
    ours = np.array(rows, dtype=float)
    ref = _state_space_reference()[:4]
    np.testing.assert_allclose(ours[:, 1], ref[:, 1] - 1.0, rtol=RTOL, atol=ATOL)
    assert ours[:, 2].tolist() == [0.0] * 4 and ours[:, 3].tolist() == [0.0] * 4


@pytest.mark.parametrize("extra,message", [
    ('[record]\nvariables = ["m.y"]\n',
     "record.variables[0]: 'm.y' is an array variable (record its elements, 'y[1]' ..)"),
    ('[record]\nvariables = ["m.y[4]"]\n',
     "record.variables[0]: unknown variable 'm.y[4]'"),
    ('[components.m.parameters]\nD = [1, 2]\n', "'m.D' has 9 elements, got a list of 2"),
    ('[components.m.parameters]\nD = 1.0\n',
     "type mismatch: 'm.D' is an array of 9 Float64"),
    ('[components.m.parameters]\nD = [0, 0, 0, 0, true, 0, 0, 0, 0]\n',
     "type mismatch: 'm.D' is an array of Float64: element 5 is Float64, got True"),
    ('[components.ft]\nfmu = "FT"\n[[connections]]\nfrom = "m.y[1]"\n'
     'to = "ft.Float64_continuous_input"\n',
     "connections[0]: 'm.y[1]' is an array element (only recorded; set the whole array "
     "as a parameter)"),
])
def test_array_misuse_refused(reference_fmus, tmp_path, capsys, extra, message):
    fmu = reference_fmus["3"] / "StateSpace.fmu"
    extra = extra.replace("FT", str(reference_fmus["3"] / "Feedthrough.fmu"))
    _run(tmp_path, f'[simulation]\nstop = 1.0\nstep = 1.0\n[components.m]\nfmu = "{fmu}"\n'
                   + extra, expect=2)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err


def test_model_exchange_only_runs_integrated(reference_fmus, tmp_path):
    """An FMU without <CoSimulation> runs through ``agv-cosim run``: the orchestrator
    integrates it (agv_cosim.execution.model_exchange, CVODE at relative tolerance 1e-6):
    Dahlquist's x = exp(-t) within 1e-5."""
    source = reference_fmus["2"] / "Dahlquist.fmu"
    target = tmp_path / "DahlquistME.fmu"
    with zipfile.ZipFile(source) as zin, zipfile.ZipFile(target, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item)
            if item.filename == "modelDescription.xml":
                text = data.decode()
                start = text.index("<CoSimulation")
                end = text.index(">", text.index("</CoSimulation>") if "</CoSimulation>"
                                 in text else start) + 1
                data = (text[:start] + text[end:]).encode()
            zout.writestr(item, data)
    run = _run(tmp_path, f'[simulation]\nstop = 1.0\nstep = 0.1\n'
                         f'[components.m]\nfmu = "{target}"\n')
    header, rows = _ours(run)
    values = np.array(rows, dtype=float)
    assert header == ["time", "m.x"] and len(values) == 11
    assert np.allclose(values[:, 1], np.exp(-values[:, 0]), rtol=0, atol=1e-5)


def test_ssp_enumeration_connectors_round_trip(reference_fmus, tmp_path):
    """Enumeration connectors are exported as ``ssc:Enumeration name="Option"`` with the
    items in ``ssd:Enumerations`` (FMI 2.0 SimpleType and FMI 3.0 EnumerationType give the
    same one), read back into the same connections, and the .ssp runs like the manifest."""
    from xml.etree import ElementTree

    from agv_cosim.ssp import common as ssp
    from agv_cosim.ssp import exporter as ssp_export
    from agv_cosim.ssp import importer as ssp_import

    ft2, ft3 = (reference_fmus[v] / "Feedthrough.fmu" for v in ("2", "3"))
    manifest = tmp_path / "enum.toml"
    manifest.write_text(
        f'[simulation]\nstop = 0.3\nstep = 0.1\nalgorithm = "gauss-seidel"\n'
        f'[components.a]\nfmu = "{ft2}"\n[components.b]\nfmu = "{ft3}"\n'
        f'[components.c]\nfmu = "{ft3}"\n'
        '[[connections]]\nfrom = "a.Enumeration_output"\nto = "b.Enumeration_input"\n'
        '[[connections]]\nfrom = "b.Enumeration_output"\nto = "c.Enumeration_input"\n'
        '[record]\nvariables = ["a.Enumeration_output", "b.Enumeration_output", '
        '"c.Enumeration_output"]\n')
    package = ssp_export.export_ssp(manifest, tmp_path / "enum.ssp")
    with zipfile.ZipFile(package) as archive:
        root = ElementTree.fromstring(archive.read("SystemStructure.ssd"))
    ns = ssp.NS
    for comp, kinds in (("a", {"output"}), ("b", {"input", "output"}), ("c", {"input"})):
        found = root.findall(f"ssd:System/ssd:Elements/ssd:Component[@name='{comp}']/"
                             "ssd:Connectors/ssd:Connector", ns)
        enums = {c.get("name"): (c.get("kind"), c.find("ssc:Enumeration", ns))
                 for c in found if c.find("ssc:Enumeration", ns) is not None}
        assert {k for k, _ in enums.values()} >= kinds
        assert all(e.get("name") == "Option" for _, e in enums.values())
    defined = root.findall("ssd:Enumerations/ssc:Enumeration", ns)
    assert [e.get("name") for e in defined] == ["Option"]
    assert [(i.get("name"), i.get("value")) for i in defined[0].findall("ssc:Item", ns)] \
        == [("Option 1", "1"), ("Option 2", "2")]
    again = ssp_import.load_ssp(package, tmp_path / "back")
    assert [(c.source, c.target) for c in again.connections] == \
        [(("a", "Enumeration_output"), ("b", "Enumeration_input")),
         (("b", "Enumeration_output"), ("c", "Enumeration_input"))]
    out_m, out_s = tmp_path / "out_m", tmp_path / "out_s"
    for source, out in ((manifest, out_m), (package, out_s)):
        assert cli.main(["run", str(source), "--out", str(out), "--jobs", "1",
                         "--quiet"]) == 0
    ours_m, ours_s = _ours(out_m / "base"), _ours(out_s / "base")
    assert ours_m == ours_s
    assert ours_m[0] == ["time", "a.Enumeration_output", "b.Enumeration_output",
                         "c.Enumeration_output"]
    assert [r[1:] for r in ours_m[1]] == [["1", "1", "1"]] * 4


def test_ssp_export_refuses_array_parameters(reference_fmus, tmp_path, capsys):
    """SSP parameters are scalars: a manifest setting an FMI 3.0 array is not exported."""
    fmu = reference_fmus["3"] / "StateSpace.fmu"
    manifest = tmp_path / "ss.toml"
    manifest.write_text(f'[simulation]\nstop = 1.0\nstep = 1.0\n[components.m]\n'
                        f'fmu = "{fmu}"\nparameters = {{ x0 = [1, 2, 3] }}\n')
    code = cli.main(["export-ssp", str(manifest), "-o", str(tmp_path / "ss.ssp")])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "components.m.parameters.x0: an FMI 3.0 array parameter " \
        "cannot be written to an SSP package" in err[0], err
    assert not (tmp_path / "ss.ssp").exists()
