"""FMI 3.0 twins (``agv-cosim build --fmi 3``): valid, described, and bit-identical to FMI 2.0.

Every slave script in components/agv_core/*/ is built a second time as an FMI 3.0 co-simulation
FMU with pythonfmu3 (agv_core/fmi/fmi3_slave.py). Checked here, per component:

- ``fmpy.validation.validate_fmu`` reports nothing;
- units, descriptions and output dependencies say what the FMI 2.0 twin says;
- simulated with ``fmpy.simulate_fmu`` over the FMU's default experiment with its
  reference inputs (every component declares one), every output equals the FMI 2.0
  twin's bit for bit (same slave code, same core, same float operations: no tolerance is
  due);
- state save/restore (and serialisation) on a twin restarts the run exactly;
- ``agv-cosim run`` on a closed loop (the seed-000 model-a loop) with every FMU FMI 2.0,
  every FMU an FMI 3.0 twin, and FMI 2.0 and 3.0 mixed records the same time series
  text (repr floats, so bit for bit), Gauss-Seidel and Jacobi.

The FMI 3.0 twins run pythonfmu3's own binary, which has pythonfmu 0.7's exit-time defect
(docs/using-the-fmus.md): they are only ever run in child processes here (the
orchestrator runs every run in a child of its own), never in the test process.
"""

import hashlib
import json
import subprocess
import sys
import textwrap
import zipfile
from xml.etree import ElementTree

import pytest
from fmpy.validation import validate_fmu

from agv_cosim import cli
from agv_cosim.build import (
    BuildError,
    build_one,
    default_components_dir,
    slave_script,
    slave_scripts,
)

SCRIPTS = [p.stem for p in slave_scripts(default_components_dir())]

# Run in a child process: simulate every (FMI 2.0, FMI 3.0) pair over the default
# experiment with the reference inputs; print {stem: {"2": {col: [...]}, "3": {...}}}.
_SIMULATE_PAIRS = textwrap.dedent("""
    import json, sys, zipfile
    import numpy as np
    from fmpy import read_model_description, simulate_fmu
    from agv_cosim.build import reference_experiment, reference_input_rows

    pairs = json.loads(sys.argv[1])
    out = {}
    for stem, (fmu2, fmu3) in pairs.items():
        with zipfile.ZipFile(fmu2) as archive:
            experiment = reference_experiment(archive.read("modelDescription.xml"))
        if experiment is None:
            out[stem] = {"2": {"error": "no default experiment"}, "3": {}}
            continue
        signals = None
        if experiment["inputs"]:
            names, rows = reference_input_rows(experiment)
            signals = np.array(rows, dtype=[("time", float)] + [(n, float) for n in names])
        out[stem] = {}
        for version, fmu in (("2", fmu2), ("3", fmu3)):
            md = read_model_description(fmu)
            outputs = [v.name for v in md.modelVariables if v.causality == "output"]
            try:
                result = simulate_fmu(fmu, start_time=experiment["start"],
                                      stop_time=experiment["stop"],
                                      step_size=experiment["step"],
                                      output_interval=experiment["step"], input=signals,
                                      output=outputs)
            except Exception as error:
                out[stem][version] = {"error": f"{type(error).__name__}: {error}"}
                continue
            out[stem][version] = {name: [float(x) for x in result[name]]
                                  for name in result.dtype.names}
    print(json.dumps(out))
""")

# Run in a child process: the steering actuator (model a, a 50 ms dead time held in the
# core's delay line) under a 1 V step at 0.5 s; save the state at 0.52 s, inside the dead
# time, run on to 0.6 s; restore (directly, and through serialisation) and run again.
_STATE_ROUND_TRIP = textwrap.dedent("""
    import json, sys
    from fmpy import extract, read_model_description
    from fmpy.fmi3 import FMU3Slave

    fmu = sys.argv[1]
    md = read_model_description(fmu)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    slave = FMU3Slave(guid=md.guid, unzipDirectory=extract(fmu),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="a")
    slave.instantiate()
    slave.enterInitializationMode(startTime=0.0)
    slave.exitInitializationMode()
    h, t = 0.001, 0.0

    def run(until):
        global t
        trace = []
        while t < until - h / 2:
            slave.setFloat64([vr["u"]], [1.0 if t >= 0.5 - h / 2 else 0.0])
            slave.doStep(t, h)
            t += h
            trace.append(slave.getFloat64([vr["alpha"], vr["alpha_rate"]]))
        return trace

    run(0.52)
    saved_t, state = t, slave.getFMUState()
    first = run(0.6)
    slave.setFMUState(state)
    t = saved_t
    again = run(0.6)
    blob = slave.serializeFMUState(state)
    slave.setFMUState(slave.deserializeFMUState(blob))
    t = saved_t
    from_bytes = run(0.6)
    slave.freeFMUState(state)
    slave.terminate()
    slave.freeInstance()
    print(json.dumps({"first": first, "again": again, "from_bytes": from_bytes,
                      "serialised_bytes": len(blob)}))
""")


def _child(code, *args):
    done = subprocess.run([sys.executable, "-c", code, *args], capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def pair_results(component_fmus, twins):
    pairs = {stem: [str(component_fmus[stem]), str(twins[stem])] for stem in SCRIPTS}
    return _child(_SIMULATE_PAIRS, json.dumps(pairs))


def _description(fmu):
    with zipfile.ZipFile(fmu) as archive:
        return ElementTree.fromstring(archive.read("modelDescription.xml"))


def _interface(root):
    """name -> (causality, unit, description, dependencies by name or None) of an FMU."""
    fmi3 = root.get("fmiVersion") == "3.0"
    variables = list(root.find("ModelVariables"))
    if fmi3:
        by_ref = {v.get("valueReference"): v for v in variables}
        outputs = root.find("ModelStructure").iterfind("Output")
        key, lookup = "valueReference", by_ref
    else:
        by_ref = {str(i): v for i, v in enumerate(variables, start=1)}
        found = root.find("ModelStructure/Outputs")
        outputs = [] if found is None else list(found)
        key, lookup = "index", by_ref
    deps = {}
    for unknown in outputs:
        listed = unknown.get("dependencies")
        names = None if listed is None else sorted(lookup[d].get("name")
                                                   for d in listed.split())
        deps[lookup[unknown.get(key)].get("name")] = names
    table = {}
    for v in variables:
        if v.get("causality") == "independent":
            continue
        unit = v.get("unit") if fmi3 else (v[0].get("unit") if len(v) else None)
        table[v.get("name")] = (v.get("causality"), unit, v.get("description"),
                                deps.get(v.get("name")))
    return table


@pytest.mark.parametrize("name", SCRIPTS)
def test_twin_validates_clean_and_declares_what_its_fmi2_twin_does(component_fmus, twins,
                                                                   name):
    fmu3 = twins[name]
    assert validate_fmu(str(fmu3)) == []
    root3 = _description(fmu3)
    assert root3.get("fmiVersion") == "3.0"
    cosim = root3.find("CoSimulation")
    assert cosim.get("canGetAndSetFMUState") == "true"
    assert cosim.get("canSerializeFMUState") == "true"
    assert cosim.get("canHandleVariableCommunicationStepSize") == "true"
    fmi2, fmi3 = _interface(_description(component_fmus[name])), _interface(root3)
    assert fmi3 == fmi2
    assert all(description for _, _, description, _ in fmi3.values())
    for causality, _, _, deps in fmi3.values():
        assert (deps is not None) == (causality == "output")  # every output says its own
    units = {u.get("name") for u in root3.iterfind("UnitDefinitions/Unit")}
    float64 = [v for v in root3.find("ModelVariables") if v.tag == "Float64"]
    assert all(v.get("unit") in units for v in float64)
    # starts in repr's exact form (pythonfmu3's 16 digits do not round-trip every double)
    starts = [v.get("start") for v in float64 if v.get("start") is not None]
    assert starts and all(text == repr(float(text)) for text in starts)


@pytest.mark.parametrize("name", SCRIPTS)
def test_twin_outputs_are_bit_identical_to_the_fmi2_twin(pair_results, name):
    fmi2, fmi3 = pair_results[name]["2"], pair_results[name]["3"]
    assert "error" not in fmi2, f"{name} (FMI 2.0): {fmi2['error']}"
    assert "error" not in fmi3, f"{name} (FMI 3.0): {fmi3['error']}"
    assert list(fmi3) == list(fmi2)
    assert len(fmi2["time"]) > 10
    for column in fmi2:
        assert [x.hex() for x in fmi3[column]] == [x.hex() for x in fmi2[column]], column


def test_every_compared_twin_has_a_moving_output(pair_results):
    """The comparison above is not between constants: in every run some output varies."""
    ran = {stem for stem, runs in pair_results.items()
           if "error" not in runs["2"] and "error" not in runs["3"]}
    moving = {stem for stem in ran
              if any(len(set(values)) > 1
                     for col, values in pair_results[stem]["3"].items() if col != "time")}
    assert moving == ran == set(SCRIPTS)


def test_twin_state_save_and_restore_repeats_the_run_exactly(twins):
    result = _child(_STATE_ROUND_TRIP, str(twins["agv_steering_a"]))
    assert len(result["first"]) == 80
    # the saved state is inside the dead time: the motor starts moving only after it
    assert result["first"][0][0] != result["first"][-1][0]
    assert result["again"] == result["first"]
    assert result["from_bytes"] == result["first"]
    assert result["serialised_bytes"] > 0


def test_twins_never_replace_fmi2_fmus(component_fmus, tmp_path):
    out = tmp_path / "mixed"
    out.mkdir()
    fmi2 = out / component_fmus["agv_vehicle"].name
    fmi2.write_bytes(component_fmus["agv_vehicle"].read_bytes())
    with pytest.raises(BuildError, match="is an FMI 2.0 FMU; build the FMI 3.0 twins into"):
        build_one(slave_script("agv_vehicle"), out, fmi_version=3)
    assert fmi2.read_bytes() == component_fmus["agv_vehicle"].read_bytes()


# The seed-000 model-a loop (experiments/seed000_models_abc.toml): vehicle -> vision sensor
# -> state feedback -> actuator (50 ms dead time) -> vehicle, actuator -> steering-angle
# sensor -> state feedback; 0.1 m initial offset. One variant per FMI mix. In "mixed" the
# signals cross versions both ways: vehicle, sensor and steer are FMI 3.0, act and ctrl
# FMI 2.0 (ctrl 2 -> act 2 -> vehicle 3 -> sensor 3 -> ctrl 2; act 2 -> steer 3 -> ctrl 2).
_LOOP_VERSIONS = {
    "fmi2": {"act": 2, "vehicle": 2, "sensor": 2, "steer": 2, "ctrl": 2},
    "fmi3": {"act": 3, "vehicle": 3, "sensor": 3, "steer": 3, "ctrl": 3},
    "mixed": {"act": 2, "vehicle": 3, "sensor": 3, "steer": 3, "ctrl": 2},
}
_LOOP_STEMS = {"act": "agv_steering_a", "vehicle": "agv_vehicle",
               "sensor": "agv_vision_sensor", "steer": "agv_steer_sensor",
               "ctrl": "agv_state_feedback"}
_LOOP = """
name = "fmi_mix"
[simulation]
start = 0.0
stop = 2.0
step = 0.001
algorithm = "{algorithm}"
[components.act]
fmu = "{act}"
parameters = {{ K = 0.6, tau = 0.05 }}
[components.vehicle]
fmu = "{vehicle}"
parameters = {{ wheelbase = 1.4944, v0 = 1.0, y0 = 0.1, reference_point = "front", linear = false }}
[components.sensor]
fmu = "{sensor}"
parameters = {{ path = "line:", frame_period = 0.0, latency = 0.0 }}
[components.steer]
fmu = "{steer}"
[components.ctrl]
fmu = "{ctrl}"
parameters = {{ Ka = 4.828, Kb = 3.767, Ke = 4.472 }}
[[connections]]
from = "vehicle.x"
to = "sensor.x"
[[connections]]
from = "vehicle.y"
to = "sensor.y"
[[connections]]
from = "vehicle.heading"
to = "sensor.heading"
[[connections]]
from = "sensor.lateral_error"
to = "ctrl.lateral_error"
[[connections]]
from = "sensor.heading_error"
to = "ctrl.heading_error"
[[connections]]
from = "act.alpha"
to = "steer.alpha"
[[connections]]
from = "steer.alpha_meas"
to = "ctrl.alpha"
[[connections]]
from = "ctrl.u"
to = "act.u"
[[connections]]
from = "act.alpha"
to = "vehicle.alpha"
[record]
variables = ["vehicle.x", "vehicle.y", "vehicle.heading", "vehicle.distance",
             "sensor.lateral_error", "sensor.heading_error", "steer.alpha_meas",
             "act.alpha", "act.alpha_rate", "ctrl.u"]
"""


@pytest.mark.parametrize("algorithm", ["gauss-seidel", "jacobi"])
def test_orchestrator_runs_fmi2_fmi3_and_mixed_loops_bit_identically(component_fmus, twins,
                                                                    tmp_path, algorithm):
    """``agv-cosim run`` on one closed loop three ways: every FMU FMI 2.0, every FMU its
    FMI 3.0 twin, and a mix; the recorded time series (repr floats) are the same text."""
    fmus = {2: component_fmus, 3: twins}
    text = _LOOP.format(algorithm=algorithm,
                        **{c: component_fmus[s].as_posix() for c, s in _LOOP_STEMS.items()})
    for variant, versions in _LOOP_VERSIONS.items():
        text += f"[variants.{variant}]\n"
        for component, version in versions.items():
            path = fmus[version][_LOOP_STEMS[component]].as_posix()
            text += f'[variants.{variant}.components.{component}]\nfmu = "{path}"\n'
    manifest = tmp_path / "fmi_mix.toml"
    manifest.write_text(text)
    out = tmp_path / "out"
    assert cli.main(["run", str(manifest), "--out", str(out), "--quiet"]) == 0

    series = {}
    for variant in _LOOP_VERSIONS:
        run = json.loads((out / variant / "run.json").read_text())
        assert run["status"] == "complete"
        # each component ran the FMU of the version the variant names
        assert run["fmu_sha256"] == {
            c: hashlib.sha256(fmus[v][_LOOP_STEMS[c]].read_bytes()).hexdigest()
            for c, v in _LOOP_VERSIONS[variant].items()}
        series[variant] = (out / variant / "timeseries.csv").read_text()
    rows = series["fmi2"].splitlines()
    assert len(rows) == 2002  # header + t = 0 .. 2 s at 1 ms
    # the loop does something: the 0.1 m offset is being corrected, the actuator moves
    head = rows[0].split(",")
    first, last = (dict(zip(head, map(float, r.split(",")))) for r in (rows[1], rows[-1]))
    assert first["sensor.lateral_error"] != last["sensor.lateral_error"]
    assert first["act.alpha"] != last["act.alpha"]
    assert series["fmi3"] == series["fmi2"]
    assert series["mixed"] == series["fmi2"]


def test_annotations_stand_where_the_fmi3_schema_puts_them(twins):
    """FMI 3.0's fmi3ModelDescription.xsd puts <Annotations> last in fmiModelDescription,
    after ModelStructure: our twins do, and validate. (The FMI Library's FMI 3 parser
    rejecting it there is that parser's error.) The same document with Annotations
    moved first does not validate, so the check can fail."""
    from pathlib import Path

    import fmpy
    from lxml import etree

    schema = etree.XMLSchema(etree.parse(str(Path(fmpy.__file__).parent / "schema" / "fmi3" /
                                             "fmi3ModelDescription.xsd")))
    with zipfile.ZipFile(twins["agv_vehicle"]) as archive:
        document = etree.fromstring(archive.read("modelDescription.xml"))
    assert [child.tag for child in document][-2:] == ["ModelStructure", "Annotations"]
    assert schema.validate(document), schema.error_log
    annotations = document.find("Annotations")
    document.remove(annotations)
    document.insert(0, annotations)
    assert not schema.validate(document)
