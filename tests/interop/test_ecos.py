"""Integration tier: ecos (PyPI ``ecospy``, a C++ co-simulation library) as a host of the
FMI 2.0 FMUs and their FMI 3.0 twins.

Every FMU runs alone in ecos over its reference experiment (the default experiment's start,
stop and step; its reference inputs held, set before initialisation and before every step)
and must reproduce its shipped reference output within 1e-12 + 1e-9 |ref|, the tolerance
of the other C hosts (test_fmusim.py). Each FMU runs in a child process of its own, which
leaves with ``os._exit`` (ecos loads the FMU into that process).

What ecos does that a test must not miss:

- it sums its clock (t += h), so its times drift from start + k h in the last bits: the
  time column is compared within 1e-9 s, the inputs are held by step number;
- an FMU that fails to instantiate leaves ecos running with every output 0.0 and nothing
  said at its default log level: the child logs at ``debug`` (the FMU's own messages then
  reach its output, which a failure shows), and a run whose outputs never move where the
  reference's do fails.

ecospy needs Debian's libtbb12 (``make test-deps``). Without ecospy or libtbb12 the tests
skip on a developer machine and fail in CI (``CI`` set).
"""

import json
import os
import subprocess
import sys
import textwrap
import zipfile

import numpy as np
import pytest

from agv_cosim.build import default_components_dir, reference_experiment, slave_scripts

from fmusim_host import ATOL, RTOL, reference_of

pytestmark = pytest.mark.interop

SCRIPTS = [p.stem for p in slave_scripts(default_components_dir())]

# Run one FMU in ecos: argv[1] the FMU, argv[2] JSON {start, stop, step, inputs, outputs};
# print the log and, last, one JSON line {"init": bool, "time": [...], name: [...]}.
_RUN = textwrap.dedent("""
    import json, os, sys
    from ecospy import EcosLib, EcosSimulation, EcosSimulationStructure

    fmu, job = sys.argv[1], json.loads(sys.argv[2])
    EcosLib.set_log_level("debug")
    start, step, steps = job["start"], job["step"], job["steps"]

    def held(name, t):
        return [v for time, v in job["inputs"][name] if time <= t][-1]

    def set_inputs(sim, k):
        for name in job["inputs"]:
            sim.set_real("m::" + name, held(name, start + k * step))

    table = {"time": []}
    table.update({name: [] for name in job["outputs"]})

    def record(sim, t):
        table["time"].append(t)
        for name in job["outputs"]:
            table[name].append(sim.get_real("m::" + name))

    with EcosSimulationStructure() as structure:
        structure.add_model("m", fmu)
        with EcosSimulation(structure=structure, step_size=step) as sim:
            set_inputs(sim, 0)
            table["init"] = bool(sim.init(start))
            set_inputs(sim, 0)
            record(sim, sim.get_time())
            for k in range(steps):
                set_inputs(sim, k)
                record(sim, sim.step(1))
            sim.terminate()
    print(json.dumps(table))
    sys.stdout.flush()
    os._exit(0)
""")


def _unavailable(reason):
    """Skip on a developer machine; in CI (CI=true) a missing host is a failure."""
    if os.environ.get("CI"):
        pytest.fail(f"{reason} (CI must run the ecos tests: `make test-deps`, the [test] "
                    "extra)")
    pytest.skip(reason)


@pytest.fixture(scope="module")
def ecos():
    """None once ``import ecospy`` works in a child process (it loads libecosc.so, which
    needs libtbb12); skips (fails in CI) otherwise."""
    done = subprocess.run([sys.executable, "-c", "import ecospy"], capture_output=True,
                          text=True, timeout=300)
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["?"])[-1]
        _unavailable(f"ecospy cannot be imported: {last}")


def _run_in_ecos(fmu, tmp_path):
    """(child process, ecos table or None, reference) for ``fmu``'s reference experiment."""
    with zipfile.ZipFile(fmu) as archive:
        experiment = reference_experiment(archive.read("modelDescription.xml"))
    _, reference = reference_of(fmu, tmp_path)
    job = {"start": experiment["start"], "step": experiment["step"],
           "steps": round((experiment["stop"] - experiment["start"]) / experiment["step"]),
           "inputs": experiment["inputs"], "outputs": list(reference.dtype.names[1:])}
    done = subprocess.run([sys.executable, "-c", _RUN, str(fmu), json.dumps(job)],
                          capture_output=True, text=True, timeout=1800)
    table = None
    if done.returncode == 0 and done.stdout.strip():
        table = json.loads(done.stdout.strip().splitlines()[-1])
    return done, table, reference


def _assert_matches_reference(done, table, reference):
    log = (done.stdout + done.stderr)[-3000:]
    assert done.returncode == 0 and table is not None, log
    assert table["init"], f"ecos failed to initialise the FMU:\n{log}"
    time = np.array(table["time"])
    assert len(time) == len(reference), log
    assert np.allclose(time, reference["time"], rtol=0, atol=1e-9)
    names = reference.dtype.names[1:]
    moving = [n for n in names if np.ptp(reference[n]) > 0]
    assert any(np.ptp(table[n]) > 0 for n in moving), f"no output moves in ecos:\n{log}"
    for name in names:
        values = np.array(table[name])
        worst = int(np.argmax(np.abs(values - reference[name])))
        assert np.allclose(values, reference[name], rtol=RTOL, atol=ATOL), (
            f"{name} at t={reference['time'][worst]}: ecos {values[worst]!r}, reference "
            f"{reference[name][worst]!r}")


@pytest.mark.parametrize("name", SCRIPTS)
def test_fmi2_fmu_in_ecos_matches_its_reference(ecos, component_fmus, name, tmp_path):
    _assert_matches_reference(*_run_in_ecos(component_fmus[name], tmp_path))


@pytest.mark.parametrize("name", SCRIPTS)
def test_fmi3_twin_in_ecos_matches_its_reference(ecos, twins, name, tmp_path):
    _assert_matches_reference(*_run_in_ecos(twins[name], tmp_path))
