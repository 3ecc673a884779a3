"""What the single-rate loop (:mod:`.simulation`) and the multirate loop (:mod:`.multirate`)
share: whether a stop request was reached at a communication point, the outcome it gives,
and the compiled stretch of macro steps (:mod:`.compiled`'s ``run_stretch``)."""

from __future__ import annotations

from collections.abc import Callable

from . import compiled
from .algorithm import Algorithm, Stepper, StopRequest
from .grid import Grid
from .pacing import Pacer


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
