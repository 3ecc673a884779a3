"""Integration tier: every component FMU is correct FMI 2.0 and runs in fmpy and libcosim.

Parametrised over every slave script (components/agv_core/*/agv_*.py), so a new component
is checked
the moment it is added.
"""

import json
import math
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path
from xml.etree import ElementTree

import numpy as np
import pytest
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi2 import FMU2Slave
from fmpy.validation import validate_fmu

from agv_cosim.build import default_components_dir, slave_scripts

pytestmark = pytest.mark.interop

SCRIPTS = [p.stem for p in slave_scripts(default_components_dir())]


def _inputs(md):
    return [v for v in md.modelVariables if v.causality == "input" and v.type == "Real"]


def _drive(slave, md, t):
    """Set every Real input to a smooth, bounded, deterministic function of time."""
    inputs = _inputs(md)
    if inputs:
        values = [0.05 * math.sin(0.7 * t + k) for k in range(len(inputs))]
        slave.setReal([v.valueReference for v in inputs], values)


@pytest.mark.parametrize("name", SCRIPTS)
def test_model_description_is_complete(component_fmus, name):
    fmu = component_fmus[name]
    assert validate_fmu(str(fmu)) == []
    md = read_model_description(fmu)
    for variable in md.modelVariables:
        assert variable.description, f"{variable.name} has no description"
        if variable.type == "Real":
            assert variable.unit, f"{variable.name} has no unit"
    with zipfile.ZipFile(fmu) as archive:
        root = ElementTree.fromstring(archive.read("modelDescription.xml"))
    unknowns = root.find("ModelStructure/Outputs")
    assert unknowns is not None and len(unknowns)
    # every output states its direct dependencies (possibly none): no implicit "all inputs"
    assert all(u.get("dependencies") is not None for u in unknowns)
    inputs = {str(i) for i, v in enumerate(md.modelVariables, start=1) if v.causality == "input"}
    for unknown in unknowns:
        assert set(unknown.get("dependencies").split()) <= inputs
    assert md.defaultExperiment is not None
    assert md.coSimulation.canGetAndSetFMUstate and md.coSimulation.canSerializeFMUstate


@pytest.mark.parametrize("name", SCRIPTS)
def test_simulates_standalone_in_fmpy(component_fmus, name):
    result = simulate_fmu(str(component_fmus[name]), stop_time=1.0, output_interval=0.01)
    outputs = [n for n in result.dtype.names if n != "time"]
    assert outputs, "no outputs recorded"
    for column in outputs:
        assert np.all(np.isfinite(result[column])), f"{column} is not finite"


@pytest.mark.parametrize("name", SCRIPTS)
def test_state_restore_is_bit_identical(component_fmus, name):
    fmu = component_fmus[name]
    md = read_model_description(fmu)
    folder = extract(str(fmu))
    outputs = [v.valueReference for v in md.modelVariables
               if v.causality == "output" and v.type == "Real"]
    slave = FMU2Slave(guid=md.guid, unzipDirectory=folder,
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="s")
    h = 0.01

    def run(k0, n):
        rows = []
        for k in range(k0, k0 + n):
            _drive(slave, md, k * h)
            slave.doStep(k * h, h)
            rows.append(slave.getReal(outputs))
        return rows

    try:
        slave.instantiate()
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        run(0, 150)
        state = slave.getFMUstate()
        serialized = slave.serializeFMUstate(state)
        first = run(150, 150)
        slave.setFMUstate(state)
        second = run(150, 150)
        slave.setFMUstate(slave.deSerializeFMUstate(serialized))
        third = run(150, 150)
        slave.freeFMUstate(state)
        slave.terminate()
        slave.freeInstance()
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    assert first == second, "restored state diverged"
    assert first == third, "deserialised state diverged"


def test_runs_without_the_repository(component_fmus, tmp_path):
    """Each FMU runs from a temp folder with agv_core / agv_cosim made unimportable."""
    fmus = {name: str(shutil.copy(path, tmp_path)) for name, path in component_fmus.items()}
    code = (
        "import sys, json\n"
        "sys.modules['agv_core'] = None\n"
        "sys.modules['agv_cosim'] = None\n"
        "import fmpy\n"
        f"fmus = json.loads({json.dumps(json.dumps(fmus))})\n"
        "for name, path in fmus.items():\n"
        "    r = fmpy.simulate_fmu(path, stop_time=0.2, output_interval=0.01)\n"
        "    print(name, len(r))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    for name in fmus:
        assert f"{name} 21" in done.stdout


@pytest.mark.parametrize("name", SCRIPTS)
def test_runs_in_libcosim(component_fmus, name):
    libcosimpy = pytest.importorskip("libcosimpy")  # noqa: F841 - the third-party master
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    log_output_level(CosimLogLevel.WARNING)
    md = read_model_description(component_fmus[name])
    execution = CosimExecution.from_step_size(step_size=10_000_000)  # 10 ms in ns
    index = execution.add_local_slave(
        CosimLocalSlave(fmu_path=str(component_fmus[name]), instance_name="dut"))
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    assert execution.simulate_until(target_time=500_000_000)  # 0.5 s
    outputs = [v.valueReference for v in md.modelVariables
               if v.causality == "output" and v.type == "Real"]
    values = observer.last_real_values(slave_index=index, variable_references=outputs)
    # the same FMU, inputs at their start values, in fmpy with the same 10 ms step: a
    # fixed-step master with nothing connected must give the same numbers (1e-12: only
    # rounding may differ, the FMU code and step sequence are identical)
    reference = simulate_fmu(str(component_fmus[name]), stop_time=0.5, step_size=0.01,
                             output_interval=0.01)
    names = [v.name for v in md.modelVariables if v.causality == "output" and v.type == "Real"]
    expected = [float(reference[n][-1]) for n in names]
    assert values == pytest.approx(expected, rel=1e-12, abs=1e-12)


def test_outputs_are_valid_in_initialisation_mode(component_fmus):
    """FMI 2.0 lets a master read outputs before fmi2ExitInitializationMode (libcosim
    propagates initial values then): the vehicle reports the initial pose it was given,
    also after a parameter changes within initialisation mode (exact: no arithmetic)."""
    fmu = component_fmus["agv_vehicle"]
    md = read_model_description(fmu)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    folder = extract(str(fmu))
    slave = FMU2Slave(guid=md.guid, unzipDirectory=folder,
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="v")
    try:
        slave.instantiate()
        slave.setupExperiment(startTime=0.0)
        slave.setReal([vr["y0"], vr["x0"]], [0.1, -2.0])
        slave.enterInitializationMode()
        assert slave.getReal([vr["x"], vr["y"]]) == [-2.0, 0.1]
        slave.setReal([vr["y0"]], [0.25])
        assert slave.getReal([vr["y"]]) == [0.25]
        slave.exitInitializationMode()
        assert slave.getReal([vr["x"], vr["y"]]) == [-2.0, 0.25]
        slave.terminate()
        slave.freeInstance()
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def test_a_loaded_fmu_never_shadows_the_installed_agv_core(component_fmus, tmp_path):
    """A Python host that has an FMU instantiated and then imports agv_core gets the
    installed package, not the FMU's bundle (which holds only what its slave needs and
    sits in resources/, on sys.path while the instance lives): the vehicle ships no
    numerics/paths.py, the installed package has it."""
    code = (
        "import sys\n"
        "from fmpy import extract, read_model_description\n"
        "from fmpy.fmi2 import FMU2Slave\n"
        f"folder = extract({str(component_fmus['agv_vehicle'])!r})\n"
        "md = read_model_description(folder)\n"
        "slave = FMU2Slave(guid=md.guid, unzipDirectory=folder, instanceName='v',\n"
        "                  modelIdentifier=md.coSimulation.modelIdentifier)\n"
        "slave.instantiate()\n"
        "assert any(p.startswith(str(folder)) for p in sys.path), sys.path\n"
        "import agv_core.numerics.paths as paths, agv_core\n"
        "print(agv_core.__file__)\n"
        "print(paths.parse_path('line:y0=0.5').project(1.0, 0.0).offset)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    where, offset = done.stdout.split()
    assert Path(where).parent == default_components_dir() / "agv_core"
    assert float(offset) == -0.5
