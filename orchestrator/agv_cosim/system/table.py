"""Input from a CSV time table: a component without an FMU (``[components.X] table = ...``).

The file has a header ``time,<name>,<name>...`` and one row per instant: time [s]
strictly increasing, every value a finite number (like the Reference FMUs' ``_in.csv``
and fmpy's ``input``). Each column becomes a Real (FMI 2.0 kind float64) output
``X.<name>`` without inputs, so it can feed any Real/Float64 input, be recorded and be
plotted. Its value at a communication point t:

``linear`` (default)
    linear interpolation between the two rows around t;
``hold``
    the value of the last row with time <= t (zero-order hold: a step is the new value
    written at the switch time; times must strictly increase).

Before the first row a column holds its first value, after the last row its last value.
Interpolation is chosen per column (``interpolation = { <name> = "hold" }``), and so is the
unit a connection checks (``units = { <name> = "rad" }``; default none = dimensionless).
"""

import bisect
import csv
import io
import math
from collections.abc import MutableSequence
from pathlib import Path

from ..errors import TableError, UnreadableFile
from ..files import CSV_LIMIT, read_bytes
from .model import ModelInfo, Variable, file_sha256

MODES = ("linear", "hold")


class Table:
    """Columns of a time table, evaluated at a time [s] (see the module docstring)."""

    def __init__(self, path: str | Path, interpolation: dict[str, str] | None = None) -> None:
        self.path = Path(path)
        interpolation = dict(interpolation or {})
        rows = self._read_rows()
        self.names = self._column_names(rows)
        self.modes = self._modes(interpolation)
        self.times: list[float] = []
        self.columns: list[list[float]] = [[] for _ in self.names]
        for number, row in enumerate(rows[1:], start=2):
            if row:
                self._add_row(number, row, len(rows[0]))
        if not self.times:
            raise TableError(f"'{self.path}': no rows")

    def _read_rows(self) -> list[list[str]]:
        """The file's rows (CSV fields), read non-blocking and at most CSV_LIMIT bytes
        (files.read_bytes)."""
        if self.path.exists() and not self.path.is_file():  # a FIFO would block a read
            raise TableError(f"'{self.path}' is not a regular file")
        try:
            data = read_bytes(self.path, CSV_LIMIT)
            return list(csv.reader(io.StringIO(data.decode("utf-8"), newline="")))
        except OSError as error:
            raise TableError(f"cannot read '{self.path}': {error.strerror}") from None
        except UnreadableFile as error:
            raise TableError(f"'{self.path}' {error.problem}") from None
        except UnicodeDecodeError:
            raise TableError(f"'{self.path}' is not UTF-8 text") from None

    def _column_names(self, rows: list[list[str]]) -> list[str]:
        """The column names of the header ``time,<column>,...`` (distinct, non-empty)."""
        if not rows or not rows[0] or rows[0][0].strip() != "time" or len(rows[0]) < 2:
            raise TableError(f"'{self.path}': the header must be 'time,<column>,...'")
        names = [name.strip() for name in rows[0][1:]]
        if len(set(names)) != len(names) or not all(names):
            raise TableError(f"'{self.path}': column names must be distinct and non-empty")
        return names

    def _modes(self, interpolation: dict[str, str]) -> list[str]:
        """Each column's interpolation (default linear), ``interpolation`` checked."""
        unknown = set(interpolation) - set(self.names)
        if unknown:
            raise TableError(f"interpolation: no column '{sorted(unknown)[0]}' in "
                             f"'{self.path}' (columns: {', '.join(self.names)})")
        for name, mode in interpolation.items():
            if mode not in MODES:
                raise TableError(f"interpolation.{name}: {mode!r} is not one of "
                                 f"{', '.join(MODES)}")
        return [interpolation.get(name, "linear") for name in self.names]

    def _add_row(self, number: int, row: list[str], fields: int) -> None:
        """The row at line ``number`` appended to the times and columns, checked: as many
        fields as the header's ``fields``, finite numbers, its time after the last."""
        if len(row) != fields:
            raise TableError(f"'{self.path}' line {number}: {len(row)} fields, the "
                             f"header has {fields}")
        try:
            values = [float(text) for text in row]
        except ValueError:
            raise TableError(f"'{self.path}' line {number}: not a number in "
                             f"{row!r}") from None
        if not all(math.isfinite(v) for v in values):
            raise TableError(f"'{self.path}' line {number}: a value is not finite")
        if self.times and values[0] <= self.times[-1]:
            raise TableError(f"'{self.path}' line {number}: time {values[0]!r} is not "
                             f"after {self.times[-1]!r} (times must increase)")
        self.times.append(values[0])
        for column, value in zip(self.columns, values[1:]):
            column.append(value)

    def values_at(self, t: float, out: MutableSequence[float]) -> None:
        """Write every column's value at ``t`` [s] into ``out`` (a sequence)."""
        times = self.times
        i = bisect.bisect_right(times, t)  # times[i - 1] <= t < times[i]
        last = len(times) - 1
        for j, (column, mode) in enumerate(zip(self.columns, self.modes)):
            if i == 0:
                out[j] = column[0]
            elif i > last:
                out[j] = column[last]
            elif mode == "hold":
                out[j] = column[i - 1]
            else:
                t0, t1 = times[i - 1], times[i]
                v0, v1 = column[i - 1], column[i]
                out[j] = v0 + (v1 - v0) * ((t - t0) / (t1 - t0))


def read_table(path: str | Path, interpolation: dict[str, str] | None = None,
               units: dict[str, str] | None = None) -> ModelInfo:
    """A :class:`~agv_cosim.system.model.ModelInfo` for a time table (``info.table`` set)."""
    table = Table(path, interpolation)
    units = dict(units or {})
    unknown = set(units) - set(table.names)
    if unknown:
        raise TableError(f"units: no column '{sorted(unknown)[0]}' in '{path}'")
    path = Path(path).resolve()
    info = ModelInfo(path=path, sha256=file_sha256(path), model_name="time table",
                     identifier="", guid="", description=f"time table {path.name}")
    for vr, (name, mode) in enumerate(zip(table.names, table.modes)):
        info.variables[name] = Variable(name=name, vr=vr, type="Real", causality="output",
                                        variability="continuous", unit=units.get(name),
                                        description=f"column '{name}' ({mode})", start=None)
        info.dependencies[name] = []
    info.table = table
    return info
