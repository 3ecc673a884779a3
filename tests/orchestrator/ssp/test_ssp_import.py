"""Class 4 of issue 10: SSP import is exact or refuses.

Hand-written SSDs around the vehicle FMU: parameter bindings at system and component
level, inline and in .ssv files, with unit conversion through ssc:Unit/BaseUnit; what
cannot be applied exactly is refused with one line naming the .ssp and the element;
names are data; run.json names the .ssp and its FMUs by hash.
"""

import hashlib
import json
import math
import zipfile

import pytest

from agv_cosim import cli
from agv_cosim.timeseries import read_timeseries

HEAD = ('<?xml version="1.0" encoding="UTF-8"?>\n'
        '<ssd:SystemStructureDescription name="imp" version="1.0" '
        'xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription" '
        'xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon" '
        'xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues">\n')
UNITS = ('<ssd:Units><ssc:Unit name="deg"><ssc:BaseUnit rad="1" '
         'factor="0.017453292519943295"/></ssc:Unit>'
         '<ssc:Unit name="mm"><ssc:BaseUnit m="1" factor="0.001"/></ssc:Unit></ssd:Units>')
TAIL = ('<ssd:DefaultExperiment startTime="0.0" stopTime="0.2"><ssd:Annotations>'
        '<ssc:Annotation type="org.agv-cosim"><agv:Experiment '
        'xmlns:agv="https://agv-cosim.org/SSP/Experiment" algorithm="gauss-seidel" '
        'stepSize="0.1"/></ssc:Annotation></ssd:Annotations></ssd:DefaultExperiment>\n'
        '</ssd:SystemStructureDescription>\n')


def _set(params, prefix=""):
    body = "".join(f'<ssv:Parameter name="{n}"><ssv:{t} value="{v}"{u}/></ssv:Parameter>'
                   for n, t, v, u in params)
    return (f'<ssv:ParameterSet version="1.0" name="p" xmlns:ssv='
            f'"http://ssp-standard.org/SSP1/SystemStructureParameterValues">'
            f'<ssv:Parameters>{body}</ssv:Parameters></ssv:ParameterSet>')


def _binding(params, source=None, prefix=""):
    attrs = (f' source="{source}"' if source else "") + (f' prefix="{prefix}"' if prefix
                                                        else "")
    inline = "" if source else f"<ssd:ParameterValues>{_set(params)}</ssd:ParameterValues>"
    return f"<ssd:ParameterBinding{attrs}>{inline}</ssd:ParameterBinding>"


def _package(tmp_path, vehicle_fmu, component_bindings="", system_bindings="",
             name="vehicle", units=UNITS, extra_files=None, connectors=""):
    comp = (f'<ssd:Component name="{name}" source="resources/AgvVehicle.fmu" '
            'type="application/x-fmu-sharedlibrary">'
            + (f"<ssd:Connectors>{connectors}</ssd:Connectors>" if connectors else "")
            + (f"<ssd:ParameterBindings>{component_bindings}</ssd:ParameterBindings>"
               if component_bindings else "") + "</ssd:Component>")
    system = ('<ssd:System name="imp"><ssd:Elements>' + comp + "</ssd:Elements>"
              + (f"<ssd:ParameterBindings>{system_bindings}</ssd:ParameterBindings>"
                 if system_bindings else "") + "</ssd:System>")
    path = tmp_path / "imp.ssp"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("SystemStructure.ssd", HEAD + system + units + TAIL)
        archive.write(vehicle_fmu, "resources/AgvVehicle.fmu")
        for entry, text in (extra_files or {}).items():
            archive.writestr(entry, text)
    return path


@pytest.fixture
def vehicle(component_fmus):
    return component_fmus["agv_vehicle"]


def _run(capsys, ssp, out):
    code = cli.main(["run", str(ssp), "--quiet", "--out", str(out)])
    err = [line for line in capsys.readouterr().err.splitlines() if "warning" not in line]
    return code, err


def test_bindings_at_every_level_with_units(vehicle, tmp_path, capsys):
    """Component: heading0 = 90 deg, x0 = 1 m, y0 from an .ssv with prefix; system:
    vehicle.x0 = 250 mm (overrides the component's 1 m). The pose at t = 0 shows them."""
    ssv = _set([("0", "Real", "-30", ' unit="mm"')])
    ssp = _package(tmp_path, vehicle,
                   connectors='<ssd:Connector name="heading" kind="output"><ssc:Real '
                              'unit="rad"/></ssd:Connector>',
                   component_bindings=_binding([("heading0", "Real", "90", ' unit="deg"'),
                                                ("x0", "Real", "1.0", ' unit="m"')])
                   + _binding(None, source="resources/y.ssv", prefix="y"),
                   system_bindings=_binding([("vehicle.x0", "Real", "250", ' unit="mm"')]),
                   extra_files={"resources/y.ssv": '<?xml version="1.0"?>' + ssv.replace(
                       "</ssv:Parameters>", "</ssv:Parameters><ssv:Units><ssc:Unit "
                       'xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon" '
                       'name="mm"><ssc:BaseUnit m="1" factor="0.001"/></ssc:Unit>'
                       "</ssv:Units>")})
    code, err = _run(capsys, ssp, tmp_path / "out")
    assert code == 0, err
    info = json.loads((tmp_path / "out" / "base" / "run.json").read_text())
    p = info["parameters"]["vehicle"]
    assert p["heading0"] == pytest.approx(math.pi / 2, rel=1e-15)  # 90 deg, not 90 rad
    assert p["x0"] == pytest.approx(0.25, rel=1e-15)   # the system's 250 mm wins
    assert p["y0"] == pytest.approx(-0.03, rel=1e-15)  # .ssv, prefix "y" + name "0"
    t, sig = read_timeseries(tmp_path / "out" / "base" / "timeseries.csv")
    assert sig["vehicle.heading"][0] == pytest.approx(math.pi / 2, rel=1e-15)
    # run.json names the .ssp (with its hash) and the FMU inside it, not a temp folder
    assert info["manifest"] == str(ssp)
    assert info["manifest_sha256"] == hashlib.sha256(ssp.read_bytes()).hexdigest()
    assert info["fmus"]["vehicle"] == f"{ssp}!/resources/AgvVehicle.fmu"
    assert info["fmu_sha256"]["vehicle"] == hashlib.sha256(vehicle.read_bytes()).hexdigest()


@pytest.mark.parametrize("kwargs, element, problem", [
    ({"component_bindings": _binding([("heading0", "Real", "90", ' unit="grad"')])},
     "Component 'vehicle': ParameterBinding: parameter 'heading0'",
     "unit 'grad' has no ssc:Unit definition"),
    ({"component_bindings": _binding([("wheelbase", "Real", "90", ' unit="deg"')])},
     "Component 'vehicle': ParameterBinding: parameter 'wheelbase'",
     "unit 'deg' cannot be converted to [m]"),
    ({"system_bindings": _binding([("v0", "Real", "1", "")])},
     "System: ParameterBinding: parameter 'v0'", "names no component"),
    ({"system_bindings": _binding([("truck.v0", "Real", "1", "")])},
     "System: ParameterBinding: parameter 'truck.v0'", "unknown component 'truck'"),
    ({"component_bindings": _binding([("nope", "Real", "1", "")])},
     "Component 'vehicle': ParameterBinding: parameter 'nope'", "not a parameter"),
    ({"component_bindings": _binding(None, source="resources/missing.ssv")},
     "Component 'vehicle': ParameterBinding", "is not a file in the package"),
    ({"component_bindings": '<ssd:ParameterBinding type="application/json"/>'},
     "Component 'vehicle': ParameterBinding", "type 'application/json' is not supported"),
    ({"connectors": '<ssd:Connector name="heading" kind="output"><ssc:Real unit="deg"/>'
                    '</ssd:Connector>'},
     "Component 'vehicle': Connector 'heading'", "connector unit conversion is not supported"),
    ({"connectors": '<ssd:Connector name="heading" kind="input"><ssc:Real unit="rad"/>'
                    '</ssd:Connector>'},
     "Component 'vehicle': Connector 'heading'", "kind 'input', but the FMU's variable is "
                                                 "output"),
    ({"connectors": '<ssd:Connector name="nope" kind="input"/>'},
     "Component 'vehicle': Connector 'nope'", "not a variable of AgvVehicle"),
    ({"name": "my vehicle"}, "Component 'my vehicle'", "component names must be identifiers"),
    ({"name": "v]x"}, "Component 'v]x'", "component names must be identifiers"),
])
def test_refused_with_one_line_naming_the_ssp(vehicle, tmp_path, capsys, kwargs, element,
                                              problem):
    ssp = _package(tmp_path, vehicle, **kwargs)
    code, err = _run(capsys, ssp, tmp_path / "out")
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith(f"agv-cosim: error: {ssp}: {element}: "), err[0]
    assert problem in err[0]
    assert "agv-cosim-" not in err[0]  # no temporary path
    assert not (tmp_path / "out").exists()


def test_broken_fmu_in_the_package_is_named_inside_it(vehicle, tmp_path, capsys):
    ssp = _package(tmp_path, vehicle,
                   component_bindings=_binding([("heading0", "Real", "1.0", "")]))
    broken = tmp_path / "broken.ssp"
    with zipfile.ZipFile(ssp) as old, zipfile.ZipFile(broken, "w") as new:
        for info in old.infolist():
            data = old.read(info)
            new.writestr(info, b"not a zip" if info.filename.endswith(".fmu") else data)
    code, err = _run(capsys, broken, tmp_path / "out")
    assert code == 2 and len(err) == 1
    assert err[0].startswith(f"agv-cosim: error: {broken}: Component 'vehicle': broken FMU")
    assert f"'{broken}!/resources/AgvVehicle.fmu'" in err[0]


def test_manifest_level_errors_name_the_ssp(vehicle, tmp_path, capsys):
    """A value the manifest check refuses (a String for a Boolean parameter) names the
    .ssp, and an FMU-level refusal at validate too."""
    ssp = _package(tmp_path, vehicle,
                   component_bindings=_binding([("linear", "String", "yes", "")]))
    code, err = _run(capsys, ssp, tmp_path / "out")
    assert code == 2 and len(err) == 1
    assert err[0].startswith(f"agv-cosim: error: {ssp}: ") and "type mismatch" in err[0]
    ssp = _package(tmp_path, vehicle,
                   component_bindings=_binding([("wheelbase", "Real", "-1.5", "")]))
    assert cli.main(["validate", str(ssp)]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if "warning" not in line]
    assert err[0].startswith(f"agv-cosim: error: {ssp}: components.vehicle: the FMU "
                             "refuses to initialise")
    assert "wheelbase" in err[0]
    assert "agv-cosim-" not in err[0]


def test_hostile_text_reaches_the_manifest_unchanged(vehicle, tmp_path):
    """Names and values from an SSD are data, mapped onto the manifest without passing
    through TOML text. The former route (an SSD written out as TOML and read back)
    escaped a non-printable character as ``\\uXXXX`` with ``ord(c):04x``: U+E0041 (a
    format character outside the BMP) became ``\\ue0041``, which TOML reads as U+E004
    followed by "1". Quotes, backslashes, newlines and '#' would all have had to be
    escaped as well; here they are simply strings."""
    from xml.sax.saxutils import escape

    from agv_cosim.ssp.importer import load_ssp

    hostile = '"] \\ #\n[components.x]\nfmu = "/etc/passwd" \U000E0041'
    attribute = escape(hostile, {'"': "&quot;", "\n": "&#10;"})
    ssp = _package(tmp_path, vehicle, component_bindings=_binding(
        [("reference_point", "String", attribute, "")]))
    with zipfile.ZipFile(ssp) as archive:
        text = archive.read("SystemStructure.ssd").decode()
    text = text.replace('<ssd:System name="imp">',
                        f'<ssd:System name="imp" description="{attribute}">')
    with zipfile.ZipFile(ssp, "w") as archive:
        archive.writestr("SystemStructure.ssd", text)
        archive.write(vehicle, "resources/AgvVehicle.fmu")
    manifest = load_ssp(ssp, tmp_path / "work")
    assert manifest.description == hostile
    assert manifest.components["vehicle"].parameters == {"reference_point": hostile}
    assert list(manifest.components) == ["vehicle"]
    assert manifest.path == ssp and not list((tmp_path / "work").rglob("*.toml"))
