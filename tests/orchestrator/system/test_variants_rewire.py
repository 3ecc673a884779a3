"""Variants that rewire (issue 24, item 1): ``remove``, ``disconnect`` and ``connections``
in ``[variants.<name>]``; each variant's resulting system checked like a base one, its
errors naming the variant; per-run records; SSP export of a variant's own system; and
the shipped experiment ``experiments/controllers_rewired.toml``.

The fast tests use the small test FMUs (tests/conftest.py ``fmus``): the chain
src -> gain -> gain2 -> int of tests/orchestrator/conftest.py, in which a variant swaps
``gain`` (u -> y) for ``pair`` (u1 -> y1, u2 -> y2: another interface).
"""

import zipfile
from pathlib import Path
from xml.etree import ElementTree

import numpy as np
import pytest

from agv_cosim import cli
from agv_cosim.errors import ManifestError
from agv_cosim.execution import RowObserver, simulate
from agv_cosim.manifest import load_manifest
from agv_cosim.pipeline import prepare, run_manifest
from agv_cosim.plan import plan_runs
from agv_cosim.ssp import common as ssp
from agv_cosim.ssp import exporter as ssp_export
from agv_cosim.ssp import importer as ssp_import

from manifests import assert_complete, localise

ROOT = Path(__file__).resolve().parents[3]

#: ``gain`` replaced by ``p`` (pair): src.y -> p.u1, p.y1 -> gain2.u; p.y1 = u1, so the
#: variant is the chain with a unit gain, which the variant ``unit`` is directly
PAIRED = """
[variants.unit]
description = "gain k = 1"
[variants.unit.components.gain]
parameters = {{ k = 1.0 }}

[variants.paired]
description = "gain replaced by pair (another interface)"
remove = ["gain"]
disconnect = ["gain"]
[variants.paired.components.p]
fmu = "{pair}"
[[variants.paired.connections]]
from = "src.y"
to = "p.u1"
[[variants.paired.connections]]
from = "p.y1"
to = "gain2.u"
"""


def _paired(chain, fmus, extra="", body=PAIRED, **kwargs):
    return chain(extra=body.format(pair=fmus["agv_test_pair"]) + extra, **kwargs)


def _error(path, variants=None):
    with pytest.raises(ManifestError) as caught:
        prepare(path, variants)
    return str(caught.value)


def _rows(job):
    rows = []
    simulate(job.plan, [RowObserver(lambda row: rows.append(list(row)))])
    return np.array(rows)


# --------------------------------------------------------------------------- the system

def test_a_variant_swaps_a_component_for_another_interface(chain, fmus):
    manifest, jobs, warnings = prepare(_paired(chain, fmus))
    unit, paired = jobs
    assert [str(c) for c in paired.plan.connections] == [
        "gain2.y -> int.u", "src.y -> p.u1", "p.y1 -> gain2.u"]
    assert list(paired.plan.models) == ["src", "gain2", "int", "p"]  # new ones last
    assert paired.plan.order == ["src", "p", "gain2", "int"]
    # each run records its own components' outputs
    assert "gain.y" in unit.plan.record and "gain.y" not in paired.plan.record
    assert {"p.y1", "p.y2"} <= set(paired.plan.record)
    # pair's y1 = u1 is a unit gain: the same numbers as the variant with k = 1
    a, b = _rows(unit), _rows(paired)
    column = {name: i + 1 for i, name in enumerate(unit.plan.record)}
    other = {name: i + 1 for i, name in enumerate(paired.plan.record)}
    assert np.array_equal(a[:, column["int.y"]], b[:, other["int.y"]])
    assert np.array_equal(a[:, column["gain2.y"]], b[:, other["gain2.y"]])
    assert a[-1, column["int.y"]] != 0.0
    # p.u2 is left unconnected in that variant only: the warning names it
    assert warnings == [f"{manifest.path}: connections: unconnected inputs in variant(s) "
                        "paired (held at their start values): p.u2"]


def test_the_base_connections_and_components_stay_for_a_plain_variant(chain, fmus):
    manifest = load_manifest(_paired(chain, fmus))
    unit, paired = plan_runs(manifest)
    assert unit.connections == manifest.connections
    assert list(unit.components) == ["src", "gain", "gain2", "int"]
    assert unit.components["gain"].parameters == {"k": 1.0}
    assert [c.key for c in paired.connections] == [
        "connections[2]", "variants.paired.connections[0]", "variants.paired.connections[1]"]


def test_a_removed_component_added_again_keeps_its_place_and_nothing_of_the_base(chain,
                                                                                  fmus):
    body = """
[variants.again]
remove = ["gain"]
disconnect = ["gain"]
[variants.again.components.gain]
fmu = "{pair}"
[[variants.again.connections]]
from = "src.y"
to = "gain.u1"
[[variants.again.connections]]
from = "gain.y1"
to = "gain2.u"
"""
    _, jobs, _ = prepare(_paired(chain, fmus, body=body))
    assert list(jobs[0].plan.models) == ["src", "gain", "gain2", "int"]
    assert jobs[0].plan.models["gain"].model_name != "AgvTestGain"
    assert jobs[0].plan.parameters["gain"] == {}  # k of the base is not inherited


def test_disconnect_then_connect_replaces_a_driver(chain, fmus):
    body = """
[variants.bypass]
disconnect = ["gain2.u"]
[[variants.bypass.connections]]
from = "src.y"
to = "gain2.u"
"""
    _, jobs, warnings = prepare(_paired(chain, fmus, body=body))
    assert [str(c) for c in jobs[0].plan.connections] == [
        "src.y -> gain.u", "gain2.y -> int.u", "src.y -> gain2.u"]
    assert warnings == []


def test_a_base_valid_only_in_its_variants_is_accepted(chain, fmus):
    """The base has no run of its own when it has variants: a connection from an unknown
    output is fine once every variant replaces it."""
    path = chain()
    text = path.read_text().replace('from = "gain2.y"', 'from = "gain2.nope"')
    path.write_text(text)
    assert _error(path).endswith("connections[2].from: unknown variable 'gain2.nope' of "
                                 "AgvTestGain (outputs: y)")
    path.write_text(text + """
[variants.fixed]
disconnect = ["int.u"]
[[variants.fixed.connections]]
from = "gain2.y"
to = "int.u"
""")
    _, jobs, _ = prepare(path)
    assert [str(c) for c in jobs[0].plan.connections] == [
        "src.y -> gain.u", "gain.y -> gain2.u", "gain2.y -> int.u"]


# --------------------------------------------------------------------------- errors

def test_a_base_key_failing_in_a_variant_names_the_variant(chain, fmus):
    body = """
[variants.swap]
[variants.swap.components.int]
fmu = "{pair}"
"""
    message = _error(_paired(chain, fmus, body=body))
    assert "connections[2].to: variant 'swap': unknown variable 'int.u' of AgvTestPair" \
        in message
    assert message.endswith("; variants.swap replaces 'int': disconnect = [\"int.u\"] there "
                            "drops this connection")
    assert message.startswith(f"{chain().parent / 'chain.toml'}:")  # with the line


def test_base_parameters_of_a_replaced_component_name_the_variant(chain, fmus):
    body = """
[variants.swap]
[variants.swap.components.gain]
fmu = "{pair}"
"""
    message = _error(_paired(chain, fmus, body=body))
    assert "components.gain.parameters.k: variant 'swap': unknown parameter 'k' of gain " \
           "(AgvTestPair" in message
    assert message.endswith("variants.swap replaces 'gain' but keeps the base's parameters "
                            "(remove = [\"gain\"] and add a new 'gain' to start without "
                            "them)")


def test_an_unknown_variable_of_a_variant_connection(chain, fmus):
    path = _paired(chain, fmus)
    path.write_text(path.read_text().replace('to = "p.u1"', 'to = "p.u3"'))
    message = _error(path)
    assert "variants.paired.connections[0].to: unknown variable 'p.u3' of AgvTestPair " \
           "(inputs: u1, u2)" in message
    line = path.read_text().splitlines().index('to = "p.u3"') + 1
    assert message.startswith(f"{path}:{line}: ")


def test_a_variant_connection_to_a_driven_input(chain, fmus):
    body = """
[variants.twice]
[[variants.twice.connections]]
from = "src.y"
to = "gain2.u"
"""
    assert _error(_paired(chain, fmus, body=body)).endswith(
        "variants.twice.connections[0].to: input 'gain2.u' is already connected by "
        "connections[1] (to replace it, list 'gain2.u' in variants.twice.disconnect)")


def test_an_algebraic_loop_of_a_variant(chain, fmus):
    body = """
[variants.loop]
disconnect = ["gain.u"]
[[variants.loop.connections]]
from = "gain2.y"
to = "gain.u"
"""
    message = _error(_paired(chain, fmus, body=body))
    assert "connections: variant 'loop': algebraic loop (a cycle of direct feedthrough): " \
           "gain.u -> gain.y -> gain2.u -> gain2.y -> gain.u" in message


@pytest.mark.parametrize("change, key, problem", [
    ('remove = ["gain"]\n', "variants.v.remove[0]",
     "'gain' is removed but connections[0] (src.y -> gain.u), connections[1] "
     "(gain.y -> gain2.u) still connect it; disconnect them (disconnect = [\"gain\"])"),
    ('remove = ["gian"]\n', "variants.v.remove[0]",
     "unknown component 'gian' (did you mean 'gain'?)"),
    ('remove = ["gain", "gain"]\ndisconnect = ["gain"]\n', "variants.v.remove[1]",
     "'gain' is listed twice"),
    ('disconnect = ["int.y"]\n', "variants.v.disconnect[0]",
     "no connection of the base drives 'int.y' (did you mean 'int.u'?)"),
    ('disconnect = ["gian"]\n', "variants.v.disconnect[0]",
     "unknown component 'gian' (did you mean 'gain'?) (give 'component.input' or a "
     "component of the base)"),
    ('disconnect = ["gain", "gain"]\n', "variants.v.disconnect[1]", "'gain' is listed twice"),
    ('[variants.v.components.gian]\nparameters = { k = 1.0 }\n', "variants.v.components.gian",
     "unknown component 'gian' (did you mean 'gain'?); a new component needs 'fmu' or "
     "'table'"),
    ('remove = ["gain"]\ndisconnect = ["gain"]\n[variants.v.components.gain]\n'
     'parameters = { k = 1.0 }\n', "variants.v.components.gain",
     "'gain' is removed: a component of that name is a new one and needs 'fmu' or 'table'"),
    ('disconect = ["gain"]\n', "variants.v.disconect",
     "unknown section 'disconect' (did you mean 'disconnect'?)"),
    ('connections = [{ from = "src.y", to = "gain2" }]\n', "variants.v.connections[0].to",
     "'gain2' is not of the form 'component.variable'"),
])
def test_name_errors_of_a_variant(chain, fmus, change, key, problem):
    path = chain(extra="[variants.v]\n" + change)
    with pytest.raises(ManifestError) as caught:
        load_manifest(path)
    assert caught.value.key == key and caught.value.problem == problem


def test_signals_every_run_must_have(chain, fmus):
    message = _error(_paired(chain, fmus, '[metrics]\ncontrol = "gain.y"\n'))
    assert message.endswith("metrics: variant 'paired': signal 'gain.y' is not recorded "
                            "(see [record])")
    message = _error(_paired(chain, fmus, '[record]\nvariables = ["int.y", "gain.y"]\n'))
    assert message.endswith("record.variables[1]: variant 'paired': unknown component "
                            "'gain' (did you mean 'gain2'?)")
    # only the variants that run are checked
    _, jobs, _ = prepare(_paired(chain, fmus, '[metrics]\ncontrol = "gain.y"\n'), ["unit"])
    assert [job.label for job in jobs] == ["unit"]


def test_a_sweep_over_a_component_a_variant_removes(chain, fmus):
    message = _error(_paired(chain, fmus, '[sweep]\n"gain.k" = [1.0, 2.0]\n'))
    assert message.endswith("sweep.gain.k: variant 'paired' has no component 'gain' (it "
                            "removes it or the base has none)")
    # a component a variant adds may be swept when every run has it
    _, jobs, _ = prepare(_paired(chain, fmus, '[sweep]\n"p.n" = [1, 2]\n'), ["paired"])
    assert [job.plan.parameters["p"]["n"] for job in jobs] == [1, 2]


def test_the_cli_says_it_in_one_line_with_exit_2(chain, fmus, capsys):
    path = _paired(chain, fmus)
    path.write_text(path.read_text().replace('from = "p.y1"', 'from = "p.y3"'))
    assert cli.main(["validate", "--no-init", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("agv-cosim: error: ")
    assert "variants.paired.connections[1].from: unknown variable 'p.y3'" in err[0]


# --------------------------------------------------------------------------- SSP

def test_ssp_export_of_a_rewiring_variant_round_trips(chain, fmus, tmp_path):
    path = _paired(chain, fmus)
    with pytest.raises(ManifestError, match=r"expands to 2 runs; an SSP package holds one "
                                            r"\(choose --variant \(unit, paired\)"):
        ssp_export.export_ssp(path, tmp_path / "both.ssp")
    out = ssp_export.export_ssp(path, tmp_path / "paired.ssp", variant="paired")
    with zipfile.ZipFile(out) as archive:
        root = ElementTree.fromstring(archive.read(ssp.SSD_NAME))
    names = [c.get("name") for c in root.iterfind("ssd:System/ssd:Elements/ssd:Component",
                                                    ssp.NS)]
    assert names == ["src", "gain2", "int", "p"]
    wiring = [(c.get("startElement"), c.get("startConnector"), c.get("endElement"),
               c.get("endConnector"))
              for c in root.iterfind("ssd:System/ssd:Connections/ssd:Connection", ssp.NS)]
    assert wiring == [("gain2", "y", "int", "u"), ("src", "y", "p", "u1"),
                      ("p", "y1", "gain2", "u")]
    again = ssp_import.load_ssp(out, tmp_path / "unpacked")
    assert not again.variants
    assert [(c.source, c.target) for c in again.connections] == [
        (("gain2", "y"), ("int", "u")), (("src", "y"), ("p", "u1")),
        (("p", "y1"), ("gain2", "u"))]
    _, jobs, _ = prepare(path, ["paired"])
    _, imported, _ = prepare(again)
    assert np.array_equal(_rows(jobs[0]), _rows(imported[0]))


# --------------------------------------------------------------------------- experiment

def test_controllers_rewired_experiment_runs(component_fmus, tmp_path):
    """The shipped comparison: every run completes with its metrics, each variant holds
    only its own controller, and the front-wheel and rear-axle errors differ the way
    each law's reference point says (slow: builds the component FMUs)."""
    manifest = localise(ROOT / "experiments" / "controllers_rewired.toml", tmp_path,
                        component_fmus)
    out, results, warnings = run_manifest(manifest, tmp_path / "out", quiet=True)
    assert_complete(results, 3)
    metrics = {r["label"]: r["metrics"] for r in results}
    assert list(metrics) == ["lqr", "chained_form", "preview_lq"]
    models = {job.label: {c: m.model_name for c, m in job.plan.models.items()}
              for job in prepare(manifest)[1]}
    assert models["lqr"]["ctrl"] == "AgvStateFeedback" and "sen_f" in models["lqr"]
    assert models["chained_form"]["ctrl"] == "AgvChainedForm"
    assert models["preview_lq"]["ctrl"] == "AgvPreviewLq"
    assert all(len(m) == len(set(m)) for m in models.values())
    # the state feedback regulates the front wheel, the other two the rear axle: each
    # is best at its own point over the settled window
    rear = {k: m["lateral_error_settled_max"] for k, m in metrics.items()}
    front = {k: m["path_error_settled_max"] for k, m in metrics.items()}
    assert min(front, key=front.get) == "lqr"
    assert max(rear, key=rear.get) == "lqr"
    assert all(m["saturated_fraction"] == 0.0 for m in metrics.values())
    assert (out / "index.html").is_file() and (out / "trajectory.png").is_file()
    # each variant leaves other inputs unconnected: the manifest lists them all in held
    assert warnings == []


def test_ssp_export_refuses_a_variants_event_or_table(chain, fmus, tmp_path):
    body = """
[variants.kick]
disconnect = ["int.u"]
[variants.kick.events.push]
at = 0.5
set = {{ "int.u" = 1.0 }}

[variants.tabled]
disconnect = ["int.u"]
[variants.tabled.components.tab]
table = "in.csv"
[[variants.tabled.connections]]
from = "tab.a"
to = "int.u"
"""
    path = _paired(chain, fmus, body=body)
    (path.parent / "in.csv").write_text("time,a\n0,1\n1,2\n")
    for variant, key, problem in (
            ("kick", "variants.kick.events.push",
             "a scenario event cannot be written to an SSP package (SSP 1.0 has no events)"),
            ("tabled", "variants.tabled.components.tab.table",
             "a time table cannot be written to an SSP package (SSP components are FMUs)")):
        with pytest.raises(ManifestError) as caught:
            ssp_export.export_ssp(path, tmp_path / f"{variant}.ssp", variant=variant)
        assert (caught.value.key, caught.value.problem) == (key, problem)
        assert not (tmp_path / f"{variant}.ssp").exists()
    # both run (the refusal is the export's alone)
    _, jobs, _ = prepare(path)
    assert [len(job.plan.events) for job in jobs] == [1, 0]


def test_a_sampled_parameter_every_run_must_have(chain, fmus):
    sampled = ('[montecarlo]\nsamples = 2\nseed = 1\n[montecarlo.parameters."p.n"]\n'
               'distribution = "choice"\nvalues = [1, 2]\n')
    assert _error(_paired(chain, fmus, sampled)).endswith(
        "montecarlo.parameters.p.n: variant 'unit' has no component 'p' (it removes it or "
        "the base has none)")
    _, jobs, _ = prepare(_paired(chain, fmus, sampled), ["paired"])
    assert [job.label for job in jobs] == ["paired__mc0000", "paired__mc0001"]
    with pytest.raises(ManifestError, match=r"montecarlo\.parameters\.q\.n: unknown "
                                            r"component 'q'$"):
        load_manifest(_paired(chain, fmus, sampled.replace('"p.n"', '"q.n"')))


def test_validate_counts_each_variants_own_wiring(chain, fmus, capsys):
    more = """
[variants.more.components.q]
fmu = "{pair}"
[[variants.more.connections]]
from = "src.y"
to = "q.u1"
"""
    path = _paired(chain, fmus, extra=more.format(pair=fmus["agv_test_pair"]))
    assert cli.main(["validate", str(path), "--no-init"]) == 0
    out = capsys.readouterr().out
    # unit and paired: 4 components, 3 connections; more: 5 components, 4 connections
    assert out.strip().endswith(": ok: 3 run(s), 4-5 component(s), 3-4 connection(s), "
                                "gauss-seidel"), out
