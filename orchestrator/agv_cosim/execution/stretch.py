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

    k counts the macro steps completed with their exchange (the loop is at t_k).
    :attr:`bound` is the next k at which the tail has work (a recording point, a
    progress report, or the last step): a loop calls :meth:`point` when it reaches it,
    and ends a compiled stretch there; between two bounds it calls nothing.
    :meth:`stop` ends the run on a stop request, :meth:`finish` tells the progress not
    yet told.

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
        #: k of the last progress report
        self.reported = 0
        #: ``Outcome.ended_by`` and ``Outcome.stop_time`` (set by :meth:`stop`)
        self.ended_by: str | None = None
        self.stop_time: float | None = None
        #: the next k at which :meth:`point` has work: the first recording point,
        #: progress report or the last step after the k of the last :meth:`point`
        self.bound = min(every, progress_every if progress else steps, steps)

    def point(self, k: int, t: float) -> None:
        """At t_k = ``t``, k = :attr:`bound`: the row when t_k is a recording point, the
        progress report when one is due; then the next :attr:`bound`."""
        every, steps = self.every, self.steps
        if k % every == 0 or k == steps:
            self.record(t)
        bound = k + every - k % every
        if self.progress:
            if k - self.reported >= self.progress_every:
                self.report(k)
            if self.reported + self.progress_every < bound:
                bound = self.reported + self.progress_every
        self.bound = bound if bound < steps else steps

    def stop(self, k: int, t: float) -> None:
        """The macro step from t_k to ``t`` = t_{k+1} brought a stop request: the outcome,
        and when the FMU that asked reached t_{k+1} the last exchange and its row."""
        requests = self.requests
        self.ended_by, self.stop_time = ended(requests[0])
        if reached(requests[0], t):
            self.algorithm_at(k + 1).last(t, {n for n, _ in requests})
            self.record(t)

    def report(self, k: int) -> None:
        """The macro steps completed since the last report, to every progress observer."""
        for report in self.progress:
            report(k - self.reported)
        self.reported = k

    def finish(self, k: int) -> None:
        """The loop ends with k macro steps completed: the progress not yet told."""
        if self.progress and k > self.reported:
            self.report(k)
