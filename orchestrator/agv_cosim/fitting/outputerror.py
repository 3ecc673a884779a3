"""Output-error least squares: the parameters of a simulation fitted so that its signals
match measured data (issue 34's ``fit``), on a ``simulate`` callable (no files, no
manifest).

``simulate(batch)`` takes a list of parameter vectors (in the order of the parameters)
and returns, for each, ``{signal: (time, values)}``: a batch so that the runs one
iteration needs (the finite-difference Jacobian's columns) can run in parallel.

- **Residuals** at the data's time stamps: the simulated signal is interpolated linearly
  between its samples; where the simulation recorded one time twice (an event), the
  value at that time is the later one, and before it the segment runs to the earlier.
  When the data's stamps are output points of the simulation (a co-simulation step that
  divides them) nothing is interpolated. A data stamp outside the simulated signal's
  time raises FitError.
- **Weights**: the residual of signal ``s`` at every stamp is ``w_s (simulated -
  measured)``; by default ``w_s = 1 / std(measured column)``, so that signals in
  different units count by their number of samples, not their units; ``weights``
  overrides it per signal (a positive number, in 1/the signal's unit).
- **Solver**: ``scipy.optimize.least_squares``, trust-region reflective (``"trf"``) with
  the bounds, ``x_scale="jac"``; its Jacobian by forward differences computed as one
  batch (step ``relative_step * max(|x|, 1e-3 (max - min))``, taken backward at the
  upper bound).
- **Standard errors** from the Jacobian ``J`` of the weighted residuals at the optimum
  (central differences, one batch of ``2 p`` runs): ``C = (J^T J)^-1 J^T D J
  (J^T J)^-1``, ``D`` diagonal holding, for the rows of signal ``s``, its weighted
  residuals' variance ``sum(r_s^2) / (n_s (1 - p / n))``. With one signal (or equal
  variances) this is the usual ``sigma^2 (J^T J)^-1``; with several it stays right when
  the weights are not the inverse noise levels. It assumes white noise of constant
  variance on each signal. A parameter at a bound, or one the data do not determine
  (its column of J zero or in J's null space), gets no standard error but a reason;
  the others' covariance is taken with it held.
- **Not converged** (the solver's budget ``max_nfev`` ran out): the best point found is
  kept, ``converged`` is False and no standard error is given (the formula holds only
  at an optimum); :meth:`FitResult.check_converged` raises
  :class:`~agv_cosim.errors.FitNotConverged` carrying the result.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import FitError, FitNotConverged
from .data import MeasuredData
from .parameters import Parameter, check_parameters

__all__ = ["FitResult", "Signal", "Simulate", "default_weights", "fit", "interpolate"]

#: One simulated signal: (time [s], values).
Signal = tuple[np.ndarray, np.ndarray]
#: The simulation: a batch of parameter vectors -> for each, {signal: (time, values)}.
Simulate = Callable[[list[np.ndarray]], Sequence[Mapping[str, Signal]]]

#: The solver's statuses that mean converged (scipy.optimize.least_squares).
_CONVERGED = {1: "gradient small (gtol)", 2: "cost change small (ftol)",
              3: "step small (xtol)", 4: "cost and step changes small (ftol, xtol)"}


@dataclass
class FitResult:
    """What a fit found.

    ``values`` and ``stderr`` per parameter (stderr None with a ``reasons`` entry where
    there is none), ``correlation`` (rows and columns in the parameters' order, None
    where a parameter has no standard error), ``cost`` (half the sum of squared weighted
    residuals), ``iterations`` (the solver's Jacobian evaluations), ``evaluations`` (its
    function evaluations), ``runs`` (simulations, all batches), ``converged`` and
    ``message``; ``weights`` used, and at the data's stamps the ``fitted`` signals and
    ``residuals`` (simulated - measured, in the data's units), ``rms`` of each."""

    names: tuple[str, ...]
    start: dict[str, float]
    values: dict[str, float]
    stderr: dict[str, float | None]
    reasons: dict[str, str]
    correlation: list[list[float | None]]
    cost: float
    iterations: int
    evaluations: int
    runs: int
    converged: bool
    message: str
    weights: dict[str, float]
    signals: dict[str, str]
    fitted: dict[str, np.ndarray] = field(repr=False)
    residuals: dict[str, np.ndarray] = field(repr=False)
    rms: dict[str, float] = field(default_factory=dict)

    def as_json(self) -> dict[str, Any]:
        """fit.json's content: ``{"parameters": {name: {"value", "stderr"[, "reason"]}},
        "correlation": {"names", "matrix"}, "cost", "iterations", "evaluations", "runs",
        "converged", "message", "weights", "rms", "start"}``."""
        parameters: dict[str, dict[str, Any]] = {}
        for name in self.names:
            entry: dict[str, Any] = {"value": self.values[name],
                                     "stderr": self.stderr[name]}
            if name in self.reasons:
                entry["reason"] = self.reasons[name]
            parameters[name] = entry
        return {"parameters": parameters,
                "correlation": {"names": list(self.names), "matrix": self.correlation},
                "cost": self.cost, "iterations": self.iterations,
                "evaluations": self.evaluations, "runs": self.runs,
                "converged": self.converged, "message": self.message,
                "weights": dict(self.weights), "rms": dict(self.rms),
                "start": dict(self.start)}

    def check_converged(self) -> None:
        """FitNotConverged (carrying this result) when the fit did not converge."""
        if not self.converged:
            raise FitNotConverged(f"fit: not converged ({self.message}); the best point "
                                  "found is kept, marked not converged", result=self)


def default_weights(data: MeasuredData, signals: Mapping[str, str]) -> dict[str, float]:
    """``1 / std`` of each signal's measured column; FitError for a constant column."""
    out = {}
    for signal, column in signals.items():
        spread = float(np.std(data.columns[column]))
        if not spread > 0.0:
            raise FitError(f"fit: signal '{signal}': measured column '{column}' is "
                           f"constant ({float(data.columns[column][0])!r}): its default "
                           "weight 1/spread does not exist; give it a weight")
        out[signal] = 1.0 / spread
    return out


def interpolate(signal: Signal, at: np.ndarray, name: str = "signal") -> np.ndarray:
    """``signal`` (time, values) linearly interpolated at the times ``at`` (the later
    value at a time recorded twice); FitError for a signal that is not two arrays of one
    length, time decreasing, a value not finite, or a time of ``at`` outside the
    signal's time (to 1e-9 of its length)."""
    try:
        t = np.asarray(signal[0], dtype=float)
        y = np.asarray(signal[1], dtype=float)
    except (TypeError, ValueError, IndexError):
        raise FitError(f"fit: simulated signal '{name}': not a pair (time, values) of "
                       "numbers") from None
    if t.ndim != 1 or y.shape != t.shape or t.size == 0:
        raise FitError(f"fit: simulated signal '{name}': time ({t.size}) and values "
                       f"({y.size}) are not two arrays of one length")
    if not np.all(np.isfinite(t)):
        raise FitError(f"fit: simulated signal '{name}': time not finite")
    if np.any(np.diff(t) < 0):
        raise FitError(f"fit: simulated signal '{name}': time decreasing")
    slack = 1e-9 * max(float(t[-1] - t[0]), 1.0)
    if at[0] < t[0] - slack or at[-1] > t[-1] + slack:
        raise FitError(f"fit: data from {float(at[0])!r} to {float(at[-1])!r} s are outside "
                       f"simulated signal '{name}' ({float(t[0])!r} to {float(t[-1])!r} s)")
    if t.size == 1:
        return np.full(at.shape, float(y[0]))
    x = np.clip(at, t[0], t[-1])
    right = np.clip(np.searchsorted(t, x, side="right"), 1, t.size - 1)
    left = right - 1
    width = t[right] - t[left]
    share = np.divide(x - t[left], width, out=np.ones_like(x), where=width > 0)
    with np.errstate(invalid="ignore", over="ignore"):  # a value not finite stays so
        out: np.ndarray = y[left] + share * (y[right] - y[left])
    return out


class _Problem:
    """The residual function over a batched ``simulate``, with a cache of the points
    already simulated and the count of runs."""

    def __init__(self, simulate: Simulate, data: MeasuredData, signals: Mapping[str, str],
                 weights: Mapping[str, float], parameters: tuple[Parameter, ...]) -> None:
        self.simulate = simulate
        self.data = data
        self.signals = dict(signals)
        self.weights = dict(weights)
        self.parameters = parameters
        self.runs = 0
        self.cache: dict[bytes, np.ndarray] = {}
        self.best: tuple[float, np.ndarray] | None = None

    def describe(self, x: np.ndarray) -> str:
        return ", ".join(f"{p.name} = {float(v):.6g}" for p, v in zip(self.parameters, x))

    def residuals(self, batch: list[np.ndarray]) -> list[np.ndarray]:
        """The weighted residuals (signals in order, stamps in order) of each point."""
        todo = [x for x in dict.fromkeys(x.tobytes() for x in batch)
                if x not in self.cache]
        if todo:
            points = [np.frombuffer(key, dtype=float).copy() for key in todo]
            outputs = list(self.simulate(points))
            self.runs += len(points)
            if len(outputs) != len(points):
                raise FitError(f"fit: the simulation returned {len(outputs)} result(s) "
                               f"for {len(points)} parameter point(s)")
            for key, x, output in zip(todo, points, outputs):
                r = self._weighted(x, output)
                self.cache[key] = r
                cost = 0.5 * float(r @ r)
                if self.best is None or cost < self.best[0]:
                    self.best = (cost, x)
        return [self.cache[x.tobytes()] for x in batch]

    def _weighted(self, x: np.ndarray, output: Mapping[str, Signal]) -> np.ndarray:
        parts = []
        for signal, column in self.signals.items():
            if signal not in output:
                known = ", ".join(sorted(output)) or "none"
                raise FitError(f"fit: the simulation has no signal '{signal}' "
                               f"(signals: {known})")
            simulated = interpolate(output[signal], self.data.time, signal)
            if not np.all(np.isfinite(simulated)):
                raise FitError(f"fit: simulated signal '{signal}' is not finite at "
                               f"{self.describe(x)}")
            parts.append(self.weights[signal] * (simulated - self.data.columns[column]))
        return np.concatenate(parts)

    def steps(self, x: np.ndarray, relative_step: float) -> np.ndarray:
        scale = np.array([1e-3 * (p.max - p.min) for p in self.parameters])
        steps: np.ndarray = relative_step * np.maximum(np.abs(x), scale)
        return steps

    def forward_jacobian(self, x: np.ndarray, relative_step: float) -> np.ndarray:
        h = self.steps(x, relative_step)
        upper = np.array([p.max for p in self.parameters])
        h = np.where(x + h > upper, -h, h)
        points = [x.copy()]
        for j in range(len(x)):
            point = x.copy()
            point[j] += h[j]
            points.append(point)
        r0, *shifted = self.residuals(points)
        return np.column_stack([(r - r0) / (points[j + 1][j] - x[j])
                                for j, r in enumerate(shifted)])

    def central_jacobian(self, x: np.ndarray, relative_step: float) -> np.ndarray:
        h = self.steps(x, relative_step)
        points: list[np.ndarray] = []
        for j, p in enumerate(self.parameters):
            up, down = x.copy(), x.copy()
            up[j] = min(x[j] + h[j], p.max)
            down[j] = max(x[j] - h[j], p.min)
            points += [up, down]
        rows = self.residuals(points)
        return np.column_stack([(rows[2 * j] - rows[2 * j + 1]) /
                                (points[2 * j][j] - points[2 * j + 1][j])
                                for j in range(len(x))])


def fit(simulate: Simulate, data: MeasuredData, signals: Mapping[str, str],
        parameters: Sequence[Parameter], *, weights: Mapping[str, float] | None = None,
        max_nfev: int | None = None, xtol: float = 1e-10, ftol: float = 1e-10,
        gtol: float = 1e-10, relative_step: float = 1e-6) -> FitResult:
    """Fit ``parameters`` (bounded, from their start) so that the ``simulate``d signals
    match ``data``: ``signals`` maps each simulated signal to its measured column,
    ``weights`` overrides the default weight of some signals (see the module);
    ``max_nfev`` the solver's budget of function evaluations (None: scipy's, 100 per
    parameter), ``xtol``/``ftol``/``gtol`` its tolerances, ``relative_step`` the finite
    differences'. FitError for a bad set-up (one line naming the culprit)."""
    import scipy.optimize

    chosen = check_parameters(parameters, FitError, "fit")
    used = _signal_weights(data, signals, weights)
    for name, value in (("max_nfev", max_nfev),):
        if value is not None and (isinstance(value, bool) or not isinstance(value, int)
                                  or value < 1):
            raise FitError(f"fit: {name} {value!r}: must be a positive whole number")
    if not (math.isfinite(relative_step) and 0 < relative_step < 0.1):
        raise FitError(f"fit: relative_step {relative_step!r}: must be in (0, 0.1)")

    problem = _Problem(simulate, data, signals, used, chosen)
    x0 = np.array([p.start for p in chosen])
    lower = np.array([p.min for p in chosen])
    upper = np.array([p.max for p in chosen])

    def residual(x: np.ndarray) -> np.ndarray:
        return problem.residuals([np.asarray(x, dtype=float)])[0]

    def jacobian(x: np.ndarray) -> np.ndarray:
        return problem.forward_jacobian(np.asarray(x, dtype=float), relative_step)

    solved = scipy.optimize.least_squares(residual, x0, jac=jacobian, bounds=(lower, upper),
                                          method="trf", x_scale="jac", xtol=xtol, ftol=ftol,
                                          gtol=gtol, max_nfev=max_nfev)
    converged = int(solved.status) in _CONVERGED
    assert problem.best is not None
    x = np.asarray(solved.x, dtype=float)
    if not converged and problem.best[0] < 0.5 * float(residual(x) @ residual(x)):
        x = problem.best[1]  # the lowest cost of every run, finite-difference probes too
    message = (_CONVERGED[int(solved.status)] if converged else
               f"the solver's budget of {solved.nfev} evaluations ran out"
               if int(solved.status) == 0 else str(solved.message))
    r = residual(x)
    names = tuple(p.name for p in chosen)
    stderr: dict[str, float | None] = {n: None for n in names}
    reasons: dict[str, str] = {}
    correlation: list[list[float | None]] = [[None] * len(names) for _ in names]
    if converged:
        jac = problem.central_jacobian(x, relative_step)
        _uncertainties(problem, x, r, jac, stderr, reasons, correlation)
    else:
        for name in names:
            reasons[name] = "not converged: no standard error"
    fitted, residuals, rms = {}, {}, {}
    offset = 0
    n = len(data.time)
    for signal, column in signals.items():
        part = r[offset:offset + n] / used[signal]
        offset += n
        residuals[signal] = part
        fitted[signal] = data.columns[column] + part
        rms[signal] = float(np.sqrt(np.mean(part ** 2)))
    return FitResult(names=names, start={p.name: p.start for p in chosen},
                     values={p.name: float(v) for p, v in zip(chosen, x)},
                     stderr=stderr, reasons=reasons, correlation=correlation,
                     cost=0.5 * float(r @ r), iterations=int(solved.njev or 0),
                     evaluations=int(solved.nfev), runs=problem.runs, converged=converged,
                     message=message, weights=used, signals=dict(signals), fitted=fitted,
                     residuals=residuals, rms=rms)


def _signal_weights(data: MeasuredData, signals: Mapping[str, str],
                    weights: Mapping[str, float] | None) -> dict[str, float]:
    """The weight of each fitted signal (in the order of ``signals``): ``weights``'
    where given, else the default (see the module); FitError for no signal, a column
    ``data`` lacks, or a weight that is not for a fitted signal or not positive."""
    if not signals:
        raise FitError("fit: no signal to fit (map at least one simulated signal to a "
                       "measured column)")
    for signal, column in signals.items():
        if column not in data.columns:
            known = ", ".join(data.columns)
            raise FitError(f"fit: signal '{signal}': {data.source} has no column "
                           f"'{column}' (columns: {known})")
    used = default_weights(data, {s: c for s, c in signals.items()
                                  if weights is None or s not in weights})
    for signal, weight in (weights or {}).items():
        if signal not in signals:
            raise FitError(f"fit: weight for '{signal}', which is not a fitted signal "
                           f"(signals: {', '.join(signals)})")
        if isinstance(weight, bool) or not isinstance(weight, int | float) or \
                not math.isfinite(weight) or weight <= 0:
            raise FitError(f"fit: weight of '{signal}': {weight!r} is not a positive "
                           "number")
        used[signal] = float(weight)
    return {s: used[s] for s in signals}


def _uncertainties(problem: _Problem, x: np.ndarray, r: np.ndarray, jac: np.ndarray,
                   stderr: dict[str, float | None], reasons: dict[str, str],
                   correlation: list[list[float | None]]) -> None:
    """Fill ``stderr``, ``reasons`` and ``correlation`` from the Jacobian ``jac`` of the
    weighted residuals ``r`` at the optimum ``x`` (see the module)."""
    chosen = problem.parameters
    n, p = jac.shape
    free = []
    for j, par in enumerate(chosen):
        span = par.max - par.min
        if min(x[j] - par.min, par.max - x[j]) <= 1e-9 * span:
            side = "min" if x[j] - par.min <= par.max - x[j] else "max"
            reasons[par.name] = (f"at its bound ({side} {getattr(par, side)!r}): no "
                                 "standard error")
        elif not np.any(jac[:, j]):
            reasons[par.name] = "the simulated signals do not depend on it"
        else:
            free.append(j)
    if free and n <= len(free):
        for j in free:
            reasons[chosen[j].name] = (f"{n} residual(s) for {len(free)} parameter(s): "
                                       "no degree of freedom left for the noise")
        return
    if free:
        sub = jac[:, free]
        norms = np.linalg.norm(sub, axis=0)
        scaled = sub / norms
        _, singular, vt = np.linalg.svd(scaled, full_matrices=False)
        tolerance = 1e-9 * singular[0]
        null = sorted({int(free[i]) for s, v in zip(singular, vt) if s <= tolerance
                       for i in np.flatnonzero(np.abs(v) > 0.1)})
        for j in null:
            reasons[chosen[j].name] = ("the data cannot tell it apart from the other "
                                       "parameters (the Jacobian is singular)")
        free = [j for j in free if j not in null]
    if not free:
        return
    sub = jac[:, free]
    norms = np.linalg.norm(sub, axis=0)
    scaled = sub / norms
    variance = np.empty(n)
    rows = len(problem.data.time)
    dof = 1.0 - len(free) / n
    for k in range(n // rows):
        part = r[k * rows:(k + 1) * rows]
        variance[k * rows:(k + 1) * rows] = float(part @ part) / (rows * dof)
    inverse = np.linalg.inv(scaled.T @ scaled)
    middle = scaled.T @ (scaled * variance[:, None])
    cov = inverse @ middle @ inverse / np.outer(norms, norms)
    sd = np.sqrt(np.diag(cov))
    for a, j in enumerate(free):
        stderr[chosen[j].name] = float(sd[a])
        for b, k in enumerate(free):
            correlation[j][k] = float(cov[a, b] / (sd[a] * sd[b])) if sd[a] > 0 and \
                sd[b] > 0 else None
