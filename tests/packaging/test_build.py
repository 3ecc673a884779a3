"""The FMU build: deterministic GUIDs, rebuild-only-changed, bundle isolation, errors."""

import os
import shutil
import subprocess
import sys
import zipfile

import fmpy
import pytest
from fmpy.fmi1 import FMICallException

from agv_cosim.build import (
    BuildError,
    build_fmus,
    build_one,
    default_components_dir,
    fmu_guid_of,
    slave_script,
)

pytestmark = pytest.mark.slow  # every test builds FMUs (seconds each) or runs the built ones

VEHICLE = slave_script("agv_vehicle")


def test_unchanged_rebuild_is_skipped_and_keeps_the_guid(tmp_path):
    first = build_fmus(tmp_path, [VEHICLE])[0]
    second = build_fmus(tmp_path, [VEHICLE])[0]
    assert first.rebuilt and not second.rebuilt
    assert fmu_guid_of(first.fmu) == fmu_guid_of(second.fmu) == first.guid
    forced = build_one(VEHICLE, tmp_path / "again", force=True)
    assert forced.guid == first.guid  # the GUID comes from the sources, not the clock


def test_the_guid_and_the_binaries_do_not_depend_on_where_the_fmu_is_built(tmp_path):
    """The same sources copied elsewhere, built into another folder, from another working
    directory: the same GUID and the same loader and bridge bytes, and neither the
    checkout's nor the venv's path in any file of the FMU."""
    here = build_one(VEHICLE, tmp_path / "a")
    copy = tmp_path / "elsewhere" / "components"
    shutil.copytree(default_components_dir(), copy,
                    ignore=shutil.ignore_patterns("__pycache__"))
    code = ("import sys\nfrom agv_cosim.build import build_one\n"
            "print(build_one(sys.argv[1], sys.argv[2], core_dir=sys.argv[3]).guid)\n")
    done = subprocess.run([sys.executable, "-c", code,
                           str(copy / "agv_core" / "vehicle" / "agv_vehicle.py"),
                           str(tmp_path / "b" / "deeper"), str(copy / "agv_core")],
                          capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split()[-1] == here.guid
    there = tmp_path / "b" / "deeper" / here.fmu.name
    with zipfile.ZipFile(here.fmu) as a, zipfile.ZipFile(there) as b:
        for name in ("binaries/linux64/AgvVehicle.so", "binaries/linux64/AgvVehicle.bridge.so"):
            assert a.read(name) == b.read(name), name
        contents = {info.filename: a.read(info) for info in a.infolist()}
    machine = [str(default_components_dir().parent).encode(), sys.prefix.encode(),
               sys.base_prefix.encode()]
    assert not [(name, path) for name, data in contents.items() for path in machine
                if path in data]


def test_changed_source_changes_the_guid(tmp_path):
    original = build_one(VEHICLE, tmp_path / "a")
    core = tmp_path / "core"
    shutil.copytree(default_components_dir() / "agv_core", core,
                    ignore=shutil.ignore_patterns("__pycache__"))
    with open(core / "vehicle" / "vehicle.py", "a") as handle:
        handle.write("\n# a changed line\n")
    changed = build_one(VEHICLE, tmp_path / "b", core_dir=core)
    assert changed.guid != original.guid


def test_a_module_the_fmu_does_not_ship_leaves_its_guid(tmp_path):
    """The vehicle ships only the modules its slave script reaches: a change in the MPC
    (which it never imports) neither rebuilds it nor changes its GUID; one in the arc
    numerics it uses does."""
    core = tmp_path / "core"
    shutil.copytree(default_components_dir() / "agv_core", core,
                    ignore=shutil.ignore_patterns("__pycache__"))
    original = build_one(VEHICLE, tmp_path / "out", core_dir=core)
    with zipfile.ZipFile(original.fmu) as archive:
        shipped = {n for n in archive.namelist() if n.startswith("resources/agv_core_bundle/")}
    assert "resources/agv_core_bundle/vehicle/vehicle.py" in shipped
    assert "resources/agv_core_bundle/numerics/arc.py" in shipped
    assert "resources/agv_core_bundle/ltv_mpc/ltv_mpc.py" not in shipped
    assert "resources/agv_core_bundle/numerics/paths.py" not in shipped
    with open(core / "ltv_mpc" / "ltv_mpc.py", "a") as handle:
        handle.write("\n# a changed line\n")
    index = {VEHICLE.name: original.fmu.name}
    again = build_one(VEHICLE, tmp_path / "out", core_dir=core, index=index)
    assert not again.rebuilt and again.guid == original.guid
    with open(core / "numerics" / "arc.py", "a") as handle:
        handle.write("\n# a changed line\n")
    assert build_one(VEHICLE, tmp_path / "out", core_dir=core).guid != original.guid


def test_two_builds_of_one_fmu_in_a_process_each_run_their_own_code(tmp_path):
    """A slave module is imported once per process by its file name; the FMU bridge
    executes it again for every instance, from that FMU's own folder, so a second build
    of the same slave script (here one whose vehicle drifts 1 m in x per step) runs its
    own code, and the first build, instantiated again afterwards, its own."""
    old = build_one(VEHICLE, tmp_path / "old").fmu
    core = tmp_path / "core"
    shutil.copytree(default_components_dir() / "agv_core", core,
                    ignore=shutil.ignore_patterns("__pycache__"))
    with open(core / "vehicle" / "vehicle.py", "a") as handle:
        handle.write("\n\n_step = Vehicle.step\n\n\n"
                     "def _drifting(self, *args):\n"
                     "    _step(self, *args)\n"
                     "    self.x += 1.0\n\n\n"
                     "Vehicle.step = _drifting\n")
    new = build_one(VEHICLE, tmp_path / "new", core_dir=core).fmu
    code = (
        "import fmpy\n"
        "for path in [" + ", ".join(repr(str(p)) for p in (old, new, old)) + "]:\n"
        "    result = fmpy.simulate_fmu(path, stop_time=0.1, step_size=0.01)\n"
        "    print(repr(float(result['x'][-1])))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    first, second, third = (float(x) for x in done.stdout.split())
    assert third == first
    assert second == pytest.approx(first + 10.0, abs=1e-9)  # 10 steps, 1 m each


def test_bad_parameter_fails_initialisation_naming_it(tmp_path):
    fmu = build_one(VEHICLE, tmp_path).fmu
    messages = []

    def logger(component, instance, status, category, message):
        messages.append(message.decode())

    with pytest.raises(FMICallException, match="ExitInitializationMode"):
        fmpy.simulate_fmu(str(fmu), stop_time=0.1, start_values={"wheelbase": -2.0},
                          debug_logging=True, logger=logger)
    assert any("wheelbase" in m and "-2.0" in m for m in messages), messages


def test_many_instantiations_in_one_process(component_fmus):
    """pythonfmu 0.7 drops a reference to the slave module's globals at every
    instantiation (agv_boot pins one back). Model b's slave script defines no function, so
    without the pin its globals are freed by the second instantiation. Run in a
    subprocess: the failure mode is a crash of the host."""
    fmu = str(component_fmus["agv_steering_b"])
    code = (
        "import fmpy\n"
        "for k in range(40):\n"
        f"    r = fmpy.simulate_fmu({fmu!r}, stop_time=0.05, step_size=0.01,\n"
        "                          start_values={'u': 1.0})\n"
        "print('alpha', repr(float(r['alpha'][-1])))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-1500:]
    # alpha = K u t = 0.6 * 1 * 0.05 after 40 fresh instances (1e-12: exact ramp)
    assert float(done.stdout.split()[-1]) == pytest.approx(0.03, abs=1e-12)


def test_failing_instances_do_not_corrupt_the_host(component_fmus):
    """pythonfmu 0.7 releases the slave's class, instance and log queue twice after a
    Python exception (once in its error handler, once in fmi2FreeInstance); the adapter
    keeps a reference to balance it. Without that, a host that frees a failed instance
    (as it should) corrupts its heap and crashes later. Run in a subprocess."""
    fmu = str(component_fmus["agv_steering_b"])
    code = (
        "import gc, shutil, fmpy\n"
        "from fmpy.fmi2 import FMU2Slave\n"
        f"md = fmpy.read_model_description({fmu!r})\n"
        f"folder = fmpy.extract({fmu!r})\n"
        "vr = {v.name: v.valueReference for v in md.modelVariables}\n"
        "def instance():\n"
        "    s = FMU2Slave(guid=md.guid, unzipDirectory=folder,\n"
        "                  modelIdentifier=md.coSimulation.modelIdentifier, instanceName='i')\n"
        "    s.instantiate()\n"
        "    s.setupExperiment(startTime=0.0)\n"
        "    s.enterInitializationMode()\n"
        "    return s\n"
        "for k in range(20):\n"
        "    s = instance()\n"
        "    s.setReal([vr['K']], [-1.0])\n"
        "    try:\n"
        "        s.exitInitializationMode()\n"
        "    except Exception:\n"
        "        pass\n"
        "    s.freeInstance()\n"
        "    gc.collect()\n"
        "s = instance()\n"
        "s.exitInitializationMode()\n"
        "s.setReal([vr['u']], [1.0])\n"
        "for k in range(5):\n"
        "    s.doStep(k * 0.01, 0.01)\n"
        "alpha = s.getReal([vr['alpha']])[0]\n"
        "s.terminate(); s.freeInstance(); gc.collect()\n"
        "shutil.rmtree(folder)\n"
        "print('alpha', repr(alpha))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-1500:]
    # alpha = K u t = 0.6 * 1 * 0.05 (1e-12: an exact ramp)
    assert float(done.stdout.split()[-1]) == pytest.approx(0.03, abs=1e-12)


def test_failing_runs_do_not_corrupt_the_orchestrator(tmp_path):
    """The reproducer of the third release (see agv_core/fmi/fmi_slave.py): FMUs built in the
    process, then two runs whose FMU fails, then a garbage collection, with CPython's
    debug allocator (freed memory is overwritten, so a use after free crashes at once)."""
    source = default_components_dir().parent / "tests" / "fmu_src"
    manifest = tmp_path / "fails.toml"
    code = f"""
import gc
from pathlib import Path
from agv_cosim import cli
from agv_cosim.build import build_one
out = Path({str(tmp_path)!r})
fail = build_one(Path({str(source / "agv_test_fail.py")!r}), out / "fmus").fmu
src = build_one(Path({str(source / "agv_test_source.py")!r}), out / "fmus").fmu
Path({str(manifest)!r}).write_text(f'''
[simulation]
stop = 1.0
step = 0.1
[components.src]
fmu = "{{src}}"
[components.bad]
fmu = "{{fail}}"
parameters = {{{{ fail_time = 0.5 }}}}
[[connections]]
from = "src.y"
to = "bad.u"
''')
for k in range(2):
    print("exit", cli.main(["run", {str(manifest)!r}, "--out", str(out / f"run{{k}}"),
                            "--quiet", "--jobs", "1"]))
    gc.collect()
print("survived")
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300, env={**os.environ, "PYTHONMALLOC": "debug"})
    assert done.returncode == 0, done.stderr[-1500:]
    assert done.stdout.split() == ["exit", "1", "exit", "1", "survived"]


def _variant_of_test_fail(tmp_path, class_body):
    """The test-fail slave script with extra class attributes (its own file name)."""
    source = (default_components_dir().parent / "tests" / "fmu_src" / "agv_test_fail.py")
    text = source.read_text().replace(
        '    description = "Test FMU that fails at a given time"\n',
        '    description = "Test FMU that fails at a given time"\n' + class_body)
    script = tmp_path / "agv_test_fail_reference.py"
    script.write_text(text.replace("class AgvTestFail(", "class AgvTestFailReference("))
    return script


def test_a_failing_default_experiment_fails_the_build_naming_it(tmp_path):
    script = _variant_of_test_fail(tmp_path, (
        "    default_experiment = core.fmi.fmi_slave.DefaultExperiment(start_time=0.0,\n"
        "                                                          stop_time=2.0,\n"
        "                                                          step_size=0.1)\n"))
    with pytest.raises(BuildError, match="its default experiment failed.*deliberate failure"):
        build_one(script, tmp_path / "out")
    assert not (tmp_path / "out" / "AgvTestFailReference.fmu").exists()


def test_reference_inputs_must_name_inputs(tmp_path):
    script = _variant_of_test_fail(tmp_path, (
        "    default_experiment = core.fmi.fmi_slave.DefaultExperiment(start_time=0.0,\n"
        "                                                          stop_time=0.5,\n"
        "                                                          step_size=0.1)\n"
        "    reference_inputs = {'fail_time': ((0.0, 1.0),)}\n"))
    with pytest.raises(BuildError, match="'fail_time' is not an input"):
        build_one(script, tmp_path / "out")


def test_no_default_experiment_no_reference(tmp_path):
    """A slave that declares no experiment gets no DefaultExperiment and no reference
    (the tests over components/agv_core/*/ require one of every component)."""
    fmu = build_one(default_components_dir().parent / "tests" / "fmu_src" / "agv_test_gain.py",
                    tmp_path).fmu
    with zipfile.ZipFile(fmu) as archive:
        assert not [n for n in archive.namelist() if n.startswith("extra/")]
        assert b"<DefaultExperiment" not in archive.read("modelDescription.xml")
