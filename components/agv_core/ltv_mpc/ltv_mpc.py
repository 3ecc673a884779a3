"""Linear time-varying MPC of seed 001 (notes-001-003.md sections 1.3-1.4).

Prediction model: the unicycle x = [X, Y, alpha], u = [v_c, omega] (eq 11), linearised
about the reference (x_r, u_r) at the current sample and discretised by forward
differences with sample time T (eq 18)::

    A(k) = [[1, 0, -v_r sin(alpha_r) T], [0, 1, v_r cos(alpha_r) T], [0, 0, 1]]
    B(k) = [[cos(alpha_r) T, 0], [sin(alpha_r) T, 0], [0, T]]

on the errors x' = x - x_r (heading error wrapped to (-pi, pi]) and u' = u - u_r.
The state is augmented with the previous input (eqs 19-22), xi = [x'(k); u'(k-1)],
and the decision variables are the increments Delta u over the control horizon N_c
plus one slack gamma (eqs 23-29)::

    Y = Phi xi + Theta Delta U        (Y = [eta(k+1); ...; eta(k+N)], eta = x')
    J = Y' Qp Y + Delta U' Rc Delta U + rho gamma^2,   Qp = I_N (x) Q,  Rc = I_Nc (x) R

subject to (eqs 31-32, bounds per sample, A(k), B(k) and u_r frozen over the horizon)::

    du_min <= Delta u(k+i) <= du_max
    u_min - u_r <= u'(k-1) + sum_{j<=i} Delta u(k+j) <= u_max - u_r
    0 <= gamma <= gamma_max
    |e_X(k+i)|, |e_Y(k+i)| <= e_max + gamma     (only when e_max > 0)

The slack softens the optional "feasible region" bound e_max on the predicted position
errors; with e_max = 0 (default: its value is lost from the paper) it appears in the
cost only and the optimum has gamma = 0. The first increment is applied:
u(k) = u(k-1) + Delta u(k) (eq 30); the controller output is held for T (sampled at
k T by the rule of :mod:`agv_core.numerics.sampling`,
:class:`~agv_core.numerics.sampling.SampleHold` with memory: u(k-1) and the warm start come
from the committed sample before).

The QP (1/2 z' P z + q' z, l <= A z <= u with z = [Delta U; gamma]) is solved by OSQP
(operator splitting, with solution polishing), warm-started from the previous solution
shifted by one sample. A fresh solver is set up at every sample, so the result depends
only on the inputs and the saved warm start (bit-identical after a state restore; OSQP's
adaptive step is updated on a fixed iteration interval, never by wall-clock time). Any
status other than "solved" raises :class:`MpcSolveError`.
"""

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import osqp
import scipy.sparse as sp
from numpy.typing import ArrayLike

from ..errors import ParameterError
from ..numerics.paths import heading_error
from ..numerics.sampling import SampleHold


class MpcSolveError(RuntimeError):
    """The QP of one sample was not solved (the message names the solver status)."""


def error_model(v_r: float, alpha_r: float, T: float) -> tuple[np.ndarray, np.ndarray]:
    """A(k) (3x3) and B(k) (3x2) of eq (18), forward-difference discretisation."""
    s, c = math.sin(alpha_r), math.cos(alpha_r)
    A = np.array([[1.0, 0.0, -v_r * s * T], [0.0, 1.0, v_r * c * T], [0.0, 0.0, 1.0]])
    B = np.array([[c * T, 0.0], [s * T, 0.0], [0.0, T]])
    return A, B


def prediction_matrices(A: np.ndarray, B: np.ndarray, N: int, Nc: int
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Phi (3N x 5) and Theta (3N x 2Nc) of eqs (22)-(24) for a frozen A, B.

    Parameters
    ----------
    A, B : numpy.ndarray
        Error model (3x3, 3x2).
    N, Nc : int
        Prediction and control horizons, 1 <= Nc <= N. Increments after Nc are zero.
    """
    At = np.block([[A, B], [np.zeros((2, 3)), np.eye(2)]])
    Bt = np.vstack([B, np.eye(2)])
    Ct = np.hstack([np.eye(3), np.zeros((3, 2))])
    powers = [np.eye(5)]
    for _ in range(N):
        powers.append(At @ powers[-1])
    Phi = np.vstack([Ct @ powers[i] for i in range(1, N + 1)])
    Theta = np.zeros((3 * N, 2 * Nc))
    for i in range(1, N + 1):
        for j in range(1, min(i, Nc) + 1):
            Theta[3 * (i - 1):3 * i, 2 * (j - 1):2 * j] = Ct @ powers[i - j] @ Bt
    return Phi, Theta


class LtvMpc:
    """The seed-001 LTV MPC (see the module docstring).

    Parameters
    ----------
    sample_time : float
        T [s], > 0: prediction step and the period at which the output is updated.
    horizon : int
        Prediction horizon N >= 1 (the paper's p = N).
    control_horizon : int
        N_c, 1 <= N_c <= N; 0 means N_c = N.
    q : sequence of 3 float
        Diagonal of Q: weights on e_X [1/m^2], e_Y [1/m^2], e_alpha [1/rad^2], >= 0.
    lam : float
        R = lam I_2 (weight on Delta v_c [s^2/m^2] and Delta omega [s^2/rad^2]), > 0.
    rho : float
        Slack weight, > 0.
    slack_max : float
        Upper bound of the slack gamma [m], >= 0.
    e_max : float
        Soft bound [m] on the predicted |e_X|, |e_Y|; 0 = no bound.
    u_min, u_max : sequence of 2 float
        Bounds of (v_c [m/s], omega [rad/s]).
    du_min, du_max : sequence of 2 float
        Bounds of the increments per sample (m/s, rad/s).
    eps : float
        OSQP absolute and relative tolerance (before polishing).
    max_iter : int
        OSQP iteration limit per sample.
    warm_start : bool
        Start each QP from the previous solution, shifted (False: OSQP's cold start;
        for the benchmark).
    """

    def __init__(self, sample_time: float = 0.2, horizon: int = 5, control_horizon: int = 0,
                 q: Sequence[float] = (1.0, 1.0, 0.5), lam: float = 0.1, rho: float = 10.0,
                 slack_max: float = 10.0, e_max: float = 0.0,
                 u_min: Sequence[float] = (0.0, -0.6), u_max: Sequence[float] = (0.8, 0.6),
                 du_min: Sequence[float] = (-0.05, -0.05),
                 du_max: Sequence[float] = (0.05, 0.05), eps: float = 1e-7,
                 max_iter: int = 4000, warm_start: bool = True) -> None:
        if not (math.isfinite(sample_time) and sample_time > 0.0):
            raise ParameterError("sample_time", f"must be > 0 s, got {sample_time}")
        if int(horizon) != horizon or horizon < 1:
            raise ParameterError("horizon", f"must be an integer >= 1, got {horizon}")
        horizon = int(horizon)
        control_horizon = int(control_horizon) or horizon
        if not 1 <= control_horizon <= horizon:
            raise ParameterError("control_horizon",
                                 f"must be 0 or within 1..{horizon}, got {control_horizon}")
        q = [float(v) for v in q]
        if len(q) != 3 or not all(math.isfinite(v) and v >= 0.0 for v in q):
            raise ParameterError("q", f"needs three finite weights >= 0, got {q}")
        for name, value in (("lam", lam), ("rho", rho), ("eps", eps)):
            if not (math.isfinite(value) and value > 0.0):
                raise ParameterError(name, f"must be > 0, got {value}")
        for name, value in (("slack_max", slack_max), ("e_max", e_max)):
            if not (math.isfinite(value) and value >= 0.0):
                raise ParameterError(name, f"must be >= 0, got {value}")
        if int(max_iter) != max_iter or max_iter < 1:
            raise ParameterError("max_iter", f"must be an integer >= 1, got {max_iter}")
        bounds = {}
        for label, lo, hi in (("u", u_min, u_max), ("du", du_min, du_max)):
            lo, hi = [float(v) for v in lo], [float(v) for v in hi]
            for i, part in enumerate(("v", "omega")):
                if not (math.isfinite(lo[i]) and math.isfinite(hi[i]) and lo[i] <= hi[i]):
                    raise ParameterError(f"{label}_{part}", f"bounds [{lo[i]}, {hi[i]}] are "
                                                           "not an interval")
            if label == "du" and not all(low <= 0.0 <= high for low, high in zip(lo, hi)):
                raise ParameterError("du", f"increment bounds {lo}..{hi} must contain 0")
            bounds[label] = (np.array(lo), np.array(hi))
        self.T = float(sample_time)
        self.N = horizon
        self.Nc = control_horizon
        self.q = np.array(q)
        self.lam = float(lam)
        self.rho = float(rho)
        self.slack_max = float(slack_max)
        self.e_max = float(e_max)
        self.u_min, self.u_max = bounds["u"]
        self.du_min, self.du_max = bounds["du"]
        self.eps = float(eps)
        self.max_iter = int(max_iter)
        self.warm_start = bool(warm_start)
        self.u_prev: list[float] | None = None  # u(k-1) [v_c, omega] of the last sample
        self.warm: Any = None       # its warm start (x, y): the solution before, shifted
        self._hold = SampleHold(self.T, memory=True)

    # ------------------------------------------------------------------ the QP
    def qp(self, x_err: np.ndarray, u_prev_err: np.ndarray, v_r: float, alpha_r: float,
           u_r: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """P, q, A, l, u of the sample's QP (dense numpy; see the module docstring)."""
        N, Nc = self.N, self.Nc
        A, B = error_model(v_r, alpha_r, self.T)
        Phi, Theta = prediction_matrices(A, B, N, Nc)
        xi = np.concatenate([x_err, u_prev_err])
        Qp = np.kron(np.eye(N), np.diag(self.q))
        Rc = np.kron(np.eye(Nc), self.lam * np.eye(2))
        n = 2 * Nc + 1
        P = np.zeros((n, n))
        P[:-1, :-1] = 2.0 * (Theta.T @ Qp @ Theta + Rc)
        P[-1, -1] = 2.0 * self.rho
        E = Phi @ xi
        qv = np.zeros(n)
        qv[:-1] = 2.0 * Theta.T @ Qp @ E
        rows, lo, hi = [], [], []
        # increments
        rows.append(np.hstack([np.eye(2 * Nc), np.zeros((2 * Nc, 1))]))
        lo.append(np.tile(self.du_min, Nc))
        hi.append(np.tile(self.du_max, Nc))
        # absolute inputs
        AI = np.kron(np.tril(np.ones((Nc, Nc))), np.eye(2))
        rows.append(np.hstack([AI, np.zeros((2 * Nc, 1))]))
        lo.append(np.tile(self.u_min - u_r - u_prev_err, Nc))
        hi.append(np.tile(self.u_max - u_r - u_prev_err, Nc))
        # slack
        slack_row = np.zeros((1, n))
        slack_row[0, -1] = 1.0
        rows.append(slack_row)
        lo.append(np.zeros(1))
        hi.append(np.array([self.slack_max if self.e_max > 0.0 else 0.0]))
        # soft bound on the predicted position errors: +-(E + Theta dU) - gamma <= e_max
        if self.e_max > 0.0:
            pos = [3 * i + j for i in range(N) for j in (0, 1)]
            G = Theta[pos]
            ones = np.ones((len(pos), 1))
            rows.append(np.hstack([G, -ones]))
            lo.append(np.full(len(pos), -np.inf))
            hi.append(self.e_max - E[pos])
            rows.append(np.hstack([-G, -ones]))
            lo.append(np.full(len(pos), -np.inf))
            hi.append(self.e_max + E[pos])
        return P, qv, np.vstack(rows), np.concatenate(lo), np.concatenate(hi)

    def solve(self, x_err: ArrayLike, u_prev_err: ArrayLike, v_r: float,
              alpha_r: float, u_r: ArrayLike, warm: Any = None
              ) -> tuple[np.ndarray, np.ndarray, int]:
        """Solve one sample's QP.

        Returns
        -------
        tuple
            (z, y, iterations): primal solution [Delta U; gamma], dual solution,
            OSQP iterations.

        Raises
        ------
        MpcSolveError
            When OSQP's status is not "solved" (infeasible, iteration limit, ...).
        """
        P, qv, Acon, lo, hi = self.qp(np.asarray(x_err, float), np.asarray(u_prev_err, float),
                                      v_r, alpha_r, np.asarray(u_r, float))
        solver = osqp.OSQP()
        solver.setup(sp.csc_matrix(np.triu(P)), qv, sp.csc_matrix(Acon), lo, hi,
                     verbose=False, eps_abs=self.eps, eps_rel=self.eps, polishing=True,
                     max_iter=self.max_iter, adaptive_rho_interval=25, warm_starting=True,
                     check_termination=5)
        if warm is not None and len(warm[0]) == P.shape[0] and len(warm[1]) == Acon.shape[0]:
            solver.warm_start(x=np.asarray(warm[0]), y=np.asarray(warm[1]))
        result = solver.solve(raise_error=False)
        status = result.info.status_val
        if status != osqp.SolverStatus.OSQP_SOLVED:
            raise MpcSolveError(f"QP not solved: OSQP status '{result.info.status}' after "
                                f"{result.info.iter} iterations (horizon {self.N}, "
                                f"max_iter {self.max_iter})")
        return result.x, result.y, int(result.info.iter)

    # ------------------------------------------------------------------ the law
    def compute(self, x: float, y: float, heading: float, ref: Mapping[str, float],
                u_prev: ArrayLike) -> dict[str, Any]:
        """One sample: the command u(k) from the pose and the reference.

        Parameters
        ----------
        x, y, heading : float
            Measured centroid position [m] and heading [rad].
        ref : mapping
            x, y, heading, v, omega of the reference at this sample.
        u_prev : sequence of 2 float
            u(k-1) = (v_c [m/s], omega [rad/s]).

        Returns
        -------
        dict
            v_c, omega: the command; dv_c, domega: its increment; slack; iterations;
            e_x, e_y, e_heading (errors x - x_r, wrapped), e_lat (lateral error,
            positive left of the reference), e_pos (position error norm).
        """
        u_r = np.array([ref["v"], ref["omega"]])
        x_err = np.array([x - ref["x"], y - ref["y"], heading_error(heading, ref["heading"])])
        u_prev = np.asarray(u_prev, float)
        z, dual, iterations = self.solve(x_err, u_prev - u_r, ref["v"], ref["heading"], u_r,
                                         self.warm if self.warm_start else None)
        du = z[:2]
        u = u_prev + du
        # warm start of the next sample: shift the increments by one sample
        shifted = np.concatenate([z[2:-1], np.zeros(2), z[-1:]])
        self._next_warm = (shifted.tolist(), dual.tolist())
        out = errors(x, y, heading, ref)
        out.update(v_c=float(u[0]), omega=float(u[1]), dv_c=float(du[0]),
                   domega=float(du[1]), slack=float(z[-1]), iterations=iterations)
        return out

    def _law(self, x: float, y: float, heading: float, x_r: float, y_r: float,
             heading_r: float, v_r: float, omega_r: float) -> dict[str, Any]:
        """One sample from the held inputs, starting from the committed sample before it
        (its command is u(k-1), its shifted solution the warm start)."""
        prior = self._hold.prior
        if prior is None:                   # the first sample: u(-1) = u_r, no warm start
            self.u_prev, self.warm = None, None
            u_prev = [v_r, omega_r]
        else:
            self.u_prev = [prior["out"]["v_c"], prior["out"]["omega"]]
            self.warm = prior["warm"]
            u_prev = self.u_prev
        ref = {"x": x_r, "y": y_r, "heading": heading_r, "v": v_r, "omega": omega_r}
        out = self.compute(x, y, heading, ref, u_prev)
        return {"out": out, "warm": self._next_warm}

    @staticmethod
    def _inputs(x: float, y: float, heading: float, ref: Mapping[str, float]
                ) -> tuple[float, float, float, float, float, float, float, float]:
        return (float(x), float(y), float(heading), float(ref["x"]), float(ref["y"]),
                float(ref["heading"]), float(ref["v"]), float(ref["omega"]))

    def update(self, t: float, x: float, y: float, heading: float, ref: Mapping[str, float]
               ) -> dict[str, Any]:
        """Output at time ``t`` [s], sampled at k T and held in between.

        The project's one sampling rule (:mod:`agv_core.numerics.sampling`, a sample-and-hold
        with memory): at an instant k T on a communication point the law is evaluated
        from the current inputs at every call (newer inputs at the same instant), each
        time from the same u(k-1) and warm start; between instants the held output is
        returned. :meth:`step` commits the samples of a step.
        """
        return dict(self._hold.output(t, self._inputs(x, y, heading, ref), self._law)["out"])

    def step(self, t: float, h: float, x: float, y: float, heading: float,
             ref: Mapping[str, float]) -> None:
        """Commit the samples of the step from ``t`` to ``t + h`` [s], inputs held."""
        self._hold.step(t, h, self._inputs(x, y, heading, ref), self._law)

    def get_state(self) -> dict[str, Any]:
        """JSON-safe snapshot: the sample-and-hold (held and prior samples)."""
        return {"hold": self._hold.get_state(), "u_prev": self.u_prev, "warm": self.warm}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a snapshot from :meth:`get_state`."""
        self._hold.set_state(state["hold"])
        self.u_prev, self.warm = state["u_prev"], state["warm"]


def errors(x: float, y: float, heading: float, ref: Mapping[str, float]) -> dict[str, float]:
    """Tracking errors of the pose against a reference sample (signs: pose - reference).

    Returns a dict: e_x, e_y [m], e_heading [rad] (wrapped), e_lat [m] (positive left of
    the reference heading), e_long [m] (positive ahead), e_pos [m] (distance).
    """
    dx, dy = x - ref["x"], y - ref["y"]
    s, c = math.sin(ref["heading"]), math.cos(ref["heading"])
    return {"e_x": dx, "e_y": dy, "e_heading": heading_error(heading, ref["heading"]),
            "e_lat": -s * dx + c * dy, "e_long": c * dx + s * dy, "e_pos": math.hypot(dx, dy)}
