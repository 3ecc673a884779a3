"""docs/manifest.md against the schema: every key of every table is documented, every
documented key exists, the documented defaults are the schema's, and the example is a
manifest the schema accepts."""

import re
import tomllib
from pathlib import Path

import pytest
from pydantic_core import PydanticUndefined

from agv_cosim.manifest import manifest_from_data, schema

DOC = Path(__file__).resolve().parents[3] / "docs" / "manifest.md"

#: the page's section headings -> the schema's model of that table
SECTIONS = {
    "top level": schema.ManifestTable,
    "`[simulation]`": schema.Simulation,
    "`[components.<name>]`": schema.ComponentTable,
    "`[[connections]]`": schema.ConnectionTable,
    "`[events.<name>]`": schema.EventTable,
    "`[variants.<name>]`": schema.VariantTable,
    "`[record]`": schema.RecordTable,
    "`[metrics]`": schema.MetricsTable,
    "`[metrics.saturation]`": schema.Saturation,
    "`[metrics.reference]`": schema.Reference,
    "`[plots]`": schema.PlotsTable,
    "`[plots.trajectory]`": schema.Trajectory,
    "`[montecarlo]`": schema.MonteCarloTable,
    '`[montecarlo.parameters."<c.p>"]` normal': schema.Normal,
    '`[montecarlo.parameters."<c.p>"]` uniform': schema.Uniform,
    '`[montecarlo.parameters."<c.p>"]` truncnormal': schema.TruncNormal,
    '`[montecarlo.parameters."<c.p>"]` choice': schema.Choice,
    "`[tune]`": schema.TuneTable,
    '`[tune.parameters."<c.p>"]`': schema.Bounds,
    "`[fit]`": schema.FitTable,
    '`[fit.parameters."<c.p>"]`': schema.Bounds,
}


def _tables():
    """Heading -> {key: default column} of each table on the page."""
    tables, heading = {}, None
    for line in DOC.read_text().splitlines():
        if line.startswith("### "):
            heading = line[4:].strip()
            tables[heading] = {}
        cells = [cell.strip() for cell in line.split("|")[1:-1]]
        if heading is not None and len(cells) == 5 and re.fullmatch(r"`[^`]+`", cells[0]):
            tables[heading][cells[0].strip("`")] = cells[3]
    return tables


def test_every_table_of_the_schema_has_a_section():
    assert set(_tables()) == set(SECTIONS)


@pytest.mark.parametrize("heading", list(SECTIONS))
def test_every_key_and_default_is_the_schemas(heading):
    model, documented = SECTIONS[heading], _tables()[heading]
    fields = {field.alias or name: field for name, field in model.model_fields.items()}
    assert set(documented) == set(fields)
    for key, field in fields.items():
        text = documented[key]
        if field.is_required():
            assert text == "required", key
            continue
        assert text != "required", key
        default = field.default
        if default is PydanticUndefined or default is None or isinstance(default,
                                                                          schema.BaseModel):
            continue  # "-" or a phrase for what an absent table means
        if isinstance(default, (dict, list)) and not default:
            assert text == ("{}" if isinstance(default, dict) else "[]") or \
                text.strip("`") in ("{}", "[]"), key
            continue
        assert text.strip("`") == (f'"{default}"' if isinstance(default, str) else
                                   repr(default)), key


def test_the_example_is_a_valid_manifest():
    example = re.search(r"```toml\n(.*?)```", DOC.read_text(), re.S).group(1)
    manifest = manifest_from_data(tomllib.loads(example), DOC.parent / "demo.toml", "0")
    assert set(manifest.components) == {"veh", "ctl"}
    assert list(manifest.variants) == ["slow"]
