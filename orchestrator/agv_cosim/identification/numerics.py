"""Seed 000's identification procedure on arrays (no files): pre-filter, dead time,
initial values, output-error fits of the steering-actuator models a, b and c.

The record is ``t`` [s] (uniformly sampled), the command ``u`` [V] and the wheel angle
``y`` [rad]; ``u[k]`` is taken as held from ``t[k]`` to ``t[k + 1]`` (the zero-order hold
of a co-simulation step and of a stepper-motor drive), so every model's response is
computed exactly, as the FMUs compute it (components/agv_core/steering/actuator.py):

- a: ``y(t) = K U(t - tau)``, ``U`` the integral of the held command (piecewise linear);
- b: ``y(t) = K U(t)``;
- c: the rate ``(num1 s + num0) / (s^2 + den1 s + den0)`` driven by ``u(t - tau)``,
  integrated: discretised exactly (matrix exponential) with the dead time split into
  whole steps and a fraction of a step.

The procedure (seed 000 section 2.3):

1. pre-filter (eq 4): a Butterworth low-pass of order ``order`` and cut-off ``cutoff``
   [Hz] (``scipy.signal.butter``), applied forward and backward (``sosfiltfilt``):
   zero-phase, so the filter adds no delay that the fit would take for dead time (a
   causal 3rd-order Butterworth at 30 Hz delays by about 16 ms, a third of eq 8's
   50 ms); the record is measured offline, so the filter need not be causal. The filter
   is applied to the residual ``y - y_hat`` (the same as filtering the measured and the
   simulated output alike), so noise-free data are fitted exactly whatever the filter
   does at the record's ends;
2. initial values removed: ``u`` minus its first value, ``y`` minus its mean before the
   command first changes (the first sample when it changes at once);
3. dead time: a first estimate from model a on a grid of whole steps (K by linear least
   squares for each), then refined by the fits of a and c (parameter ``tau``);
4. output-error fits (eq 5) by ``scipy.optimize.least_squares`` (trust-region
   reflective, bounds K > 0, tau >= 0, num0, den1, den0 > 0), model c from several
   starts (natural frequencies 5 to 150 rad/s), the best kept;
5. standard errors ``sqrt(diag(sigma^2 (J^T J)^-1))``: J the Jacobian of the model's
   output with respect to its parameters (central differences), sigma^2 the variance of
   the unfiltered residual (``n - p`` degrees of freedom); plus the share of the initial
   value removed (the mean of the samples before the command changes has variance
   sigma^2 / n_before and moves the parameters by ``(J^T J)^-1 J^T 1`` per unit);
6. ``fit_percent = 100 (1 - ||y - y_hat|| / ||y - mean(y)||)`` on the unfiltered output.

A parameter the data do not determine gets no number: value and standard error None and
a ``reason`` (the output does not depend on it, it is in the null space of J, or its
standard error exceeds its value); one at its bound keeps its value without standard
error. A record with nothing to identify raises :class:`~agv_cosim.errors.IdentifyError`.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import IdentifyError

#: The FMU parameters each model's fit determines, in order.
PARAMETERS = {"a": ("K", "tau"), "b": ("K",), "c": ("num1", "num0", "den1", "den0", "tau")}
#: Units of the parameters (the FMUs').
UNITS = {"K": "rad/(V.s)", "tau": "s", "num1": "rad/(V.s2)", "num0": "rad/(V.s3)",
         "den1": "1/s", "den0": "1/s2"}
#: The FMU of each model.
FMUS = {"a": "AgvSteeringA", "b": "AgvSteeringB", "c": "AgvSteeringC"}
MODELS = tuple(PARAMETERS)
#: Fewest samples of a record, and after the command's first change.
MIN_SAMPLES = 20
MIN_AFTER_CHANGE = 10
#: A sampling step may differ from the median step by this fraction.
UNIFORM_TOLERANCE = 1e-3
#: Function evaluations of each of model c's starts before the best goes on.
SCOUT_BUDGET = 150
#: Starting natural frequencies of model c's fits [rad/s].
C_STARTS = (5.0, 15.0, 50.0, 150.0)


@dataclass
class Prepared:
    """A record ready to fit: relative time, command and output with initial values
    removed, the sampling step, the filter."""

    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    h: float
    u0: float
    y0: float
    change: int
    sos: np.ndarray
    cutoff: float
    order: int

    def filtered(self, x: np.ndarray) -> np.ndarray:
        """``x`` through the pre-filter, forward and backward (zero phase)."""
        import scipy.signal

        filtered: np.ndarray = scipy.signal.sosfiltfilt(self.sos, x)  # scipy: untyped
        return filtered


@dataclass
class ModelFit:
    """One model's identification."""

    model: str
    #: name -> {"value": float | None, "stderr": float | None[, "reason": str]}
    parameters: dict[str, dict[str, Any]]
    fit_percent: float
    #: the model's response on the record's time, initial value added back [rad]
    response: np.ndarray
    #: the fitted values (all of them, also those reported as not determined)
    values: dict[str, float] = field(default_factory=dict)
    #: the solver's cost (half the sum of squared filtered residuals), evaluations
    cost: float = math.nan
    evaluations: int = 0
    #: the output's initial value removed [rad]
    initial: float = math.nan

    def as_json(self) -> dict[str, Any]:
        return {"parameters": self.parameters, "fit_percent": self.fit_percent}


# --------------------------------------------------------------------------- checks

def check_record(t: np.ndarray, u: np.ndarray, y: np.ndarray, names: tuple[str, str, str],
                 cutoff: float, order: int) -> None:
    """Raise IdentifyError when the record cannot be identified from (names: the time,
    input and output columns, for the message)."""
    time_name, input_name, output_name = names
    n = len(t)
    if n < MIN_SAMPLES:
        raise IdentifyError(f"too short: {n} sample(s), at least {MIN_SAMPLES} needed")
    steps = np.diff(t)
    if not np.all(steps > 0):
        k = int(np.argmax(~(steps > 0)))
        raise IdentifyError(f"column '{time_name}': not increasing at sample {k + 2} "
                            f"({float(t[k + 1])!r} after {float(t[k])!r})")
    h = float(np.median(steps))
    worst = int(np.argmax(np.abs(steps - h)))
    if abs(steps[worst] - h) > UNIFORM_TOLERANCE * h:
        raise IdentifyError(f"column '{time_name}': not uniformly sampled (step "
                            f"{float(steps[worst])!r} s at sample {worst + 2}, median {h!r} s); "
                            "the pre-filter needs a uniform sampling: resample first")
    if not (math.isfinite(cutoff) and cutoff > 0):
        raise IdentifyError(f"--cutoff {cutoff!r}: must be a positive number of Hz")
    if cutoff >= 0.5 / h:
        raise IdentifyError(f"--cutoff {cutoff:g} Hz: must be below half the sampling "
                            f"rate ({0.5 / h:g} Hz)")
    if not (1 <= order <= 8):
        raise IdentifyError(f"--order {order}: must be 1 to 8")
    changes = np.flatnonzero(u != u[0])
    if changes.size == 0:
        raise IdentifyError(f"column '{input_name}': constant ({float(u[0])!r}): no step or "
                            "excitation to identify from")
    if n - changes[0] < MIN_AFTER_CHANGE:
        raise IdentifyError(f"too short: {n - changes[0]} sample(s) after "
                            f"'{input_name}' first changes, at least {MIN_AFTER_CHANGE} "
                            "needed")


def prepare(t: np.ndarray, u: np.ndarray, y: np.ndarray, names: tuple[str, str, str],
            cutoff: float = 30.0, order: int = 3) -> Prepared:
    """Check the record, remove the initial values, design the pre-filter."""
    import scipy.signal

    t, u, y = (np.asarray(x, dtype=float) for x in (t, u, y))
    check_record(t, u, y, names, cutoff, order)
    h = float(np.median(np.diff(t)))
    change = int(np.flatnonzero(u != u[0])[0])
    before = max(change, 1)
    u0 = float(u[0])
    y0 = float(np.mean(y[:before]))
    sos = scipy.signal.butter(order, cutoff, fs=1.0 / h, output="sos")
    prepared = Prepared(t=t - t[0], u=u - u0, y=y - y0, h=h, u0=u0, y0=y0, change=change,
                        sos=sos, cutoff=float(cutoff), order=int(order))
    if len(t) <= 3 * (2 * len(sos) + 1):
        raise IdentifyError(f"too short: {len(t)} samples for a pre-filter of order "
                            f"{order} (more than {3 * (2 * len(sos) + 1)} needed)")
    smooth = prepared.filtered(prepared.y)
    spread = float(np.ptp(smooth))
    noise = float(np.std(prepared.y - smooth))
    if spread == 0.0 or spread <= 10.0 * noise:
        raise IdentifyError(f"column '{names[2]}': flat (range {spread:.3g} after the "
                            f"pre-filter, noise {noise:.3g}): the output does not respond, "
                            "nothing to identify")
    return prepared


# --------------------------------------------------------------------------- models

def _integral(u: np.ndarray, h: float) -> np.ndarray:
    """The integral of the held command at the samples (0 at the first)."""
    out = np.empty_like(u)
    out[0] = 0.0
    np.cumsum(u[:-1] * h, out=out[1:])
    return out


def _delayed_integral(prep: Prepared, tau: float,
                      integral: np.ndarray | None = None) -> np.ndarray:
    """``U(t - tau)`` at the samples: the integral is piecewise linear (held command),
    0 before the record (the command's initial value removed)."""
    if integral is None:
        integral = _integral(prep.u, prep.h)
    shifted: np.ndarray = np.interp(prep.t - tau, prep.t, integral, left=0.0)
    return shifted


def _c_response(prep: Prepared, num1: float, num0: float, den1: float, den0: float,
                tau: float) -> np.ndarray:
    """Model c's angle at the samples, exact for the held, delayed command: the rate's
    state ``x`` and the angle's increment over each step are linear in the state and the
    commands in force during the step (the dead time's whole steps ``m`` and fraction
    ``f``: ``u[k - m - 1]`` for ``f``, ``u[k - m]`` for ``h - f``); the increments come
    from two stable second-order filters (``lfilter``), the angle is their running sum."""
    import scipy.linalg
    import scipy.signal

    h = prep.h
    with warnings.catch_warnings():  # a numerator whose leading coefficient is 0
        warnings.simplefilter("ignore", scipy.signal.BadCoefficients)
        a, b, c, _ = scipy.signal.tf2ss([num1, num0], [1.0, den1, den0])
    n = a.shape[0]
    aug = np.zeros((n + 2, n + 2))  # [x; alpha; input]
    aug[:n, :n] = a
    aug[n, :n] = c.ravel()
    aug[:n, n + 1] = b.ravel()

    def maps(d: float) -> tuple[np.ndarray, np.ndarray]:
        e = scipy.linalg.expm(aug * d)
        return e[:n + 1, :n + 1], e[:n + 1, n + 1]

    whole = int(math.floor(tau / h + 1e-9))
    frac = max(tau - whole * h, 0.0)
    if frac < 1e-12 * h:
        frac = 0.0
    phi, gamma = maps(h)
    if frac > 0.0:
        _, gamma_f = maps(frac)
        phi_r, gamma_r = maps(h - frac)
        g1 = phi_r @ gamma_f  # the command of the step before, over the first frac
        g2 = gamma_r
    else:
        g1, g2 = np.zeros(n + 1), gamma
    u = prep.u
    increment = np.zeros_like(u)
    for g, v in ((g2, _shift(u, whole)), (g1, _shift(u, whole + 1))):
        if not np.any(g) or not np.any(v):
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", scipy.signal.BadCoefficients)
            num, den = scipy.signal.ss2tf(phi[:n, :n], g[:n].reshape(-1, 1),
                                          phi[n:, :n], g[n:].reshape(1, 1))
        increment += scipy.signal.lfilter(num[0], den, v)
    y = np.empty_like(u)
    y[0] = 0.0
    np.cumsum(increment[:-1], out=y[1:])
    return y


def _shift(u: np.ndarray, m: int) -> np.ndarray:
    """``u`` delayed by ``m`` samples (0 before the record)."""
    if m <= 0:
        return u.copy()
    out = np.zeros_like(u)
    if m < len(u):
        out[m:] = u[:-m]
    return out


def response(model: str, prep: Prepared, values: dict[str, float]) -> np.ndarray:
    """The model's angle response (initial value removed) to the prepared command."""
    if model == "b":
        return values["K"] * _integral(prep.u, prep.h)
    if model == "a":
        return values["K"] * _delayed_integral(prep, values["tau"])
    if model == "c":
        return _c_response(prep, values["num1"], values["num0"], values["den1"],
                           values["den0"], values["tau"])
    raise ValueError(f"unknown model {model!r}")


# --------------------------------------------------------------------------- fitting

def _max_delay(prep: Prepared) -> float:
    """Longest dead time searched [s]: half the record after the command first changes."""
    return 0.5 * float(prep.t[-1] - prep.t[prep.change])


def estimate_dead_time(prep: Prepared) -> tuple[float, float]:
    """``(tau, K)`` of model a on a grid of whole sampling steps, each K by linear least
    squares on the pre-filtered output: the dead time's first estimate. The filtered
    integral is shifted rather than filtered again for each delay (the same but for the
    record's ends: a first estimate only)."""
    target = prep.filtered(prep.y)
    smooth = prep.filtered(_integral(prep.u, prep.h))
    best = (math.inf, 0.0, 0.0)
    steps = int(_max_delay(prep) / prep.h)
    for m in range(steps + 1):
        basis = _shift(smooth, m)
        norm = float(basis @ basis)
        if norm <= 0.0:
            continue
        k = float(basis @ target) / norm
        cost = float(np.sum((target - k * basis) ** 2))
        if cost < best[0]:
            best = (cost, m * prep.h, k)
    return best[1], best[2]


#: Model c is searched in better-conditioned coordinates: log gain K = num0/den0, log
#: natural frequency, log damping, zero time constant num1/num0, dead time.
def _c_to_search(values: dict[str, float]) -> np.ndarray:
    k = values["num0"] / values["den0"]
    wn = math.sqrt(values["den0"])
    zeta = values["den1"] / (2 * wn)
    return np.array([math.log(k), math.log(wn), math.log(zeta),
                     values["num1"] / values["num0"], values["tau"]])


def _c_from_search(x: np.ndarray) -> dict[str, float]:
    k, wn, zeta = math.exp(x[0]), math.exp(x[1]), math.exp(x[2])
    den0 = wn * wn
    num0 = k * den0
    return {"num1": float(x[3]) * num0, "num0": num0, "den1": 2 * zeta * wn, "den0": den0,
            "tau": float(x[4])}


def _solve(model: str, prep: Prepared, start: dict[str, float], fix_tau: bool = False,
           budget: int = 1200) -> tuple[Any, dict[str, float]]:
    """Levenberg-Marquardt (least_squares, method "lm") from ``start``; with
    ``fix_tau`` the dead time stays at the start's. Returns (result, fitted values)."""
    import scipy.optimize

    names = PARAMETERS[model]
    if model == "c":
        full = _c_to_search(start)
        free = [0, 1, 2, 3] if fix_tau else [0, 1, 2, 3, 4]

        def unpack(x: np.ndarray) -> dict[str, float]:
            z = full.copy()
            z[free] = x
            return _c_from_search(z)

        x0 = full[free]
    else:
        free_names = [n for n in names if not (fix_tau and n == "tau")]

        def unpack(x: np.ndarray) -> dict[str, float]:
            values = dict(start)
            values.update(zip(free_names, (float(v) for v in x)))
            return {n: values[n] for n in names}

        x0 = np.array([start[n] for n in free_names])

    penalty = np.full(len(prep.y), 1e3 * (float(np.ptp(prep.y)) + 1.0))

    def residual(x: np.ndarray) -> np.ndarray:
        # a point where the model has no finite response (an exponent that overflows
        # far from the data) is a large residual: the solver steps back from it
        try:
            with np.errstate(all="ignore"):
                values = unpack(x)
                out = prep.filtered(prep.y - response(model, prep, values))
        except (ArithmeticError, ValueError, np.linalg.LinAlgError):
            return penalty
        return out if np.all(np.isfinite(out)) else penalty

    result = scipy.optimize.least_squares(residual, x0, method="lm", x_scale="jac",
                                          xtol=1e-13, ftol=1e-13, gtol=1e-13,
                                          max_nfev=budget)
    return result, unpack(result.x)


def _solve_bounded(model: str, prep: Prepared, start: dict[str, float],
                   budget: int = 1200) -> tuple[Any, dict[str, float], int]:
    """:func:`_solve`; a dead time found negative is set to its bound 0 and the other
    parameters fitted again."""
    result, values = _solve(model, prep, start, budget=budget)
    evaluations = int(result.nfev)
    if "tau" in values and values["tau"] < 0.0:
        result, values = _solve(model, prep, dict(values, tau=0.0), fix_tau=True,
                                budget=budget)
        evaluations += int(result.nfev)
    return result, values, evaluations


def _jacobian(model: str, prep: Prepared, values: dict[str, float]) -> np.ndarray:
    """d(model output)/d(parameters) at ``values`` (central differences; one-sided for a
    dead time at its bound 0)."""
    names = PARAMETERS[model]
    columns = []
    for name in names:
        x = values[name]
        step = 1e-6 * max(abs(x), 1e-3 if name != "tau" else prep.h)
        up = dict(values, **{name: x + step})
        if name == "tau" and x - step < 0.0:
            down, width = values, step
        else:
            down, width = dict(values, **{name: x - step}), 2 * step
        columns.append((response(model, prep, up) - response(model, prep, down)) / width)
    return np.column_stack(columns)


def _starts(model: str, prep: Prepared, tau_a: float, k_a: float) -> list[dict[str, float]]:
    k = k_a if k_a > 0 else 1.0
    if model == "a":
        return [{"K": k, "tau": tau_a}]
    if model == "b":
        return [{"K": k}]
    starts = []
    for wn in C_STARTS:
        zeta = 0.7
        lag = 2 * zeta / wn  # how far the rate's lag delays a ramp
        for tau in sorted({max(tau_a - lag, 0.0), 0.5 * max(tau_a - lag, 0.0)}):
            starts.append({"num1": 0.0, "num0": k * wn * wn, "den1": 2 * zeta * wn,
                           "den0": wn * wn, "tau": tau})
    return starts


def fit_model(model: str, prep: Prepared, tau_a: float, k_a: float) -> ModelFit:
    """Fit ``model`` ("a", "b" or "c") to the prepared record (see the module)."""
    names = PARAMETERS[model]
    best, values = None, {}
    evaluations = 0
    starts = _starts(model, prep, tau_a, k_a)
    for start in starts:  # each start briefly (model c), then the best one to the end
        result, found, count = _solve_bounded(model, prep, start,
                                              SCOUT_BUDGET if len(starts) > 1 else 1200)
        evaluations += count
        if best is None or result.cost < best.cost:
            best, values = result, found
    assert best is not None
    if len(starts) > 1 and best.status == 0:  # the budget ran out: go on from there
        result, found, count = _solve_bounded(model, prep, values)
        evaluations += count
        if result.cost <= best.cost:
            best, values = result, found
    y_hat = response(model, prep, values)
    raw = prep.y - y_hat
    n, p = len(raw), len(names)
    sigma2 = float(raw @ raw) / max(n - p, 1)
    jac = _jacobian(model, prep, values)
    parameters = _uncertainties(names, values, jac, sigma2, prep.change)
    if model == "c":
        parameters = _with_gain(parameters, values, jac, sigma2, prep.change)
    denominator = float(np.linalg.norm(prep.y + prep.y0 - np.mean(prep.y + prep.y0)))
    fit = 100.0 * (1.0 - float(np.linalg.norm(raw)) / denominator) if denominator > 0 \
        else math.nan
    return ModelFit(model=model, parameters=parameters, fit_percent=fit,
                    response=y_hat + prep.y0, values=values, cost=float(best.cost),
                    evaluations=evaluations, initial=prep.y0)


def _covariance(jac: np.ndarray, sigma2: float,
                before: int = 0) -> tuple[np.ndarray, list[int]]:
    """``sigma^2 (J^T J)^-1`` (pseudo-inverse), plus the share of the initial value
    removed when it is the mean of ``before`` samples (its error ``delta``, variance
    ``sigma^2 / before``, moves the parameters by ``(J^T J)^-1 J^T 1 delta``); and the
    columns in J's null space."""
    norms = np.linalg.norm(jac, axis=0)
    scale = np.where(norms > 0, norms, 1.0)
    scaled = jac / scale
    _, singular, vt = np.linalg.svd(scaled, full_matrices=False)
    rank_tol = 1e-9 * singular[0] if singular.size and singular[0] > 0 else 0.0
    null = [i for i in range(jac.shape[1]) if norms[i] == 0.0]
    for s, v in zip(singular, vt):
        if s <= rank_tol:
            null += [int(i) for i in np.flatnonzero(np.abs(v) > 0.1) if i not in null]
    inverse = np.linalg.pinv(scaled.T @ scaled)
    cov = sigma2 * inverse / np.outer(scale, scale)
    if before > 0:
        shift = (inverse @ (scaled.T @ np.ones(jac.shape[0]))) / scale
        cov = cov + (sigma2 / before) * np.outer(shift, shift)
    return cov, sorted(set(int(i) for i in null))


def _uncertainties(names: tuple[str, ...], values: dict[str, float], jac: np.ndarray,
                   sigma2: float, before: int) -> dict[str, dict[str, Any]]:
    cov, null = _covariance(jac, sigma2, before)
    out: dict[str, dict[str, Any]] = {}
    for i, name in enumerate(names):
        value = values[name]
        stderr = math.sqrt(cov[i, i]) if cov[i, i] >= 0 else math.nan
        if name == "K" and value <= 0.0:
            out[name] = {"value": None, "stderr": None,
                         "reason": f"fitted {value:.4g} <= 0: the output does not follow "
                                   "the command (positive u drives alpha positive; the "
                                   "FMUs need K > 0)"}
        elif i in null:
            reason = ("the output does not depend on it" if not np.any(jac[:, i]) else
                      "the data cannot tell it apart from the other parameters (J is "
                      "singular)")
            out[name] = {"value": None, "stderr": None, "reason": reason}
        elif name == "tau" and value <= 0.0:
            out[name] = {"value": 0.0, "stderr": None,
                         "reason": "at its bound 0 (no dead time found): no standard error"}
        elif name == "tau" and math.isfinite(stderr) and stderr > abs(value):
            out[name] = {"value": None, "stderr": None,
                         "reason": f"not distinguishable from 0 (fitted {value:.3g} s, "
                                   f"standard error {stderr:.2g} s exceeds it)"}
        elif not math.isfinite(stderr) or stderr > abs(value):
            out[name] = {"value": None, "stderr": None,
                         "reason": f"not determined by the data (fitted {value:.4g}, "
                                   f"standard error {stderr:.3g} exceeds it)"}
        else:
            out[name] = {"value": value, "stderr": stderr}
    return out


def _with_gain(parameters: dict[str, dict[str, Any]], values: dict[str, float],
               jac: np.ndarray, sigma2: float, before: int) -> dict[str, dict[str, Any]]:
    """Model c's parameters and its steady rate gain ``K = num0 / den0`` (the FMU's K,
    so that the FMU's scale K den0 / num0 is 1), standard error by the delta method."""
    cov, _ = _covariance(jac, sigma2, before)
    num0, den0 = values["num0"], values["den0"]
    k = num0 / den0
    grad = np.zeros(cov.shape[0])
    grad[PARAMETERS["c"].index("num0")] = 1.0 / den0
    grad[PARAMETERS["c"].index("den0")] = -num0 / den0 ** 2
    var = float(grad @ cov @ grad)
    out: dict[str, dict[str, Any]] = {
        "K": {"value": k, "stderr": math.sqrt(var) if var >= 0 else None}}
    if parameters["num0"]["value"] is None or parameters["den0"]["value"] is None:
        out["K"] = {"value": k, "stderr": None,
                    "reason": "from num0 / den0, which the data do not determine apart"}
    out.update(parameters)
    return out


def identify_arrays(t: Any, u: Any, y: Any, models: tuple[str, ...] = MODELS,
                    cutoff: float = 30.0, order: int = 3,
                    names: tuple[str, str, str] = ("time", "u", "y")
                    ) -> tuple[Prepared, dict[str, Any], dict[str, ModelFit]]:
    """Seed 000's procedure on arrays: ``(prepared record, settings, {model: ModelFit})``.

    ``settings`` holds what the procedure found besides the fits: the sampling step,
    the initial values removed, the dead time's first estimate.
    """
    for model in models:
        if model not in PARAMETERS:
            raise IdentifyError(f"--models: unknown model '{model}' (models: a, b, c)")
    prep = prepare(t, u, y, names, cutoff, order)
    tau_a, k_a = estimate_dead_time(prep)
    fits = {model: fit_model(model, prep, tau_a, k_a) for model in models}
    settings = {"samples": len(prep.t), "step": prep.h, "cutoff_hz": prep.cutoff,
                "order": prep.order, "filter": "Butterworth, zero-phase (sosfiltfilt)",
                "input_initial": prep.u0, "output_initial": prep.y0,
                "first_change_time": float(t[prep.change]),
                "dead_time_estimate": tau_a}
    return prep, settings, fits
