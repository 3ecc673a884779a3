"""Numeric columns of a CSV table, checked field by field, for the commands that read
measured data (``fit``: :mod:`agv_cosim.fitting.data`, ``identify``:
:mod:`agv_cosim.identification.data`): a header row naming the columns, then one row per
sample, blank rows skipped. Every problem is one line naming the source, and the line
and the column where there is one, raised as the caller's error class."""

from __future__ import annotations

import csv
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import AgvCosimError, did_you_mean

__all__ = ["Columns", "read_columns"]


@dataclass(frozen=True)
class Columns:
    """Columns read from a CSV text: ``values`` (name -> float array, one value per
    sample, each name once, in the order asked) and ``lines`` (each sample's line in the
    text, the header being line 1)."""

    values: dict[str, np.ndarray]
    lines: tuple[int, ...]


def read_columns(text: str, source: str | Path, names: Sequence[str],
                 error: type[AgvCosimError], min_fields: int = 0) -> Columns:
    """The columns ``names`` of the CSV ``text`` (a header row, then one row per sample;
    rows with no field or only blank fields skipped). ``error``, its message starting
    with ``source``, for a text the csv module cannot read, a header row of fewer than
    ``min_fields`` fields, a column not in the header (with the closest name), a row
    with more or fewer fields than the header, a field that is not a number or not
    finite."""
    rows = csv.reader(text.splitlines())
    header = _header(rows, source, error, min_fields)
    index = _index(header, names, source, error)
    values: dict[str, list[float]] = {name: [] for name in index}
    lines: list[int] = []
    try:
        for line, row in enumerate(rows, start=2):
            if not row or all(not field.strip() for field in row):
                continue
            if len(row) != len(header):
                raise error(f"{source}: line {line}: {len(row)} field(s), the header has "
                            f"{len(header)}: not a CSV table")
            for name, column in index.items():
                values[name].append(_number(row[column], source, line, name, error))
            lines.append(line)
    except csv.Error as problem:
        # the line the csv module was reading when it failed (the last line it fetched)
        raise error(f"{source}: line {rows.line_num}: not a CSV file ({problem})") from None
    return Columns(values={name: np.array(v, dtype=float) for name, v in values.items()},
                   lines=tuple(lines))


def _header(rows: Iterator[list[str]], source: str | Path, error: type[AgvCosimError],
            min_fields: int) -> list[str]:
    """The header row's fields, stripped."""
    try:
        header = [name.strip() for name in next(rows)]
    except StopIteration:
        raise error(f"{source}: empty, not a CSV file with a header row") from None
    except csv.Error as problem:
        raise error(f"{source}: not a CSV file ({problem})") from None
    if len(header) < min_fields:
        raise error(f"{source}: not a CSV file with a header row of column names (line 1 "
                    f"holds {len(header)} field)")
    return header


def _index(header: list[str], names: Sequence[str], source: str | Path,
           error: type[AgvCosimError]) -> dict[str, int]:
    """Each of ``names`` (once, in order) -> its field in ``header``."""
    index: dict[str, int] = {}
    for name in dict.fromkeys(names):
        if name not in header:
            raise error(f"{source}: no column '{name}'{did_you_mean(name, header)} "
                        f"(columns: {', '.join(header)})")
        index[name] = header.index(name)
    return index


def _number(field: str, source: str | Path, line: int, name: str,
            error: type[AgvCosimError]) -> float:
    """The finite number written in ``field`` (surrounding blanks ignored)."""
    text = field.strip()
    try:
        number = float(text)
    except ValueError:
        raise error(f"{source}: line {line}, column '{name}': {text!r} is not a "
                    "number") from None
    if not math.isfinite(number):
        raise error(f"{source}: line {line}, column '{name}': {text!r} is not a finite "
                    "number")
    return number
