"""What the single-rate loop (:mod:`.simulation`) and the multirate loop (:mod:`.multirate`)
share: whether a stop request was reached at a communication point, the outcome it gives,
the compiled stretch of macro steps (:mod:`.compiled`'s ``run_stretch``), and the
:class:`Tail` both loops run after their macro steps (the recorded rows, the progress
reports, the end a stop request gives)."""

from __future__ import annotations

from collections.abc import Callable

from . import compiled
from .algorithm import Algorithm, Stepper, StopRequest
from .grid import Grid
from .pacing import Pacer

__all__ = ["Tail", "compiled_stretch", "ended", "reached"]


def reached(request: StopRequest, t: float) -> bool:
    """True when the FMU that asked to stop reached the communication point ``t``."""
    when = request[1]
    return when is not None and abs(when - t) <= 1e-9 * max(1.0, abs(t))


def ended(request: StopRequest) -> tuple[str, float | None]:
    """``(Outcome.ended_by, Outcome.stop_time)`` of a stop request."""
    name, when = request
    return f"{name} requested stop at t={when!r} s", when


def compiled_stretch(algorithm: Algorithm, stepper: Stepper, grid: Grid,
             pace: Pacer | None) -> Callable[[int, int], int] | None:
    """``run(k0, k1)``: macro steps k0 .. k1 - 1 (step, then exchange) in C, returning
    how many were completed with their exchange (fewer when a step brought a stop
    request: that step is made, its exchange is not); None when the run cannot use it.

    The compiled loop (:func:`agv_cosim.execution.compiled.module`'s ``run_stretch``)
    is used when the stepper and the algorithm's exchange are compiled programs (every
    unit an FMI 2.0 / 3.0 co-simulation FMU or a table, called without fmpy's wrapper:
    :mod:`.programs`), the run is not paced and its time grid is exact in doubles
    (:meth:`.grid.Grid.exact_parts`). Otherwise every macro step runs in Python.
    """
    exchanges = getattr(algorithm, "exchanges", None)
    program = getattr(stepper, "compiled", None)
    parts = grid.exact_parts()
    module = compiled.module()
    if pace is not None or exchanges is None or program is None or parts is None or \
            module is None:
        return None
    run_stretch, requests = module.run_stretch, stepper.requests

    def run(k0: int, k1: int) -> int:
        ran: int = run_stretch(program, exchanges, parts, k0, k1, requests)
        return ran

    return run


class Tail:
    """What a loop does after its macro steps, the same in the single-rate loop
    (:func:`agv_cosim.execution.simulation._loop`) and the multirate one
    (:func:`agv_cosim.execution.multirate.run_multirate`): the row at every recording
    point (every ``every``-th macro step, and the last), a progress report to each of
    ``progress`` every ``progress_every`` macro steps (and the remainder at the end), and
    the end of the run a stop request gives.

    A loop calls :meth:`point` once per stretch of macro steps completed with their
    exchange (one macro step in Python, or a compiled stretch), :meth:`stop` when a stop
    request came, :meth:`finish` when it leaves; :meth:`end` bounds a compiled stretch so
    that it ends at the next recording point or progress report.

    ``requests``: the steppers' stop requests (the list a step appends to);
    ``algorithm_at(k)``: the algorithm whose :meth:`~.algorithm.Algorithm.last` exchange
    ends a run stopped at t_k (asked for only when the FMU reached t_k).
    """

    def __init__(self, steps: int, every: int, record: Callable[[float], None],
                 progress: list[Callable[[int], None]], progress_every: int,
                 requests: list[StopRequest],
                 algorithm_at: Callable[[int], Algorithm]) -> None:
        self.steps, self.every, self.record = steps, every, record
        self.progress, self.progress_every = progress, progress_every
        self.requests, self.algorithm_at = requests, algorithm_at
        #: macro steps done since the last progress report
        self.done = 0
        #: ``Outcome.ended_by`` and ``Outcome.stop_time`` (set by :meth:`stop`)
        self.ended_by: str | None = None
        self.stop_time: float | None = None

    def end(self, k: int, next_event: int, last: int) -> int:
        """The end (exclusive) of a stretch of macro steps from k: at most ``last``, at
        the next recording point, progress report, and before the scenario's next event
        step ``next_event`` when it lies ahead (that macro step runs in Python)."""
        every = self.every
        end = min(last, k + every - k % every,
                  k + self.progress_every - self.done if self.progress else last)
        if next_event > k + 1:
            end = min(end, next_event - 1)
        return end

    def point(self, k: int, t: float, ran: int) -> None:
        """``ran`` more macro steps completed with their exchange, the last to t_k = ``t``:
        the row when t_k is a recording point, the progress report when one is due."""
        if k % self.every == 0 or k == self.steps:
            self.record(t)
        if self.progress:
            self.done += ran
            if self.done >= self.progress_every:
                self.report()

    def stop(self, k: int, t: float, ran: int = 0) -> None:
        """The macro step to t_k = ``t`` brought a stop request (after ``ran`` macro steps
        completed with their exchange): the outcome, and when the FMU that asked reached
        t_k the last exchange and its row."""
        requests = self.requests
        if self.progress:
            self.done += ran
        self.ended_by, self.stop_time = ended(requests[0])
        if reached(requests[0], t):
            self.algorithm_at(k).last(t, {n for n, _ in requests})
            self.record(t)

    def report(self) -> None:
        """The macro steps done since the last report, to every progress observer."""
        for report in self.progress:
            report(self.done)
        self.done = 0

    def finish(self) -> None:
        """The macro steps not yet reported, when the loop ends."""
        if self.progress and self.done:
            self.report()
