"""The one sampling rule of every sampled component (controllers and sensors).

Convention (written once here and in components/README.md, "Sampling"):

- Sample instants are t_k = k T for whole k (absolute time, k computed from time, never
  accumulated), or a sensor's own schedule (the total station's jittered fixes).
- The master holds every input constant over a communication step [t, t + h). The
  sample of instant t_k is taken from the input *held at t_k*: an instant belongs to the
  step [t, t + h) when ``t - TIME_EPS <= t_k < t + h - TIME_EPS``
  (:func:`in_step`). So an instant on a communication point t (within
  :data:`TIME_EPS`) is sampled from the inputs set at t, and an instant inside a step
  from the inputs held over that step (those set at its start), whatever the step size.
- On a communication point that is a sample instant, the output shown at t is the
  sample of t computed from the current inputs, and it is computed again at every
  further call at that same time (a Gauss-Seidel master or an initialisation exchange
  may set newer inputs at the same instant); the step from t commits the last one.
- Between instants the newest committed sample is held. Before the first sample (a
  start between instants), the first call's inputs are sampled and held.
- T = 0: no hold; the law is evaluated at every call.

:class:`SampleHold` implements it for the controllers: memoryless laws, and laws with
memory from sample to sample (``memory=True``: the law reads :attr:`SampleHold.prior`,
the committed sample before the one being computed; every instant of a step is then
evaluated in turn, each from the same held inputs). The sampled sensors
(agv_core.sensors) add latency and noise to the same instants and the same
:func:`in_step` / :func:`at_instant` tests.
"""

import math
from collections.abc import Callable, Sequence
from typing import Any

#: Time tolerance [s]: two instants closer than this are the same instant (1 ns: far
#: above the rounding of t = start + k h in doubles for any run shorter than ~1e6 s,
#: far below any step or period used).
TIME_EPS = 1e-9


def at_instant(t_k: float, t: float) -> bool:
    """True when the instant ``t_k`` [s] is the communication point ``t`` [s]."""
    return abs(t_k - t) <= TIME_EPS


def in_step(t_k: float, t: float, h: float) -> bool:
    """True when the instant ``t_k`` [s] is sampled in the step [t, t + h) [s]."""
    return t - TIME_EPS <= t_k < t + h - TIME_EPS


def last_index(t: float, period: float) -> int:
    """k of the newest instant k ``period`` at or before ``t`` [s] (within TIME_EPS)."""
    return math.floor((t + TIME_EPS) / period)


class SampleHold:
    """Sample-and-hold of a memoryless law at t_k = k ``period`` (see the module rule).

    Parameters
    ----------
    period : float
        Sample period T [s], >= 0 (0: no hold, every call evaluates).
    memory : bool
        True for a law with memory (an integral, the previous command): the law reads
        :attr:`prior`, the value of the newest sample before the one it computes (None
        before the second sample), so a re-evaluation at the same instant starts from
        the same memory, and :meth:`step` evaluates every instant of a step that holds
        several (a memoryless law needs only the newest). Needs ``period`` > 0.

    Notes
    -----
    The owner calls :meth:`output` from its output function and :meth:`step` from its
    step function, each with the current (held) inputs as a tuple and the law
    ``law(*inputs)``. The step from an instant t commits the sample of t from the inputs
    held over the step; the value shown at t is reused when it was computed from those
    same inputs (the law is not evaluated twice for one sample).
    """

    def __init__(self, period: float, memory: bool = False) -> None:
        self.period = float(period)
        self.memory = bool(memory)
        if self.memory and not self.period > 0.0:
            raise ValueError("a law with memory needs a sample period > 0")
        self.value: Any = None    # the value shown (held, or tentative at an instant)
        self.index: int | None = None  # k of the held (or tentative) sample; None before any
        self.inputs: tuple[Any, ...] | None = None  # the inputs ``value`` was computed from
        self.prior: Any = None    # the sample before ``index`` (memory=True); None before

    def _evaluate(self, law: Callable[..., Any], inputs: Sequence[Any], index: int) -> Any:
        if self.index is not None and index != self.index:
            self.prior = self.value          # a new instant: the held sample is now past
        self.value = law(*inputs)
        self.inputs = tuple(inputs)
        self.index = index
        return self.value

    def output(self, t: float, inputs: Sequence[Any], law: Callable[..., Any]) -> Any:
        """The value at ``t`` [s] for the current ``inputs``."""
        if self.period == 0.0:
            return law(*inputs)
        k = last_index(t, self.period)
        if at_instant(k * self.period, t) or self.value is None:
            return self._evaluate(law, inputs, k)  # tentative at an instant, per call
        return self.value

    def step(self, t: float, h: float, inputs: Sequence[Any], law: Callable[..., Any]
             ) -> None:
        """Commit the samples of the step from ``t`` to ``t + h`` [s], ``inputs`` held.

        Every instant of the step sees the same held inputs, so for a memoryless law
        only the newest matters; a law with memory is evaluated at each in turn.
        """
        if self.period == 0.0:
            return
        newest = last_index(t + h - 2.0 * TIME_EPS, self.period)
        if not in_step(newest * self.period, t, h):
            return                           # no instant in this step: hold
        first = newest
        if self.memory:
            while in_step((first - 1) * self.period, t, h):
                first -= 1
        inputs = tuple(inputs)
        for index in range(first, newest + 1):
            if self.index == index and self.inputs == inputs:
                continue                     # shown at t from these very inputs
            self._evaluate(law, inputs, index)

    def get_state(self) -> dict[str, Any]:
        """JSON-safe snapshot."""
        return {"value": self.value, "index": self.index, "prior": self.prior,
                "inputs": None if self.inputs is None else list(self.inputs)}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a snapshot from :meth:`get_state`."""
        self.value, self.index, self.prior = state["value"], state["index"], state["prior"]
        self.inputs = None if state["inputs"] is None else tuple(state["inputs"])
