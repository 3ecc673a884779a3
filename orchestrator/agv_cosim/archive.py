"""Zip archives (SSP packages, FMUs) read and unpacked within bounds.

An archive's entries are checked from its headers before anything is written, and
again while they are written, since headers can lie:

- before: the entry count and central directory size its end record declares (read
  before the central directory is parsed: at most :data:`DIRECTORY_ENTRY` bytes of
  directory per entry of the limit), then its central directory: at most
  :attr:`Limits.entries` entries, their uncompressed sizes summing to at most
  :attr:`Limits.size` bytes, compressed with *stored* or *deflate* only (the two
  methods FMI and SSP allow; their decompression is streamed in bounded chunks), and no
  entry that is a symbolic link or whose name is absolute, has a drive letter or a
  ``..`` component;
- while writing (:func:`extract`): each entry streamed to a new file of its own (never
  over an existing one, never through a link; a name the archive holds twice is written
  twice, the later entry kept, as :mod:`zipfile` and fmpy do) with a byte budget: no
  entry writes more than its header declares, and the archive no more than
  :attr:`Limits.size` in all.

A refused archive raises :class:`ArchiveRefused` (its ``reason`` names the entry and
why); :func:`extract` then removes every file and folder it created, and only those.
There is no ratio check (compressed to uncompressed): the byte cap bounds what can be
written whatever the ratio, and a ratio low enough to catch a bomb would refuse
legitimate, highly compressible entries (zero-filled tables, sparse data).

Limits (:data:`SSP_LIMITS`, :data:`FMU_LIMITS`): 4 GiB and 10 000 entries for an SSP
package (its entries are the FMUs and the SSD: a few dozen); 4 GiB and 20 000 entries
for an FMU (a standalone FMU carries a Python runtime: our largest has about 2 500 files,
190 MiB).
"""

import os
import re
import stat
import struct
import zipfile
from pathlib import Path
from typing import IO, BinaryIO, NamedTuple

from .errors import ArchiveRefused

__all__ = ["FMU_LIMITS", "SSP_LIMITS", "ArchiveRefused", "Limits", "check_entries",
           "declared_entries", "extract", "open_bounded"]

#: Compression methods an FMU or an SSP package may use (FMI, SSP: stored or deflate).
METHODS = {zipfile.ZIP_STORED: "stored", zipfile.ZIP_DEFLATED: "deflate"}
#: Bytes read and written at a time while unpacking an entry.
CHUNK = 1 << 20
#: Most bytes of central directory per entry of the limit (a record is 46 bytes, its
#: name and extra fields): bounds what :mod:`zipfile` parses when an end record
#: understates the entry count.
DIRECTORY_ENTRY = 1024


class Limits(NamedTuple):
    """Most uncompressed bytes (``size``) and entries (``entries``) of one archive."""

    size: int
    entries: int


#: An SSP package: 4 GiB, 10 000 entries.
SSP_LIMITS = Limits(size=4 << 30, entries=10_000)
#: An FMU: 4 GiB, 20 000 entries.
FMU_LIMITS = Limits(size=4 << 30, entries=20_000)


def _size_text(size: int) -> str:
    for unit, shift in (("GiB", 30), ("MiB", 20), ("KiB", 10)):
        if size >= 1 << shift:
            return f"{size / (1 << shift):.3g} {unit}"
    return f"{size} bytes"


_EOCD = b"PK\x05\x06"
_EOCD64_LOCATOR = b"PK\x06\x07"
_EOCD64 = b"PK\x06\x06"


def declared_entries(stream: BinaryIO) -> int | None:
    """The entry count an archive's end record declares (ZIP64's when it has one), read
    from its last 64 KiB without parsing its central directory; None when there is no
    readable end record (:mod:`zipfile` then says what is wrong)."""
    record = _end_record(stream)
    return None if record is None else record[0]


def _end_record(stream: BinaryIO) -> tuple[int, int] | None:
    """(entries, central directory bytes) the end record declares, or None."""
    end = stream.seek(0, os.SEEK_END)
    stream.seek(max(0, end - (22 + 0xFFFF)))
    tail = stream.read()
    at = tail.rfind(_EOCD)
    if at < 0 or len(tail) - at < 22:
        return None
    count, size = struct.unpack_from("<HI", tail, at + 10)
    if (count != 0xFFFF and size != 0xFFFFFFFF) or at < 20 or \
            tail[at - 20:at - 16] != _EOCD64_LOCATOR:
        return int(count), int(size)
    offset: int = struct.unpack_from("<Q", tail, at - 12)[0]
    stream.seek(offset)
    record = stream.read(56)
    if len(record) < 56 or record[:4] != _EOCD64:
        return None
    count, size = struct.unpack_from("<QQ", record, 32)
    return int(count), int(size)


def _unsafe_reason(info: zipfile.ZipInfo) -> str | None:
    name = info.filename
    if stat.S_ISLNK(info.external_attr >> 16):
        return "a symbolic link"
    if name.startswith(("/", "\\")) or re.match(r"^[A-Za-z]:", name):
        return "an absolute path"
    if ".." in re.split(r"[\\/]", name):
        return "a '..' path"
    return None


def check_entries(infos: list[zipfile.ZipInfo], limits: Limits) -> None:
    """Refuse what the headers ``infos`` of one archive show to be unsafe or too large.

    Raises
    ------
    ArchiveRefused
        (archive named ``""``: the caller names it) More than ``limits.entries``
        entries, more than ``limits.size`` bytes in all, a compression method other than
        stored or deflate, or an unsafe entry name (see the module docstring).
    """
    if len(infos) > limits.entries:
        raise ArchiveRefused("", f"refused: {len(infos)} entries, more than the limit of "
                             f"{limits.entries}")
    total = 0
    for info in infos:
        reason = _unsafe_reason(info)
        if reason:
            raise ArchiveRefused("", f"refused: entry '{info.filename}' is {reason}")
        if info.compress_type not in METHODS:
            raise ArchiveRefused("", f"refused: entry '{info.filename}' is compressed with "
                                 f"method {info.compress_type} (only stored and deflate "
                                 "are allowed)")
        total += info.file_size
    if total > limits.size:
        raise ArchiveRefused("", f"refused: its entries expand to {total} bytes "
                             f"({_size_text(total)}), more than the limit of "
                             f"{_size_text(limits.size)}")


def open_bounded(stream: BinaryIO, name: object, limits: Limits) -> zipfile.ZipFile:
    """``stream`` opened as a zip archive whose headers pass :func:`check_entries`.

    Raises
    ------
    ArchiveRefused
        Named ``name``; the entry count and central directory size its end record
        declares are checked before the central directory is read.
    zipfile.BadZipFile, OSError
        Not a readable zip archive.
    """
    declared = _end_record(stream)
    if declared is not None and declared[0] > limits.entries:
        raise ArchiveRefused(name, f"refused: {declared[0]} entries, more than the limit of "
                             f"{limits.entries}")
    if declared is not None and declared[1] > limits.entries * DIRECTORY_ENTRY:
        raise ArchiveRefused(name, f"refused: its central directory is {declared[1]} bytes, "
                             f"more than {DIRECTORY_ENTRY} per entry of the limit of "
                             f"{limits.entries} entries")
    stream.seek(0)
    archive = zipfile.ZipFile(stream)
    try:
        check_entries(archive.infolist(), limits)
    except ArchiveRefused as refused:
        archive.close()
        raise ArchiveRefused(name, refused.reason) from None
    except BaseException:
        archive.close()
        raise
    return archive


def _parts(name: str) -> list[str]:
    """The path components of an entry name (empty and ``.`` ones dropped)."""
    return [part for part in name.split("/") if part not in ("", ".")]


class _Unpacking:
    """The files and folders one :func:`extract` created (removed if it fails)."""

    def __init__(self, archive_name: object, dest: Path, limits: Limits) -> None:
        self.name, self.dest, self.limits = archive_name, dest, limits
        self.created: list[tuple[Path, bool]] = []  # (path, is a folder)
        self.folders: set[Path] = set()  # folders made or found to be folders
        self.files: set[Path] = set()  # files made
        self.written = 0

    def refuse(self, reason: str) -> ArchiveRefused:
        return ArchiveRefused(self.name, f"refused: {reason}")

    def folder(self, parts: list[str], entry: str) -> Path:
        """The folder ``dest/parts``, made where missing (a link or a file in the way
        is refused)."""
        path = self.dest
        for part in parts:
            path = path / part
            if path in self.folders:
                continue
            try:
                mode = os.lstat(path).st_mode
            except FileNotFoundError:
                os.mkdir(path, 0o777)
                self.created.append((path, True))
                self.folders.add(path)
                continue
            if not stat.S_ISDIR(mode):
                raise self.refuse(f"entry '{entry}': '{part}' is in the way (not a "
                                  "folder)")
            self.folders.add(path)
        return path

    def entry(self, archive: zipfile.ZipFile, info: zipfile.ZipInfo) -> None:
        parts = _parts(info.filename)
        if info.is_dir() or not parts:
            self.folder(parts, info.filename)
            return
        target = self.folder(parts[:-1], info.filename) / parts[-1]
        if target in self.files:  # a name twice in the archive: the later one is kept
            os.unlink(target)
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC
        try:
            fd = os.open(target, flags, 0o666)
        except FileExistsError:
            raise self.refuse(f"entry '{info.filename}': '{target}' exists already "
                              "(nothing is written over)") from None
        if target not in self.files:
            self.created.append((target, False))
            self.files.add(target)
        with os.fdopen(fd, "wb") as out, archive.open(info) as source:
            try:
                self.copy(source, out, info)
            except zipfile.BadZipFile as error:  # zipfile stops at the declared size
                raise self.refuse(f"entry '{info.filename}' does not match its header "
                                  f"({error})") from None

    def copy(self, source: IO[bytes], out: IO[bytes], info: zipfile.ZipInfo) -> None:
        """Stream one entry within the byte budget (its header's size, the archive's)."""
        own = 0
        while True:
            chunk = source.read(CHUNK)
            if not chunk:
                return
            own += len(chunk)
            self.written += len(chunk)
            if own > info.file_size:
                raise self.refuse(f"entry '{info.filename}' holds more than the "
                                  f"{info.file_size} bytes its header declares")
            if self.written > self.limits.size:
                raise self.refuse(f"it expands to more than the limit of "
                                  f"{_size_text(self.limits.size)}")
            out.write(chunk)

    def undo(self) -> None:
        """Remove what was created, in the reverse order of its making (what is in a
        folder before the folder)."""
        for path, is_folder in reversed(self.created):
            try:
                if is_folder:
                    os.rmdir(path)
                else:
                    os.unlink(path)
            except OSError:
                pass


def extract(archive_path: str | Path, dest: str | Path, limits: Limits,
            stream: BinaryIO | None = None) -> None:
    """Unpack the zip archive at ``archive_path`` (or read from ``stream``, named by
    ``archive_path``) into the existing folder ``dest``, within ``limits``.

    Headers are checked first (:func:`open_bounded`), then every entry is streamed with
    a byte budget; when anything fails, every file and folder this call created is
    removed, and nothing else.

    Raises
    ------
    ArchiveRefused
        See :func:`check_entries`; also an entry that writes more than its header
        declares, an archive that writes more than ``limits.size``, or an entry whose
        target exists already (nothing is written over) or has a file in its way.
    zipfile.BadZipFile, zlib.error, EOFError, OSError
        Not a readable zip archive (e.g. an entry whose CRC does not match), or a write
        that failed.
    """
    if stream is None:
        with open(archive_path, "rb") as opened:
            extract(archive_path, dest, limits, opened)
        return
    with open_bounded(stream, archive_path, limits) as archive:
        unpacking = _Unpacking(archive_path, Path(dest), limits)
        try:
            for info in archive.infolist():
                unpacking.entry(archive, info)
        except BaseException:
            unpacking.undo()
            raise

