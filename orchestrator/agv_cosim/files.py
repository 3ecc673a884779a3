"""Files and folders this tool writes, and how safely: every file created new, never
through a symbolic link; names from manifests checked as one path component; output
folders assembled under a temporary name and renamed into place at the end
(:class:`AtomicDir`), so an interrupted run never leaves a folder that looks complete.
JSON, text and summary files are written through here too.

And the files it reads (:func:`open_regular`, :func:`read_bytes` and their kin): opened
without blocking, refused unless a regular file, read whole only up to the limit of their
kind (:data:`JSON_LIMIT`, :data:`CSV_LIMIT`, :data:`XML_LIMIT`, :data:`FMU_LIMIT`).
"""

import csv
import errno
import io
import json
import math
import os
import re
import shutil
import stat
import sys
import tempfile
from collections.abc import Iterable
from pathlib import Path
from types import TracebackType
from typing import IO, Any, BinaryIO

from .errors import FolderLost, OutputError, UnreadableFile
from .lifetime import CREATE_FLAGS, signals_blocked
from .version import __version__


def create_file(path: str | Path, binary: bool = False) -> IO[Any]:
    """A new file at ``path``, opened for writing (text: UTF-8, ``\\n`` line ends).

    Never an existing file and never through a symbolic link (``O_CREAT | O_EXCL |
    O_NOFOLLOW``): every file we write is one we created, in a folder of ours.
    """
    fd = os.open(path, CREATE_FLAGS, 0o666)
    if binary:
        return os.fdopen(fd, "wb")
    return os.fdopen(fd, "w", encoding="utf-8", newline="")


def create_beside(target: str | Path, suffix: str = ".partial") -> tuple[Path, IO[Any]]:
    """A new file beside ``target`` under a temporary name of ours
    (``.<name>.<random><suffix>``, :func:`create_file`: never an existing file, never
    through a symbolic link), opened for writing bytes; ``(its path, the stream)``. To be
    renamed onto ``target`` once complete."""
    target = Path(target)
    for _ in range(100):
        path = target.parent / f".{target.stem}.{os.urandom(4).hex()}{suffix}"
        try:
            return path, create_file(path, binary=True)
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, "no free temporary name", str(target))


def open_output(path: str | Path) -> BinaryIO:
    """``path`` opened for writing bytes, created or truncated, never through a
    symbolic link (``O_NOFOLLOW``): for files a library call may write again (figures)."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_NOFOLLOW | os.O_CLOEXEC
    return os.fdopen(os.open(path, flags, 0o666), "wb")


def csv_line(fields: Iterable[Any]) -> str:
    """One CSV record of ``fields`` as the csv module writes it (quoted where a field
    holds a comma, a quote or a line break), ending in ``\\n``."""
    buffer = io.StringIO()
    csv.writer(buffer, lineterminator="\n").writerow(fields)
    return buffer.getvalue()


def write_json(path: str | Path, data: Any, replace: bool = False) -> None:
    """Write ``data`` as indented, key-sorted JSON (NaN/inf written as null) into a new
    file (:func:`create_file`); ``replace`` first removes a file of ours already there."""
    if replace:
        Path(path).unlink(missing_ok=True)
    with create_file(path) as stream:
        stream.write(json_text(data))


def json_text(data: Any) -> str:
    """``data`` as :func:`write_json` writes it (indented, keys sorted, NaN/inf as null)."""
    return json.dumps(_json_safe(data), indent=1, sort_keys=True) + "\n"


def write_text(path: str | Path, text: str) -> None:
    """Write ``text`` into a new file (:func:`create_file`)."""
    with create_file(path) as stream:
        stream.write(text)


def _json_safe(value: object) -> object:
    np = sys.modules.get("numpy")  # a numpy value exists only once numpy is imported
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, float) or (np is not None and isinstance(value, np.floating)):
        value = float(value)
        return value if math.isfinite(value) else None
    if np is not None and isinstance(value, np.integer):
        return int(value)
    if isinstance(value, Path):
        return str(value)
    return value


def write_summary(path: str | Path, rows: list[dict[str, Any]]) -> None:
    """Write ``summary.csv``: one row per run (dicts; columns = union in first-seen order)."""
    columns = {}
    for row in rows:
        columns.update(dict.fromkeys(row))
    with create_file(path) as stream:
        writer = csv.DictWriter(stream, fieldnames=list(columns))
        writer.writeheader()
        for row in rows:
            writer.writerow({k: (repr(v) if isinstance(v, float) else v)
                             for k, v in row.items()})


#: Characters that reorder the text around them on a terminal (Unicode bidi controls).
_BIDI = set(range(0x202A, 0x202F)) | set(range(0x2066, 0x206A)) | {0x200E, 0x200F, 0x061C}


def printable(text: object) -> str:
    """``text`` safe to print on a terminal as one line: control characters (C0, DEL,
    C1: escape sequences, line breaks, bells) and bidi controls are written as escapes
    (``\\x1b``, ``\\n``, ``\\u202e``); everything else is unchanged."""
    text = str(text)
    if text.isprintable():
        return text
    out = []
    for ch in text:
        code = ord(ch)
        if code < 0x20 or 0x7F <= code <= 0x9F:
            out.append({"\n": "\\n", "\r": "\\r", "\t": "\\t"}.get(ch, f"\\x{code:02x}"))
        elif code in _BIDI:
            out.append(f"\\u{code:04x}")
        else:
            out.append(ch)
    return "".join(out)


#: File that marks a folder as a result folder this tool wrote (JSON: tool, version).
MARKER = ".agv-cosim"
#: What a result folder written before the marker existed holds (besides run folders
#: that each contain a run.json): recognised so that re-running into it still works.
_LEGACY_FILES = {"summary.csv", "plots_error.txt"}
_NAME = re.compile(r"^[A-Za-z0-9_.-]+$")
#: Longest name accepted as one path component (most file systems allow 255 bytes;
#: what we add around a name, ``.<name>.incomplete-XXXXXXXX``, must fit too).
MAX_NAME = 128


def check_name(name: object, what: str = "name") -> str:
    """Return ``name`` if it is one safe path component, else raise ValueError.

    Safe: letters, digits, ``-``, ``_``, ``.``; not ``.`` or ``..``; not starting with
    ``.`` (hidden, and our own temporary names start so); at most :data:`MAX_NAME`
    characters. Names from manifests and SSP packages are data: they pass through here
    before they are used in a path.
    """
    if not isinstance(name, str) or not name:
        raise ValueError(f"{what} {name!r} is empty or not a string")
    if len(name) > MAX_NAME:
        raise ValueError(f"{what} is {len(name)} characters long (at most {MAX_NAME})")
    if not _NAME.match(name) or name.startswith("."):
        raise ValueError(f"{what} {name!r} is not a plain file name (letters, digits, "
                         "'-', '_', '.'; not starting with '.')")
    return name


def user_mode(directory: bool = True) -> int:
    """Permission bits a new folder (file) gets under the process's umask."""
    mask = os.umask(0)
    os.umask(mask)
    return (0o777 if directory else 0o666) & ~mask


# --------------------------------------------------------------------------- reading
#
# Every file the tool reads from a user or from a result folder is opened here: without
# blocking (a FIFO cannot hang the command), checked to be a regular file (a FIFO, a
# device such as /dev/zero, a folder or a socket is refused with one line naming it),
# and read whole only up to the limit of its kind.

#: Largest JSON record read whole [bytes] (run.json, metrics.json, montecarlo.json,
#: the report's record): a run.json of 3000 components' parameters is a few MB.
JSON_LIMIT = 64 << 20
#: Largest CSV table read whole [bytes] (summary.csv, timings.csv: one row per run).
CSV_LIMIT = 256 << 20
#: Largest XML document read whole [bytes] (an SSD, a parameter set .ssv).
XML_LIMIT = 64 << 20
#: Largest FMU read whole out of an SSP package [bytes] (FMUs on disk are streamed).
FMU_LIMIT = 1 << 30
#: Bytes of a note (partial.txt, plots_error.txt, ...) shown: its beginning only.
NOTE_LIMIT = 1 << 16


def _kind(mode: int) -> str:
    return ("a folder" if stat.S_ISDIR(mode) else
            "a FIFO" if stat.S_ISFIFO(mode) else
            "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else
            "a socket" if stat.S_ISSOCK(mode) else "not a file")


def open_regular(path: str | Path) -> BinaryIO:
    """``path`` opened for reading bytes, when it is a regular file (a symbolic link to
    one is followed). Opened non-blocking first, so that a FIFO cannot hang us; anything
    but a regular file is refused before any read.

    Raises
    ------
    UnreadableFile
        ``path`` is a FIFO, a device, a folder or a socket (the text names it).
    OSError
        As :func:`os.open` (missing file, permissions).
    """
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise UnreadableFile(path, f"is {_kind(info.st_mode)}, not a regular file")
        os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_bytes(path: str | Path, limit: int) -> bytes:
    """The bytes of the regular file ``path`` (:func:`open_regular`), at most ``limit``:
    a larger file is refused (:class:`~agv_cosim.errors.UnreadableFile`, naming the
    limit) before it is read."""
    with open_regular(path) as stream:
        size = os.fstat(stream.fileno()).st_size
        if size > limit:
            raise UnreadableFile(path, f"is {size} bytes; at most {limit} are read")
        data = stream.read(limit + 1)
    if len(data) > limit:  # it grew while we read it
        raise UnreadableFile(path, f"is more than {limit} bytes; at most {limit} are "
                             "read")
    return data


def read_head(path: str | Path, limit: int = NOTE_LIMIT) -> bytes:
    """The first ``limit`` bytes of the regular file ``path`` (:func:`open_regular`)."""
    with open_regular(path) as stream:
        return stream.read(limit)


def read_text(path: str | Path, limit: int, what: str = "file") -> str:
    """The UTF-8 text of the regular file ``path`` (:func:`read_bytes`); a file that is
    not UTF-8 is refused (:class:`~agv_cosim.errors.UnreadableFile`)."""
    data = read_bytes(path, limit)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as error:
        raise UnreadableFile(path, f"is not UTF-8 text (byte {error.start}); a {what} "
                             "must be") from None


def open_text(path: str | Path) -> IO[str]:
    """The regular file ``path`` (:func:`open_regular`) as UTF-8 text read as it goes
    (``newline=""``, as the csv module wants): for files streamed in pieces."""
    return io.TextIOWrapper(open_regular(path), encoding="utf-8", newline="")


def read_json_object(path: str | Path) -> dict[str, Any] | None:
    """The JSON object in the file ``path``, or None when it is missing, is not JSON or
    holds something other than an object. A file that must not be read (a FIFO, a
    device, larger than :data:`JSON_LIMIT`) raises
    :class:`~agv_cosim.errors.UnreadableFile` (:func:`read_bytes`)."""
    try:
        data = json.loads(read_bytes(path, JSON_LIMIT).decode("utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError):
        return None
    return data if isinstance(data, dict) else None


def displayable(text: object) -> str:
    """``text`` that encodes as UTF-8: a file name's undecodable bytes (held as lone
    surrogates, ``surrogateescape``) and any other lone surrogate written as escapes
    (``\\xff``, ``\\udcff``)."""
    text = str(text)
    try:
        text.encode("utf-8")
        return text
    except UnicodeEncodeError:
        pass
    try:
        return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    except UnicodeEncodeError:
        return text.encode("utf-8", "backslashreplace").decode("utf-8")


def marker_data(folder: str | Path) -> dict[str, Any] | None:
    """Our marker's JSON in ``folder`` (a regular file, not a link), or None."""
    try:
        fd = os.open(Path(folder) / MARKER, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except OSError:
        return None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return None
        data = json.loads(os.read(fd, 1 << 16).decode("utf-8"))
    except (OSError, ValueError):
        return None
    finally:
        os.close(fd)
    return data if isinstance(data, dict) and data.get("tool") == "agv-cosim" else None


def is_result_folder(path: str | Path) -> bool:
    """True when ``path`` is a folder this tool wrote (marker, or the legacy layout)."""
    path = Path(path)
    if marker_data(path) is not None:
        return True
    if not (path / "summary.csv").is_file():
        return False
    for entry in path.iterdir():
        if entry.is_symlink():
            return False
        if entry.is_dir():
            if not (entry / "run.json").is_file():
                return False
        elif entry.name not in _LEGACY_FILES and entry.suffix != ".png":
            return False
    return True


def _write_marker(folder: str | Path, **extra: Any) -> None:
    write_json(Path(folder) / MARKER, {"tool": "agv-cosim", "version": __version__,
                                       **extra}, replace=True)


class FolderLock:
    """An exclusive lock on ``path`` (a lock file removed on release), or OutputError.

    The lock file is opened without following a symbolic link and must be a regular
    file: a link or anything else at its place is refused, never written through.
    """

    def __init__(self, path: Path, target: Path) -> None:
        import fcntl

        self.path = Path(path)
        flags = os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC
        while True:
            try:
                fd = os.open(self.path, flags, 0o644)
            except OSError as error:
                if error.errno == errno.ELOOP:
                    raise OutputError(f"{target}: its lock file '{self.path}' is a symbolic "
                                      "link; refusing to follow it (remove it if no run "
                                      "is writing this folder)") from None
                raise OutputError(f"{target}: cannot write here: {error.strerror}") from None
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                os.close(fd)
                raise OutputError(f"{target}: its lock file '{self.path}' is not a regular "
                                  "file; refusing to use it")
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                owner = os.read(fd, 32).decode(errors="replace").strip()
                os.close(fd)
                owner = owner if owner.isdigit() else ""
                raise OutputError(f"{target}: another agv-cosim run is writing this folder"
                                  + (f" (process {owner})" if owner else "")
                                  + "; wait for it or choose another --out") from None
            # the file we locked may have been unlinked by its previous holder: retry
            if self._same(fd):
                break
            os.close(fd)
        os.ftruncate(fd, 0)
        os.write(fd, str(os.getpid()).encode())
        self.fd: int | None = fd

    def _same(self, fd: int) -> bool:
        """True when ``path`` is still the file open as ``fd`` (not a link)."""
        try:
            here = os.lstat(self.path)
        except FileNotFoundError:
            return False
        mine = os.fstat(fd)
        return (here.st_dev, here.st_ino) == (mine.st_dev, mine.st_ino)

    def release(self) -> None:
        if self.fd is not None:
            if self._same(self.fd):
                self.path.unlink(missing_ok=True)
            os.close(self.fd)
            self.fd = None


class AtomicDir:
    """Build a folder under a temporary name beside ``target``; rename it in at the end.

    Safety (a user's data is never lost):

    - ``target`` is replaced only when it is missing, an empty folder, or a result
      folder this tool wrote (:func:`is_result_folder`); anything else raises
      :class:`OutputError` naming it, unless ``overwrite`` (then any folder is
      replaced; a file never is);
    - one run at a time per target: a lock file ``.<name>.lock`` beside it;
    - leftovers of runs to the same target that were killed (``.<name>.incomplete-*``,
      ``.<name>.old-*``) are removed first, each only when it carries our marker;
    - the folder gets the user's umask (``mkdtemp`` alone would make it 0700);
    - the folder is the one we created until the end: :meth:`commit` checks it
      (:meth:`intact`) and raises :class:`FolderLost` when it was removed or replaced.

    ``commit()`` replaces ``target``; ``mark_partial()`` before it marks the folder as
    holding only part of the runs; ``discard()`` deletes the temporary folder. ``about``
    goes into the folder's marker (:func:`marker_data`; the pipeline records the
    manifest's name, which ``--resume`` checks, and its hash there). Used as a
    context manager it discards on an exception and always releases the lock.
    """

    def __init__(self, target: str | Path, overwrite: bool = False,
                 about: dict[str, Any] | None = None) -> None:
        self.target = Path(os.path.abspath(target))
        self.overwrite = overwrite
        #: written into the folder's marker besides tool and version (e.g. the manifest)
        self.about = dict(about or {})
        self.lock: FolderLock | None = None
        self.path: Path | None = None
        self.identity: tuple[int, int] | None = None
        parent, name = self.target.parent, self.target.name
        if not name:
            raise OutputError(f"{target}: not a folder name")
        if parent.exists() and not parent.is_dir():
            raise OutputError(f"{target}: '{parent}' is not a folder")
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise OutputError(f"{target}: cannot create '{error.filename or parent}': "
                              f"{error.strerror}") from None
        self._check_target()
        self.lock = FolderLock(parent / f".{name}.lock", self.target)
        try:
            self._check_target()  # again, now that no other run can change it
            self._clean_stale()
            try:
                self.path = Path(tempfile.mkdtemp(prefix=f".{name}.incomplete-",
                                                  dir=parent))
                info = os.lstat(self.path)
                self.identity = (info.st_dev, info.st_ino)
                _write_marker(self.path, **self.about)
            except OSError as error:
                raise OutputError(f"{target}: cannot write here: {error.strerror}") from None
            os.chmod(self.path, user_mode())
        except BaseException:
            self.discard()
            raise

    def _check_target(self) -> None:
        target = self.target
        if target.is_symlink() and not target.is_dir():
            raise OutputError(f"{target}: exists and is not a folder; refusing to replace it")
        if not target.exists():
            return
        if not target.is_dir():
            raise OutputError(f"{target}: exists and is not a folder; refusing to replace it")
        if target.is_symlink():
            raise OutputError(f"{target}: is a symbolic link; refusing to replace it "
                              "(give the folder it points to)")
        if self.overwrite or is_result_folder(target) or not any(target.iterdir()):
            return
        raise OutputError(f"{target}: exists and is not a result folder of agv-cosim; "
                          "refusing to replace it (choose another --out, or pass "
                          "--overwrite to replace it)")

    def _clean_stale(self) -> None:
        name = self.target.name
        for pattern in (f".{name}.incomplete-*", f".{name}.old-*"):
            for stale in self.target.parent.glob(pattern):
                try:
                    info = stale.lstat()
                except OSError:
                    continue
                if stat.S_ISDIR(info.st_mode) and marker_data(stale) is not None:
                    shutil.rmtree(stale, ignore_errors=True)

    def intact(self) -> bool:
        """True while the temporary folder is the one we created (same inode, marked)."""
        if self.path is None or self.identity is None:
            return False
        try:
            info = os.lstat(self.path)
        except OSError:
            return False
        return ((info.st_dev, info.st_ino) == self.identity and stat.S_ISDIR(info.st_mode)
                and marker_data(self.path) is not None)

    def check_intact(self) -> None:
        """Raise :class:`FolderLost` (naming the folder) unless :meth:`intact`."""
        if not self.intact():
            raise FolderLost(f"{self.target}: the folder being written ({self.path}) was "
                             "removed or replaced during the run; no result folder was "
                             "written")

    def mark_partial(self, reason: str, complete: int, total: int) -> None:
        """Mark the folder as holding only part of the runs: the marker says so
        (``complete: false`` and ``reason``) and ``partial.txt`` says it in words."""
        assert self.path is not None, "the folder was committed or discarded"
        _write_marker(self.path, **self.about, complete=False, reason=reason,
                      runs_complete=complete, runs=total)
        write_text(self.path / "partial.txt",
                   f"partial result: {reason}; {complete} of {total} run(s) complete "
                   "(status of each run: summary.csv)\n")

    def commit(self) -> Path:
        with signals_blocked():  # the renames are not cut half-way by a Ctrl-C/SIGTERM
            return self._commit()

    def _commit(self) -> Path:
        self.check_intact()
        old = None
        if self.target.exists():
            self._check_target()
            # an empty folder of our own to rename the old target onto (never a name
            # that may already be someone's folder)
            old = Path(tempfile.mkdtemp(prefix=f".{self.target.name}.old-",
                                        dir=self.target.parent))
            self.target.rename(old)
            if marker_data(old) is None:
                try:
                    _write_marker(old)  # so that a run killed now still cleans it
                except OSError:
                    pass
        assert self.path is not None, "the folder was committed or discarded"
        self.path.rename(self.target)
        self.path = None
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
        self._release()
        return self.target

    def discard(self) -> None:
        if self.path is not None:
            if self.intact():
                shutil.rmtree(self.path, ignore_errors=True)
            self.path = None
        self._release()

    def _release(self) -> None:
        if self.lock is not None:
            self.lock.release()
            self.lock = None

    def __enter__(self) -> "AtomicDir":
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 traceback: TracebackType | None) -> None:
        if kind is not None:
            self.discard()
        self._release()
