"""agv_cosim.schema: pydantic errors mapped onto one line ``<key>: <problem>`` (the key is
dotted, with [i] for array items and without pydantic's union tags), strict scalars."""
import pytest

from agv_cosim.manifest import ManifestError, manifest_from_data, schema

BASE = {"simulation": {"stop": 1.0, "step": 0.1}, "components": {"a": {"fmu": "a.fmu"}}}


def _error(**tables):
    with pytest.raises(ManifestError) as info:
        manifest_from_data({**BASE, **tables}, "m.toml", "0")
    text = str(info.value)
    assert "\n" not in text and text.startswith("m.toml: ")
    return text.removeprefix("m.toml: ")


@pytest.mark.parametrize("tables, message", [
    ({"zzz": 1}, "zzz: unknown key 'zzz' (allowed: name, description, simulation, components, "
                 "connections, held, variants, sweep, record, events, metrics, plots, montecarlo, "
                 "tune, fit)"),
    ({"simulation": {"stop": "1", "step": 0.1}}, "simulation.stop: '1' is not a number"),
    ({"simulation": {"stop": True, "step": 0.1}}, "simulation.stop: True is not a number"),
    ({"simulation": {"stop": float("inf"), "step": 0.1}}, "simulation.stop: inf is not finite"),
    ({"simulation": {"stop": 1.0, "step": 0.0}}, "simulation.step: 0.0 must be > 0"),
    ({"simulation": {"stop": 1.0, "step": 0.1, "algorithm": "rk4"}},
     "simulation.algorithm: 'rk4' is not one of gauss-seidel, jacobi"),
    ({"components": {"a": {"fmu": "a.fmu", "p": 1}}},
     "components.a.p: unknown key 'p' (allowed: fmu, parameters, table, interpolation, units, "
     "step, interface, solver, tolerance)"),
    ({"connections": [{"from": "a.x", "to": "a.y"}, {"from": "ax", "to": "a.y"}]},
     "connections[1].from: 'ax' is not of the form 'component.variable'"),
    ({"events": {"e": {"at": 0.1, "set": {"ax": 1}}}},
     "events.e.set.ax: 'ax' is not of the form 'component.variable'"),
    ({"metrics": {"reference": {"path": "", "x": "a.x", "y": "a.y"}}},
     "metrics.reference.path: expected a path string, got ''"),
    ({"plots": {"dpi": 120.5}}, "plots.dpi: 120.5 is not an integer"),
    ({"montecarlo": {"samples": 1, "seed": 1,
                     "parameters": {"a.p": {"distribution": "normal", "mean": 0, "std": 1,
                                            "s": 1}}}},
     "montecarlo.parameters.a.p.s: unknown key 's' (allowed: distribution, mean, std)"),
    ({"montecarlo": {"samples": 1, "seed": 1,
                     "parameters": {"a.p": {"distribution": "cauchy"}}}},
     "montecarlo.parameters.a.p.distribution: 'cauchy' is not one of normal, uniform, "
     "truncnormal, choice"),
    ({"montecarlo": {"samples": 1, "seed": 1,
                     "parameters": {"a.p": {"distribution": "uniform", "low": 1, "high": 1}}}},
     "montecarlo.parameters.a.p.high: 1.0 must be > low (1.0)"),
])
def test_errors_name_the_dotted_key(tables, message):
    assert _error(**tables) == message


def _errors(data):
    """Every problem of ``data`` as a manifest, ``<key>: <problem>`` each."""
    with pytest.raises(ManifestError) as info:
        manifest_from_data(data, "m.toml", "0")
    return [line.removeprefix("m.toml: ") for line in info.value.lines()]


@pytest.mark.parametrize("data, message", [
    # a misspelt section or key is named as unknown, with the closest valid name; the
    # "missing" it causes is not reported
    ({"simulaton": {"stop": 1.0, "step": 0.1}, "components": {"a": {"fmu": "a.fmu"}}},
     "simulaton: unknown section 'simulaton' (did you mean 'simulation'?)"),
    ({**BASE, "simulation": {"stp": 1.0, "step": 0.1}},
     "simulation.stp: unknown key 'stp' (did you mean 'stop'?)"),
    ({**BASE, "conections": [{"from": "a.x", "to": "a.y"}]},
     "conections: unknown section 'conections' (did you mean 'connections'?)"),
    ({**BASE, "components": {"a": {"fmuu": "a.fmu"}}},
     "components.a.fmuu: unknown key 'fmuu' (did you mean 'fmu'?)"),
    ({**BASE, "connections": [{"frm": "a.x", "to": "a.y"}]},
     "connections[0].frm: unknown key 'frm' (did you mean 'from'?)"),
    ({**BASE, "simulation": {"stop": 1.0, "step": 0.1, "algorithm": "gauss-siedel"}},
     "simulation.algorithm: 'gauss-siedel' is not one of gauss-seidel, jacobi (did you "
     "mean 'gauss-seidel'?)"),
])
def test_misspellings_say_did_you_mean(data, message):
    assert _errors(data) == [message]


def test_every_schema_problem_is_reported_once():
    data = {"simulation": {"stp": 1.0, "step": -0.1, "algorithm": "fast"},
            "components": {"a": {"fmu": 1}}, "zzz": 1}
    # in the schema's order (a manifest file's problems are sorted by line)
    assert _errors(data) == [
        "simulation.step: -0.1 must be > 0",
        "simulation.algorithm: 'fast' is not one of gauss-seidel, jacobi",
        "simulation.stp: unknown key 'stp' (did you mean 'stop'?)",
        "components.a.fmu: 1 is not a string",
        "zzz: unknown key 'zzz' (allowed: name, description, simulation, components, "
        "connections, held, variants, sweep, record, events, metrics, plots, montecarlo, "
                 "tune, fit)",
    ]
    # a missing key with no misspelt neighbour is still reported as missing
    assert _errors({"simulation": {"step": 0.1}, "components": {"a": {"fmu": "a"}},
                    "zzz": 1})[0] == "simulation.stop: missing"


def test_problems_are_capped():
    components = {f"c{i}": {"fmu": i} for i in range(30)}
    lines = _errors({"simulation": {"stop": 1.0, "step": 0.1}, "components": components})
    assert len(lines) == 20
    assert lines[:19] == [f"components.c{i}.fmu: {i} is not a string" for i in range(19)]
    assert lines[19] == "11 more problem(s) not shown"


def test_ints_are_numbers_and_defaults_fill_in():
    manifest = manifest_from_data({**BASE, "simulation": {"stop": 1, "step": 0.5}},
                                  "m.toml", "0")
    assert (manifest.start, manifest.stop, manifest.step) == (0.0, 1.0, 0.5)
    assert type(manifest.stop) is float and manifest.algorithm == "gauss-seidel"
    spec = schema.check(schema.MetricsTable, {"saturation": {"signal": "a.u", "limit": 2}},
                        "metrics").spec()
    assert spec == {"settle_band": 0.02,
                    "saturation": {"signal": "a.u", "limit": 2.0, "tolerance": 2e-9}}


def test_a_table_checked_alone_is_prefixed():
    with pytest.raises(schema.SchemaError) as info:
        schema.check(schema.PlotsTable, {"trajectory": {"x": "v.x"}}, "plots")
    assert (info.value.key, info.value.problem) == ("plots.trajectory.y", "missing")
