"""Integration tier: the FMUs, loaded by another host, refuse what FMI forbids.

Each forbidden call returns fmi2Error / fmi3Error (fmpy raises ``FMICallException`` with
that status) and logs its reason through the host's logger; the instance is left as it
was (the refused value is not applied, a refused step does not move the model). Checked
through fmpy's low-level calls on the FMI 2.0 FMUs and their FMI 3.0 twins, and in a plain
C host (c_host/fmi_refusals.c):

- a step of size <= 0 or not finite, and calls in the wrong state of FMI's state machine
  (a step before initialisation or after fmi2Terminate, initialisation twice, ...);
- a wrong GUID / instantiationToken (instantiation returns NULL);
- setting an output, the independent variable, or a fixed parameter after initialisation
  (tunable parameters and inputs stay settable);
- a non-finite value on any Real input of any component (no component documents a safe
  reaction to one), e.g. AgvChainedForm's lateral_error, heading_error, curvature;
- restoring a state that is not the FMU's (unknown keys, out-of-range values, another
  FMU's state, bytes that are no state);
- a step at which the model reaches a limit of its validity (AgvDynamicVehicle: a wheel
  lifts, the drive exceeds its friction): Error with the reason, not Fatal.

Where each check lives: components/fmu_loader/agv_fmu_bridge.c (state machine, step,
GUID, who may set what) and components/agv_core/fmi/slave_base.py (non-finite inputs,
states).
"""

import dataclasses
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import fmpy
import pytest
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException

from agv_cosim.build import default_components_dir, host_python, slave_scripts
from agv_cosim.execution.instance import FmuInstance
from agv_cosim.system.model import read_model

pytestmark = pytest.mark.interop

SCRIPTS = [p.stem for p in slave_scripts(default_components_dir())]
HOST_SOURCE = Path(__file__).parent / "c_host" / "fmi_refusals.c"


@pytest.fixture(params=["2", "3"])
def version(request):
    return request.param


@pytest.fixture
def built(version, component_fmus, twins):
    """The FMUs of the FMI version under test: script stem -> path."""
    return component_fmus if version == "2" else twins


class Dut:
    """One instance through the orchestrator's FmuInstance (fmpy's FMU2Slave/FMU3Slave
    underneath, every message the FMU logs in ``log`` as (status, text))."""

    def __init__(self, fmu, **changes):
        self.info = read_model(fmu)
        if changes:
            self.info = dataclasses.replace(self.info, **changes)
        self.fmi3 = self.info.fmi_version == "3.0"
        self.log = []
        self.instance = FmuInstance(self.info, "dut",
                                    on_message=lambda _, status, text:
                                    self.log.append((status, text)))
        self.slave = self.instance.slave

    def vr(self, name):
        return self.info.variables[name].vr

    def ready(self):
        """Initialised at t = 0, in step mode."""
        if self.fmi3:
            self.slave.enterInitializationMode(startTime=0.0)
        else:
            self.slave.setupExperiment(startTime=0.0)
            self.slave.enterInitializationMode()
        self.slave.exitInitializationMode()
        return self

    def set_real(self, name, value):
        setter = self.slave.setFloat64 if self.fmi3 else self.slave.setReal
        return setter([self.vr(name)], [value])

    def get_real(self, name):
        getter = self.slave.getFloat64 if self.fmi3 else self.slave.getReal
        return getter([self.vr(name)])[0]

    def step(self, t, h):
        return self.slave.doStep(t, h)

    # fmpy spells the FMU-state methods FMUstate (FMI 2.0) and FMUState (FMI 3.0)
    def get_state(self):
        return self.slave.getFMUState() if self.fmi3 else self.slave.getFMUstate()

    def set_state(self, state):
        return (self.slave.setFMUState if self.fmi3 else self.slave.setFMUstate)(state)

    def serialize(self, state):
        return bytes((self.slave.serializeFMUState if self.fmi3
                      else self.slave.serializeFMUstate)(state))

    def deserialize(self, data):
        return (self.slave.deserializeFMUState if self.fmi3
                else self.slave.deSerializeFMUstate)(data)

    def errors(self):
        return [text for status, text in self.log if status == 3]

    def close(self):
        self.instance.close()


@pytest.fixture
def open_dut():
    opened = []

    def make(fmu, **changes):
        dut = Dut(fmu, **changes)
        opened.append(dut)
        return dut

    yield make
    for dut in opened:
        dut.close()


def refused(call, *args):
    """The status of a call fmpy reports as failed (FMICallException); fails the test
    when the call succeeds."""
    with pytest.raises(FMICallException) as failure:
        call(*args)
    return failure.value.status


@pytest.mark.parametrize("h", [-0.1, 0.0, math.nan, math.inf])
def test_a_step_that_does_not_go_forward_is_refused(built, open_dut, h):
    """fmi2DoStep / fmi3DoStep with a step size <= 0 or not finite: Error, and the
    vehicle has not moved (it integrated backwards before)."""
    dut = open_dut(built["agv_vehicle"]).ready()
    x = dut.get_real("x")
    assert refused(dut.step, 0.0, h) == 3
    assert "the step size must be a finite number > 0" in dut.errors()[-1]
    assert dut.get_real("x") == x


def _terminated(dut):
    dut.ready().step(0.0, 0.1)
    dut.slave.terminate()


#: (case, what the host did first, the forbidden call, the logged reason)
WRONG_STATE = [
    ("step before initialisation", lambda d: None, lambda d: d.step(0.0, 0.1),
     "not allowed before initialisation mode"),
    ("step after terminate", _terminated, lambda d: d.step(0.1, 0.1),
     "not allowed after fmi{v}Terminate"),
    ("terminate twice", _terminated, lambda d: d.slave.terminate(),
     "not allowed after fmi{v}Terminate"),
    ("set an input after terminate", _terminated, lambda d: d.set_real("alpha", 0.1),
     "not allowed after fmi{v}Terminate"),
    ("leave initialisation twice", Dut.ready, lambda d: d.slave.exitInitializationMode(),
     "not allowed in step mode"),
    ("terminate before initialisation", lambda d: None, lambda d: d.slave.terminate(),
     "not allowed before initialisation mode"),
    ("step after an error", lambda d: (d.ready(), refused(d.step, 0.0, -1.0)),
     lambda d: d.step(0.0, 0.1), "not allowed after an error"),
]


@pytest.mark.parametrize("case, before, call, reason", WRONG_STATE,
                         ids=[case[0] for case in WRONG_STATE])
def test_calls_in_the_wrong_state_are_refused(built, open_dut, version, case, before, call,
                                              reason):
    dut = open_dut(built["agv_vehicle"])
    before(dut)
    assert refused(call, dut) == 3
    assert reason.format(v=version) in dut.errors()[-1]


def test_fmi2_setup_experiment_after_initialisation_is_refused(component_fmus, open_dut):
    dut = open_dut(component_fmus["agv_vehicle"]).ready()
    assert refused(dut.slave.setupExperiment, None, 0.0) == 3
    assert "fmi2SetupExperiment: refused: not allowed in step mode" in dut.errors()[-1]


def test_fmi3_enter_step_mode_is_refused(twins, open_dut):
    """No event mode: a twin is in step mode right after fmi3ExitInitializationMode."""
    dut = open_dut(twins["agv_vehicle"]).ready()
    assert refused(dut.slave.enterStepMode) == 3
    assert "this FMU has no event mode" in dut.errors()[-1]


def test_a_wrong_guid_is_refused_at_instantiation(built, version):
    log = []
    info = dataclasses.replace(read_model(built["agv_vehicle"]),
                               guid="{00000000-0000-0000-0000-000000000000}")
    with pytest.raises(Exception, match="nstantiat"):
        FmuInstance(info, "dut", on_message=lambda _, status, text: log.append((status, text)))
    argument = "instantiationToken" if version == "3" else "fmuGUID"
    errors = [text for status, text in log if status == 3]
    assert errors and f'{argument} "{{00000000-0000-0000-0000-000000000000}}" is not ' \
                      "this FMU's" in errors[-1]


def test_outputs_cannot_be_set(built, open_dut, version):
    dut = open_dut(built["agv_vehicle"]).ready()
    assert refused(dut.set_real, "x", 5.0) == 3
    assert "'x' is an output" in dut.errors()[-1]
    assert dut.get_real("x") == 0.0


def test_fmi3_time_cannot_be_set(twins, open_dut):
    dut = open_dut(twins["agv_vehicle"]).ready()
    assert refused(dut.set_real, "time", 5.0) == 3
    assert "'time' cannot be set" in dut.errors()[-1]


def test_a_fixed_parameter_is_set_only_before_initialisation_ends(built, open_dut, version):
    """v0 is settable before and in initialisation mode; in step mode the set is refused
    and the run goes on with the old v0 (it changed the run before)."""
    dut = open_dut(built["agv_vehicle"])
    dut.set_real("v0", 0.5)                       # instantiated: allowed
    if dut.fmi3:
        dut.slave.enterInitializationMode(startTime=0.0)
    else:
        dut.slave.setupExperiment(startTime=0.0)
        dut.slave.enterInitializationMode()
    dut.set_real("v0", 2.0)                       # initialisation mode: allowed
    dut.slave.exitInitializationMode()
    assert refused(dut.set_real, "v0", 3.0) == 3
    assert (f"'v0' is a fixed parameter: it can be set only before "
            f"fmi{version}ExitInitializationMode") in dut.errors()[-1]
    assert dut.get_real("v0") == 2.0


def test_a_tunable_parameter_stays_settable(built, open_dut):
    """The total station's `available` (tunable, Boolean) is set between steps."""
    dut = open_dut(built["agv_total_station"]).ready()
    vr = dut.vr("available")
    dut.step(0.0, 0.1)
    dut.slave.setBoolean([vr], [False])
    dut.step(0.1, 0.1)
    assert dut.slave.getBoolean([vr]) == [False]
    assert dut.errors() == []


@pytest.mark.parametrize("name", ["lateral_error", "heading_error", "curvature"])
@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_chained_form_refuses_a_non_finite_input(built, open_dut, name, value):
    """A sensor fault (NaN/inf) is refused naming the input, not turned into full lock
    (delta = -pi/4 with status OK before): the input keeps its value, delta stays 0."""
    dut = open_dut(built["agv_chained_form"]).ready()
    assert refused(dut.set_real, name, value) == 3
    assert f"input '{name}' set to {value!r}: an input must be a finite number" \
        in dut.errors()[-1]
    assert dut.get_real(name) == 0.0
    assert dut.get_real("delta") == 0.0


@pytest.mark.parametrize("name", SCRIPTS)
def test_every_component_refuses_a_non_finite_input(component_fmus, open_dut, name):
    """One mechanism in the adapter: every Real input of every FMU refuses NaN (no
    component documents a safe reaction), before initialisation and in step mode;
    fmi2Reset brings a refused instance back."""
    md = read_model_description(component_fmus[name])
    inputs = [v.name for v in md.modelVariables if v.causality == "input" and v.type == "Real"]
    if not inputs:
        pytest.skip(f"{name} has no Real input")
    dut = open_dut(component_fmus[name])
    for input_name in inputs:
        assert refused(dut.set_real, input_name, math.nan) == 3
        assert f"input '{input_name}' set to nan" in dut.errors()[-1]
        dut.slave.reset()
    dut.ready()
    assert refused(dut.set_real, inputs[-1], math.inf) == 3
    assert f"input '{inputs[-1]}' set to inf" in dut.errors()[-1]


def _tamper_variables(state, name, value):
    state["variables"][name] = value


#: (case, change to the vehicle's serialised state, the logged reason)
FOREIGN_STATES = [
    ("unknown key", lambda s: s.update(extra=1), "unknown keys ['extra']"),
    ("missing key", lambda s: s.pop("time"), "missing keys ['time']"),
    ("unknown variable", lambda s: _tamper_variables(s, "bogus", 1.0),
     "unknown variables ['bogus']"),
    ("unknown core key", lambda s: s["core"].update(bogus=1.0),
     "the core does not take as given"),
    ("non-finite core value", lambda s: s["core"].update(x=math.nan),
     "core['x'] is not a finite number"),
    ("non-finite variable", lambda s: _tamper_variables(s, "alpha", math.inf),
     "variable 'alpha' = inf is not a finite float"),
    ("out-of-range parameter", lambda s: _tamper_variables(s, "wheelbase", -1.0),
     "its parameters build no core: ParameterError"),
    ("wrong type", lambda s: _tamper_variables(s, "reference_point", 3),
     "variable 'reference_point' = 3 is not a str"),
    ("unknown mode", lambda s: s.update(mode="paused"), "mode 'paused' is not one of"),
    ("non-finite time", lambda s: s.update(time=-math.inf), "time -inf is not a finite"),
]


@pytest.mark.parametrize("case, tamper, reason", FOREIGN_STATES,
                         ids=[case[0] for case in FOREIGN_STATES])
def test_a_state_that_is_not_the_fmus_is_refused(built, open_dut, case, tamper, reason):
    """The vehicle's own serialised state, changed: deserialised (it is JSON), then
    refused by fmi2SetFMUstate / fmi3SetFMUState with Error; the untouched state is
    restored after that and the run continues exactly as from the saved point."""
    dut = open_dut(built["agv_vehicle"]).ready()
    dut.set_real("alpha", 0.2)
    for k in range(5):
        dut.step(0.1 * k, 0.1)
    data = dut.serialize(dut.get_state())
    dut.step(0.5, 0.1)
    reference = dut.get_real("heading")
    state = json.loads(data)
    tamper(state)
    bad = dut.deserialize(json.dumps(state).encode())
    assert refused(dut.set_state, bad) == 3
    assert "a state that does not belong to this FMU: " in dut.errors()[-1]
    assert reason in dut.errors()[-1]
    dut.set_state(dut.deserialize(data))
    dut.step(0.5, 0.1)
    assert dut.get_real("heading") == reference


def test_another_fmus_state_and_garbage_are_refused(built, open_dut):
    chained = open_dut(built["agv_chained_form"]).ready()
    foreign = chained.serialize(chained.get_state())
    dut = open_dut(built["agv_vehicle"]).ready()
    assert refused(dut.set_state, dut.deserialize(foreign)) == 3
    assert "does not belong to this FMU: unknown variables" in dut.errors()[-1]
    garbage = open_dut(built["agv_vehicle"]).ready()
    assert refused(garbage.deserialize, b"\x00not a state") == 3
    assert "does not belong to this FMU: not a serialised state" in garbage.errors()[-1]


def test_a_wheel_that_lifts_is_an_error_with_its_reason(built, open_dut, version):
    """A three-wheel AgvDynamicVehicle at 4 m/s, straight, then the wheel held at 0.45 rad
    (kinematic a_y 7.7 m/s^2 above its tip-over limit 6.54 m/s^2): the step from
    t = 0.44 s, where the rear left wheel lifts, returns Error (a modelling limit, not
    Fatal) and logs one line naming the step, the wheel and the limit; the instance is
    then in FMI's error state: getters answer, a further step is refused."""
    dut = open_dut(built["agv_dynamic_vehicle"])
    names = {"layout": "three", "drive": "front", "reference_point": "rear"}
    if dut.fmi3:
        dut.slave.enterInitializationMode(startTime=0.0)
    else:
        dut.slave.setupExperiment(startTime=0.0)
        dut.slave.enterInitializationMode()
    dut.slave.setString([dut.vr(name) for name in names], list(names.values()))
    dut.set_real("v0", 4.0)
    dut.slave.exitInitializationMode()
    dut.set_real("alpha", 0.45)  # from a straight start
    for k in range(44):
        dut.step(0.01 * k, 0.01)
    assert refused(dut.step, 0.44, 0.01) == 3
    reason = dut.errors()[-1]
    assert "\n" not in reason
    assert ("'dut': step at t=0.44 s failed: WheelLiftError: the rear left wheel lifts"
            in reason)
    assert "tip-over limit 6.540 m/s2" in reason
    assert not [text for status, text in dut.log if status == 4]
    assert math.isfinite(dut.get_real("x"))
    assert refused(dut.step, 0.44, 0.01) == 3
    assert "not allowed after an error" in dut.errors()[-1]


# ---------------------------------------------------------------------- the C host
@pytest.fixture(scope="module")
def refusals_host(tmp_path_factory):
    """c_host/fmi_refusals.c, compiled into a temp folder."""
    if not Path(host_python()["libpython"]).is_file():
        pytest.skip(f"this Python has no shared library ({host_python()['libpython']}): "
                    "a C host cannot start it")
    out = tmp_path_factory.mktemp("refusals_host") / "fmi_refusals"
    headers = Path(fmpy.__file__).parent / "c-code"
    subprocess.run(["gcc", "-O1", "-Wall", "-Werror", f"-I{headers}", "-o", str(out),
                    str(HOST_SOURCE), "-ldl", "-lm"], check=True, capture_output=True,
                   text=True)
    return out


#: case of fmi_refusals.c -> the reason its refusal logs (FMI 2.0; {v} the version)
C_HOST_REASONS = {
    "wrong_guid": "is not this FMU's",
    "negative_step": "fmi{v}DoStep: refused: communicationStepSize -0.1",
    "zero_step": "fmi2DoStep: refused: communicationStepSize 0 ",
    "nan_step": "fmi2DoStep: refused: communicationStepSize nan",
    "step_before_initialisation": "fmi2DoStep: refused: not allowed before initialisation",
    "step_after_terminate": "fmi{v}DoStep: refused: not allowed after fmi{v}Terminate",
    "exit_initialisation_twice": "fmi2ExitInitializationMode: refused: not allowed in step",
    "set_output": "refused: 'x' is an output",
    "set_fixed_parameter": "refused: 'v0' is a fixed parameter",
    "nan_input": "input 'alpha' set to nan: an input must be a finite number",
    "inf_input": "input 'alpha' set to -inf: an input must be a finite number",
    "foreign_state": "a state that does not belong to this FMU: unknown keys ['unknown']",
}
C_HOST_FMI3 = {"wrong_guid", "negative_step", "step_after_terminate", "set_output",
               "set_fixed_parameter", "nan_input"}


def test_a_c_host_sees_every_refusal(refusals_host, built, version, tmp_path):
    """The C host makes each forbidden call on a fresh vehicle instance (and the allowed
    calls around them): every status is the expected one (Error for each refusal, OK
    for the positive controls, NULL from a wrong GUID), and each refusal's reason
    reaches the host's logger."""
    fmu = built["agv_vehicle"]
    md = read_model_description(fmu)
    folder = fmpy.extract(str(fmu), unzipdir=str(tmp_path / "unzipped"))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    env = {"PATH": "/usr/bin:/bin", "LANG": "C", "VIRTUAL_ENV": sys.prefix,
           **{k: v for k, v in os.environ.items() if k.startswith(("OPENBLAS_", "OMP_"))}}
    done = subprocess.run([str(refusals_host), version, folder,
                           md.coSimulation.modelIdentifier, md.guid, str(vr["alpha"]),
                           str(vr["x"]), str(vr["v0"])], capture_output=True, text=True,
                          env=env, timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    checks = [line for line in done.stdout.splitlines() if line.startswith("check ")]
    assert checks and all(line.endswith(" ok") for line in checks)
    cases = set(C_HOST_REASONS) if version == "2" else C_HOST_FMI3
    assert {line.split()[1] for line in checks} == cases
    for case in cases:
        logged = [line for line in done.stderr.splitlines()
                  if line.startswith(f"[{case}] status 3 ")]
        reason = C_HOST_REASONS[case].format(v=version)
        assert any(reason in line for line in logged), (case, logged)
