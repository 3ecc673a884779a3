"""An FMU is read and unpacked within bounds (agv_cosim.archive.FMU_LIMITS): its headers
are checked when its model description is read (system.model.read_model: before the CRC
test and fmpy's parse), and its entries are streamed with a byte budget when an instance
unpacks it (execution.instance._unzip); a refused FMU leaves nothing unpacked."""

import zipfile

import pytest

from agv_cosim import cli
from agv_cosim.archive import FMU_LIMITS, Limits
from agv_cosim.errors import ArchiveRefused, ModelError
from agv_cosim.execution import instance
from agv_cosim.files import XML_LIMIT
from agv_cosim.system import model

from zips import MiB, set_declared_size, zeros_archive

DESCRIPTION = b'<?xml version="1.0"?>\n<fmiModelDescription fmiVersion="2.0"/>\n'

MANIFEST = """
name = "bounded"
[simulation]
stop = 0.1
step = 0.01
[components.bomb]
fmu = "{fmu}"
"""


def _bomb(path, size=64 * MiB):
    return zeros_archive(path, size, "resources/zeros.bin",
                         {"modelDescription.xml": DESCRIPTION})


def test_an_fmu_expanding_beyond_the_limit_is_refused_in_one_line(tmp_path, monkeypatch,
                                                                   capsys):
    assert FMU_LIMITS == Limits(size=4 << 30, entries=20_000)
    monkeypatch.setattr(model, "FMU_LIMITS", Limits(size=16 * MiB, entries=100))
    fmu = _bomb(tmp_path / "Bomb.fmu")
    with pytest.raises(ModelError, match=f"FMU '{fmu}': refused: its entries expand to "
                       r"67108926 bytes \(64 MiB\), more than the limit of 16 MiB"):
        model.read_model(fmu)
    path = tmp_path / "bounded.toml"
    path.write_text(MANIFEST.format(fmu=fmu))
    assert cli.main(["validate", str(path), "--no-init"]) == 2
    [line] = capsys.readouterr().err.strip().splitlines()
    assert "components.bomb.fmu" in line and "more than the limit of 16 MiB" in line


def test_a_model_description_larger_than_xml_limit_is_refused_unread(tmp_path):
    fmu = tmp_path / "Big.fmu"
    with zipfile.ZipFile(fmu, "w", zipfile.ZIP_DEFLATED) as out:
        out.writestr("modelDescription.xml", DESCRIPTION)
    set_declared_size(fmu, "modelDescription.xml", XML_LIMIT + 1)
    with pytest.raises(ModelError, match=f"refused: modelDescription.xml is more than "
                       f"{XML_LIMIT} bytes"):
        model.read_model(fmu)


def test_unpacking_an_fmu_is_bounded_and_leaves_nothing(tmp_path, monkeypatch):
    liar = tmp_path / "Liar.fmu"
    with zipfile.ZipFile(liar, "w", zipfile.ZIP_DEFLATED) as out:
        out.writestr("modelDescription.xml", DESCRIPTION)
        out.writestr("binaries/linux64/x.so", bytes(4 * MiB))
    set_declared_size(liar, "binaries/linux64/x.so", 100)
    dest = tmp_path / "dest"
    dest.mkdir()
    with pytest.raises(ArchiveRefused, match="entry 'binaries/linux64/x.so' does not match "
                       "its header"):
        instance._unzip(liar, str(dest))
    assert list(dest.iterdir()) == []

    monkeypatch.setattr(instance, "FMU_LIMITS", Limits(size=16 * MiB, entries=100))
    with pytest.raises(ArchiveRefused, match="more than the limit of 16 MiB"):
        instance._unzip(_bomb(tmp_path / "Bomb.fmu"), str(dest))
    assert list(dest.iterdir()) == []

    fine = _bomb(tmp_path / "Fine.fmu", 2 * MiB)
    instance._unzip(fine, str(dest))
    assert (dest / "modelDescription.xml").read_bytes() == DESCRIPTION
    assert (dest / "resources" / "zeros.bin").read_bytes() == bytes(2 * MiB)
