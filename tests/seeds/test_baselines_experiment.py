"""The baselines comparison (issue 37, item 2): experiments/baselines.toml and the
numbers of experiments/baselines.md.

The shipped manifest is one scenario of the page (kinematic vehicle, actuator a, the sine,
2.5 m/s) with one variant per law; experiments/figures/baselines.py rewrites it into the
others and tunes the laws. The test runs that scenario (6 runs of 30 s: a shortened
version of the 17 scenarios and the tuning grid) on the session-built FMUs and checks
that each law's row on the page is what the run gives, that the script's rewriting leaves
the shipped scenario as it is, and that the gains in the manifest are the best points of
the page's tuning table (slow: builds the component FMUs).
"""

import importlib.util
import re
import tomllib
from pathlib import Path

import pytest

from agv_cosim.pipeline import run_manifest

from manifests import assert_complete, fmus_by_model, localise

pytestmark = pytest.mark.seed

ROOT = Path(__file__).resolve().parents[2]
EXPERIMENTS = ROOT / "experiments"
SCENARIO = ("kin", "a", "sine", 2.5)


def _script():
    spec = importlib.util.spec_from_file_location(
        "baselines_figures", EXPERIMENTS / "figures" / "baselines.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_script_rewrites_the_shipped_scenario_into_itself(component_fmus, tmp_path):
    script = _script()
    fmus = fmus_by_model(component_fmus)
    base = script.load_base()
    data = script.scenario_manifest(base, *SCENARIO, fmus)
    shipped = tomllib.loads(localise(EXPERIMENTS / "baselines.toml", tmp_path,
                                     component_fmus).read_text())
    for key in ("name", "description"):
        data.pop(key), shipped.pop(key)
    assert data == shipped
    # and its TOML writer round-trips a manifest
    assert tomllib.loads(script.to_toml(data)) == data


def test_page_rows_of_the_shipped_scenario_are_what_it_gives(component_fmus, tmp_path):
    script = _script()
    manifest = localise(EXPERIMENTS / "baselines.toml", tmp_path, component_fmus)
    out, results, _ = run_manifest(manifest, tmp_path / "out", quiet=True)
    assert_complete(results, 6)
    rows = []
    for result in results:
        metrics = {k: repr(v) for k, v in result["metrics"].items()}
        row = {"scenario": script.label(*SCENARIO), "law": result["label"],
               "status": "complete", **metrics}
        rows.append({"scenario": row["scenario"], "law": row["law"],
                     **{k: metrics[k] for k in script.COLUMNS},
                     "cost": repr(script.cost(row))})
    page = (EXPERIMENTS / "baselines.md").read_text()
    lines = script.table_lines(rows)[2:]
    assert len(lines) == 6
    missing = [line for line in lines if line not in page]
    assert not missing, "rows not on experiments/baselines.md:\n" + "\n".join(missing)


def test_manifest_gains_are_the_best_points_of_the_page_tuning_table():
    script = _script()
    page = (EXPERIMENTS / "baselines.md").read_text()
    table = []
    for law, gains, mean in re.findall(r"^\| (\w+) \| ([\w=. ]+) \| [^\n]*\| ([\d.]+|inf) \|$",
                                       page, re.M):
        if law in script.LAWS:
            table.append({"law": law, "gains": gains, "mean_cost": mean})
    assert {row["law"] for row in table} == set(script.LAWS)
    assert len(table) == sum(
        len(list(_product(grid.values()))) for grid in script.GRIDS.values())
    base = tomllib.loads((EXPERIMENTS / "baselines.toml").read_text())
    for law, (gains, _) in script.best_gains(table).items():
        parameters = base["variants"][law]["components"]["ctrl"]["parameters"]
        for item in gains.split():
            name, value = item.split("=")
            assert parameters[name] == float(value), (law, name)


def _product(lists):
    import itertools

    return itertools.product(*lists)
