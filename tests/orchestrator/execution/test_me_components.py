"""Model Exchange components from a manifest: the keys ``interface``, ``solver`` and
``tolerance`` of ``[components.<name>]`` (and of a variant's component) through every path:
validate, run (local pool and Dask), run.json, --resume, the init check, ``agv-cosim
list``, SSP export and import, and their bad input.

The Reference FMUs are built as tests/orchestrator/execution/test_model_exchange.py
builds them (its ``reference`` fixture, cached in pytest's cache folder); ``me_only``
copies one without its ``<CoSimulation>``. Closed forms: Dahlquist x' = -k x integrated
by CVODE or solve_ivp against exp(-k t) within 1e-7 (tolerance 1e-9); through its
co-simulation interface (the Reference FMUs' forward Euler at their fixed step 0.1, one
step per communication step of 0.1) x_n = 0.9^n; our co-simulation integrator
(y' = u, exact for a held input) in a loop through an ME Feedthrough and a gain
(u = g y) gives y_n = (1 + g h)^n exactly (Gauss-Seidel).
"""

import csv
import json
import math

import numpy as np
import pytest
import test_model_exchange
from test_model_exchange import me_only

from agv_cosim import cli
from agv_cosim.pipeline import execute, prepare
from agv_cosim.system.interface import INTERFACES, SOLVERS

#: the Reference FMUs built once (test_model_exchange's fixture)
reference = test_model_exchange.reference


def _rows(path):
    with open(path, newline="") as stream:
        rows = list(csv.reader(stream))
    return rows[0], np.array(rows[1:], dtype=float)


def _column(header, rows, name):
    return rows[:, header.index(name)]


def _record(folder):
    return json.loads((folder / "run.json").read_text())


def test_the_schema_names_the_engines_interfaces_and_solvers():
    """The manifest's schema offers exactly what the engine accepts."""
    from agv_cosim.manifest import schema

    fields = schema.ComponentTable.model_fields
    assert fields["interface"].annotation.__args__[0].__args__ == INTERFACES
    assert fields["solver"].annotation.__args__[0].__args__ == SOLVERS


# a closed loop ---------------------------------------------------------------------------

LOOP = """
[simulation]
stop = 2.0
step = 0.1
[components.dq]
fmu = "{dahlquist}"
solver = "scipy"
tolerance = 1e-9
[components.ft]
fmu = "{feedthrough}"
tolerance = 1e-8
[components.integ]
fmu = "{integrator}"
parameters = {{ y0 = 1.0 }}
[components.gain]
fmu = "{gain}"
parameters = {{ k = -0.5 }}
[[connections]]
from = "integ.y"
to = "ft.Float64_continuous_input"
[[connections]]
from = "ft.Float64_continuous_output"
to = "gain.u"
[[connections]]
from = "gain.y"
to = "integ.u"
[[connections]]
from = "dq.x"
to = "ft.Float64_discrete_input"
[record]
variables = ["integ.y", "ft.Float64_continuous_output", "ft.Float64_discrete_output",
             "dq.x"]
"""


def _loop(reference, fmus, tmp_path):
    manifest = tmp_path / "loop.toml"
    manifest.write_text(LOOP.format(
        dahlquist=me_only(reference, "3", "Dahlquist", tmp_path),
        feedthrough=me_only(reference, "2", "Feedthrough", tmp_path),
        integrator=fmus["agv_test_integrator"], gain=fmus["agv_test_gain"]))
    return manifest


def _check_loop(folder):
    header, rows = _rows(folder / "timeseries.csv")
    t, n = rows[:, 0], np.arange(len(rows))
    y = _column(header, rows, "integ.y")
    assert np.allclose(y, 0.95 ** n, rtol=1e-12, atol=0)  # (1 + g h)^n, g = -0.5, h = 0.1
    assert np.array_equal(_column(header, rows, "ft.Float64_continuous_output"), y)
    x = _column(header, rows, "dq.x")
    assert np.allclose(x, np.exp(-t), rtol=0, atol=1e-7)
    # a discrete input: set in event mode at each point, shown at once
    assert np.array_equal(_column(header, rows, "ft.Float64_discrete_output"), x)


def test_an_me_only_fmu_in_a_closed_loop_from_a_manifest(reference, fmus, tmp_path, capsys):
    """Two model-exchange-only FMUs (FMI 3.0 Dahlquist with solver = "scipy", FMI 2.0
    Feedthrough with the default CVODE) with our co-simulation integrator and gain, the
    loop closed through the ME Feedthrough: ``agv-cosim validate`` (init check included)
    passes, ``agv-cosim run`` follows the closed forms, and run.json records each
    component's interface and the integrated ones' solver and tolerance (in its inputs
    too)."""
    manifest = _loop(reference, fmus, tmp_path)
    assert cli.main(["validate", str(manifest)]) == 0
    out = tmp_path / "out"
    assert cli.main(["run", str(manifest), "--out", str(out), "--jobs", "1", "--quiet"]) == 0
    _check_loop(out / "base")
    record = _record(out / "base")
    assert record["interfaces"] == {"dq": "model-exchange", "ft": "model-exchange",
                                    "integ": "co-simulation", "gain": "co-simulation"}
    integration = {"dq": {"solver": "scipy", "tolerance": 1e-9},
                   "ft": {"solver": "cvode", "tolerance": 1e-8}}
    assert record["integration"] == integration
    assert record["inputs"]["integration"] == integration
    capsys.readouterr()


@pytest.mark.slow  # a Dask cluster of worker processes
def test_the_closed_loop_on_dask_writes_what_the_local_pool_writes(reference, fmus,
                                                                     tmp_path):
    """The same manifest on a Dask cluster (a LocalCluster of one worker process): the
    same timeseries.csv bytes and the same interfaces and integration in run.json."""
    from distributed import LocalCluster

    manifest = _loop(reference, fmus, tmp_path)
    local, remote = tmp_path / "local", tmp_path / "dask"
    assert cli.main(["run", str(manifest), "--out", str(local), "--jobs", "1",
                     "--quiet"]) == 0
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                      dashboard_address=":0") as cluster:
        assert cli.main(["run", str(manifest), "--out", str(remote), "--dask",
                         cluster.scheduler_address, "--quiet"]) == 0
    assert (remote / "base" / "timeseries.csv").read_bytes() == \
        (local / "base" / "timeseries.csv").read_bytes()
    for key in ("interfaces", "integration"):
        assert _record(remote / "base")[key] == _record(local / "base")[key]
    _check_loop(remote / "base")


# one FMU, both interfaces --------------------------------------------------------------

BOTH = """
[simulation]
stop = 3.0
step = 0.1
[components.m]
fmu = "{fmu}"
[variants.cs]
description = "through its co-simulation interface (the FMU's own forward Euler)"
[variants.cs.components.m]
interface = "co-simulation"
[variants.me]
description = "integrated"
[variants.me.components.m]
interface = "model-exchange"
solver = "{solver}"
tolerance = 1e-9
[variants.default]
description = "no interface given: co-simulation, the FMU has it"
"""


@pytest.mark.parametrize("version,solver", [("2", "cvode"), ("3", "scipy")])
def test_an_fmu_with_both_interfaces_run_each_way(reference, tmp_path, version, solver,
                                                  capsys):
    """Dahlquist (k = 1) with both interfaces in one manifest: the variant with
    interface = "co-simulation" and the one without follow the FMU's forward Euler
    (0.9^n, one Euler step of 0.1 per communication step), the one with interface =
    "model-exchange" exp(-t) within 1e-7; run.json says which."""
    manifest = tmp_path / "both.toml"
    manifest.write_text(BOTH.format(fmu=reference[version] / "Dahlquist.fmu",
                                    solver=solver))
    out = tmp_path / "out"
    assert cli.main(["run", str(manifest), "--out", str(out), "--jobs", "1", "--quiet"]) == 0
    for label in ("cs", "default"):
        header, rows = _rows(out / label / "timeseries.csv")
        x = _column(header, rows, "m.x")
        assert np.allclose(x, 0.9 ** np.arange(len(rows)), rtol=1e-12, atol=0), label
        assert _record(out / label)["interfaces"] == {"m": "co-simulation"}
        assert _record(out / label)["integration"] == {}
        assert "integration" not in _record(out / label)["inputs"]
    header, rows = _rows(out / "me" / "timeseries.csv")
    x = _column(header, rows, "m.x")
    assert np.allclose(x, np.exp(-rows[:, 0]), rtol=0, atol=1e-7)
    assert np.max(np.abs(x - 0.9 ** np.arange(len(rows)))) > 0.01
    assert _record(out / "me")["interfaces"] == {"m": "model-exchange"}
    assert _record(out / "me")["integration"] == {"m": {"solver": solver,
                                                        "tolerance": 1e-9}}
    capsys.readouterr()


def test_the_init_check_checks_each_interface_of_an_fmu(reference, tmp_path):
    """One FMU as two components with the same parameters, one through each interface:
    the initialisation check instantiates it both ways (as the runs do)."""
    from agv_cosim.workers.initcheck import plan_checks

    fmu = reference["2"] / "Dahlquist.fmu"
    manifest = tmp_path / "two.toml"
    manifest.write_text(f'[simulation]\nstop = 1.0\nstep = 0.1\n[components.a]\n'
                        f'fmu = "{fmu}"\n[components.b]\nfmu = "{fmu}"\n'
                        'interface = "model-exchange"\n')
    loaded, jobs, _ = prepare(manifest)
    checks = plan_checks(loaded, jobs)
    assert checks is not None
    assert [(cname, info.integration is not None) for cname, info, *_ in checks.items] \
        == [("a", False), ("b", True)]
    assert cli.main(["validate", str(manifest)]) == 0


# a solver failure --------------------------------------------------------------------------

#: the solver's reason for k = -1000 (x = exp(1000 t) overflows near t = 0.7 s)
REASONS = {"cvode": ("the CVODE solver failed at t=", "mxstep steps taken"),
           "scipy": ("the solve_ivp solver failed at t=",
                     "solve_ivp (LSODA): the derivatives are not finite")}


@pytest.mark.parametrize("solver", ["cvode", "scipy"])
def test_a_solver_failure_ends_its_run_and_the_sweep_goes_on(reference, tmp_path, capsys,
                                                             solver):
    """A sweep over Dahlquist's k (both interfaces, interface = "model-exchange", the
    solver given, tolerance = 1e-8): with k = -1000, x = exp(1000 t) overflows, the
    solver gives up (CVODE after its step limit; solve_ivp on derivatives that are no
    longer finite, where LSODA alone would never return: the run's timeout of 120 s is
    only a guard), that run ends partial with the solver's reason in one line and in its
    run.json, its rows up to the failing step kept; k = 1 completes."""
    manifest = tmp_path / "sweep.toml"
    manifest.write_text(f'[simulation]\nstop = 2.0\nstep = 0.1\ntimeout = 120.0\n'
                        f'[components.m]\nfmu = "{reference["2"] / "Dahlquist.fmu"}"\n'
                        f'interface = "model-exchange"\nsolver = "{solver}"\n'
                        'tolerance = 1e-8\n[sweep]\n"m.k" = [1.0, -1000.0]\n')
    out = tmp_path / "out"
    code = cli.main(["run", str(manifest), "--out", str(out), "--jobs", "1", "--quiet"])
    assert code == 1
    err = capsys.readouterr().err.strip().splitlines()
    where, reason = REASONS[solver]
    failed = [line for line in err if where in line]
    assert len(failed) == 1 and "component 'm'" in failed[0] and reason in failed[0], err
    with open(out / "summary.csv", newline="") as stream:
        status = {row["run"]: row["status"] for row in csv.DictReader(stream)}
    assert status == {"base__m.k=1.0": "complete", "base__m.k=-1000.0": "partial"}
    record = _record(out / "base__m.k=-1000.0")
    assert record["status"] == "partial" and reason in record["error"]
    assert record["integration"] == {"m": {"solver": solver, "tolerance": 1e-8}}
    header, rows = _rows(out / "base__m.k=-1000.0" / "timeseries.csv")
    assert record["rows"] == len(rows) >= 5 and rows[-1, 0] < 1.0
    x = _column(header, rows, "m.x")
    assert x[1] == pytest.approx(math.exp(100.0), rel=1e-4)
    header, rows = _rows(out / "base__m.k=1.0" / "timeseries.csv")
    assert np.allclose(_column(header, rows, "m.x"), np.exp(-rows[:, 0]), rtol=0,
                       atol=1e-5)


# resume -------------------------------------------------------------------------------------

def _resumed(manifest, out):
    loaded, jobs, _ = prepare(manifest)
    _, results = execute(loaded, jobs, out, workers=1, quiet=True, resume=True)
    assert all(r["status"] == "complete" for r in results), results
    return {r["label"]: r.get("reused", False) for r in results}


@pytest.mark.parametrize("change", ["tolerance", "solver", "interface"])
def test_resume_reruns_a_run_whose_integration_changed(reference, tmp_path, change):
    """A run of an integrated component is reused when nothing changed; after its
    tolerance, its solver or its interface changes it is run again (the other variant's
    run, unchanged, is still reused) and its run.json says what it ran with."""
    fmu = reference["2"] / "Dahlquist.fmu"
    manifest = tmp_path / "r.toml"
    text = (f'[simulation]\nstop = 1.0\nstep = 0.1\n[components.m]\nfmu = "{fmu}"\n'
            'interface = "model-exchange"\n'
            '[variants.a.components.m]\ntolerance = 1e-6\n'
            '[variants.b.components.m]\ntolerance = 1e-7\n')
    manifest.write_text(text)
    out = tmp_path / "out"
    assert _resumed(manifest, out) == {"a": False, "b": False}
    assert _resumed(manifest, out) == {"a": True, "b": True}
    changed = {"tolerance": ("tolerance = 1e-6", "tolerance = 1e-8"),
               "solver": ("tolerance = 1e-6", 'tolerance = 1e-6\nsolver = "scipy"'),
               "interface": ("[variants.a.components.m]\ntolerance = 1e-6",
                             '[variants.a.components.m]\ninterface = "co-simulation"')}
    manifest.write_text(text.replace(*changed[change]))
    assert _resumed(manifest, out) == {"a": False, "b": True}
    expected = {"tolerance": {"m": {"solver": "cvode", "tolerance": 1e-8}},
                "solver": {"m": {"solver": "scipy", "tolerance": 1e-6}},
                "interface": {}}[change]
    assert _record(out / "a")["integration"] == expected
    assert _resumed(manifest, out) == {"a": True, "b": True}


# list and SSP ------------------------------------------------------------------------------

def test_list_shows_the_interfaces(reference, tmp_path, capsys):
    """``agv-cosim list``: an FMU's interfaces, Model Exchange with its states and event
    indicators, and how a component runs it by default."""
    assert cli.main(["list", str(reference["3"] / "BouncingBall.fmu")]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[1] == ('  interfaces: co-simulation, model-exchange (2 continuous states, '
                        '1 event indicators): run as co-simulation unless a component sets '
                        'interface = "model-exchange"')
    assert cli.main(["list", str(me_only(reference, "2", "VanDerPol", tmp_path))]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[1] == ("  interfaces: model-exchange (2 continuous states, 0 event "
                        "indicators): integrated by the orchestrator (solver cvode unless "
                        "a component sets one)")


def test_ssp_export_and_import_keep_the_interface_solver_and_tolerance(reference, fmus,
                                                                       tmp_path, capsys):
    """The closed loop exported as SSP: each Model Exchange component carries
    implementation="ModelExchange" and an org.agv-cosim agv:Integration annotation
    (solver, tolerance); a component of an FMU with both interfaces run as co-simulation
    carries implementation="CoSimulation"; a co-simulation-only FMU's nothing. Imported
    back, the package runs with the same interfaces, solvers and tolerances and writes
    the same timeseries.csv."""
    import zipfile
    from xml.etree import ElementTree

    from agv_cosim.ssp.common import NS
    from agv_cosim.ssp.importer import load_ssp

    manifest = _loop(reference, fmus, tmp_path)
    both = reference["2"] / "Dahlquist.fmu"
    manifest.write_text(manifest.read_text() + f'[components.extra]\nfmu = "{both}"\n'
                        'interface = "co-simulation"\n')
    package = tmp_path / "loop.ssp"
    assert cli.main(["export-ssp", str(manifest), "-o", str(package)]) == 0
    with zipfile.ZipFile(package) as archive:
        root = ElementTree.fromstring(archive.read("SystemStructure.ssd"))
    found = {}
    for node in root.iterfind("ssd:System/ssd:Elements/ssd:Component", NS):
        notes = node.find("ssd:Annotations/ssc:Annotation/agv:Integration", NS)
        found[node.get("name")] = (node.get("implementation"),
                                   None if notes is None else dict(notes.attrib))
    assert found == {"dq": ("ModelExchange", {"solver": "scipy", "tolerance": "1e-09"}),
                     "ft": ("ModelExchange", {"solver": "cvode", "tolerance": "1e-08"}),
                     "integ": (None, None), "gain": (None, None),
                     "extra": ("CoSimulation", None)}
    loaded = load_ssp(package, tmp_path / "work")
    keys = {c: (comp.interface, comp.solver, comp.tolerance)
            for c, comp in loaded.components.items()}
    assert keys == {"dq": ("model-exchange", "scipy", 1e-9),
                    "ft": ("model-exchange", "cvode", 1e-8),
                    "integ": (None, None, None), "gain": (None, None, None),
                    "extra": ("co-simulation", None, None)}
    # the SSP keeps the manifest's algorithm and record: the same bytes
    direct, imported = tmp_path / "direct", tmp_path / "imported"
    assert cli.main(["run", str(manifest), "--out", str(direct), "--jobs", "1",
                     "--quiet"]) == 0
    assert cli.main(["run", str(package), "--out", str(imported), "--jobs", "1",
                     "--quiet"]) == 0
    assert (imported / "base" / "timeseries.csv").read_bytes() == \
        (direct / "base" / "timeseries.csv").read_bytes()
    assert _record(imported / "base")["integration"] == _record(direct / "base")["integration"]
    capsys.readouterr()


def test_an_unknown_ssp_implementation_is_refused_in_one_line(reference, tmp_path, capsys):
    """``implementation="ScheduledExecution"`` (SSP has it, agv-cosim does not): one line
    naming the package and the component, exit 2."""
    manifest = tmp_path / "m.toml"
    manifest.write_text(f'[simulation]\nstop = 1.0\nstep = 0.1\n[components.m]\n'
                        f'fmu = "{reference["2"] / "Dahlquist.fmu"}"\n'
                        'interface = "model-exchange"\n')
    package = tmp_path / "m.ssp"
    assert cli.main(["export-ssp", str(manifest), "-o", str(package)]) == 0
    edited = tmp_path / "edited.ssp"
    with zipfile_copy(package, edited) as text:
        text[0] = text[0].replace('implementation="ModelExchange"',
                                  'implementation="ScheduledExecution"')
    capsys.readouterr()
    assert cli.main(["validate", str(edited)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "edited.ssp" in err[0] and "Component 'm'" in err[0]
    assert "implementation 'ScheduledExecution' is not supported" in err[0]


class zipfile_copy:
    """Context: ``[ssd text]`` of the package ``source`` to edit in place; written with
    the other entries into ``target`` when the context ends."""

    def __init__(self, source, target):
        self.source, self.target = source, target

    def __enter__(self):
        import zipfile

        with zipfile.ZipFile(self.source) as archive:
            self.entries = {i.filename: archive.read(i) for i in archive.infolist()}
        self.text = [self.entries["SystemStructure.ssd"].decode()]
        return self.text

    def __exit__(self, *exc):
        import zipfile

        self.entries["SystemStructure.ssd"] = self.text[0].encode()
        with zipfile.ZipFile(self.target, "w") as archive:
            for name, data in self.entries.items():
                archive.writestr(name, data)
        return False


# bad input ----------------------------------------------------------------------------------

def _with_tool(reference, tmp_path):
    """Dahlquist with both interfaces whose Model Exchange needs its exporting tool."""
    import zipfile

    source, target = reference["2"] / "Dahlquist.fmu", tmp_path / "tool.fmu"
    with zipfile.ZipFile(source) as zin, zipfile.ZipFile(target, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item)
            if item.filename == "modelDescription.xml":
                data = data.decode().replace(
                    "<ModelExchange", '<ModelExchange needsExecutionTool="true"').encode()
            zout.writestr(item, data)
    return target


BAD = [
    # (component text, key named, what the line says)
    ('fmu = "{both}"\ninterface = "modelexchange"\n', "components.m.interface",
     "'modelexchange' is not one of co-simulation, model-exchange (did you mean "
     "'model-exchange'?)"),
    ('fmu = "{both}"\ninterface = "model-exchange"\nsolver = "rk4"\n', "components.m.solver",
     "'rk4' is not one of cvode, scipy"),
    ('fmu = "{both}"\ninterface = "model-exchange"\ntolerance = 0\n',
     "components.m.tolerance", "0 must be > 0"),
    ('fmu = "{both}"\ninterface = "model-exchange"\ntolerance = 1.5\n',
     "components.m.tolerance", "1.5 must be < 1"),
    ('fmu = "{both}"\ninterface = "model-exchange"\ntolerance = "1e-6"\n',
     "components.m.tolerance", "'1e-6' is not a number"),
    ('fmu = "{both}"\ninterface = "co-simulation"\ntolerance = 1e-6\n',
     "components.m.tolerance", "applies to a component integrated as Model Exchange, not "
     "to one with interface = \"co-simulation\""),
    ('fmu = "{both}"\nsolver = "scipy"\n', "components.m.solver",
     "solver and tolerance apply to a component integrated as Model Exchange"),
    ('fmu = "{gain}"\ninterface = "model-exchange"\n', "components.m.interface",
     "has no Model Exchange interface (it declares co-simulation)"),
    ('fmu = "{me}"\ninterface = "co-simulation"\n', "components.m.interface",
     "has no co-simulation interface (it declares model-exchange)"),
    ('table = "{table}"\nsolver = "cvode"\n', "components.m.solver",
     "only for an FMU component (a time table has no FMI interface)"),
    ('fmu = "{tool}"\ninterface = "model-exchange"\n', "components.m.interface",
     "needsExecutionTool"),
]


@pytest.mark.parametrize("component,key,message", BAD,
                         ids=["interface", "solver", "tolerance-0", "tolerance-1.5",
                              "tolerance-string", "tolerance-co-simulation",
                              "solver-implicit-co-simulation", "no-me", "no-cs", "table",
                              "needs-tool"])
def test_bad_input_is_one_line_exit_2(reference, fmus, tmp_path, capsys, component, key,
                                      message):
    table = tmp_path / "in.csv"
    table.write_text("time,c\n0,0\n1,1\n")
    text = component.format(both=reference["2"] / "Dahlquist.fmu", gain=fmus["agv_test_gain"],
                            me=me_only(reference, "2", "Dahlquist", tmp_path), table=table,
                            tool=_with_tool(reference, tmp_path))
    manifest = tmp_path / "bad.toml"
    manifest.write_text(f"[simulation]\nstop = 1.0\nstep = 0.1\n[components.m]\n{text}")
    for command in (["validate", str(manifest)],
                    ["run", str(manifest), "--out", str(tmp_path / "out"), "--quiet"]):
        assert cli.main(command) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1, err
        assert "bad.toml:" in err[0] and f": {key}: " in err[0], err[0]
        assert message in err[0], err[0]
    assert not (tmp_path / "out").exists()


def test_a_variants_bad_interface_names_the_variant(reference, fmus, tmp_path, capsys):
    """A variant asking a co-simulation-only FMU for Model Exchange: the variant's key."""
    manifest = tmp_path / "v.toml"
    manifest.write_text(f'[simulation]\nstop = 1.0\nstep = 0.1\n[components.m]\n'
                        f'fmu = "{fmus["agv_test_gain"]}"\n'
                        '[variants.ok]\n[variants.me.components.m]\n'
                        'interface = "model-exchange"\n')
    assert cli.main(["validate", str(manifest)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and ": variants.me.components.m.interface: " in err[0], err
    assert "has no Model Exchange interface" in err[0]


def test_a_variant_run_as_co_simulation_drops_the_bases_solver(reference, tmp_path):
    """The base integrates the FMU with solve_ivp at 1e-8; a variant with interface =
    "co-simulation" runs it as co-simulation (the base's solver and tolerance dropped),
    a variant giving only a tolerance keeps the base's interface and solver."""
    manifest = tmp_path / "v.toml"
    manifest.write_text(f'[simulation]\nstop = 1.0\nstep = 0.1\n[components.m]\n'
                        f'fmu = "{reference["2"] / "Dahlquist.fmu"}"\n'
                        'interface = "model-exchange"\nsolver = "scipy"\ntolerance = 1e-8\n'
                        '[variants.cs.components.m]\ninterface = "co-simulation"\n'
                        '[variants.tight.components.m]\ntolerance = 1e-10\n')
    _, jobs, _ = prepare(manifest)
    integration = {job.variant: job.plan.models["m"].integration for job in jobs}
    assert integration["cs"] is None
    assert (integration["tight"].solver, integration["tight"].tolerance) == ("scipy", 1e-10)


def test_run_json_of_a_co_simulation_system_has_no_integration_input(fmus, chain, tmp_path):
    """A system of co-simulation FMUs only: run.json's inputs carry no ``integration``
    (the inputs of such a run, and so --resume of a folder written before, are as they
    were); ``interfaces`` names each FMU's."""
    manifest = chain()
    out = tmp_path / "out"
    assert cli.main(["run", str(manifest), "--out", str(out), "--jobs", "1", "--quiet"]) == 0
    record = _record(out / "base")
    assert "integration" not in record["inputs"] and record["integration"] == {}
    assert record["interfaces"] == {c: "co-simulation" for c in ("src", "gain", "gain2",
                                                                 "int")}


def test_api_run_reads_the_interfaces(reference, tmp_path):
    """agv_cosim.run: each Run's ``interfaces`` and ``integration`` from its run.json."""
    import agv_cosim

    manifest = tmp_path / "m.toml"
    manifest.write_text(BOTH.format(fmu=reference["2"] / "Dahlquist.fmu", solver="cvode"))
    results = agv_cosim.run(manifest, out=tmp_path / "out", jobs=1, quiet=True)
    assert results.run("me").interfaces == {"m": "model-exchange"}
    assert results.run("me").integration == {"m": {"solver": "cvode", "tolerance": 1e-9}}
    assert results.run("cs").interfaces == {"m": "co-simulation"}
    assert results.run("cs").integration == {}
