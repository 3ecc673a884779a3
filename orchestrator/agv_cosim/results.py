"""Writing and reading results: streamed CSV time series, JSON files, the summary.

Floats are written with ``repr`` (shortest text that round-trips exactly), so a CSV read
back gives the bit-identical doubles. Output folders are assembled under a temporary name
and renamed into place at the end (:class:`AtomicDir`): an interrupted run never leaves a
folder that looks complete.
"""

import csv
import errno
import io
import itertools
import json
import os
import re
import shutil
import stat
import tempfile
from pathlib import Path

import numpy as np


def create_file(path, binary=False):
    """A new file at ``path``, opened for writing (text: UTF-8, ``\\n`` line ends).

    Never an existing file and never through a symbolic link (``O_CREAT | O_EXCL |
    O_NOFOLLOW``): every file we write is one we created, in a folder of ours.
    """
    from .lifetime import CREATE_FLAGS

    fd = os.open(path, CREATE_FLAGS, 0o666)
    if binary:
        return os.fdopen(fd, "wb")
    return os.fdopen(fd, "w", encoding="utf-8", newline="")


def open_output(path):
    """``path`` opened for writing bytes, created or truncated, never through a
    symbolic link (``O_NOFOLLOW``): for files a library call may write again (figures)."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_NOFOLLOW | os.O_CLOEXEC
    return os.fdopen(os.open(path, flags, 0o666), "wb")


def csv_line(fields):
    """One CSV record of ``fields`` as the csv module writes it (quoted where a field
    holds a comma, a quote or a line break), ending in ``\\n``."""
    buffer = io.StringIO()
    csv.writer(buffer, lineterminator="\n").writerow(fields)
    return buffer.getvalue()


class CsvSink:
    """Stream rows of values to ``path`` (header: ``time`` then the column names).

    The header is written by the csv module, so any FMI variable name (commas, quotes,
    line breaks) reads back exactly (:func:`timeseries_columns`). Each row goes to the
    file in one ``write`` call, unbuffered: a run whose process dies keeps every row it
    recorded (the kernel holds what was written). ``bytes`` counts what was written.

    Parameters
    ----------
    path : Path
    columns : list of str
        Names after ``time``.
    formats : list of callable, optional
        One per column (value -> text, :func:`agv_cosim.fmitypes.record_format`); None
        when every column is a float (written with ``repr``).
    """

    def __init__(self, path, columns, formats=None):
        from .lifetime import CREATE_FLAGS

        self.path = Path(path)
        self.fd = os.open(self.path, CREATE_FLAGS, 0o666)
        self.bytes = 0
        # formats: one callable per column (value -> text, fmitypes.record_format);
        # None (every column a float) keeps the plain repr path
        self.formats = None if formats is None else [repr] + list(formats)
        self._write(csv_line(["time"] + list(columns)).encode("utf-8"))

    def _write(self, data):
        view = memoryview(data)
        while view:
            done = os.write(self.fd, view)
            view = view[done:]
            self.bytes += done

    def write(self, row):
        """Append one row (time, then the column values)."""
        if self.formats is None:
            text = ",".join(map(repr, map(float, row)))
        else:
            text = ",".join([f(v) for f, v in zip(self.formats, row)])
        self._write((text + "\n").encode("utf-8"))

    def close(self):
        if self.fd is not None:
            fd, self.fd = self.fd, None
            os.close(fd)


def read_timeseries(path, columns=None):
    """Read a ``timeseries.csv`` back (whole; :func:`iter_timeseries` reads in pieces).

    Returns
    -------
    (numpy.ndarray, dict of str -> numpy.ndarray)
        Time [s] and the requested (default: all) columns.
    """
    wanted = timeseries_columns(path) if columns is None else list(columns)
    times, data = [], {c: [] for c in wanted}
    for t, chunk in iter_timeseries(path, wanted):
        times.append(t)
        for c in wanted:
            data[c].append(chunk[c])
    if not times:
        return np.zeros(0), {c: np.zeros(0) for c in wanted}
    return np.concatenate(times), {c: np.concatenate(data[c]) for c in wanted}


#: Rows per chunk when a ``timeseries.csv`` is read in pieces (:func:`iter_timeseries`).
#: Parsing a chunk of 10 000 rows of 10 columns peaked 6-10 MiB above one of 2 000 (as
#: fast), which showed in the peak of a long run against a short one.
CHUNK_ROWS = 2_000


def _header(stream):
    """The header record of a ``timeseries.csv`` opened as text (csv module: a quoted
    name may hold commas, quotes and line breaks); the stream is left after it."""
    try:
        return next(csv.reader(stream))
    except StopIteration:
        return []


def timeseries_columns(path):
    """Column names of a ``timeseries.csv`` after ``time`` (its header)."""
    with open(path, encoding="utf-8", newline="") as stream:
        return _header(stream)[1:]


def _records(stream, count):
    """Up to ``count`` CSV records of ``stream`` as lines (a quoted field with a line
    break keeps its record whole: a record ends where its quotes are balanced)."""
    lines = list(itertools.islice(stream, count))
    quoted = any('"' in line for line in lines)
    if not quoted:
        return lines, False
    records, current = [], ""
    pending = iter(lines)
    while True:
        line = next(pending, None)
        if line is None:
            if current:  # the last record goes on past this chunk
                line = stream.readline()
                if not line:
                    records.append(current)
                    break
            else:
                break
        current += line
        if current.count('"') % 2 == 0:
            records.append(current)
            current = ""
    return records, True


def iter_timeseries(path, columns=None, chunk_rows=CHUNK_ROWS):
    """Read a ``timeseries.csv`` in pieces of at most ``chunk_rows`` rows.

    Memory is bounded by the chunk, whatever the length of the file. The values are the
    doubles :func:`read_timeseries` gives (same parser); concatenating the chunks gives its
    arrays. The header is read with the csv module; rows holding quoted text (String
    columns) are split by it too.

    Yields
    ------
    (numpy.ndarray, dict of str -> numpy.ndarray)
        Time [s] and the requested (default: all) columns of the next rows.

    Raises
    ------
    ValueError
        If a requested column is not in the file (the message names it).
    """
    if chunk_rows < 1:
        raise ValueError(f"chunk_rows must be >= 1, got {chunk_rows!r}")
    with open(path, encoding="utf-8", newline="") as stream:
        header = _header(stream)
        wanted = header[1:] if columns is None else list(columns)
        position = {name: i for i, name in reversed(list(enumerate(header)))}
        for name in wanted:
            if position.get(name, 0) == 0:
                raise ValueError(f"{path}: no column {name!r}")
        index = [0] + [position[c] for c in wanted]
        while True:
            lines, quoted = _records(stream, chunk_rows)
            if not lines:
                return
            if quoted:
                rows = list(csv.reader(lines))
                data = np.array([[float(row[i]) for i in index] for row in rows],
                                dtype=float).reshape(len(rows), len(index))
            else:
                data = np.loadtxt(lines, delimiter=",", usecols=index, ndmin=2)
            yield data[:, 0].copy(), {c: data[:, i + 1].copy() for i, c in enumerate(wanted)}


def _header_end(stream):
    """Bytes of the header record at the start of a binary stream (quotes respected)."""
    quoted, size = False, 0
    while block := stream.read(1 << 16):
        for i, byte in enumerate(block):
            if byte == 0x22:
                quoted = not quoted
            elif byte == 0x0A and not quoted:
                return size + i + 1
        size += len(block)
    return size


def count_rows(path):
    """Rows of a ``timeseries.csv`` after its header (a last line without its newline
    counts too). Counted in fixed-size blocks; rows with quoted text (String columns,
    which may hold line breaks) are counted by the csv module."""
    with open(path, "rb") as stream:
        stream.seek(_header_end(stream))
        lines, last, quoted = 0, b"\n", False
        while block := stream.read(1 << 20):
            lines += block.count(b"\n")
            last = block[-1:]
            quoted = quoted or b'"' in block
        if not quoted:
            return lines + (last != b"\n")
    with open(path, encoding="utf-8", newline="") as stream:
        _header(stream)
        return sum(1 for _ in csv.reader(stream))


def write_json(path, data, replace=False):
    """Write ``data`` as indented, key-sorted JSON (NaN/inf written as null) into a new
    file (:func:`create_file`); ``replace`` first removes a file of ours already there."""
    if replace:
        Path(path).unlink(missing_ok=True)
    with create_file(path) as stream:
        stream.write(json.dumps(_json_safe(data), indent=1, sort_keys=True) + "\n")


def write_text(path, text):
    """Write ``text`` into a new file (:func:`create_file`)."""
    with create_file(path) as stream:
        stream.write(text)


def _json_safe(value):
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, (np.floating, float)):
        value = float(value)
        return value if np.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, Path):
        return str(value)
    return value


def write_summary(path, rows):
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


def printable(text):
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


class OutputError(Exception):
    """An output folder we must not (or cannot) write; the text names the path."""


#: File that marks a folder as a result folder this tool wrote (JSON: tool, version).
MARKER = ".agv-cosim"
#: What a result folder written before the marker existed holds (besides run folders
#: that each contain a run.json): recognised so that re-running into it still works.
_LEGACY_FILES = {"summary.csv", "plots_error.txt"}
_NAME = re.compile(r"^[A-Za-z0-9_.-]+$")
#: Longest name accepted as one path component (most file systems allow 255 bytes;
#: what we add around a name, ``.<name>.incomplete-XXXXXXXX``, must fit too).
MAX_NAME = 128


def check_name(name, what="name"):
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


def user_mode(directory=True):
    """Permission bits a new folder (file) gets under the process's umask."""
    mask = os.umask(0)
    os.umask(mask)
    return (0o777 if directory else 0o666) & ~mask


def _marker_data(folder):
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


def is_result_folder(path):
    """True when ``path`` is a folder this tool wrote (marker, or the legacy layout)."""
    path = Path(path)
    if _marker_data(path) is not None:
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


def _write_marker(folder, **extra):
    from . import __version__

    write_json(Path(folder) / MARKER, {"tool": "agv-cosim", "version": __version__,
                                       **extra}, replace=True)


class _Lock:
    """An exclusive lock on ``path`` (a lock file removed on release), or OutputError.

    The lock file is opened without following a symbolic link and must be a regular
    file: a link or anything else at its place is refused, never written through.
    """

    def __init__(self, path, target):
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
        self.fd = fd

    def _same(self, fd):
        """True when ``path`` is still the file open as ``fd`` (not a link)."""
        try:
            here = os.lstat(self.path)
        except FileNotFoundError:
            return False
        mine = os.fstat(fd)
        return (here.st_dev, here.st_ino) == (mine.st_dev, mine.st_ino)

    def release(self):
        if self.fd is not None:
            if self._same(self.fd):
                self.path.unlink(missing_ok=True)
            os.close(self.fd)
            self.fd = None


class FolderLost(Exception):
    """The folder a run was writing was removed or replaced during the run."""


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
    holding only part of the runs; ``discard()`` deletes the temporary folder. Used as a
    context manager it discards on an exception and always releases the lock.
    """

    def __init__(self, target, overwrite=False):
        self.target = Path(os.path.abspath(target))
        self.overwrite = overwrite
        self.lock = None
        self.path = None
        self.identity = None
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
        self.lock = _Lock(parent / f".{name}.lock", self.target)
        try:
            self._check_target()  # again, now that no other run can change it
            self._clean_stale()
            try:
                self.path = Path(tempfile.mkdtemp(prefix=f".{name}.incomplete-",
                                                  dir=parent))
                info = os.lstat(self.path)
                self.identity = (info.st_dev, info.st_ino)
                _write_marker(self.path)
            except OSError as error:
                raise OutputError(f"{target}: cannot write here: {error.strerror}") from None
            os.chmod(self.path, user_mode())
        except BaseException:
            self.discard()
            raise

    def _check_target(self):
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

    def _clean_stale(self):
        name = self.target.name
        for pattern in (f".{name}.incomplete-*", f".{name}.old-*"):
            for stale in self.target.parent.glob(pattern):
                try:
                    info = stale.lstat()
                except OSError:
                    continue
                if stat.S_ISDIR(info.st_mode) and _marker_data(stale) is not None:
                    shutil.rmtree(stale, ignore_errors=True)

    def intact(self):
        """True while the temporary folder is the one we created (same inode, marked)."""
        if self.path is None or self.identity is None:
            return False
        try:
            info = os.lstat(self.path)
        except OSError:
            return False
        return ((info.st_dev, info.st_ino) == self.identity and stat.S_ISDIR(info.st_mode)
                and _marker_data(self.path) is not None)

    def check_intact(self):
        """Raise :class:`FolderLost` (naming the folder) unless :meth:`intact`."""
        if not self.intact():
            raise FolderLost(f"{self.target}: the folder being written ({self.path}) was "
                             "removed or replaced during the run; no result folder was "
                             "written")

    def mark_partial(self, reason, complete, total):
        """Mark the folder as holding only part of the runs: the marker says so
        (``complete: false`` and ``reason``) and ``partial.txt`` says it in words."""
        _write_marker(self.path, complete=False, reason=reason,
                      runs_complete=complete, runs=total)
        write_text(self.path / "partial.txt",
                   f"partial result: {reason}; {complete} of {total} run(s) complete "
                   "(status of each run: summary.csv)\n")

    def commit(self):
        from .lifetime import signals_blocked

        with signals_blocked():  # the renames are not cut half-way by a Ctrl-C/SIGTERM
            return self._commit()

    def _commit(self):
        self.check_intact()
        old = None
        if self.target.exists():
            self._check_target()
            # an empty folder of our own to rename the old target onto (never a name
            # that may already be someone's folder)
            old = Path(tempfile.mkdtemp(prefix=f".{self.target.name}.old-",
                                        dir=self.target.parent))
            self.target.rename(old)
            if _marker_data(old) is None:
                try:
                    _write_marker(old)  # so that a run killed now still cleans it
                except OSError:
                    pass
        self.path.rename(self.target)
        self.path = None
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
        self._release()
        return self.target

    def discard(self):
        if self.path is not None:
            if self.intact():
                shutil.rmtree(self.path, ignore_errors=True)
            self.path = None
        self._release()

    def _release(self):
        if self.lock is not None:
            self.lock.release()
            self.lock = None

    def __enter__(self):
        return self

    def __exit__(self, kind, value, traceback):
        if kind is not None:
            self.discard()
        self._release()
        return False
