"""Seed-000 state-feedback steering controller (eqs 9-10) and its LQR design on model b.

Control law (seed 000 eq 9, signs per components/README.md, negative feedback)::

    u = -(Ka alpha + Kb heading_error + Ke lateral_error)        [V]

with the paper's gains (eq 10) ``[Ka, Kb, Ke] = [4.828, 3.767, 4.472]`` in
[V/rad, V/rad, V/m]. ``lateral_error`` is the signed distance of the front-wheel centre
from the path, ``heading_error`` the heading relative to the path.

Design model (seed 000 model b), states ``(alpha, beta, e)``::

    alpha' = K u,   beta' = (V0 / L) alpha,   e' = V0 (alpha + beta)

For ``Q = diag(0, 0, q)``, ``R = r`` the LQR gain on e is exactly ``Ke = sqrt(q / r)``
for every V0, L and K: the loop transfer function from u to e is
``V0 K (s + V0/L) / s^3``, the closed-loop characteristic polynomial under the gains is
``s^3 + K Ka s^2 + K (Kb V0/L + Ke V0) s + K Ke V0^2/L``, and the spectral factorisation
``s^6 + (q/r) V0^2 K^2 (s^2 - (V0/L)^2)`` fixes its constant term to
``sqrt(q/r) V0^2 K / L``. So the paper's ``Ke = 4.472 = sqrt(20)`` gives ``q/r = 20``;
the wheelbase L then moves Ka and Kb only (:func:`find_wheelbase`).
"""

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ParameterError
from ..numerics.finite import finite as _finite
from ..numerics.sampling import SampleHold

#: seed 000 eq 10: [Ka [V/rad], Kb [V/rad], Ke [V/m]]
PAPER_GAINS = (4.828, 3.767, 4.472)


class StateFeedback:
    """``u = -(Ka alpha + Kb heading_error + Ke lateral_error)``, optional hold and limit.

    Parameters
    ----------
    Ka : float
        Gain on the wheel angle [V/rad].
    Kb : float
        Gain on the heading error [V/rad].
    Ke : float
        Gain on the lateral error [V/m].
    sample_period : float
        Sample period [s], >= 0. 0: the law is evaluated at every communication point.
        Otherwise the output is sampled at multiples ``k * sample_period`` of absolute
        time and held, by the project's one rule (:mod:`agv_core.numerics.sampling`): an instant
        is sampled from the inputs held at it (an instant inside a communication step
        from the inputs held over that step, committed by :meth:`step`).
    u_max : float
        Output limit [V], >= 0; 0 = off.
    """

    def __init__(self, Ka: float = PAPER_GAINS[0], Kb: float = PAPER_GAINS[1],
                 Ke: float = PAPER_GAINS[2], sample_period: float = 0.0, u_max: float = 0.0
                 ) -> None:
        self.gains = np.array([_finite("Ka", Ka), _finite("Kb", Kb), _finite("Ke", Ke)])
        self.sample_period = _finite("sample_period", sample_period)
        if self.sample_period < 0.0:
            raise ParameterError("sample_period", f"must be >= 0 s (0 = every step), got "
                                 f"{sample_period}")
        self.u_max = _finite("u_max", u_max)
        if self.u_max < 0.0:
            raise ParameterError("u_max", f"must be >= 0 V (0 = off), got {u_max}")
        self.u = 0.0
        self._hold = SampleHold(self.sample_period)
        # the law in plain floats: Ka a + Kb b + Ke e summed left to right (numpy's dot of
        # the three agrees within rounding: tests/components/test_fast_step.py)
        self._ka, self._kb, self._ke = (float(g) for g in self.gains)

    def law(self, alpha: float, heading_error: float, lateral_error: float) -> float:
        """The control law without sampling [V] (limited by ``u_max`` if set)."""
        u = -(self._ka * alpha + self._kb * heading_error + self._ke * lateral_error)
        if self.u_max > 0.0:
            u = min(max(u, -self.u_max), self.u_max)
        return u

    def update(self, t: float, alpha: float, heading_error: float, lateral_error: float
               ) -> float:
        """Output [V] at time ``t`` [s] for the current inputs (the sample, or held)."""
        self.u = self._hold.output(t, (alpha, heading_error, lateral_error), self.law)
        return self.u

    def step(self, t: float, h: float, alpha: float, heading_error: float,
             lateral_error: float) -> None:
        """Commit the samples of the step from ``t`` to ``t + h`` [s] (inputs held)."""
        self._hold.step(t, h, (alpha, heading_error, lateral_error), self.law)

    def get_state(self) -> dict[str, Any]:
        """JSON-safe snapshot of the state."""
        return {"u": self.u, "hold": self._hold.get_state()}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a snapshot from :meth:`get_state`."""
        self.u = float(state["u"])
        self._hold.set_state(state["hold"])


# ---------------------------------------------------------------------- design
def model_b(V0: float, L: float, K: float) -> tuple[np.ndarray, np.ndarray]:
    """State-space matrices of seed 000 model b, states (alpha, beta, e).

    Parameters
    ----------
    V0 : float
        Speed [m/s].
    L : float
        Wheelbase [m], > 0.
    K : float
        Actuator gain [rad/(V.s)].

    Returns
    -------
    A : ndarray, shape (3, 3)
    B : ndarray, shape (3, 1)
    """
    if not L > 0.0:
        raise ParameterError("L", f"must be > 0 m, got {L}")
    A = np.array([[0.0, 0.0, 0.0],
                  [V0 / L, 0.0, 0.0],
                  [V0, V0, 0.0]])
    B = np.array([[K], [0.0], [0.0]])
    return A, B


def lqr_gains(V0: float, L: float, K: float, Q: Any, R: Any) -> np.ndarray:
    """LQR gains [Ka [V/rad], Kb [V/rad], Ke [V/m]] for model b (python-control).

    Parameters
    ----------
    V0, L, K : float
        Speed [m/s], wheelbase [m], actuator gain [rad/(V.s)].
    Q : array_like, shape (3, 3) or (3,)
        State weight (a vector is a diagonal).
    R : float or array_like, shape (1, 1)
        Input weight.

    Returns
    -------
    ndarray, shape (3,)
        Gains with ``u = -gains @ (alpha, beta, e)``.
    """
    import control

    A, B = model_b(V0, L, K)
    Q = np.asarray(Q, dtype=float)
    if Q.ndim == 1:
        Q = np.diag(Q)
    R = np.atleast_2d(np.asarray(R, dtype=float))
    gains, _, _ = control.lqr(A, B, Q, R)
    return np.asarray(gains, dtype=float).ravel()


def find_wheelbase(target: ArrayLike = PAPER_GAINS, V0: float = 1.0, K: float = 0.6,
                   q: float | None = 20.0, r: float = 1.0,
                   bounds: tuple[float, float] = (0.2, 5.0)) -> dict[str, Any]:
    """The wheelbase L for which LQR on model b reproduces ``target`` gains.

    Uses ``Q = diag(0, 0, q)``, ``R = r``; ``q = 20`` reproduces the paper's
    ``Ke = 4.472 = sqrt(20)`` (``Ke = sqrt(q / r)`` exactly, see the module docstring;
    ``q=None`` takes ``q = r * Ke^2`` from ``target``). It then minimises the squared error
    of (Ka, Kb) over L with :func:`scipy.optimize.minimize_scalar`.

    Parameters
    ----------
    target : sequence of 3 float
        [Ka [V/rad], Kb [V/rad], Ke [V/m]] to reproduce.
    V0 : float
        Design speed [m/s].
    K : float
        Actuator gain [rad/(V.s)].
    q : float or None
        Weight on e in Q.
    r : float
        Input weight R.
    bounds : (float, float)
        Search interval for L [m].

    Returns
    -------
    dict
        ``L`` [m], ``Q`` (3x3 list), ``R`` (float), ``gains`` (list of 3), ``residual``
        (max abs gain error).
    """
    from scipy.optimize import minimize_scalar

    target = np.asarray(target, dtype=float)
    if q is None:
        q = r * target[2] ** 2
    Q = np.diag([0.0, 0.0, q])

    def cost(L: float) -> float:
        return float(np.sum((lqr_gains(V0, L, K, Q, r)[:2] - target[:2]) ** 2))

    result = minimize_scalar(cost, bounds=bounds, method="bounded",
                             options={"xatol": 1e-10})
    L = float(result.x)
    gains = lqr_gains(V0, L, K, Q, r)
    return {"L": L, "Q": Q.tolist(), "R": float(r), "gains": gains.tolist(),
            "residual": float(np.max(np.abs(gains - target)))}


def closed_loop(gains: Sequence[float], V0: float, L: float, K: float) -> dict[str, Any]:
    """Closed-loop poles of model b under ``u = -gains @ (alpha, beta, e)``.

    Parameters
    ----------
    gains : sequence of 3 float
        [Ka [V/rad], Kb [V/rad], Ke [V/m]].
    V0, L, K : float
        Speed [m/s], wheelbase [m], actuator gain [rad/(V.s)].

    Returns
    -------
    dict
        ``poles`` (complex ndarray [1/s], sorted by real part), ``damping`` (ndarray,
        -Re(p)/|p| per pole), ``natural_frequency`` (ndarray [rad/s], |p|),
        ``min_damping`` (float) and ``stable`` (bool).
    """
    A, B = model_b(V0, L, K)
    acl = A - B @ np.atleast_2d(np.asarray(gains, dtype=float))
    poles = np.linalg.eigvals(acl)
    poles = poles[np.argsort(poles.real)]
    wn = np.abs(poles)
    damping = np.where(wn > 0.0, -poles.real / np.where(wn > 0.0, wn, 1.0), -1.0)
    return {"poles": poles, "damping": damping, "natural_frequency": wn,
            "min_damping": float(np.min(damping)), "stable": bool(np.all(poles.real < 0.0))}


def loop_poles(gains: Sequence[float], V0: float, L: float, K: float, single_track: Any = None,
               delay: float = 0.0, pade_order: int = 7) -> dict[str, Any]:
    """Closed-loop poles of seed 000's loop u = -gains @ (alpha, heading, e) around a
    linear plant: the actuator alpha' = K u (with a dead time ``delay`` [s] on u as a
    Pade approximant of ``pade_order``, model a) and either the linear kinematic vehicle
    (``single_track=None``: model b's plant) or the linear single-track model with tyre
    slip (``single_track``: an
    :class:`agv_core.dynamic_vehicle.dynamic_vehicle.SingleTrackParameters`, whose
    ``lateral_matrices`` give the lateral dynamics). e is the front-wheel centre's
    lateral offset from the straight path, heading the vehicle's heading.

    The single-track plant has the states (Y_R, psi, vy, r) with Y_R' = V0 psi + vy - b r,
    psi' = r, (vy, r)' = A_lat (vy, r) + B_lat alpha and e = Y_R + L psi; the kinematic
    one (psi, e) with psi' = V0 alpha / L, e' = V0 (alpha + psi).

    Returns
    -------
    dict
        ``poles`` (complex ndarray [1/s], sorted by real part), ``damping`` (per pole),
        ``dominant_damping`` (of the oscillatory pair with the largest real part: the
        loop's least damped mode; a Pade approximant adds fast poles of its own, so
        the minimum over all poles is not the loop's), ``stable`` (bool).
    """
    import control

    if single_track is None:
        A, B = model_b(V0, L, K)
        C = np.eye(3)
    else:
        p = single_track
        (a11, a12), (a21, a22) = p.lateral_matrices(V0)[0]
        b1, b2 = p.lateral_matrices(V0)[1]
        # states (alpha, Y_R, psi, vy, r)
        A = np.array([[0.0, 0.0, 0.0, 0.0, 0.0],
                      [0.0, 0.0, V0, 1.0, -p.b],
                      [0.0, 0.0, 0.0, 0.0, 1.0],
                      [b1, 0.0, 0.0, a11, a12],
                      [b2, 0.0, 0.0, a21, a22]])
        B = np.array([[K], [0.0], [0.0], [0.0], [0.0]])
        C = np.array([[1.0, 0.0, 0.0, 0.0, 0.0],
                      [0.0, 0.0, 1.0, 0.0, 0.0],
                      [0.0, 1.0, p.L, 0.0, 0.0]])
    plant = control.ss(A, B, C, np.zeros((3, 1)))
    if delay > 0.0:
        num, den = control.pade(delay, pade_order)
        plant = control.series(control.ss(control.tf(num, den)), plant)
    gain = control.ss(np.zeros((0, 0)), np.zeros((0, 3)), np.zeros((1, 0)),
                      np.atleast_2d(np.asarray(gains, dtype=float)))
    poles = np.linalg.eigvals(control.feedback(plant, gain).A)
    poles = poles[np.argsort(poles.real)]
    wn = np.abs(poles)
    damping = np.where(wn > 0.0, -poles.real / np.where(wn > 0.0, wn, 1.0), -1.0)
    pairs = np.flatnonzero(poles.imag > 1e-9)
    dominant = float(damping[pairs[np.argmax(poles.real[pairs])]]) if len(pairs) else 1.0
    return {"poles": poles, "damping": damping, "dominant_damping": dominant,
            "stable": bool(np.all(poles.real < 0.0))}
