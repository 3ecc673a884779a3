"""Every FMU's declared start values are what it uses, and it ships its own reference result.

Parametrised over every slave script (components/agv_core/*/agv_*.py): a new component is
checked the
moment it is added. What a slave must declare for these tests: ``default_experiment``
(start, stop, step) and, if its experiment drives inputs, ``reference_inputs`` (see
agv_core.fmi.fmi_slave.AgvSlave); the build does the rest.
"""

import io
import math
import zipfile
from xml.etree import ElementTree

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu
from fmpy.util import read_csv

from agv_cosim.build import (
    REFERENCE_DIR,
    default_components_dir,
    reference_experiment,
    reference_input_rows,
    slave_scripts,
)

SCRIPTS = [p.stem for p in slave_scripts(default_components_dir())]
LS_NAMESPACE = "{http://fmi-standard.org/fmi-ls-manifest}"


def _typed(variable):
    if variable.type == "Real":
        return float(variable.start)
    if variable.type == "Integer":
        return int(variable.start)
    if variable.type == "Boolean":
        return variable.start in ("true", "1")
    return variable.start


@pytest.mark.parametrize("name", SCRIPTS)
def test_writing_every_declared_start_value_changes_nothing(component_fmus, name):
    """A host that writes each input's and parameter's declared start value (many do)
    must get exactly what a host that writes nothing gets."""
    fmu = str(component_fmus[name])
    md = read_model_description(fmu)
    starts = {v.name: _typed(v) for v in md.modelVariables
              if v.causality in ("input", "parameter") and v.start is not None}
    inputs = [v.name for v in md.modelVariables if v.causality == "input"]
    assert all(n in starts for n in inputs), "an input without a start value"
    stop = 1.0
    plain = simulate_fmu(fmu, stop_time=stop, step_size=0.01)
    written = simulate_fmu(fmu, stop_time=stop, step_size=0.01, start_values=starts)
    for column in plain.dtype.names:
        assert np.array_equal(plain[column], written[column]), column


def _reference_files(fmu):
    with zipfile.ZipFile(fmu) as archive:
        names = set(archive.namelist())
        manifest = ElementTree.fromstring(archive.read(f"{REFERENCE_DIR}/fmi-ls-manifest.xml"))
        related = {r.get("role"): r.get("source") for r in manifest.iter("Related")}
        files = {role: archive.read(f"{REFERENCE_DIR}/{source}")
                 for role, source in related.items()
                 if f"{REFERENCE_DIR}/{source}" in names}
        experiment = reference_experiment(archive.read("modelDescription.xml"))
    return manifest, related, files, experiment


@pytest.mark.parametrize("name", SCRIPTS)
def test_ships_its_reference_and_reproduces_it(component_fmus, tmp_path, name):
    fmu = component_fmus[name]
    md = read_model_description(str(fmu))
    assert md.defaultExperiment is not None, "the slave declares no default_experiment"
    manifest, related, files, experiment = _reference_files(fmu)
    assert manifest.get(f"{LS_NAMESPACE}fmi-ls-name") == "org.fmi-standard.fmi-ls-ref"
    assert related["result"] == f"{md.modelName}_out.csv"
    assert set(files) == set(related), "the manifest names a file the FMU lacks"

    reference = np.genfromtxt(io.BytesIO(files["result"]), delimiter=",", names=True)
    outputs = [v.name for v in md.modelVariables
               if v.causality == "output" and v.type == "Real"]
    assert list(reference.dtype.names) == ["time", *outputs]
    steps = round((experiment["stop"] - experiment["start"]) / experiment["step"])
    assert len(reference) == steps + 1
    assert reference["time"][-1] == pytest.approx(experiment["stop"], abs=1e-9)
    # a meaningful experiment: some output moves
    assert any(np.ptp(reference[c]) > 0 for c in outputs), "every output is constant"

    signals = None
    if "input" in files:
        path = tmp_path / related["input"]
        path.write_bytes(files["input"])
        signals = read_csv(str(path))
    again = simulate_fmu(str(fmu), start_time=experiment["start"],
                         stop_time=experiment["stop"], step_size=experiment["step"],
                         output_interval=experiment["step"], input=signals, output=outputs)
    # The CSV holds repr() of every double and the FMU was built, its reference computed,
    # on this machine: the re-run is identical, bit for bit (another machine's kernels
    # may move the last bits, see test_components.py, not a re-run here).
    for column in reference.dtype.names:
        assert np.array_equal(again[column], reference[column]), column


def test_references_hold_the_closed_forms(component_fmus):
    """The shipped results are right, not only reproducible (exact discretisations:
    1e-9 covers the CSV round trip and the arc formula's rounding)."""
    _, _, files, _ = _reference_files(component_fmus["agv_vehicle"])
    vehicle = np.genfromtxt(io.BytesIO(files["result"]), delimiter=",", names=True)
    # alpha = 0.2 rad, v = v0 = 1 m/s, L = 1 m: heading = v tan(alpha) t / L, distance = v t
    assert vehicle["heading"][-1] == pytest.approx(math.tan(0.2) * 10.0, abs=1e-9)
    assert vehicle["distance"][-1] == pytest.approx(10.0, abs=1e-9)
    radius = 1.0 / math.tan(0.2)  # rear-axle centre circles about (-1, R)
    r = np.hypot(vehicle["x_rear"] + 1.0, vehicle["y_rear"] - radius)
    assert np.allclose(r, radius, atol=1e-9)

    _, _, files, _ = _reference_files(component_fmus["agv_steering_a"])
    actuator = np.genfromtxt(io.BytesIO(files["result"]), delimiter=",", names=True)
    # u = 1 V from 0.5 s, K = 0.6 rad/(V s), dead time 0.05 s: alpha(2) = 0.6 (2 - 0.55)
    assert actuator["alpha"][-1] == pytest.approx(0.6 * 1.45, abs=1e-9)
    assert np.all(actuator["alpha"][actuator["time"] <= 0.55 + 1e-9] == 0.0)


def test_reference_inputs_become_held_steps():
    experiment = {"start": 0.0, "stop": 2.0, "step": 0.01,
                  "inputs": {"u": [(0.0, 0.0), (0.5, 1.0)], "w": [(0.0, 3.0), (5.0, 4.0)]}}
    names, rows = reference_input_rows(experiment)
    assert names == ["u", "w"]
    # the step at 0.5 s is two rows at one time; the breakpoint after stop is dropped
    assert rows == [(0.0, 0.0, 3.0), (0.5, 0.0, 3.0), (0.5, 1.0, 3.0), (2.0, 1.0, 3.0)]


def _reference(component_fmus, name):
    _, _, files, _ = _reference_files(component_fmus[name])
    return np.genfromtxt(io.BytesIO(files["result"]), delimiter=",", names=True)


def test_seed003_references_hold_the_closed_forms(component_fmus):
    """The seed-003 slaves' shipped results against closed forms (1e-9: CSV round trip
    and rounding of exact discretisations; the train's floating car is integrated, so
    only its exact parts are checked)."""
    train = _reference(component_fmus, "agv_train")
    v0, t = 14.0 / 3.6, train["time"]
    # u1 = v0 + dv, dv = 1 m/s from 5 s: the start value of dv (0) is what runs before
    distance = v0 * t + np.where(t > 5.0 + 1e-9, t - 5.0, 0.0)
    assert np.allclose(train["distance"], distance, atol=1e-9)
    assert np.allclose(train["heading1"], math.tan(0.05) / 5.0 * distance, atol=1e-9)
    # J2 = J1 - Lm e2(psi2): psi2 is integrated to 1e-12 rad a step, 200 steps x 9 m
    assert np.all(train["heading3"] == 0.0) and np.allclose(train["y_J2"], 0.0, atol=1e-8)
    assert np.allclose(np.hypot(train["x_J1"] - train["x_J2"], train["y_J1"] - train["y_J2"]),
                       9.0, atol=1e-9)
    assert train["heading2"][-1] > 0.5   # the floating car does swing

    ack = _reference(component_fmus, "agv_ackermann")
    delta = math.asin(5.0 / 40.0)
    for i, sign, offset in ((1, 1.0, 8.0), (2, -1.0, 3.0), (3, 1.0, -3.0), (4, -1.0, -8.0)):
        for row, held in ((4, 0.0), (6, sign * delta), (11, -sign * delta)):  # 0.4, 0.6, 1.1 s
            tt = math.tan(held)
            assert ack[f"delta{i}_left"][row] == pytest.approx(
                math.atan(offset * tt / (offset - 1.05 * tt)), abs=1e-12)
            assert ack[f"delta{i}_right"][row] == pytest.approx(
                math.atan(offset * tt / (offset + 1.05 * tt)), abs=1e-12)
            assert ack[f"centre_curvature{i}"][row] == pytest.approx(tt / offset, abs=1e-12)

    errors = _reference(component_fmus, "agv_axle_errors")   # default path: the x axis
    for i, (y_before, y_after, x_before) in enumerate(
            ((0.5, -0.25, 10.0), (-0.3, 0.125, 7.0), (0.2, 0.0, -2.0), (0.0, 1.5, -5.0)), 1):
        assert errors[f"e{i}"][4] == pytest.approx(y_before, abs=1e-12)
        assert errors[f"e{i}"][-1] == pytest.approx(y_after, abs=1e-12)
        assert errors[f"s{i}"][4] == pytest.approx(x_before, abs=1e-12)
        assert errors[f"s{i}"][-1] == pytest.approx(x_before + 2.0, abs=1e-12)

    from agv_core.axle_pd.fuzzy_pd import FuzzySchedule
    kp_fuzzy, kd_fuzzy = FuzzySchedule().gains(0.01, 14.0)
    for name, kp, kd in (("agv_fixed_pd", 710.0, 112.0), ("agv_fuzzy_pd", kp_fuzzy, kd_fuzzy)):
        pd = _reference(component_fmus, name)
        kp, kd, after = math.radians(kp), math.radians(kd), pd["time"] > 0.5 + 1e-9
        rate = 0.01 / 0.05 * np.exp(-(pd["time"][after] - 0.5) / 0.05)
        assert np.allclose(pd["Kp_used"][after], kp, atol=1e-9), name
        assert np.allclose(pd["error_rate"][after], rate, atol=1e-9), name
        assert np.allclose(pd["delta"][after], -(kp * 0.01 + kd * rate), atol=1e-9), name
        assert np.all(pd["delta"][pd["time"] < 0.5 - 1e-9] == 0.0), name
