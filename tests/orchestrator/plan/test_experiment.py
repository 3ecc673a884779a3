"""The system stage's view of a manifest: one frozen :class:`Experiment` (simulation
settings, recorded, held and swept names, the base's wiring, where relative files start,
how a problem at a key is reported), built once from the manifest; the system stage
takes it and the self-contained runs, never the manifest itself."""

import ast
import dataclasses
from pathlib import Path

import pytest

from agv_cosim.errors import ManifestError
from agv_cosim.manifest import Component, Connection, load_manifest
from agv_cosim.plan import Experiment, RunSpec, plan_runs
from agv_cosim.system import validate

SYSTEM = Path(__file__).resolve().parents[3] / "orchestrator" / "agv_cosim" / "system"

MANIFEST = """
held = ["sink.w"]

[simulation]
start = 1.0
stop = 3.0
step = 0.5
algorithm = "jacobi"

[components.src]
fmu = "Src.fmu"
parameters = { "k" = 1.0, "table" = "data/in.csv" }

[components.sink]
fmu = "Sink.fmu"

[[connections]]
from = "src.y"
to = "sink.u"

[record]
variables = ["sink.y"]

[variants.v]
[variants.v.components.extra]
fmu = "Extra.fmu"

[sweep]
"src.k" = [1.0, 2.0]
"""


def test_an_experiment_holds_what_every_run_of_the_manifest_shares(tmp_path):
    path = tmp_path / "m.toml"
    path.write_text(MANIFEST)
    manifest = load_manifest(path)
    experiment = Experiment.of(manifest)
    assert (experiment.path, experiment.start, experiment.stop, experiment.step,
            experiment.algorithm) == (path, 1.0, 3.0, 0.5, "jacobi")
    assert experiment.record == ("sink.y",) and experiment.held == ("sink.w",)
    assert experiment.sweep == ("src.k",) and experiment.variants == ("v",)
    assert experiment.connections == (Connection(("src", "y"), ("sink", "u"),
                                                 "connections[0]"),)
    assert experiment.files_dir == manifest.files_dir == tmp_path.resolve()
    assert experiment.step_index(2.5) == 3 and experiment.step_index(1.0) == 0
    # a problem is reported at its key's line, as the manifest reports it
    for key in ("held", "record.variables[0]", "sweep.src.k", "connections[0].to"):
        assert str(experiment.error(key, "bad")) == str(manifest.error(key, "bad"))
    assert experiment.error("held", "bad").line == 2
    # a variant not being run is planned on demand (the held check reads its FMUs)
    run = experiment.plan_variant("v")
    assert run.label == plan_runs(manifest, ["v"])[0].label and "extra" in run.components
    with pytest.raises(dataclasses.FrozenInstanceError):
        experiment.step = 1.0  # type: ignore[misc]
    manifest.held.append("src.u")  # the experiment is a copy, not a view
    assert experiment.held == ("sink.w",)


def test_the_system_stage_reads_no_manifest():
    """No module of agv_cosim.system takes the Manifest or plans runs itself: it gets an
    Experiment and the planned runs."""
    found = []
    for path in sorted(SYSTEM.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                found += [f"{path.name}:{node.lineno} {a.name}" for a in node.names
                          if a.name in ("Manifest", "load_manifest", "manifest_from_data",
                                        "plan_runs")]
    assert found == []


def _experiment(path: Path, **changes: object) -> Experiment:
    def no_variants(name: str) -> RunSpec:
        raise AssertionError(f"no variant to plan: {name}")

    given: dict[str, object] = dict(
        path=path, start=0.0, stop=1.0, step=0.1, algorithm="gauss-seidel", record=None,
        held=(), sweep=(), files_dir=path.parent, connections=(), variants=(),
        plan_variant=no_variants)
    given.update(changes)
    return Experiment(**given)  # type: ignore[arg-type]


def test_a_system_is_checked_from_an_experiment_and_runs_built_by_hand(fmus, tmp_path):
    connection = Connection(("src", "y"), ("gain", "u"), "connections[0]")
    run = RunSpec(label="base", variant=None, point={}, overrides={},
                  components={"src": Component("src", Path(fmus["agv_test_source"]),
                                               {"slope": 2.0}),
                              "gain": Component("gain", Path(fmus["agv_test_gain"]),
                                                {"k": 3.0})},
                  connections=[connection])
    where = tmp_path / "made-by-hand.toml"
    checked = validate(_experiment(where, connections=(connection,)), [run])
    [one] = checked.runs
    assert one.parameters == {"src": {"slope": 2.0}, "gain": {"k": 3.0}}
    assert one.order == ["src", "gain"] and "gain.y" in one.record
    with pytest.raises(ManifestError) as error:
        validate(_experiment(where, record=("gain.nope",)), [run])
    assert str(error.value) == (f"{where}: record.variables[0]: unknown variable "
                                "'gain.nope'")
