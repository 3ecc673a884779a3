"""``agv-cosim examples DIR``: the shipped manifests, pointed at the built FMUs, never over a
user's file."""

import json
import tomllib
from pathlib import Path

import pytest

from agv_cosim import cli
from agv_cosim.build import examples as examples_module
from agv_cosim.build.examples import RECORD, ExamplesError, copy_examples
from agv_cosim.build.shipped import shipped_dir
from agv_cosim.manifest import load_manifest

EXPERIMENTS = Path(__file__).resolve().parents[2] / "experiments"


def fmu_paths(data):
    """Every component's ``fmu`` value of a parsed manifest (variants too)."""
    tables = list((data.get("components") or {}).values())
    for variant in (data.get("variants") or {}).values():
        tables += list(((variant or {}).get("components") or {}).values())
    return [t["fmu"] for t in tables if "fmu" in t]


def without_fmus(data):
    return json.loads(json.dumps(data), object_hook=lambda d: {
        k: v for k, v in d.items() if k != "fmu"})


def test_the_checkout_ships_its_experiments_folder():
    assert shipped_dir("experiments") == EXPERIMENTS
    assert (shipped_dir("fmu_loader") / "agv_fmu_loader.c").is_file()


def test_every_shipped_manifest_is_copied_pointing_at_the_fmu_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    written = copy_examples("ex", "fmus")
    shipped = sorted(p.name for p in EXPERIMENTS.glob("*.toml"))
    assert sorted(p.name for p in written) == shipped
    for name in shipped:
        original = tomllib.loads((EXPERIMENTS / name).read_text())
        copy = tomllib.loads((tmp_path / "ex" / name).read_text())
        assert fmu_paths(copy) == ["../fmus/" + Path(p).name for p in fmu_paths(original)]
        assert without_fmus(copy) == without_fmus(original)  # nothing else changed
        manifest = load_manifest(tmp_path / "ex" / name)
        for component in manifest.components.values():
            if component.fmu is not None:
                assert component.fmu.parent == tmp_path / "fmus"
    # the comments stay: the copy differs from the original in FMU paths only
    text = (tmp_path / "ex" / "seed000_models_abc.toml").read_text()
    assert text == (EXPERIMENTS / "seed000_models_abc.toml").read_text()  # ../fmus either way


def test_fmu_folder_relative_to_the_copy_or_absolute(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    copy_examples("deep/er", "built/fmi2")
    data = tomllib.loads((tmp_path / "deep/er/example.toml").read_text())
    assert fmu_paths(data) == ["../../built/fmi2/AgvVehicle.fmu"]
    copy_examples("abs", str(tmp_path / "fmus3"))
    data = tomllib.loads((tmp_path / "abs/example.toml").read_text())
    assert fmu_paths(data) == [f"{(tmp_path / 'fmus3').as_posix()}/AgvVehicle.fmu"]


def test_a_users_file_is_never_replaced(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    folder = tmp_path / "ex"
    folder.mkdir()
    (folder / "seed002_sine.toml").write_text("mine\n")
    assert cli.main(["examples", "ex"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "seed002_sine.toml" in err and "nothing" in err
    assert (folder / "seed002_sine.toml").read_text() == "mine\n"
    assert sorted(p.name for p in folder.iterdir()) == ["seed002_sine.toml"]  # nothing else


def test_its_own_unchanged_copies_are_replaced_changed_ones_are_not(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    copy_examples("ex", "fmus")
    copy_examples("ex", "fmus")  # the same again: fine
    copy_examples("ex", "other")  # its own files, unchanged: replaced
    assert fmu_paths(tomllib.loads((tmp_path / "ex/example.toml").read_text())) == [
        "../other/AgvVehicle.fmu"]
    record = json.loads((tmp_path / "ex" / RECORD).read_text())["written"]
    assert set(record) == {p.name for p in EXPERIMENTS.glob("*.toml")}
    with open(tmp_path / "ex/example.toml", "a") as handle:
        handle.write("# my note\n")
    with pytest.raises(ExamplesError, match="example.toml"):
        copy_examples("ex", "fmus")
    assert (tmp_path / "ex/example.toml").read_text().endswith("# my note\n")
    assert "../other/" in (tmp_path / "ex/seed000_speed.toml").read_text()  # untouched


def test_a_folder_that_is_a_file_or_a_foreign_record_is_refused(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("x")
    with pytest.raises(ExamplesError, match="not a folder"):
        copy_examples("afile")
    (tmp_path / "ex").mkdir()
    (tmp_path / "ex" / RECORD).write_text("my own notes\n")
    with pytest.raises(ExamplesError, match="not a record"):
        copy_examples("ex")
    assert (tmp_path / "ex" / RECORD).read_text() == "my own notes\n"


def test_files_a_manifest_refers_to_are_copied_beside_it(tmp_path, monkeypatch):
    """A table component's CSV and a waypoint file (the shipped manifests use none today;
    the copy must keep any that a future one uses)."""
    shipped = tmp_path / "shipped"
    (shipped / "data").mkdir(parents=True)
    (shipped / "data" / "steer.csv").write_text("time,alpha\n0,0\n1,0.1\n")
    (shipped / "pts.csv").write_text("x,y\n0,0\n1,1\n")
    (shipped / "t.toml").write_text(
        '[simulation]\nstop = 1.0\nstep = 0.1\n'
        '[components.replay]\ntable = "data/steer.csv"\n'
        '[components.sensor]\nfmu = "../fmus/AgvVisionSensor.fmu"\n'
        'parameters = { path = "waypoints:file=pts.csv" }\n')
    monkeypatch.setattr(examples_module, "shipped_dir", lambda kind: shipped)
    monkeypatch.chdir(tmp_path)
    copy_examples("ex")
    assert (tmp_path / "ex/data/steer.csv").read_text() == "time,alpha\n0,0\n1,0.1\n"
    assert (tmp_path / "ex/pts.csv").read_text() == "x,y\n0,0\n1,1\n"
    (shipped / "t.toml").write_text('[components.a]\ntable = "../outside.csv"\n')
    (tmp_path / "outside.csv").write_text("time,a\n0,0\n")
    with pytest.raises(ExamplesError, match="not shipped beside it"):
        copy_examples("ex2")
    assert not (tmp_path / "ex2").exists()


def test_a_manifest_whose_fmu_paths_cannot_be_rewritten_is_refused(tmp_path, monkeypatch):
    shipped = tmp_path / "shipped"
    shipped.mkdir()
    (shipped / "t.toml").write_text("[components.a]\nfmu = '../fmus/A.fmu'\n")  # literal
    monkeypatch.setattr(examples_module, "shipped_dir", lambda kind: shipped)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ExamplesError, match="cannot be rewritten safely"):
        copy_examples("ex", "elsewhere")


def test_a_folder_reached_through_a_link_gets_paths_from_its_real_place(tmp_path,
                                                                       monkeypatch):
    """``examples lnk/sub`` with lnk a link to a folder at another depth: the FMU path is
    computed between real folders (the system resolves ``..`` from where the manifest
    really is), so the copy names the FMU folder given; also a --fmus through a link."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "a" / "b" / "real").mkdir(parents=True)
    (tmp_path / "lnk").symlink_to(tmp_path / "a" / "b" / "real")
    (tmp_path / "fmus").mkdir()
    copy_examples("lnk/sub", "fmus")
    manifest = load_manifest(tmp_path / "lnk" / "sub" / "example.toml")
    assert manifest.components["vehicle"].fmu.resolve() == tmp_path / "fmus" / "AgvVehicle.fmu"
    (tmp_path / "deep" / "er").mkdir(parents=True)
    (tmp_path / "fl").symlink_to(tmp_path / "deep" / "er")
    copy_examples("ex", "fl/built")
    manifest = load_manifest(tmp_path / "ex" / "example.toml")
    assert (manifest.components["vehicle"].fmu.resolve()
            == tmp_path / "deep" / "er" / "built" / "AgvVehicle.fmu")
