"""Observers of a run: what is done with each recorded row and with the progress.

:func:`agv_cosim.execution.simulate` calls every observer's :meth:`Observer.row` with
each recorded row (time [s], then the system's ``record`` values in order; the same list
object each time, overwritten for the next row) and :meth:`Observer.steps` with the
number of macro steps done since the last call (every 1000 steps and at the end).
"""

from collections.abc import Callable, Sequence
from typing import Any

from ..timeseries import CsvSink

__all__ = ["CsvObserver", "Observer", "ProgressObserver", "RowObserver"]


class Observer:
    """Base observer: does nothing with rows or progress."""

    def row(self, row: Sequence[Any]) -> None:
        """One recorded row (time first)."""

    def steps(self, count: int) -> None:
        """``count`` more macro steps are done."""


class CsvObserver(Observer):
    """Each row appended to a ``timeseries.csv`` (:class:`agv_cosim.timeseries.CsvSink`)."""

    def __init__(self, sink: CsvSink) -> None:
        self.sink = sink

    def row(self, row: Sequence[Any]) -> None:
        self.sink.write(row)


class RowObserver(Observer):
    """Each row passed to a function (e.g. to keep the rows in memory)."""

    def __init__(self, on_row: Callable[[Sequence[Any]], None]) -> None:
        self.on_row = on_row

    def row(self, row: Sequence[Any]) -> None:
        self.on_row(row)


class ProgressObserver(Observer):
    """The progress passed to a function (e.g. a progress bar's ``update``)."""

    def __init__(self, on_steps: Callable[[int], None]) -> None:
        self.on_steps = on_steps

    def steps(self, count: int) -> None:
        self.on_steps(count)
