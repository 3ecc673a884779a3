"""Reading a measured record (CSV) for ``agv-cosim identify``: three columns as float
arrays (the table checked by :func:`agv_cosim.csvcolumns.read_columns`), every problem
one line naming the file, the row and the column."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..csvcolumns import read_columns as read_csv_columns
from ..errors import IdentifyError

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
    """The columns ``names`` of the CSV file ``path`` (a header row of at least two
    fields, then one row per sample: :func:`agv_cosim.csvcolumns.read_columns`) as float
    arrays, and each sample's line number; IdentifyError for a file that is not CSV, a
    missing column, a value that is not a finite number."""
    path = Path(path)
    read = read_csv_columns(_text(path), path, names, IdentifyError, min_fields=2)
    return [read.values[name] for name in names], list(read.lines)


def check_time(path: str | Path, time: np.ndarray, name: str, lines: list[int]) -> None:
    """IdentifyError naming the line where ``time`` does not increase."""
    steps = np.diff(time)
    bad = np.flatnonzero(~(steps > 0))
    if bad.size:
        k = int(bad[0])
        raise IdentifyError(f"{path}: column '{name}': time not increasing at line "
                            f"{lines[k + 1]} "
                            f"({float(time[k + 1])!r} after {float(time[k])!r})")
