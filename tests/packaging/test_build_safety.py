"""``agv-cosim build`` writes like ``run``: each FMU a new file of its own (O_EXCL |
O_NOFOLLOW) renamed in, never through a link, and only over an FMU it wrote itself (its
build record, ``build-index.json``); ``build NAME...`` builds only the named components.

The refusals are checked before anything is built, so those tests build nothing (the
fast tier); the tests that build use the small test FMU of ``tests/fmu_src``."""

import json
import os
import re
import zipfile

import pytest

from agv_cosim import cli
from agv_cosim.build import (
    INDEX_FILE,
    build_fmus,
    component_scripts,
    default_components_dir,
    slave_script,
)
from agv_cosim.errors import OutputError

GAIN = default_components_dir().parent / "tests" / "fmu_src" / "agv_test_gain.py"
#: every kind of build: (--fmi, --standalone)
KINDS = [(["--fmi", "2"], False), (["--fmi", "3"], False), (["--fmi", "2"], True),
         (["--fmi", "3"], True)]


def _refused(capsys, argv):
    """``agv-cosim argv`` exits 2 with one error line on stderr; that line."""
    code = cli.main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    errors = [line for line in err if line.startswith("agv-cosim: error: ")]
    assert code == 2, err
    assert len(errors) == 1 and "Traceback" not in "\n".join(err), err
    return errors[0]


def _kind_args(kind):
    fmi, standalone = kind
    return [*fmi, *(["--standalone"] if standalone else [])]


@pytest.mark.parametrize("kind", KINDS)
def test_a_users_file_at_an_fmus_place_is_refused_before_building(tmp_path, capsys, kind):
    out = tmp_path / "x"
    out.mkdir()
    (out / "AgvVehicle.fmu").write_bytes(b"my own FMU\n")
    line = _refused(capsys, ["build", "AgvVehicle", "--out", str(out), *_kind_args(kind)])
    assert str(out / "AgvVehicle.fmu") in line and "not written by agv-cosim build" in line
    assert (out / "AgvVehicle.fmu").read_bytes() == b"my own FMU\n"
    assert sorted(os.listdir(out)) == ["AgvVehicle.fmu"]  # nothing built, no record


@pytest.mark.parametrize("kind", KINDS)
def test_a_symbolic_link_at_an_fmus_place_is_refused(tmp_path, capsys, kind):
    out = tmp_path / "x"
    out.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    (out / "AgvVehicle.fmu").symlink_to(victim)
    line = _refused(capsys, ["build", "agv_vehicle", "--out", str(out), *_kind_args(kind)])
    assert str(out / "AgvVehicle.fmu") in line and "symbolic link" in line
    assert victim.read_text() == "precious\n" and (out / "AgvVehicle.fmu").is_symlink()


def test_a_record_that_is_a_link_or_not_a_record_is_refused(tmp_path, capsys):
    out = tmp_path / "x"
    out.mkdir()
    victim = tmp_path / "victim.json"
    victim.write_text("{}\n")
    (out / INDEX_FILE).symlink_to(victim)
    line = _refused(capsys, ["build", "AgvVehicle", "--out", str(out)])
    assert INDEX_FILE in line and "symbolic link" in line
    (out / INDEX_FILE).unlink()
    (out / INDEX_FILE).write_text("my notes\n")
    line = _refused(capsys, ["build", "AgvVehicle", "--out", str(out)])
    assert INDEX_FILE in line and "not a build record" in line
    assert (out / INDEX_FILE).read_text() == "my notes\n" and victim.read_text() == "{}\n"


@pytest.mark.slow
def test_a_link_at_the_old_temporary_name_is_neither_followed_nor_kept(tmp_path):
    """The FMU goes into a new file of the build's own (``.<name>.<random>.fmu.partial``,
    created with O_EXCL | O_NOFOLLOW) renamed onto its place: a link at the name the
    build used before (``AgvTestGain.fmu.partial``) is left as it is, its target
    unchanged, and the FMU is a regular file."""
    out = tmp_path / "x"
    out.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    (out / "AgvTestGain.fmu.partial").symlink_to(victim)
    fmu = build_fmus(out, [GAIN])[0].fmu
    assert victim.read_text() == "precious\n"
    assert not fmu.is_symlink() and zipfile.is_zipfile(fmu)
    assert sorted(os.listdir(out)) == ["AgvTestGain.fmu", "AgvTestGain.fmu.partial",
                                       INDEX_FILE]
    record = json.loads((out / INDEX_FILE).read_text())
    assert record["agv_test_gain.py"]["fmu"] == "AgvTestGain.fmu"


@pytest.mark.slow
def test_its_own_fmus_are_replaced_changed_ones_are_not(tmp_path):
    out = tmp_path / "x"
    first = build_fmus(out, [GAIN])[0]
    again = build_fmus(out, [GAIN], force=True)[0]  # its own, unchanged: replaced
    assert again.rebuilt and zipfile.is_zipfile(again.fmu)
    with open(again.fmu, "ab") as stream:  # changed since: no longer the file it wrote
        stream.write(b"x")
    changed = again.fmu.read_bytes()
    with pytest.raises(OutputError, match="AgvTestGain.fmu: exists and was not written"):
        build_fmus(out, [GAIN], force=True)
    assert first.fmu.read_bytes() == changed


@pytest.mark.slow
def test_a_record_of_the_earlier_format_still_names_its_fmus(tmp_path):
    """``build-index.json`` as builds before the record held hashes wrote it (script ->
    file name): an FMU of agv-cosim build of that script is its own; a user's file is
    not."""
    out = tmp_path / "x"
    build_fmus(out, [GAIN])
    (out / INDEX_FILE).write_text(json.dumps({"agv_test_gain.py": "AgvTestGain.fmu"}))
    assert build_fmus(out, [GAIN], force=True)[0].rebuilt
    (out / INDEX_FILE).write_text(json.dumps({"agv_test_gain.py": "AgvTestGain.fmu"}))
    (out / "AgvTestGain.fmu").write_bytes(b"PK mine")
    with pytest.raises(OutputError, match="not written by agv-cosim build"):
        build_fmus(out, [GAIN], force=True)
    assert (out / "AgvTestGain.fmu").read_bytes() == b"PK mine"


def test_build_names_select_components_in_any_spelling():
    assert component_scripts(["AgvVehicle", "agv_gyro.py", "AgvVehicle.fmu"]) == [
        slave_script("agv_vehicle"), slave_script("agv_gyro")]


@pytest.mark.parametrize("extra", [[], ["--fmi", "3"], ["--standalone"]])
def test_an_unknown_component_name_lists_the_valid_ones(tmp_path, capsys, extra):
    line = _refused(capsys, ["build", "AgvVehicel", "--out", str(tmp_path / "x"), *extra])
    assert "no component 'AgvVehicel'" in line and "did you mean 'AgvVehicle'" in line
    assert "valid names: AgvAckermann, " in line and "AgvVisionSensor" in line
    assert not (tmp_path / "x").exists()


@pytest.mark.slow
def test_build_names_build_only_those_with_progress(tmp_path, capsys):
    out = tmp_path / "x"
    assert cli.main(["build", "AgvGyro", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert captured.err.splitlines() == ["agv-cosim build: [1/1] agv_gyro.py ..."]
    assert re.fullmatch(r".*AgvGyro\.fmu  built \(\d+\.\d s\)\n", captured.out)
    assert sorted(os.listdir(out)) == ["AgvGyro.fmu", INDEX_FILE]
    assert cli.main(["build", "agv_gyro", "--out", str(out)]) == 0
    assert "AgvGyro.fmu  up to date" in capsys.readouterr().out
