"""Reading a measured record (CSV) for ``agv-cosim identify``: three columns as float
arrays, every problem one line naming the file, the row and the column."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from ..errors import IdentifyError, did_you_mean

#: Largest file read [bytes].
MAX_BYTES = 512 * 1024 * 1024


def _text(path: Path) -> str:
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise IdentifyError(f"{path}: not found") from None
    except OSError as error:
        raise IdentifyError(f"{path}: cannot read: {error.strerror}") from None
    if not path.is_file():
        raise IdentifyError(f"{path}: not a file")
    if size > MAX_BYTES:
        raise IdentifyError(f"{path}: {size} bytes, more than the {MAX_BYTES} read")
    try:
        raw = path.read_bytes()
    except OSError as error:
        raise IdentifyError(f"{path}: cannot read: {error.strerror}") from None
    if b"\0" in raw:
        raise IdentifyError(f"{path}: not a CSV file (binary data)")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        raise IdentifyError(f"{path}: not a CSV file (not UTF-8 text at byte "
                            f"{error.start})") from None


def read_columns(path: str | Path, names: list[str]) -> tuple[list[np.ndarray], list[int]]:
    """The columns ``names`` of the CSV file ``path`` (a header row, then one row per
    sample) as float arrays, and each sample's line number; IdentifyError for a file
    that is not CSV, a missing column, a value that is not a finite number."""
    path = Path(path)
    text = _text(path)
    rows = csv.reader(text.splitlines())
    try:
        header = next(rows)
    except StopIteration:
        raise IdentifyError(f"{path}: empty, not a CSV file with a header row") from None
    except csv.Error as error:
        raise IdentifyError(f"{path}: not a CSV file ({error})") from None
    header = [h.strip() for h in header]
    if len(header) < 2:
        raise IdentifyError(f"{path}: not a CSV file with a header row of column names "
                            f"(line 1 holds {len(header)} field)")
    index = {}
    for name in names:
        if name not in header:
            raise IdentifyError(f"{path}: no column '{name}'{did_you_mean(name, header)} "
                                f"(columns: {', '.join(header)})")
        index[name] = header.index(name)
    columns: list[list[float]] = [[] for _ in names]
    lines: list[int] = []
    line = 1
    try:
        for line, row in enumerate(rows, start=2):
            if not row or all(not f.strip() for f in row):
                continue
            if len(row) != len(header):
                raise IdentifyError(f"{path}: line {line}: {len(row)} field(s), the header "
                                    f"has {len(header)}: not a CSV table")
            for out, name in zip(columns, names):
                text_value = row[index[name]].strip()
                try:
                    value = float(text_value)
                except ValueError:
                    raise IdentifyError(f"{path}: line {line}, column '{name}': "
                                        f"{text_value!r} is not a number") from None
                if not math.isfinite(value):
                    raise IdentifyError(f"{path}: line {line}, column '{name}': "
                                        f"{text_value!r} is not a finite number")
                out.append(value)
            lines.append(line)
    except csv.Error as error:
        raise IdentifyError(f"{path}: line {line}: not a CSV file ({error})") from None
    return [np.array(c, dtype=float) for c in columns], lines


def check_time(path: str | Path, time: np.ndarray, name: str, lines: list[int]) -> None:
    """IdentifyError naming the line where ``time`` does not increase."""
    steps = np.diff(time)
    bad = np.flatnonzero(~(steps > 0))
    if bad.size:
        k = int(bad[0])
        raise IdentifyError(f"{path}: column '{name}': time not increasing at line "
                            f"{lines[k + 1]} "
                            f"({float(time[k + 1])!r} after {float(time[k])!r})")
