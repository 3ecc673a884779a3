"""Measured data for ``fit``: a CSV file with a header row, a ``time`` column [s] and the
measured columns, read through :func:`agv_cosim.files.read_text` (a regular file, at
most :data:`MAX_BYTES`, UTF-8), the table checked by
:func:`agv_cosim.csvcolumns.read_columns`. Every problem is one line
(:class:`~agv_cosim.errors.FitDataError`) naming the file, and the line and column where
there is one."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..csvcolumns import read_columns
from ..errors import FitDataError, UnreadableFile
from ..files import read_text

__all__ = ["MAX_BYTES", "MeasuredData", "check_interval", "measured_data", "read_data"]

#: Largest data file read [bytes].
MAX_BYTES = 512 * 1024 * 1024
#: Fewest samples a data file must hold.
MIN_SAMPLES = 2


@dataclass(frozen=True)
class MeasuredData:
    """Measured columns on increasing time stamps: ``time`` [s], ``columns`` (name ->
    values, each as long as ``time``), ``source`` (the file, or a label, for messages)
    and ``lines`` (each sample's line in the file, for messages; 0 when not from a
    file)."""

    time: np.ndarray
    columns: dict[str, np.ndarray]
    source: str = "data"
    lines: tuple[int, ...] = ()

    def line(self, index: int) -> str:
        """Where sample ``index`` is, for a message: ``line N`` or ``sample N``."""
        if self.lines:
            return f"line {self.lines[index]}"
        return f"sample {index + 1}"


def measured_data(time: Sequence[float] | np.ndarray,
                  columns: dict[str, Sequence[float] | np.ndarray],
                  source: str = "data") -> MeasuredData:
    """Measured data from arrays, checked as a file's are (finite numbers, lengths,
    time increasing)."""
    t = np.asarray(time, dtype=float)
    cols = {name: np.asarray(values, dtype=float) for name, values in columns.items()}
    data = MeasuredData(time=t, columns=cols, source=source)
    for name, values in (("time", t), *cols.items()):
        if values.ndim != 1 or len(values) != len(t):
            raise FitDataError(f"{source}: column '{name}': {values.size} value(s), time "
                               f"has {t.size}")
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            k = int(bad[0])
            raise FitDataError(f"{source}: {data.line(k)}, column '{name}': "
                               f"{float(values[k])!r} is not a finite number")
    _check_time(data)
    return data


def read_data(path: str | Path, columns: Sequence[str], time: str = "time") -> MeasuredData:
    """The columns ``time`` and ``columns`` of the CSV file ``path`` as
    :class:`MeasuredData`; FitDataError for a file that cannot be read or is not CSV, a
    missing column, a value that is not a finite number (empty, text, NaN, inf), fewer
    than two samples, time not increasing."""
    path = Path(path)
    read = read_columns(_text(path), path, [time, *columns], FitDataError)
    if len(read.lines) < MIN_SAMPLES:
        raise FitDataError(f"{path}: {len(read.lines)} sample(s); at least {MIN_SAMPLES} "
                           "needed")
    measured = dict(read.values)
    data = MeasuredData(time=measured.pop(time), columns=measured, source=str(path),
                        lines=read.lines)
    _check_time(data)
    return data


def _text(path: Path) -> str:
    """The text of the data file ``path`` (a byte-order mark left out); FitDataError for
    a file that cannot be read, is not UTF-8 or holds binary data."""
    try:
        text = read_text(path, MAX_BYTES, "measured-data CSV file")
    except UnreadableFile as error:
        raise FitDataError(str(error)) from None
    except FileNotFoundError:
        raise FitDataError(f"{path}: not found") from None
    except OSError as error:
        raise FitDataError(f"{path}: cannot read: {error.strerror}") from None
    if text.startswith("\ufeff"):
        text = text[1:]
    if "\0" in text:
        raise FitDataError(f"{path}: not a CSV file (binary data)")
    return text


def _check_time(data: MeasuredData) -> None:
    steps = np.diff(data.time)
    bad = np.flatnonzero(~(steps > 0))
    if bad.size:
        k = int(bad[0])
        raise FitDataError(f"{data.source}: {data.line(k + 1)}, column 'time': time not "
                           f"increasing ({float(data.time[k + 1])!r} after "
                           f"{float(data.time[k])!r})")


def check_interval(data: MeasuredData, start: float, stop: float) -> None:
    """FitDataError when a time stamp of ``data`` lies outside the simulated interval
    [``start``, ``stop``] (to 1e-9 of its length): the simulation cannot be compared
    there."""
    slack = 1e-9 * max(abs(stop - start), 1.0)
    below = np.flatnonzero(data.time < start - slack)
    above = np.flatnonzero(data.time > stop + slack)
    for indices, side in ((below, "before"), (above, "after")):
        if indices.size:
            k = int(indices[0] if side == "before" else indices[-1])
            raise FitDataError(
                f"{data.source}: {data.line(k)}, column 'time': {float(data.time[k])!r} s "
                f"is {side} the simulated interval [{start!r}, {stop!r}] s (data from "
                f"{float(data.time[0])!r} to {float(data.time[-1])!r} s)")
