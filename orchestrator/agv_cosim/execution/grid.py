"""The communication points of a run: t_k = start + k step, with t_n = stop exactly.

The manifest's ``start``, ``stop`` and ``step`` are doubles, read from the decimals a
user writes (``0.1``). Summing the step, or multiplying it (``3 * 0.1`` is
``0.30000000000000004``), lands beside the decimal grid. Here the grid is computed in
exact rational arithmetic from the shortest decimals of ``start`` and ``stop`` (the
decimals written in the manifest, as ``repr`` gives them back) and the number of steps
n = (stop - start) / step (checked whole when the manifest is loaded)::

    t_k = start + k (stop - start) / n,   rounded once to the nearest double

so t_0 is ``start``, t_n is ``stop``, and with a decimal step (stop - start = n step in
decimals) every t_k is the double nearest the decimal start + k step (t_3 of step 0.1
is ``0.3``, the double a manifest's ``at = 0.3`` reads as).

The step size passed to each ``doStep`` from t_k is :meth:`Grid.step_size`: the
manifest's step where ``t_k + step`` is t_{k+1} in double arithmetic (nearly always),
otherwise a double h, from t_{k+1} - t_k, for which ``t_k + h == t_{k+1}``: an FMU that
keeps its own clock as ``currentCommunicationPoint + communicationStepSize`` (FMI 2.0
and 3.0 define the next communication point so) is at t_{k+1}, the master's next
communication point, after every step.
"""

from fractions import Fraction
from math import inf, lcm, nextafter

__all__ = ["Grid"]


class Grid:
    """The ``steps + 1`` communication points from ``start`` to ``stop`` [s]."""

    def __init__(self, start: float, stop: float, steps: int, step: float) -> None:
        if steps < 1:
            raise ValueError(f"a run has at least one step, not {steps!r}")
        first, last = Fraction(repr(float(start))), Fraction(repr(float(stop)))
        den = lcm(first.denominator, last.denominator)
        a = first.numerator * (den // first.denominator)
        b = last.numerator * (den // last.denominator)
        # t_k = (a n + (b - a) k) / (den n): a quotient of two integers, which Python
        # rounds correctly to the nearest double
        self._base = a * steps
        self._slope = b - a
        self._den = den * steps
        self.steps = steps
        self.step = float(step)

    def time(self, k: int) -> float:
        """t_k [s] (t_0 = start, t_steps = stop exactly)."""
        return (self._base + self._slope * k) / self._den

    def exact_parts(self) -> tuple[int, int, int, float] | None:
        """``(base, slope, den, step)`` with t_k = (base + slope k) / den, when every
        numerator of the run and the denominator are integers below 2**53 in magnitude
        (then exact as doubles, so one double division gives the correctly rounded t_k
        that :meth:`time` computes: the compiled loop's grid); else None."""
        limit = 2 ** 53
        ends = (abs(self._base), abs(self._base + self._slope * self.steps))
        if max(ends) >= limit or not 0 < self._den < limit:
            return None
        return self._base, self._slope, self._den, self.step

    def step_size(self, t: float, t_next: float, step: float | None = None) -> float:
        """The step size h [s] from ``t`` = t_k to ``t_next`` = t_{k+1}: the manifest's
        step when ``t + step == t_next``, else a double h with ``t + h == t_next`` found
        from their difference (the difference itself when no double reaches it).

        ``step``: a component's own step [s] instead of the manifest's, for its step
        from t_k to t_{k+m} (``t_next``), m its multiple of the manifest's step."""
        h = self.step if step is None else step
        if t + h == t_next:
            return h
        return _reaching(t, t_next)


def _reaching(t: float, t_next: float) -> float:
    """A double h > 0 with ``t + h == t_next``, starting from the difference (exact,
    hence reaching, whenever t and t_next are within a factor 2 of each other)."""
    h = t_next - t
    for _ in range(64):
        reached = t + h
        if reached == t_next:
            return h
        h = nextafter(h, inf if reached < t_next else -inf)
    return t_next - t
