"""Initial unknowns with their true dependencies, FMI 2.0 and FMI 3.0.

An ``InitialUnknown`` without ``dependencies`` depends, per the standard, on every known
of Initialization Mode, inputs included: an importer that builds the initialisation
graph from it (OMSimulator) then sees an algebraic loop wherever two FMUs are connected
both ways. Every component FMU and FMI 3.0 twin lists, for every output:

- in FMI 2.0 (2.2.8) the ``ScalarVariable`` indices, ascending, of the inputs its
  ``Outputs`` entry names (the slave's ``depends_on`` declaration), of the inputs the
  slave declares ``builds_core`` (``make_core`` reads them: ``CORE_INPUTS``) and of every
  parameter (initial="exact");
- in FMI 3.0 (2.4.8) the value references of those inputs, of every parameter and of the
  independent variable ``time``;

and nothing that is not a known. The input part is checked against the FMU itself: in
Initialization Mode, an input that an initial unknown does not list leaves its value as
it was.
"""

import math
import shutil
import zipfile
from xml.etree import ElementTree

import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from fmpy.validation import validate_fmu

from agv_cosim.build import default_components_dir, slave_scripts

SCRIPTS = [p.stem for p in slave_scripts(default_components_dir())]

_TRAIN_STEERING = {f"delta{i}" for i in range(1, 5)} | {
    f"delta{i}_{side}" for i in range(1, 5) for side in ("left", "right")}
#: the inputs each slave declares ``builds_core`` (every other slave: none)
CORE_INPUTS = {"agv_train": {"dv"}, "agv_dynamic_vehicle": {"alpha", "dv"},
               "agv_dynamic_train": {"dv"} | _TRAIN_STEERING}


def _structure(fmu):
    """(variables by key, output deps, initial-unknown deps, keys in document order) of an
    FMU's model description; keys are indices (FMI 2.0) or value references (FMI 3.0),
    deps are lists of keys in attribute order, None where the attribute is missing."""
    with zipfile.ZipFile(fmu) as archive:
        root = ElementTree.fromstring(archive.read("modelDescription.xml"))
    variables = list(root.find("ModelVariables"))
    structure = root.find("ModelStructure")
    if root.get("fmiVersion") == "3.0":
        by_key = {int(v.get("valueReference")): v for v in variables}
        outputs = list(structure.iterfind("Output"))
        initial = list(structure.iterfind("InitialUnknown"))
        key = "valueReference"
    else:
        by_key = {i: v for i, v in enumerate(variables, start=1)}
        outputs = list(structure.find("Outputs"))
        initial = list(structure.find("InitialUnknowns"))
        key = "index"

    def deps(unknowns):
        return {int(u.get(key)): (None if u.get("dependencies") is None
                                  else [int(d) for d in u.get("dependencies").split()])
                for u in unknowns}

    return by_key, deps(outputs), deps(initial), [int(u.get(key)) for u in initial]


def _check(fmu, fmi3, core_inputs):
    assert validate_fmu(str(fmu)) == []
    by_key, outputs, initial, order = _structure(fmu)
    causality = {k: v.get("causality", "local") for k, v in by_key.items()}
    name = {k: v.get("name") for k, v in by_key.items()}
    parameters = {k for k, c in causality.items() if c == "parameter"}
    independent = {k for k, c in causality.items() if c == "independent"}
    inputs = {k for k, c in causality.items() if c == "input"}
    core = {k for k in inputs if name[k] in core_inputs}
    assert len(core) == len(core_inputs)
    # parameters are knowns of Initialization Mode because their initial is "exact"
    assert all(by_key[k].get("initial", "exact") == "exact" for k in parameters)
    assert (len(independent) == 1) == fmi3
    assert set(initial) == set(outputs) and len(order) == len(initial)
    for key, listed in initial.items():
        assert listed is not None, f"initial unknown {name[key]} has no dependencies"
        assert outputs[key] is not None
        expected = set(outputs[key]) | core | parameters | independent
        assert set(listed) == expected, (
            f"{name[key]}: lists {sorted(name[k] for k in listed)}, its declaration says "
            f"{sorted(name[k] for k in expected)}")
        assert set(listed) <= inputs | parameters | independent  # knowns only
        if not fmi3:  # FMI 2.0: indices ascending, each once
            assert listed == sorted(set(listed))
    return by_key, outputs, initial


@pytest.mark.parametrize("name", SCRIPTS)
def test_fmi2_initial_unknowns_list_their_declared_dependencies(component_fmus, name):
    _check(component_fmus[name], fmi3=False, core_inputs=CORE_INPUTS.get(name, set()))


@pytest.mark.parametrize("name", SCRIPTS)
def test_fmi3_initial_unknowns_list_their_declared_dependencies(twins, name):
    _check(twins[name], fmi3=True, core_inputs=CORE_INPUTS.get(name, set()))


@pytest.mark.parametrize("name", SCRIPTS)
def test_unlisted_inputs_leave_the_initial_unknowns_unchanged(component_fmus, name):
    """In Initialization Mode, setting an input that an initial unknown does not list
    leaves the unknown's value (read with fmi2Get*) as it was."""
    fmu = component_fmus[name]
    by_key, _, initial, _ = _structure(fmu)
    md = read_model_description(fmu)
    variables = {v.name: v for v in md.modelVariables}
    getters = {"Real": "getReal", "Integer": "getInteger", "Boolean": "getBoolean",
               "String": "getString"}
    folder = extract(str(fmu))
    slave = FMU2Slave(guid=md.guid, unzipDirectory=folder,
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="init")
    try:
        slave.instantiate()
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()

        def read():
            values = {}
            for key in initial:
                v = variables[by_key[key].get("name")]
                values[key] = getattr(slave, getters[v.type])([v.valueReference])[0]
            return values

        before = read()
        for key, v in by_key.items():
            if v.get("causality") != "input" or v[0].tag != "Real":
                continue
            variable = variables[v.get("name")]
            start = float(variable.start or 0.0)
            slave.setReal([variable.valueReference], [start + 0.37])
            after = read()
            for unknown, listed in initial.items():
                if key not in listed:
                    same = (after[unknown] == before[unknown]
                            or (isinstance(before[unknown], float)
                                and math.isnan(before[unknown])
                                and math.isnan(after[unknown])))
                    assert same, (f"{by_key[unknown].get('name')} moved with input "
                                  f"{v.get('name')}, which it does not list")
            slave.setReal([variable.valueReference], [start])
            before = read()
        slave.exitInitializationMode()
        slave.terminate()
    finally:
        slave.freeInstance()
        shutil.rmtree(folder, ignore_errors=True)


def _named_initial_dependencies(fmu):
    by_key, _, initial, _ = _structure(fmu)
    return {by_key[key].get("name"): (None if listed is None else
                                       sorted(by_key[d].get("name") for d in listed))
            for key, listed in initial.items()}


def test_small_fmus_list_the_feedthrough_input_and_the_parameters(fmus):
    """The fast tier's view (the small test FMUs of fmu_src/): a gain y = k u lists u and
    k; an integrator (no feedthrough) only its parameter."""
    assert _named_initial_dependencies(fmus["agv_test_gain"]) == {"y": ["k", "u"]}
    assert _named_initial_dependencies(fmus["agv_test_integrator"]) == {"y": ["y0"]}
