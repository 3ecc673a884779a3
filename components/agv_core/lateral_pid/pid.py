"""Sampled PID on the lateral error: seed 001's comparison controller.

Seed 001 compares its MPC with "a PID controller [14]" and gives neither its structure nor
its gains. Our choice (notes-001-003.md section 1.5): constant speed, PID on the signed
lateral error of the centroid from the time-parameterised reference, no curvature
feed-forward::

    e_lat = -sin(alpha_r)(X - X_r) + cos(alpha_r)(Y - Y_r)     [m], positive left
    v_c   = v_r
    omega = -(Kp e_lat + Ki I + Kd D),  |omega| <= omega_max

sampled every T [s] and held in between (the rule of agv_core.numerics.sampling, a
sample-and-hold with memory): I is the rectangle-rule integral
I(k) = I(k-1) + T e_lat(k) (not advanced while omega is saturated in the direction that
would grow it: conditional integration as anti-windup), D the backward difference
(e_lat(k) - e_lat(k-1)) / T (0 at the first sample). Units: Kp [rad/(s m)],
Ki [rad/(s^2 m)], Kd [rad/m].
"""

import math
from collections.abc import Mapping
from typing import Any

from ..errors import ParameterError
from ..ltv_mpc.ltv_mpc import LtvMpc, errors
from ..numerics.sampling import SampleHold


class LateralPid:
    """The seed-001 comparison PID (see the module docstring).

    Parameters
    ----------
    kp, ki, kd : float
        Gains (finite; positive gains steer back). Defaults: Ki, Kd from the notes'
        prototype, Kp calibrated to the paper's 19 cm S-curve overshoot
        (experiments/seed001_pid_calibration.py): a calibration, not a paper value.
    sample_time : float
        T [s], > 0.
    omega_max : float
        Yaw-rate limit [rad/s], > 0.
    """

    def __init__(self, kp: float = 0.76, ki: float = 0.03, kd: float = 1.8,
                 sample_time: float = 0.2, omega_max: float = 0.6) -> None:
        for name, value in (("kp", kp), ("ki", ki), ("kd", kd)):
            if not math.isfinite(value):
                raise ParameterError(name, f"must be finite, got {value}")
        if not (math.isfinite(sample_time) and sample_time > 0.0):
            raise ParameterError("sample_time", f"must be > 0 s, got {sample_time}")
        if not (math.isfinite(omega_max) and omega_max > 0.0):
            raise ParameterError("omega_max", f"must be > 0 rad/s, got {omega_max}")
        self.kp, self.ki, self.kd = float(kp), float(ki), float(kd)
        self.T = float(sample_time)
        self.omega_max = float(omega_max)
        self.integral = 0.0          # I(k-1) [m s] of the last sample computed
        self.e_prev: float | None = None  # e_lat(k-1) [m] of the last sample computed
        self._hold = SampleHold(self.T, memory=True)

    def compute(self, x: float, y: float, heading: float, ref: Mapping[str, float],
                integral: float, e_prev: float | None
                ) -> tuple[dict[str, Any], float, float]:
        """One sample from I(k-1) and e(k-1); returns (out, I(k), e(k))."""
        out = errors(x, y, heading, ref)
        e = out["e_lat"]
        d = 0.0 if e_prev is None else (e - e_prev) / self.T
        i_new = integral + self.T * e
        raw = -(self.kp * e + self.ki * i_new + self.kd * d)
        omega = min(max(raw, -self.omega_max), self.omega_max)
        if omega != raw and (raw - omega) * (-self.ki * e) > 0.0:
            i_new = integral  # saturated and the integral would push further: hold it
            raw = -(self.kp * e + self.ki * i_new + self.kd * d)
            omega = min(max(raw, -self.omega_max), self.omega_max)
        out.update(v_c=float(ref["v"]), omega=omega, integral=i_new)
        return out, i_new, e

    def _law(self, x: float, y: float, heading: float, x_r: float, y_r: float,
             heading_r: float, v_r: float, omega_r: float) -> dict[str, Any]:
        """One sample from the held inputs and the committed sample before it."""
        prior = self._hold.prior
        self.integral, self.e_prev = ((0.0, None) if prior is None
                                      else (prior["integral"], prior["e"]))
        ref = {"x": x_r, "y": y_r, "heading": heading_r, "v": v_r, "omega": omega_r}
        out, i_new, e = self.compute(x, y, heading, ref, self.integral, self.e_prev)
        return {"out": out, "integral": i_new, "e": e}

    def update(self, t: float, x: float, y: float, heading: float, ref: Mapping[str, float]
               ) -> dict[str, Any]:
        """Output at time ``t`` [s], sampled at k T and held (the rule of
        :mod:`agv_core.numerics.sampling`, as :meth:`LtvMpc.update`)."""
        return dict(self._hold.output(t, LtvMpc._inputs(x, y, heading, ref), self._law)["out"])

    def step(self, t: float, h: float, x: float, y: float, heading: float,
             ref: Mapping[str, float]) -> None:
        """Commit the samples of the step from ``t`` to ``t + h`` [s], inputs held."""
        self._hold.step(t, h, LtvMpc._inputs(x, y, heading, ref), self._law)

    def get_state(self) -> dict[str, Any]:
        """JSON-safe snapshot."""
        return {"hold": self._hold.get_state(), "integral": self.integral,
                "e_prev": self.e_prev}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a snapshot from :meth:`get_state`."""
        self._hold.set_state(state["hold"])
        self.integral, self.e_prev = state["integral"], state["e_prev"]
