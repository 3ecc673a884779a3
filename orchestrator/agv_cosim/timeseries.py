"""The run's time series file, ``timeseries.csv``: written row by row, read back whole or
in chunks.

Floats are written with ``repr`` (shortest text that round-trips exactly), so a CSV read
back gives the bit-identical doubles. The header is written and read by the csv module,
so any FMI variable name (commas, quotes, line breaks) reads back exactly.
"""

import csv
import hashlib
import itertools
import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np

from .files import csv_line
from .lifetime import CREATE_FLAGS

__all__ = ["CHUNK_ROWS", "CsvSink", "count_rows", "iter_timeseries", "read_timeseries",
           "timeseries_columns"]


class CsvSink:
    """Stream rows of values to ``path`` (header: ``time`` then the column names).

    The header is written by the csv module, so any FMI variable name (commas, quotes,
    line breaks) reads back exactly (:func:`timeseries_columns`). Each row goes to the
    file in one ``write`` call, unbuffered: a run whose process dies keeps every row it
    recorded (the kernel holds what was written). ``bytes`` counts what was written,
    :meth:`sha256` is the SHA-256 of it (run.json's ``timeseries_sha256``).

    Parameters
    ----------
    path : Path
    columns : list of str
        Names after ``time``.
    formats : list of callable, optional
        One per column (value -> text, :func:`agv_cosim.fmitypes.record_format`); None
        when every column is a float (written with ``repr``).
    """

    def __init__(self, path: str | Path, columns: Sequence[str],
                 formats: Sequence[Callable[[Any], str]] | None = None) -> None:
        self.path = Path(path)
        self.fd: int | None = os.open(self.path, CREATE_FLAGS, 0o666)
        self.bytes = 0
        self._digest = hashlib.sha256()
        #: rows written
        self.rows = 0
        # formats: one callable per column (value -> text, fmitypes.record_format);
        # None (every column a float) keeps the plain repr path
        self.formats = None if formats is None else [repr] + list(formats)
        self._write(csv_line(["time"] + list(columns)).encode("utf-8"))

    def _write(self, data: bytes) -> None:
        fd = self.fd
        assert fd is not None, "write after close"
        view = memoryview(data)
        while view:
            done = os.write(fd, view)
            self._digest.update(view[:done])
            view = view[done:]
            self.bytes += done

    def write(self, row: Sequence[Any]) -> None:
        """Append one row (time, then the column values)."""
        if self.formats is None:
            text = ",".join(map(repr, map(float, row)))
        else:
            text = ",".join([f(v) for f, v in zip(self.formats, row)])
        self._write((text + "\n").encode("utf-8"))
        self.rows += 1

    def sha256(self) -> str:
        """SHA-256 (hex) of the bytes written so far."""
        return self._digest.hexdigest()

    def close(self) -> None:
        if self.fd is not None:
            fd, self.fd = self.fd, None
            os.close(fd)


def read_timeseries(path: str | Path, columns: Iterable[str] | None = None
                    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Read a ``timeseries.csv`` back (whole; :func:`iter_timeseries` reads in pieces).

    Returns
    -------
    (numpy.ndarray, dict of str -> numpy.ndarray)
        Time [s] and the requested (default: all) columns.
    """
    wanted = timeseries_columns(path) if columns is None else list(columns)
    times: list[np.ndarray] = []
    data: dict[str, list[np.ndarray]] = {c: [] for c in wanted}
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


def _header(stream: IO[str]) -> list[str]:
    """The header record of a ``timeseries.csv`` opened as text (csv module: a quoted
    name may hold commas, quotes and line breaks); the stream is left after it."""
    try:
        return next(csv.reader(stream))
    except StopIteration:
        return []


def timeseries_columns(path: str | Path) -> list[str]:
    """Column names of a ``timeseries.csv`` after ``time`` (its header)."""
    with open(path, encoding="utf-8", newline="") as stream:
        return _header(stream)[1:]


def _records(stream: IO[str], count: int) -> tuple[list[str], bool]:
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


def iter_timeseries(path: str | Path, columns: Iterable[str] | None = None,
                    chunk_rows: int = CHUNK_ROWS
                    ) -> Iterator[tuple[np.ndarray, dict[str, np.ndarray]]]:
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


def _header_end(stream: IO[bytes]) -> int:
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


def count_rows(path: str | Path) -> int:
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
