"""The typed plan: a manifest's variants and events as :class:`Variant` and
:class:`EventSpec` values, each :class:`RunSpec` saying where every parameter value came
from, and ``--set`` given as typed values by the API used as they are (no text round
trip). Nothing here opens an FMU (the FMU files named need not exist)."""

import dataclasses

import numpy as np
import pytest

from agv_cosim import api
from agv_cosim.errors import ManifestError
from agv_cosim.manifest import EventSpec, Variant, load_manifest
from agv_cosim.plan import Origin, Override, plan_runs

MANIFEST = """
[simulation]
stop = 1.0
step = 0.1

[components.src]
fmu = "Src.fmu"
parameters = { k = 1.0, m = 2.0, name = "a", sampled = 0.0 }

[components.sink]
fmu = "Sink.fmu"
parameters = { gain = 3.0 }

[[connections]]
from = "src.y"
to = "sink.u"

[events.kick]
at = 0.5
set = { "src.k" = 9.0 }

[variants.v]
description = "changes m, the kick's time, adds an event and a component"
[variants.v.components.src]
parameters = { m = 5.0 }
[variants.v.components.extra]
fmu = "Extra.fmu"
parameters = { p = 1 }
[variants.v.events.kick]
at = 0.3
[variants.v.events.late]
at = 0.8
set = { "sink.gain" = 4.0 }

[sweep]
"sink.gain" = [3.0, 6.0]
"""

MONTECARLO = """
[montecarlo]
samples = 2
seed = 7
seeds = ["extra.p"]
[montecarlo.parameters]
"src.sampled" = { distribution = "uniform", low = 0.0, high = 1.0 }
"""


@pytest.fixture
def manifest(tmp_path):
    def write(extra=""):
        path = tmp_path / "m.toml"
        path.write_text(MANIFEST + extra)
        return load_manifest(path)
    return write


def test_variants_and_events_are_frozen_typed_values(manifest):
    loaded = manifest()
    variant = loaded.variants["v"]
    assert isinstance(variant, Variant)
    assert variant.name == "v" and variant.new == ("extra",) and variant.remove == ()
    assert variant.events == {"kick": EventSpec(at=0.3, set=None),
                              "late": EventSpec(at=0.8, set={"sink.gain": 4.0})}
    assert [str(c) for c in variant.connections] == ["src.y -> sink.u"]
    assert loaded.events == {"kick": EventSpec(at=0.5, set={"src.k": 9.0})}
    with pytest.raises(dataclasses.FrozenInstanceError):
        variant.description = "x"  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        loaded.events["kick"].at = 1.0  # type: ignore[misc]


def test_each_parameter_value_says_where_it_came_from(manifest):
    runs = plan_runs(manifest(MONTECARLO), sets=["src.k=7.0"])
    run = next(r for r in runs if r.variant == "v" and r.point["sink.gain"] == 6.0)
    assert run.origins == {
        "src.k": Origin.SET, "src.m": Origin.VARIANT, "src.name": Origin.MANIFEST,
        "src.sampled": Origin.MONTECARLO, "sink.gain": Origin.SWEEP,
        "extra.p": Origin.MONTECARLO}
    assert run.components["src"].parameters["m"] == 5.0
    assert [run.parameter_key(*name.split(".")) for name in run.origins] == [
        "--set", "variants.v.components.src.parameters.m", "components.src.parameters.name",
        "montecarlo.parameters.src.sampled", "sweep.sink.gain",
        "montecarlo.parameters.extra.p"]
    assert run.spec is not None and run.spec.name == "v"
    assert run.component_key("extra") == "variants.v.components.extra.fmu"
    assert run.component_key("src") == "components.src.fmu"  # the variant keeps the FMU
    base = plan_runs(manifest(), ["v"])[0]
    assert base.origins["src.k"] is Origin.MANIFEST


def test_a_run_merges_its_variants_events_into_its_own_copies(manifest):
    loaded = manifest()
    runs = plan_runs(loaded, sets=["events.kick.set.src.m=1.5"])
    assert runs[0].events == {"kick": EventSpec(at=0.3, set={"src.k": 9.0, "src.m": 1.5}),
                              "late": EventSpec(at=0.8, set={"sink.gain": 4.0})}
    runs[0].events["kick"].set["src.k"] = -1.0  # type: ignore[index]
    assert runs[1].events["kick"].set == {"src.k": 9.0, "src.m": 1.5}
    assert loaded.events["kick"].set == {"src.k": 9.0}


@pytest.mark.parametrize("value, expected", [
    ("\U0001F600 \u00e9", "\U0001F600 \u00e9"),   # formatted as JSON text it was not TOML
    (np.float64(0.25), 0.25),                      # its repr is no TOML number
    ((1, 2.5, [True]), [1, 2.5, [True]]),
    (float("nan"), None),
])
def test_the_apis_typed_sets_reach_the_run_as_given(manifest, value, expected):
    sets = api._set_items({"src.name": value})
    assert sets == [Override("src.name", sets[0].value)]  # typed once, at the edge
    got = plan_runs(manifest(), ["v"], sets)[0].components["src"].parameters["name"]
    if expected is None:
        assert isinstance(got, float) and got != got
    else:
        assert got == expected and type(got) is type(expected)


def test_a_typed_set_is_checked_as_its_text_is(manifest):
    loaded = manifest()
    deep: list = [1.0]
    for _ in range(40):
        deep = [deep]
    for name, value in (("src.k", deep), ("srck", 1.0), ("events.nope.at", 1.0)):
        with pytest.raises(ManifestError) as typed:
            plan_runs(loaded, sets=[Override(name, value)])
        text = f"{name}={value!r}".replace("'", "")
        with pytest.raises(ManifestError) as parsed:
            plan_runs(loaded, sets=[text])
        assert str(typed.value) == str(parsed.value)
