"""Writing and reading results: streamed CSV time series, JSON files, the summary.

Floats are written with ``repr`` (shortest text that round-trips exactly), so a CSV read
back gives the bit-identical doubles. Output folders are assembled under a temporary name
and renamed into place at the end (:class:`AtomicDir`): an interrupted run never leaves a
folder that looks complete.
"""

import csv
import itertools
import json
import os
import re
import shutil
import tempfile
from pathlib import Path

import numpy as np


class CsvSink:
    """Stream rows of floats to ``path`` (header: ``time`` then the column names).

    Parameters
    ----------
    path : Path
    columns : list of str
        Names after ``time``.
    """

    #: Rows between flushes to disk: a run whose process dies keeps what was flushed.
    FLUSH_EVERY = 1000

    def __init__(self, path, columns, formats=None):
        self.path = Path(path)
        self.stream = open(self.path, "w", encoding="utf-8", newline="")
        self.stream.write(",".join(["time"] + list(columns)) + "\n")
        self.pending = 0
        # formats: one callable per column (value -> text, fmitypes.record_format);
        # None (every column a float) keeps the plain repr path
        self.formats = None if formats is None else [repr] + list(formats)

    def write(self, row):
        """Append one row (time, then the column values)."""
        if self.formats is None:
            text = ",".join(map(repr, map(float, row)))
        else:
            text = ",".join([f(v) for f, v in zip(self.formats, row)])
        self.stream.write(text + "\n")
        self.pending += 1
        if self.pending >= self.FLUSH_EVERY:
            self.stream.flush()
            self.pending = 0

    def close(self):
        self.stream.close()


def read_timeseries(path, columns=None):
    """Read a ``timeseries.csv`` back.

    Returns
    -------
    (numpy.ndarray, dict of str -> numpy.ndarray)
        Time [s] and the requested (default: all) columns.
    """
    path = Path(path)
    with open(path, encoding="utf-8") as stream:
        header = stream.readline().strip().split(",")
    wanted = header[1:] if columns is None else list(columns)
    index = [0] + [header.index(c) for c in wanted]
    data = np.loadtxt(path, delimiter=",", skiprows=1, usecols=index, ndmin=2)
    if data.shape[0] == 0:
        data = np.zeros((0, len(index)))
    return data[:, 0].copy(), {c: data[:, i + 1].copy() for i, c in enumerate(wanted)}


#: Rows per chunk when a ``timeseries.csv`` is read in pieces (:func:`iter_timeseries`).
#: Parsing a chunk of 10 000 rows of 10 columns peaked 6-10 MiB above one of 2 000 (as
#: fast), which showed in the peak of a long run against a short one.
CHUNK_ROWS = 2_000


def timeseries_columns(path):
    """Column names of a ``timeseries.csv`` after ``time`` (its header)."""
    with open(path, encoding="utf-8") as stream:
        return stream.readline().strip().split(",")[1:]


def iter_timeseries(path, columns=None, chunk_rows=CHUNK_ROWS):
    """Read a ``timeseries.csv`` in pieces of at most ``chunk_rows`` rows.

    Memory is bounded by the chunk, whatever the length of the file. The values are the
    doubles :func:`read_timeseries` gives (same parser); concatenating the chunks gives its
    arrays.

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
    with open(path, encoding="utf-8") as stream:
        header = stream.readline().strip().split(",")
        wanted = header[1:] if columns is None else list(columns)
        for name in wanted:
            if name not in header[1:]:
                raise ValueError(f"{path}: no column {name!r}")
        index = [0] + [header.index(c) for c in wanted]
        while True:
            lines = list(itertools.islice(stream, chunk_rows))
            if not lines:
                return
            data = np.loadtxt(lines, delimiter=",", usecols=index, ndmin=2)
            yield data[:, 0].copy(), {c: data[:, i + 1].copy() for i, c in enumerate(wanted)}


def count_rows(path):
    """Rows of a ``timeseries.csv`` after its header, counted in fixed-size blocks
    (a last line without its newline counts too)."""
    lines, last = 0, b"\n"
    with open(path, "rb") as stream:
        while block := stream.read(1 << 20):
            lines += block.count(b"\n")
            last = block[-1:]
    lines += last != b"\n"
    return max(0, lines - 1)


def write_json(path, data):
    """Write ``data`` as indented, key-sorted JSON (NaN/inf written as null)."""
    Path(path).write_text(json.dumps(_json_safe(data), indent=1, sort_keys=True) + "\n",
                          encoding="utf-8")


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
    columns = []
    for row in rows:
        for key in row:
            if key not in columns:
                columns.append(key)
    with open(path, "w", encoding="utf-8", newline="") as stream:
        writer = csv.DictWriter(stream, fieldnames=columns)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: (repr(v) if isinstance(v, float) else v)
                             for k, v in row.items()})


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


def is_result_folder(path):
    """True when ``path`` is a folder this tool wrote (marker, or the legacy layout)."""
    path = Path(path)
    if (path / MARKER).is_file():
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


def _write_marker(folder):
    from . import __version__

    (Path(folder) / MARKER).write_text(json.dumps({"tool": "agv-cosim",
                                                   "version": __version__}) + "\n")


class _Lock:
    """An exclusive lock on ``path`` (a lock file removed on release), or OutputError."""

    def __init__(self, path, target):
        import fcntl

        self.path = Path(path)
        while True:
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            except OSError as error:
                raise OutputError(f"{target}: cannot write here: {error.strerror}") from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                owner = os.read(fd, 32).decode(errors="replace").strip()
                os.close(fd)
                raise OutputError(f"{target}: another agv-cosim run is writing this folder"
                                  + (f" (process {owner})" if owner else "")
                                  + "; wait for it or choose another --out") from None
            # the file we locked may have been unlinked by its previous holder: retry
            try:
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        os.ftruncate(fd, 0)
        os.write(fd, str(os.getpid()).encode())
        self.fd = fd

    def release(self):
        if self.fd is not None:
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
      ``.<name>.old-*``, each carrying the marker) are removed first;
    - the folder gets the user's umask (``mkdtemp`` alone would make it 0700).

    ``commit()`` replaces ``target``; ``discard()`` deletes the temporary folder. Used
    as a context manager it discards on an exception and always releases the lock.
    """

    def __init__(self, target, overwrite=False):
        self.target = Path(os.path.abspath(target))
        self.overwrite = overwrite
        self.lock = None
        self.path = None
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
                if stale.is_dir() and not stale.is_symlink() and (stale / MARKER).is_file():
                    shutil.rmtree(stale, ignore_errors=True)

    def commit(self):
        from .lifetime import signals_blocked

        with signals_blocked():  # the renames are not cut half-way by a Ctrl-C/SIGTERM
            return self._commit()

    def _commit(self):
        old = None
        if self.target.exists():
            self._check_target()
            old = self.target.with_name(f".{self.target.name}.old-{os.getpid()}")
            shutil.rmtree(old, ignore_errors=True)
            self.target.rename(old)
            if not (old / MARKER).is_file():
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
