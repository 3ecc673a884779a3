"""SSP import unpacks an archive within bounds (agv_cosim.archive, ssp.importer.safe_extract).

Hostile archives: a deflate bomb (refused from its headers), too many entries (refused
from the end record, before the central directory is parsed), a header that lies about
an entry's size (refused while writing), a compression method FMI/SSP do not allow;
each refused in one line naming the archive, with nothing left of what was unpacked and
nothing of the user's touched. A normal package unpacks byte for byte.
"""

import io
import os
import tempfile
import zipfile
from pathlib import Path

import pytest

from agv_cosim import archive, cli
from agv_cosim.archive import ArchiveRefused, Limits
from agv_cosim.ssp import importer
from agv_cosim.ssp.common import SspError

from zips import MiB, set_declared_size, zeros_archive

SSD = b'<?xml version="1.0"?>\n<x/>\n'


def _bomb(path, size):
    """A package whose entry resources/zeros.bin is ``size`` bytes of zeros, deflated."""
    return zeros_archive(path, size, "resources/zeros.bin", {"SystemStructure.ssd": SSD})


def _one_line_refusal(error, path, reason):
    text = str(error)
    assert "\n" not in text
    assert text.startswith(f"{path}: archive: refused: "), text
    assert reason in text, text


def _tree(folder):
    return sorted(str(p.relative_to(folder)) for p in Path(folder).rglob("*"))


def test_deflate_bomb_is_refused_from_its_headers(tmp_path):
    bomb = _bomb(tmp_path / "bomb.ssp", 64 * MiB)
    assert bomb.stat().st_size < MiB
    dest = tmp_path / "dest"
    dest.mkdir()
    with pytest.raises(SspError) as caught:
        importer.safe_extract(bomb, dest, Limits(size=16 * MiB, entries=100))
    _one_line_refusal(caught.value, bomb, "expand to 67108891 bytes (64 MiB), more than "
                      "the limit of 16 MiB")
    assert _tree(dest) == []


def test_default_limit_refuses_headers_declaring_more_than_4_gib(tmp_path):
    """Two entries of 10 bytes whose headers declare 0xFFFFFFF0 bytes each (8 GiB): the
    default SSP limit (4 GiB) refuses the archive before writing anything."""
    path = tmp_path / "huge.ssp"
    with zipfile.ZipFile(path, "w") as out:
        out.writestr("a.bin", b"0123456789")
        out.writestr("b.bin", b"0123456789")
    for name in ("a.bin", "b.bin"):
        set_declared_size(path, name, 0xFFFFFFF0)
    dest = tmp_path / "dest"
    dest.mkdir()
    with pytest.raises(SspError) as caught:
        importer.safe_extract(path, dest)
    _one_line_refusal(caught.value, path, "more than the limit of 4 GiB")
    assert _tree(dest) == []
    assert archive.SSP_LIMITS == Limits(size=4 << 30, entries=10_000)


def test_too_many_entries_refused_before_the_directory_is_read(tmp_path, monkeypatch):
    path = tmp_path / "many.ssp"
    with zipfile.ZipFile(path, "w") as out:
        for i in range(101):
            out.writestr(f"e{i}", b"")
    dest = tmp_path / "dest"
    dest.mkdir()

    def no_parse(*args, **kwargs):
        raise AssertionError("the central directory was parsed")

    monkeypatch.setattr(zipfile, "ZipFile", no_parse)
    with pytest.raises(SspError) as caught:
        importer.safe_extract(path, dest, Limits(size=MiB, entries=100))
    _one_line_refusal(caught.value, path, "101 entries, more than the limit of 100")
    assert _tree(dest) == []


def test_a_central_directory_larger_than_the_limit_allows_is_refused_unread(tmp_path,
                                                                          monkeypatch):
    """An end record that understates the entry count cannot make zipfile parse a huge
    central directory: its declared size is bounded too (1 KiB per entry of the limit)."""
    path = tmp_path / "long.ssp"
    with zipfile.ZipFile(path, "w") as out:
        for i in range(40):
            out.writestr(f"{i:03d}" + "n" * 3000, b"")
    data = bytearray(path.read_bytes())
    at = data.rfind(b"PK\x05\x06")
    data[at + 8:at + 12] = (1).to_bytes(2, "little") * 2  # "1 entry"
    path.write_bytes(bytes(data))
    with open(path, "rb") as stream:
        assert archive.declared_entries(stream) == 1
    monkeypatch.setattr(zipfile, "ZipFile", None)  # never reached
    with open(path, "rb") as stream, pytest.raises(
            ArchiveRefused, match=f"central directory is {40 * (46 + 3003)} bytes, more than "
            "1024 per entry of the limit of 100 entries"):
        archive.open_bounded(stream, path, Limits(size=MiB, entries=100))


def test_entry_count_of_a_zip64_end_record(tmp_path):
    """More than 65535 entries: the count is the ZIP64 end record's."""
    path = tmp_path / "zip64.zip"
    with zipfile.ZipFile(path, "w") as out:
        for i in range(65_540):
            out.writestr(zipfile.ZipInfo(f"{i}"), b"")
    with open(path, "rb") as stream:
        assert archive.declared_entries(stream) == 65_540
    with open(path, "rb") as stream, pytest.raises(ArchiveRefused, match="65540 entries"):
        archive.open_bounded(stream, path, archive.SSP_LIMITS)


def test_header_that_lies_about_its_size_is_refused_while_writing(tmp_path):
    """The entry holds 8 MiB of zeros, its headers say 1000 bytes: nothing beyond the
    declared size is written, the archive is refused, and what was written is removed
    (the files written before it too)."""
    path = tmp_path / "liar.ssp"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as out:
        out.writestr("SystemStructure.ssd", SSD)
        out.writestr("resources/a/first.bin", b"x" * 5000)
        out.writestr("resources/b/liar.bin", bytes(8 * MiB))
    set_declared_size(path, "resources/b/liar.bin", 1000)
    with zipfile.ZipFile(path) as check:  # the headers pass the checks
        archive.check_entries(check.infolist(), Limits(size=MiB, entries=10))
    dest = tmp_path / "dest"
    dest.mkdir()
    with pytest.raises(SspError) as caught:
        importer.safe_extract(path, dest, Limits(size=MiB, entries=10))
    _one_line_refusal(caught.value, path, "entry 'resources/b/liar.bin' does not match "
                      "its header")
    assert _tree(dest) == []


def test_an_entry_is_never_written_beyond_its_declared_size(tmp_path):
    """The byte budget itself (whatever the zip reader returns): a source giving more
    than the header declares is refused before the excess is written."""
    unpacking = archive._Unpacking("x.ssp", tmp_path, Limits(size=MiB, entries=10))
    info = zipfile.ZipInfo("e.bin")
    info.file_size = 10
    out = io.BytesIO()
    source = io.BytesIO(b"y" * (archive.CHUNK + 5))
    with pytest.raises(ArchiveRefused, match="holds more than the 10 bytes its header"):
        unpacking.copy(source, out, info)
    assert out.getvalue() == b""
    unpacking = archive._Unpacking("x.ssp", tmp_path, Limits(size=15, entries=10))
    info.file_size = 10
    unpacking.copy(io.BytesIO(b"z" * 10), out, info)
    with pytest.raises(ArchiveRefused, match="expands to more than the limit of 15"):
        unpacking.copy(io.BytesIO(b"z" * 10), out, info)
    assert out.getvalue() == b"z" * 10


def test_compression_other_than_stored_or_deflate_is_refused(tmp_path):
    path = tmp_path / "bz.ssp"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_BZIP2) as out:
        out.writestr("SystemStructure.ssd", SSD)
    dest = tmp_path / "dest"
    dest.mkdir()
    with pytest.raises(SspError) as caught:
        importer.safe_extract(path, dest)
    _one_line_refusal(caught.value, path, "compressed with method 12 (only stored and "
                      "deflate are allowed)")
    assert _tree(dest) == []


def test_nothing_of_the_user_is_written_over(tmp_path):
    work = tmp_path / "work"
    (work / "package").mkdir(parents=True)
    mine = work / "package" / "SystemStructure.ssd"
    mine.write_bytes(b"the user's own")
    path = tmp_path / "p.ssp"
    with zipfile.ZipFile(path, "w") as out:
        out.writestr("resources/r.bin", b"r")
        out.writestr("SystemStructure.ssd", SSD)
    with pytest.raises(SspError) as caught:
        importer.load_ssp(path, work)
    _one_line_refusal(caught.value, path, "entry 'SystemStructure.ssd': "
                      f"'{mine}' exists already (nothing is written over)")
    assert mine.read_bytes() == b"the user's own"
    assert _tree(work) == ["package", "package/SystemStructure.ssd"]


def test_refused_package_leaves_no_folder_it_made(tmp_path, monkeypatch):
    monkeypatch.setattr(importer, "SSP_LIMITS", Limits(size=16 * MiB, entries=100))
    bomb = _bomb(tmp_path / "bomb.ssp", 64 * MiB)
    work = tmp_path / "new" / "work"
    with pytest.raises(SspError, match="more than the limit of 16 MiB"):
        importer.load_ssp(bomb, work)
    assert not (tmp_path / "new").exists()
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "note.txt").write_text("kept")
    with pytest.raises(SspError, match="more than the limit of 16 MiB"):
        importer.load_ssp(bomb, theirs)
    assert _tree(theirs) == ["note.txt"]


def test_cli_refuses_a_bomb_in_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(importer, "SSP_LIMITS", Limits(size=16 * MiB, entries=100))
    bomb = _bomb(tmp_path / "bomb.ssp", 64 * MiB)
    (tmp_path / "tmp").mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    code = cli.main(["run", str(bomb), "--quiet", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and "Traceback" not in err[0], err
    assert f"{bomb}: archive: refused: its entries expand to" in err[0]
    assert not (tmp_path / "out").exists()
    assert list((tmp_path / "tmp").iterdir()) == []  # the unpacked package is gone


def test_normal_package_unpacks_byte_for_byte(tmp_path):
    entries = {"SystemStructure.ssd": SSD, "resources/": None,
               "resources/a.fmu": os.urandom(300_000),
               "resources/sub/./b.ssv": b"<ssv/>" * 1000, "docs/readme.txt": b""}
    path = tmp_path / "ok.ssp"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as out:
        for name, data in entries.items():
            if data is None:
                out.mkdir(name)
            else:
                out.writestr(name, data, zipfile.ZIP_STORED
                             if name.endswith(".fmu") else zipfile.ZIP_DEFLATED)
    dest = tmp_path / "dest"
    dest.mkdir()
    importer.safe_extract(path, dest)
    assert (dest / "resources" / "a.fmu").read_bytes() == entries["resources/a.fmu"]
    assert (dest / "resources" / "sub" / "b.ssv").read_bytes() == \
        entries["resources/sub/./b.ssv"]
    assert (dest / "SystemStructure.ssd").read_bytes() == SSD
    assert (dest / "docs" / "readme.txt").read_bytes() == b""
    assert _tree(dest) == ["SystemStructure.ssd", "docs", "docs/readme.txt", "resources",
                           "resources/a.fmu", "resources/sub", "resources/sub/b.ssv"]


def test_a_link_in_the_folder_is_never_followed(tmp_path):
    """A symbolic link already in the folder, where an entry's folder goes: refused,
    nothing written through it."""
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    dest = tmp_path / "dest"
    dest.mkdir()
    (dest / "resources").symlink_to(elsewhere)
    path = tmp_path / "p.ssp"
    with zipfile.ZipFile(path, "w") as out:
        out.writestr("SystemStructure.ssd", SSD)
        out.writestr("resources/a.fmu", b"fmu")
    with pytest.raises(SspError) as caught:
        importer.safe_extract(path, dest)
    _one_line_refusal(caught.value, path, "entry 'resources/a.fmu': 'resources' is in the "
                      "way (not a folder)")
    assert list(elsewhere.iterdir()) == []
    assert _tree(dest) == ["resources"]


def test_a_name_held_twice_keeps_the_later_entry(tmp_path):
    """As zipfile and fmpy unpack it (the FMI 3.0 Reference FMU Roberts.fmu holds its
    extra/ files twice): the later entry is kept; the file is the extraction's own, so
    replacing it writes over nothing of the user's."""
    path = tmp_path / "twice.ssp"
    with zipfile.ZipFile(path, "w") as out:
        out.writestr("SystemStructure.ssd", SSD)
        out.writestr("extra/a.txt", b"first")
        with pytest.warns(UserWarning, match="Duplicate name"):
            out.writestr("extra/a.txt", b"second")
    dest = tmp_path / "dest"
    dest.mkdir()
    importer.safe_extract(path, dest)
    assert (dest / "extra" / "a.txt").read_bytes() == b"second"
    assert _tree(dest) == ["SystemStructure.ssd", "extra", "extra/a.txt"]
