"""Steering actuators of seed 000: models a (eq 8), b (K/s) and c (eq 7).

All three map the stepper-motor control voltage ``u`` [V] onto the steered-wheel angle
``alpha`` [rad] (positive steers left, see components/README.md):

a. ``G_a(s) = K e^(-tau s) / s``  (seed 000 eq 8; tau = 0.05 s, K = 0.6 rad/(V.s))
b. ``G_b(s) = K / s``             (eq 8 without the delay; seed 000 model b)
c. ``G_c(s) = (K / G0) (100 / s) (8.91 s + 506.3) / (s^2 + 15.7926 s + 195.23)``
   (seed 000 eq 7), where ``G0 = 100 * 506.3 / 195.23 = 259.335`` is the DC gain of the
   identified *rate* transfer function (eq 6). The identification was done in the rig's
   own units; scaling by ``K / G0`` gives model c the same steady rate gain K as eq 8, so
   the three models agree for slow commands and differ only in their transients.

Integration is exact for a command held over each step (zero-order hold):

* a and b: the (delayed) command is piecewise constant, so alpha is piecewise linear.
  Model a keeps a history of ``(time, u)`` breakpoints; inside a step the delayed command
  changes at ``t_i + tau`` and each piece is integrated exactly, whether or not the step
  divides tau. The command before the first step is 0 (actuator at rest).
* c: the state-space realisation of eq 7 is discretised exactly (matrix exponential, zero-
  order hold) for each distinct step size, cached.

Limits (each off when 0): ``rate_max`` [rad/s] clips the wheel rate, ``alpha_max`` [rad]
clamps the angle (the wheel stops at the end stop). For a and b the rate is constant
within each piece, so both limits are applied exactly. For c the unlimited angle increment
is clipped per internal sub-step of at most ``servo_period`` (an approximation at that
resolution; exact when the limits are off).

Angle mode (``mode="angle"``): an inner position loop, like the steering servo of seed
004, turns a wheel-angle set-point ``alpha_ref`` [rad] into the command
``u = servo_gain * (alpha_ref - alpha)``. The loop is a digital servo sampled every
``servo_period`` [s] (default 1 ms, the step is split into equal sub-steps no longer than
that), with its output held between samples, so every sub-step is again integrated
exactly by the command-mode rules above. The default ``servo_gain = 10 V/rad`` gives a
loop crossover of ``K * servo_gain = 6 rad/s`` and, with the 0.05 s delay of model a,
a phase margin of 90 deg - 6 rad/s * (0.05 + 0.0005) s = 72.6 deg (gain margin 5.2); on
model c the phase margin is 63 deg (gain margin 3.6).
"""

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import ParameterError
from ..numerics.finite import finite as _finite

MODES = ("command", "angle")

#: Identified rate transfer function of seed 000 eq 6 (numerator, denominator), rig units.
EQ6_NUM = (100.0 * 8.91, 100.0 * 506.3)
EQ6_DEN = (1.0, 15.7926, 195.23)
#: DC gain of eq 6 [rig units], used to scale model c to gain K.
EQ6_DC_GAIN = EQ6_NUM[1] / EQ6_DEN[2]
#: Eq 6's numerator in SI units [rad/(V.s^2), rad/(V.s^3)]: scaled to the steady rate gain
#: K = 0.6 rad/(V.s) of eq 8 (the denominator is the same in both: time is in s).
EQ6_SI_NUM = (0.6 / EQ6_DC_GAIN * EQ6_NUM[0], 0.6 / EQ6_DC_GAIN * EQ6_NUM[1])


class SteeringActuator:
    """Common part of the three steering actuators (use a subclass).

    Parameters
    ----------
    K : float
        Steady rate gain [rad/(V.s)], > 0 (seed 000: 0.6).
    alpha0 : float
        Initial wheel angle [rad].
    alpha_max : float
        Wheel-angle limit [rad], >= 0; 0 = no limit.
    rate_max : float
        Wheel-rate limit [rad/s], >= 0; 0 = no limit.
    mode : {"command", "angle"}
        ``command``: the input is the voltage ``u`` [V]; ``angle``: the input is the
        set-point ``alpha_ref`` [rad] of an inner position loop.
    servo_gain : float
        Position-loop gain [V/rad] of angle mode, > 0.
    servo_period : float
        Sample period [s] of the digital position loop (and the sub-step of model c's
        limiter), > 0.
    """

    def __init__(self, K: float = 0.6, alpha0: float = 0.0, alpha_max: float = 0.0,
                 rate_max: float = 0.0, mode: str = "command", servo_gain: float = 10.0,
                 servo_period: float = 1e-3) -> None:
        K = _finite("K", K)
        if K <= 0.0:
            raise ParameterError("K", f"must be > 0 rad/(V.s), got {K}")
        alpha_max = _finite("alpha_max", alpha_max)
        if alpha_max < 0.0:
            raise ParameterError("alpha_max", f"must be >= 0 rad (0 = off), got {alpha_max}")
        rate_max = _finite("rate_max", rate_max)
        if rate_max < 0.0:
            raise ParameterError("rate_max", f"must be >= 0 rad/s (0 = off), got {rate_max}")
        alpha0 = _finite("alpha0", alpha0)
        if alpha_max > 0.0 and abs(alpha0) > alpha_max:
            raise ParameterError("alpha0", f"|{alpha0}| exceeds alpha_max = {alpha_max} rad")
        if mode not in MODES:
            raise ParameterError("mode", f"must be one of {MODES}, got '{mode}'")
        servo_gain = _finite("servo_gain", servo_gain)
        if servo_gain <= 0.0:
            raise ParameterError("servo_gain", f"must be > 0 V/rad, got {servo_gain}")
        servo_period = _finite("servo_period", servo_period)
        if servo_period <= 0.0:
            raise ParameterError("servo_period", f"must be > 0 s, got {servo_period}")
        self.K = K
        self.alpha_max = alpha_max
        self.rate_max = rate_max
        self.mode = mode
        self.servo_gain = servo_gain
        self.servo_period = servo_period
        self.alpha = alpha0
        #: time [s] the state refers to (end of the last step)
        self.time = 0.0

    # ------------------------------------------------------------------ limits
    def _limit_rate(self, rate: float, alpha: float) -> float:
        """Rate after the rate limit and the end stops at angle ``alpha`` [rad/s]."""
        if self.rate_max > 0.0:
            rate = min(max(rate, -self.rate_max), self.rate_max)
        if self.alpha_max > 0.0:
            if (alpha >= self.alpha_max and rate > 0.0) or (alpha <= -self.alpha_max
                                                            and rate < 0.0):
                rate = 0.0
        return rate

    def _clamp(self, alpha: float) -> float:
        if self.alpha_max > 0.0:
            return min(max(alpha, -self.alpha_max), self.alpha_max)
        return alpha

    def _advance_constant_rate(self, rate: float, d: float) -> None:
        """Advance alpha by ``d`` [s] at constant unlimited rate ``rate`` (exact)."""
        if self.rate_max > 0.0:
            rate = min(max(rate, -self.rate_max), self.rate_max)
        self.alpha = self._clamp(self.alpha + rate * d)

    # ------------------------------------------------------------------ stepping
    def command(self, u: float, alpha_ref: float) -> float:
        """Command [V] the actuator receives now: ``u``, or the servo's in angle mode."""
        if self.mode == "angle":
            return self.servo_gain * (alpha_ref - self.alpha)
        return u

    def step(self, t: float, h: float, u: float = 0.0, alpha_ref: float = 0.0) -> None:
        """Advance from ``t`` to ``t + h`` [s] with ``u`` [V] and ``alpha_ref`` [rad] held."""
        if h <= 0.0:
            return
        self.time = t + h
        if self.mode == "angle" or self._needs_substeps():
            n = max(1, math.ceil(h / self.servo_period - 1e-9))
            d = h / n
            for i in range(n):
                self._step_command(t + i * d, d, self.command(u, alpha_ref))
        else:
            self._step_command(t, h, u)

    def _needs_substeps(self) -> bool:
        return False

    def _step_command(self, t: float, h: float, u: float) -> None:
        raise NotImplementedError

    def rate(self, u: float = 0.0, alpha_ref: float = 0.0) -> float:
        """Wheel rate d(alpha)/dt [rad/s] now, after the limits."""
        raise NotImplementedError

    # ------------------------------------------------------------------ state
    def get_state(self) -> dict[str, Any]:
        """JSON-safe snapshot of the state."""
        return {"alpha": self.alpha, "time": self.time}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a snapshot from :meth:`get_state`."""
        self.alpha = float(state["alpha"])
        self.time = float(state["time"])


class IntegratorActuator(SteeringActuator):
    """Model b: ``alpha' = K u`` (seed 000 eq 8 without delay). See :class:`SteeringActuator`."""

    def _step_command(self, t: float, h: float, u: float) -> None:
        self._advance_constant_rate(self.K * u, h)

    def rate(self, u: float = 0.0, alpha_ref: float = 0.0) -> float:
        return self._limit_rate(self.K * self.command(u, alpha_ref), self.alpha)


class DeadTime:
    """The dead time of models a and c: the command held over each step, delayed by
    ``tau`` [s], as a piecewise-constant signal (exact for held commands).

    Keeps a history of ``[time, command]`` breakpoints (the command before the first
    step is 0); :meth:`pieces` cuts a step where the delayed command changes, at
    ``t_i + tau``, whether or not the step divides tau.
    """

    def __init__(self, tau: float) -> None:
        self.tau = tau
        #: breakpoints [[time [s], command [V]], ...], ascending; command 0 before the first
        self.history: list[list[float]] = []

    @staticmethod
    def eps(h: float) -> float:
        return 1e-12 + 1e-9 * h

    def delayed(self, s: float) -> float:
        """Command that was applied at time ``s`` (right-continuous) [V]."""
        value = 0.0
        for time, u in self.history:
            if time <= s:
                value = u
            else:
                break
        return value

    def pieces(self, t: float, h: float, u: float) -> list[tuple[float, float]]:
        """Record command ``u`` [V] held from ``t`` [s]; return the step ``(t, t + h)``
        as ``[(duration [s], delayed command [V]), ...]``, in order."""
        eps = self.eps(h)
        u = float(u)
        history = self.history
        if history and history[-1][0] >= t - eps:
            last = history[-1]
            last[0], last[1] = t, u
            if len(history) > 1 and history[-2][1] == u:
                history.pop()
        elif not history or history[-1][1] != u:
            history.append([t, u])
        t_end = t + h
        tau = self.tau
        # pieces: the delayed command changes at t_i + tau inside (t, t_end). The times
        # ascend, so t_i + tau does too: the cuts are one run near the front (after
        # prune only the breakpoint in force and the newer ones are left).
        lower, upper = t + eps, t_end - eps
        start = t
        out = []
        for time, _ in history:
            cut = time + tau
            if cut >= upper:
                break
            if cut > lower:
                out.append((cut - start, self.delayed(start - tau + eps)))
                start = cut
        out.append((t_end - start, self.delayed(start - tau + eps)))
        self.prune(t_end - tau + eps)
        return out

    def prune(self, s: float) -> None:
        """Drop breakpoints no longer needed after delayed time ``s``: keep the newest at
        or before ``s`` (the command in force) and all later ones."""
        keep = 0
        for i, (time, _) in enumerate(self.history):
            if time > s:
                break
            keep = i
        if keep:
            del self.history[:keep]

    def now(self, time: float) -> float:
        """The delayed command in force at ``time`` [s] (applied at least tau earlier)."""
        return self.delayed(time - self.tau + self.eps(self.tau))


class DelayedIntegratorActuator(SteeringActuator):
    """Model a: ``alpha'(t) = K u(t - tau)`` (seed 000 eq 8), exact for held commands.

    Parameters
    ----------
    tau : float
        Dead time [s], > 0 (seed 000: 0.05).
    **kwargs
        See :class:`SteeringActuator`.
    """

    def __init__(self, tau: float = 0.05, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        tau = _finite("tau", tau)
        if tau <= 0.0:
            raise ParameterError("tau", f"must be > 0 s, got {tau}")
        self.tau = tau
        self.delay = DeadTime(tau)

    @property
    def history(self) -> list[list[float]]:
        """The dead time's breakpoints [[time [s], command [V]], ...]."""
        return self.delay.history

    def _step_command(self, t: float, h: float, u: float) -> None:
        for duration, delayed in self.delay.pieces(t, h, u):
            self._advance_constant_rate(self.K * delayed, duration)

    def rate(self, u: float = 0.0, alpha_ref: float = 0.0) -> float:
        # the delayed command at the current time was applied at least tau earlier: it is
        # in the history already and never depends on the present u / alpha_ref
        return self._limit_rate(self.K * self.delay.now(self.time), self.alpha)

    def get_state(self) -> dict[str, Any]:
        state = super().get_state()
        state["history"] = [list(p) for p in self.delay.history]
        return state

    def set_state(self, state: dict[str, Any]) -> None:
        super().set_state(state)
        self.delay.history = [[float(t), float(u)] for t, u in state["history"]]


class IdentifiedActuator(SteeringActuator):
    """Model c: a second-order rate transfer function (seed 000 eq 6) and a dead time,
    exact for held commands.

    The wheel rate is ``G_r(s) u(t - tau)`` with

        G_r(s) = (K den0 / num0) (num1 s + num0) / (s^2 + den1 s + den0),

    alpha its integral (eq 7 with the delay). The coefficients are in SI units (u in V,
    the rate in rad/s); ``K den0 / num0`` scales the transfer function to steady rate
    gain K, and is exactly 1 when ``K = num0 / den0``, as with the defaults: seed 000
    eq 6 scaled from the rig's units (DC gain :data:`EQ6_DC_GAIN`) to K = 0.6, so
    ``num1 = 0.6 / G0 * 891``, ``num0 = 0.6 / G0 * 50630``. The rate starts at rest and
    the command before the first step is 0.

    Parameters
    ----------
    num1 : float
        Numerator coefficient of s [rad/(V.s^2)], finite.
    num0 : float
        Numerator constant [rad/(V.s^3)], > 0.
    den1 : float
        Denominator coefficient of s [1/s], > 0.
    den0 : float
        Denominator constant [1/s^2], > 0 (den1 > 0 and den0 > 0: the rate is stable).
    tau : float
        Dead time [s], >= 0 (0: none; seed 000's eq 6 was fitted after removing it).
    **kwargs
        See :class:`SteeringActuator`.
    """

    def __init__(self, num1: float = EQ6_SI_NUM[0], num0: float = EQ6_SI_NUM[1],
                 den1: float = EQ6_DEN[1], den0: float = EQ6_DEN[2], tau: float = 0.0,
                 **kwargs: Any) -> None:
        super().__init__(**kwargs)
        import scipy.signal  # model c only: the other models do not import scipy

        num1 = _finite("num1", num1)
        num0 = _finite("num0", num0)
        den1 = _finite("den1", den1)
        den0 = _finite("den0", den0)
        tau = _finite("tau", tau)
        for name, value, unit in (("num0", num0, "rad/(V.s3)"), ("den1", den1, "1/s"),
                                  ("den0", den0, "1/s2")):
            if value <= 0.0:
                raise ParameterError(name, f"must be > 0 {unit}, got {value}")
        if tau < 0.0:
            raise ParameterError("tau", f"must be >= 0 s, got {tau}")
        self.num1, self.num0, self.den1, self.den0, self.tau = num1, num0, den1, den0, tau
        scale = self.K / (num0 / den0)
        a, b, c, d = scipy.signal.tf2ss([scale * num1, scale * num0], [1.0, den1, den0])
        self._a, self._b, self._c = a, b.ravel(), c.ravel()
        self.x: NDArray[np.float64] = np.zeros(len(self._b))
        self._cache: dict[float, tuple[NDArray[np.float64], NDArray[np.float64]]] = {}
        #: the dead time (None when tau = 0)
        self.delay = DeadTime(tau) if tau > 0.0 else None

    def _discrete(self, h: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Exact ZOH maps of [x; alpha]: (Ad [n+1 x n+1], Bd [n+1]) for step ``h``."""
        found = self._cache.get(h)
        if found is None:
            n = len(self._b)
            m = np.zeros((n + 2, n + 2))
            m[:n, :n] = self._a
            m[n, :n] = self._c          # alpha' = C x (the rate)
            m[:n, n + 1] = self._b      # input column
            import scipy.linalg

            e = scipy.linalg.expm(m * h)
            found = (e[:n + 1, :n + 1], e[:n + 1, n + 1])
            if len(self._cache) > 16:
                self._cache.clear()
            self._cache[h] = found
        return found

    def _needs_substeps(self) -> bool:
        return self.alpha_max > 0.0 or self.rate_max > 0.0

    def _step_command(self, t: float, h: float, u: float) -> None:
        if self.delay is None:
            self._advance(h, u)
            return
        for duration, delayed in self.delay.pieces(t, h, u):
            self._advance(duration, delayed)

    def _advance(self, h: float, u: float) -> None:
        """Advance by ``h`` [s] with command ``u`` [V] held (exact)."""
        ad, bd = self._discrete(h)
        z = ad @ np.append(self.x, 0.0) + bd * u
        self.x = z[:-1]
        increment = z[-1]
        if self.rate_max > 0.0:
            increment = min(max(increment, -self.rate_max * h), self.rate_max * h)
        self.alpha = self._clamp(self.alpha + increment)

    def rate(self, u: float = 0.0, alpha_ref: float = 0.0) -> float:
        return self._limit_rate(float(self._c @ self.x), self.alpha)

    def get_state(self) -> dict[str, Any]:
        state = super().get_state()
        state["x"] = [float(v) for v in self.x]
        if self.delay is not None:
            state["history"] = [list(p) for p in self.delay.history]
        return state

    def set_state(self, state: dict[str, Any]) -> None:
        super().set_state(state)
        self.x = np.array(state["x"], dtype=float)
        if self.delay is not None:
            self.delay.history = [[float(t), float(u)] for t, u in state["history"]]


#: model letter (seed 000) -> actuator class
MODELS: dict[str, type[SteeringActuator]] = {
    "a": DelayedIntegratorActuator, "b": IntegratorActuator, "c": IdentifiedActuator}


def make_actuator(model: str, **parameters: Any) -> SteeringActuator:
    """Build steering actuator ``model`` ("a", "b" or "c") with ``parameters``."""
    if model not in MODELS:
        raise ParameterError("model", f"must be one of {tuple(MODELS)}, got '{model}'")
    return MODELS[model](**parameters)
