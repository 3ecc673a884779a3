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

    def __init__(self, path, columns):
        self.path = Path(path)
        self.stream = open(self.path, "w", encoding="utf-8", newline="")
        self.stream.write(",".join(["time"] + list(columns)) + "\n")
        self.pending = 0

    def write(self, row):
        """Append one row (sequence of float)."""
        self.stream.write(",".join(map(repr, map(float, row))) + "\n")
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


class AtomicDir:
    """Build a folder under a temporary name beside ``target``; rename it in at the end.

    ``commit()`` replaces an existing ``target``; ``discard()`` deletes the temporary
    folder. Used as a context manager it discards on an exception.
    """

    def __init__(self, target):
        self.target = Path(target).resolve()
        self.target.parent.mkdir(parents=True, exist_ok=True)
        self.path = Path(tempfile.mkdtemp(prefix=f".{self.target.name}.incomplete-",
                                          dir=self.target.parent))

    def commit(self):
        old = None
        if self.target.exists():
            old = self.target.with_name(f".{self.target.name}.old-{os.getpid()}")
            shutil.rmtree(old, ignore_errors=True)
            self.target.rename(old)
        self.path.rename(self.target)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
        return self.target

    def discard(self):
        shutil.rmtree(self.path, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, kind, value, traceback):
        if kind is not None:
            self.discard()
        return False
