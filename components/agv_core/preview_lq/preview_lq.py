"""Preview + LQ path-tracking controller of seed 004 (Chen, Zhu, Torisu, Takeda 2006).

Rear-axle-centre kinematics (seed 004 eq 2), state x = [x, y, theta, alpha] (eq 1):

    x' = V cos(theta),  y' = V sin(theta),  theta' = (V / L) tan(alpha),  alpha' = u

Steps of the law, evaluated on every sample:

1. Future point Q (eq 5): the pose reached after ``tau`` at the current steering angle,
   as the paper's second-order Taylor expansion of the arc::

       alpha_q = alpha
       theta_q = theta + (V tau / L) tan(alpha)
       x_q = x + V tau cos(theta) - V^2 tau^2 tan(alpha) sin(theta) / (2 L)
       y_q = y + V tau sin(theta) + V^2 tau^2 tan(alpha) cos(theta) / (2 L)

2. Discretised path Omega (eqs 3-4): polyline vertices; heading by the central difference
   of the vertices, steering angle from the curvature by second central differences,
   alpha = atan(L kappa) (eq 4 in parametric form, see :func:`discretise`).
3. Target point P*: the point of the polyline closest to Q (nearest vertex, then the two
   adjacent segments); theta_p, alpha_p interpolated linearly along the segment.
4. Variational model about P* (eqs 6-7) with the speed variation dV as second input::

       A = [[0, 0, -V sin(theta_p), 0],          B = [[cos(theta_p),      0],
            [0, 0,  V cos(theta_p), 0],               [sin(theta_p),      0],
            [0, 0, 0, V / (L cos^2(alpha_p))],        [tan(alpha_p) / L,  0],
            [0, 0, 0, 0]]                             [0,                 1]]

5. LQ gain (eqs 8-10) by :func:`control.lqr` with Q = diag(10, 10, 10, 1),
   R = diag(10000, 1); [k_v; k_u] = -R^-1 B^T P.
6. Steering command (eq 12): alpha = alpha_p + k_u . dx tau, dx = x_q - x_p (heading
   difference wrapped to (-pi, pi]), clipped to +/- alpha_max.

The steering angle that enters Q and dalpha: eq 12 read literally uses the measured
angle, alpha_ref = F(alpha_meas). F has slope dF/dalpha = tau k_u . d(dx)/dalpha, about
-5.8 at the defaults, so with an actuator that reaches the command within one sample the
iteration alpha <- F(alpha) rings and diverges; the paper's servo-driven steering wheel
lags enough to hide this. By default (``alpha_fixed_point``) the command is therefore the
fixed point alpha_ref = F(alpha_ref), the state that a fast steering servo settles to
under the paper's law (F decreases steeply, so the root is unique in practice; Brent's
method on [-alpha_max, alpha_max]). ``alpha_fixed_point=False`` is the literal law.

Dead reckoning (our addition, not the paper's): the fix (x_meas, y_meas), ``fix_age`` s
old, is carried forward along the exact arc of eq 2 with the current steering angle and
the speed V, starting from the heading theta - (V / L) tan(alpha) fix_age.

Gain evaluation (deterministic): with q_x == q_y the Riccati problem is invariant under a
rotation of the (x, y) plane: A(theta_p) = T A(0) T^T, B(theta_p) = T B(0), Q = T Q T^T
with T = blockdiag(Rot(theta_p), 1, 1), hence K(theta_p, alpha_p) = K(0, alpha_p) T^T
exactly. K(0, alpha) is computed on demand at the nodes alpha = n ``gain_quantum``
(default 0.01 rad), cached by n, and linearly interpolated in alpha_p between nodes.
With q_x != q_y theta_p is in addition rounded to the nearest node
m ``gain_quantum`` (cache key (m, n)). Either way the gain used is a pure function of
(theta_p, alpha_p), never of the cache's history.
"""

import math
from collections.abc import Sequence
from typing import Any, cast

import numpy as np

from ..errors import ParameterError
from ..numerics.angles import wrap_angle
from ..numerics.arc import arc_pose  # the exact arc of eq 2 (numerics/arc.py)
from ..numerics.sampling import SampleHold

#: Default path of the FMU: seed 004's sine y = 2 sin(x / 3) [m] (wavelength 6 pi m).
DEFAULT_PATH = "sine:amplitude=2,wavelength=18.84955592153876"


def future_point(x: float, y: float, theta: float, alpha: float, speed: float,
                 wheelbase: float, tau: float) -> tuple[float, float, float, float]:
    """Future point Q after ``tau`` at constant steering angle (seed 004 eq 5).

    Second-order Taylor expansion in ``tau`` of the exact arc; the position error is
    bounded by V w^2 tau^3 / 6 with w = V tan(alpha) / L (Lagrange remainder: the third
    time derivative of the position has norm V w^2); theta_q is exact.

    Parameters
    ----------
    x, y : float
        Rear-axle centre [m].
    theta : float
        Heading [rad].
    alpha : float
        Steering angle [rad].
    speed : float
        V [m/s].
    wheelbase : float
        L [m].
    tau : float
        Preview time [s].

    Returns
    -------
    tuple of float
        (x_q [m], y_q [m], theta_q [rad], alpha_q [rad]).
    """
    t = math.tan(alpha)
    c, s = math.cos(theta), math.sin(theta)
    vt = speed * tau
    quad = speed * speed * tau * tau * t / (2.0 * wheelbase)
    return (x + vt * c - quad * s, y + vt * s + quad * c,
            theta + vt * t / wheelbase, alpha)


def discretise(x: Any, y: Any, wheelbase: float) -> tuple[np.ndarray, np.ndarray]:
    """Heading and steering angle along a polyline by central differences (eqs 3-4).

    Eq 3 (theta = atan(dy/dx)) and eq 4 (alpha = atan(L cos^3(theta) d2y/dx2)) are
    written for a path y(x); cos^3(theta) d2y/dx2 is the curvature kappa of the graph,
    so the parametric form used here, valid for closed paths too, is

        theta = atan2(y', x'),  kappa = (x' y'' - y' x'') / (x'^2 + y'^2)^(3/2),
        alpha = atan(L kappa),

    with derivatives with respect to the vertex index by central differences (second
    order one-sided at the ends of the array), so both are O(ds^2) accurate.

    Parameters
    ----------
    x, y : array_like
        Vertices [m], at least 3.
    wheelbase : float
        L [m].

    Returns
    -------
    theta, alpha : numpy.ndarray
        Heading [rad] (unwrapped along the array) and steering angle [rad] per vertex.
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    dx, dy = np.gradient(x, edge_order=2), np.gradient(y, edge_order=2)
    ddx, ddy = np.gradient(dx, edge_order=2), np.gradient(dy, edge_order=2)
    # interior second derivative: the three-point stencil x[i+1] - 2 x[i] + x[i-1]
    ddx[1:-1] = x[2:] - 2.0 * x[1:-1] + x[:-2]
    ddy[1:-1] = y[2:] - 2.0 * y[1:-1] + y[:-2]
    theta = np.unwrap(np.arctan2(dy, dx))
    kappa = (dx * ddy - dy * ddx) / np.hypot(dx, dy) ** 3
    return theta, np.arctan(wheelbase * kappa)


def variational_model(theta_p: float, alpha_p: float, speed: float, wheelbase: float
                      ) -> tuple[np.ndarray, np.ndarray]:
    """A(t), B(t) of the variational model about the target point (eqs 6-7).

    Returns
    -------
    A : numpy.ndarray, shape (4, 4)
    B : numpy.ndarray, shape (4, 2)
        Columns of B: speed variation dV [m/s], steering rate du [rad/s].
    """
    c, s = math.cos(theta_p), math.sin(theta_p)
    A = np.zeros((4, 4))
    A[0, 2] = -speed * s
    A[1, 2] = speed * c
    A[2, 3] = speed / (wheelbase * math.cos(alpha_p) ** 2)
    B = np.zeros((4, 2))
    B[:, 0] = (c, s, math.tan(alpha_p) / wheelbase, 0.0)
    B[3, 1] = 1.0
    return A, B


def lq_gain(theta_p: float, alpha_p: float, speed: float, wheelbase: float,
            q: Sequence[float], r: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """LQ gain of eqs 8-10 by :func:`control.lqr`.

    Parameters
    ----------
    theta_p, alpha_p : float
        Target heading and steering angle [rad].
    speed, wheelbase : float
        V [m/s], L [m].
    q, r : sequence of float
        Diagonals of Q (4) and R (2).

    Returns
    -------
    K : numpy.ndarray, shape (2, 4)
        control.lqr gain (u = -K dx), so [k_v; k_u] = -K.
    P : numpy.ndarray, shape (4, 4)
        Stabilising solution of the Riccati equation (eq 9).
    """
    import control

    A, B = variational_model(theta_p, alpha_p, speed, wheelbase)
    K, P, _ = control.lqr(A, B, np.diag(q), np.diag(r))
    return np.asarray(K), np.asarray(P)


def _rotation(theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    T = np.eye(4)
    T[:2, :2] = ((c, -s), (s, c))
    return T


class DiscretePath:
    """The discretised path Omega: vertices with theta, alpha, and nearest-point search.

    Parameters
    ----------
    source : tuple of array_like or path object
        Either ``(x, y)`` vertex arrays [m] (used as they are; ``ds`` ignored) or an
        ``agv_core.numerics.paths.ReferencePath``-like object with ``polyline(s0, s1, ds)``,
        ``project(x, y, s_hint)`` and ``length``; its vertices lie at s = i ds. A finite
        path is discretised whole at construction; an unbounded one (every kind of
        ``agv_core.numerics.paths``: defined for all s, negative too) in fixed chunks of
        ``chunk`` vertices on demand, each with one extra vertex on either side for the
        central differences, so a vertex and its theta, alpha depend only on its index
        (deterministic, whatever the order of the requests).
    ds : float
        Vertex spacing along the path [m].
    wheelbase : float
        L [m] for alpha = atan(L kappa).
    chunk : int
        Vertices per lazily built chunk.
    """

    def __init__(self, source: Any, ds: float, wheelbase: float, chunk: int = 512) -> None:
        self.ds = float(ds)
        self.wheelbase = float(wheelbase)
        self.chunk = int(chunk)
        #: (x, y, theta, alpha) arrays: of the whole path (key None) or of chunk k
        self._chunks: dict[int | None, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]
        self._chunks = {}
        #: the path source (None for vertex arrays)
        self.path: Any
        #: number of vertices (None: unbounded, built in chunks)
        self.count: int | None
        if isinstance(source, tuple):
            x, y = (np.asarray(a, dtype=float) for a in source)
            if x.shape != y.shape or x.ndim != 1 or x.size < 3:
                raise ParameterError("path", "sampled path needs two equal 1-D arrays of >= 3")
            self.path = None
            self._set_arrays(x, y)
        else:
            self.path = source
            length = source.length
            if math.isfinite(length):
                n = int(math.floor(length / self.ds + 1e-9)) + 1
                x, y = self._sample(0, n - 1)
                self._set_arrays(x, y)
            else:
                self.count = None

    def _set_arrays(self, x: np.ndarray, y: np.ndarray) -> None:
        theta, alpha = discretise(x, y, self.wheelbase)
        self.count = x.size
        self._chunks[None] = (x, y, theta, alpha)

    def _sample(self, i0: int, i1: int) -> tuple[np.ndarray, np.ndarray]:
        """Vertices i0..i1 (inclusive) of the path source, at s = i ds."""
        n = i1 - i0 + 1
        xs, ys = self.path.polyline(i0 * self.ds, i1 * self.ds, self.ds)
        xs, ys = np.asarray(xs, dtype=float), np.asarray(ys, dtype=float)
        if xs.size < n:  # endpoint-exclusive polyline: ask half a step further
            xs, ys = self.path.polyline(i0 * self.ds, (i1 + 0.5) * self.ds, self.ds)
            xs, ys = np.asarray(xs, dtype=float), np.asarray(ys, dtype=float)
        if xs.size < n:
            raise ValueError(f"path polyline gave {xs.size} vertices, expected {n}")
        return xs[:n], ys[:n]

    def _chunk(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        data = self._chunks.get(k)
        if data is None:
            lo = k * self.chunk - 1
            hi = (k + 1) * self.chunk
            x, y = self._sample(lo, hi)
            theta, alpha = discretise(x, y, self.wheelbase)
            keep = slice(k * self.chunk - lo, k * self.chunk - lo + self.chunk)
            data = (x[keep], y[keep], theta[keep], alpha[keep])
            if len(self._chunks) > 8:  # bounded memory on an unbounded path
                self._chunks.pop(next(iter(self._chunks)))
            self._chunks[k] = data
        return data

    def vertices(self, i0: int, i1: int) -> tuple[Any, ...]:
        """Arrays (x, y, theta, alpha) of vertices i0..i1 inclusive (clipped if finite)."""
        if self.count is not None:
            i0, i1 = max(i0, 0), min(i1, self.count - 1)
            x, y, th, al = self._chunks[None]
            return i0, x[i0:i1 + 1], y[i0:i1 + 1], th[i0:i1 + 1], al[i0:i1 + 1]
        parts = [self._chunk(k) for k in range(i0 // self.chunk, i1 // self.chunk + 1)]
        cat = [np.concatenate([p[j] for p in parts]) for j in range(4)]
        off = i0 - (i0 // self.chunk) * self.chunk
        return (i0,) + tuple(a[off:off + i1 - i0 + 1] for a in cat)

    def initial_index(self, x: float, y: float) -> int:
        """Index of a vertex near (x, y) [m] without a hint (global search)."""
        if self.count is not None:
            vx, vy = self._chunks[None][:2]
            dist = np.hypot(vx - x, vy - y)
            # the first of equally near vertices (a path that overlaps itself)
            return int(np.flatnonzero(dist <= dist.min() + 1e-6)[0])
        return int(round(self.path.project(x, y).s / self.ds))

    def nearest(self, x: float, y: float, hint: int, radius: float = 2.0) -> dict[str, Any]:
        """Point of the polyline closest to (x, y) [m], searched around vertex ``hint``.

        The nearest vertex is searched within ``radius`` [m] of arc length around the
        hint (re-centred while it lands on the window's edge), then the closest point
        on its two adjacent segments is taken (seed 004 section 2.1).

        Returns
        -------
        dict
            ``index`` (nearest vertex), ``x``, ``y`` [m], ``theta``, ``alpha`` [rad].
        """
        half = max(2, int(math.ceil(radius / self.ds)))
        centre = int(hint)
        for _ in range(64):
            i0, vx, vy, vth, val = self.vertices(centre - half - 1, centre + half + 1)
            d2 = (vx - x) ** 2 + (vy - y) ** 2
            j = int(np.argmin(d2))
            at_edge = (j == 0 and (self.count is None or i0 > 0)) or (
                j == vx.size - 1 and (self.count is None or i0 + j < self.count - 1))
            if not at_edge:
                break
            centre = i0 + j
        best: tuple[float, float, float, float, float] | None = None
        for a in (j - 1, j):
            b = a + 1
            if a < 0 or b >= vx.size:
                continue
            ex, ey = vx[b] - vx[a], vy[b] - vy[a]
            seg2 = ex * ex + ey * ey
            along = (x - vx[a]) * ex + (y - vy[a]) * ey
            f = 0.0 if seg2 == 0.0 else min(1.0, max(0.0, along / seg2))
            px, py = vx[a] + f * ex, vy[a] + f * ey
            dist = (px - x) ** 2 + (py - y) ** 2
            if best is None or dist < best[0]:
                theta = vth[a] + f * wrap_angle(vth[b] - vth[a])
                alpha = val[a] + f * (val[b] - val[a])
                best = (dist, px, py, theta, alpha)
        _, px, py, theta, alpha = cast(tuple[float, float, float, float, float],
                                       best)  # a window holds a segment: never None
        return {"index": i0 + j, "x": float(px), "y": float(py),
                "theta": float(theta), "alpha": float(alpha)}


class PreviewLQ:
    """Preview + LQ steering controller of seed 004 (see the module docstring).

    Parameters
    ----------
    path : tuple of array_like or path object
        The reference path, see :class:`DiscretePath`.
    wheelbase : float
        L [m], > 0.
    speed : float
        Nominal speed V [m/s], > 0 (forward).
    tau : float
        Preview time [s], > 0 (seed 004: the total station's mean sample time 0.65 s).
    ds : float
        Polyline spacing [m], > 0.
    q : sequence of 4 float
        Diagonal of Q (x, y, theta, alpha), each > 0.
    r : sequence of 2 float
        Diagonal of R (dV, du), each > 0.
    alpha_max : float
        Steering limit [rad], in (0, pi/2).
    sample_period : float
        Controller period [s]; 0 evaluates on every call (every communication step).
        Sampling follows :mod:`agv_core.numerics.sampling`.
    dead_reckoning : bool
        Propagate the last fix by ``fix_age`` along the kinematic arc (our addition).
    alpha_fixed_point : bool
        True: the steering angle in the future point and in dx is the command itself,
        alpha_ref = F(alpha_ref), solved by Brent's method (the settled state of a fast
        steering servo; stable with an ideal actuator). False: the measured steering
        angle is used, alpha_ref = F(alpha_meas), eq 12 literally; its slope
        dF/dalpha is about -5.8 at the defaults, so it needs a steering actuator with
        lag (a per-step ideal actuator makes it diverge).
    gain_quantum : float
        Node spacing of the gain table in alpha_p (and theta_p) [rad], > 0.
    search_radius : float
        Arc-length window of the nearest-vertex search [m], > 0.
    """

    def __init__(self, path: Any, wheelbase: float = 1.6, speed: float = 1.5,
                 tau: float = 0.65, ds: float = 0.05,
                 q: Sequence[float] = (10.0, 10.0, 10.0, 1.0),
                 r: Sequence[float] = (10000.0, 1.0), alpha_max: float = 0.61,
                 sample_period: float = 0.0, dead_reckoning: bool = False,
                 alpha_fixed_point: bool = True, gain_quantum: float = 0.01,
                 search_radius: float = 2.0) -> None:
        for name, value in (("wheelbase", wheelbase), ("speed", speed), ("tau", tau),
                            ("ds", ds), ("gain_quantum", gain_quantum),
                            ("search_radius", search_radius)):
            if not (math.isfinite(value) and value > 0.0):
                raise ParameterError(name, f"must be positive and finite, got {value}")
        for name, value in zip(("q_x", "q_y", "q_theta", "q_alpha", "r_v", "r_u"),
                               tuple(q) + tuple(r)):
            if not (math.isfinite(value) and value > 0.0):
                raise ParameterError(name, f"must be a positive weight, got {value}")
        if len(q) != 4 or len(r) != 2:
            raise ParameterError("q", "needs 4 state weights and 2 input weights")
        if not (0.0 < alpha_max < math.pi / 2):
            raise ParameterError("alpha_max", f"must be in (0, pi/2) rad, got {alpha_max}")
        if not (math.isfinite(sample_period) and sample_period >= 0.0):
            raise ParameterError("sample_period", f"must be >= 0 s, got {sample_period}")
        self.wheelbase = float(wheelbase)
        self.speed = float(speed)
        self.tau = float(tau)
        self.q = tuple(float(v) for v in q)
        self.r = tuple(float(v) for v in r)
        self.alpha_max = float(alpha_max)
        self.sample_period = float(sample_period)
        self.dead_reckoning = bool(dead_reckoning)
        self.alpha_fixed_point = bool(alpha_fixed_point)
        self.gain_quantum = float(gain_quantum)
        self.search_radius = float(search_radius)
        try:
            self.discrete = DiscretePath(path, ds, self.wheelbase)
        except ParameterError:
            raise
        except Exception as error:  # noqa: BLE001 - any failure of the path is a bad path
            raise ParameterError("path", f"cannot discretise: {type(error).__name__}: "
                                         f"{error}") from error
        self._gains: dict[tuple[int, int], np.ndarray] = {}
        self.hint: int | None = None
        self._hold = SampleHold(self.sample_period)

    # ------------------------------------------------------------------ gain
    def gain(self, theta_p: float, alpha_p: float) -> np.ndarray:
        """Steering-rate gain row k_u (eq 10, shape (4,)) at the target state [rad].

        Linear interpolation in alpha_p between gains computed by :func:`lq_gain` at the
        nodes alpha = n ``gain_quantum``; theta_p by the exact rotation when q_x == q_y,
        else rounded to the nearest multiple of ``gain_quantum``.
        """
        rotate = self.q[0] == self.q[1]
        theta_n = 0 if rotate else round(wrap_angle(theta_p) / self.gain_quantum)
        position = alpha_p / self.gain_quantum
        lower = math.floor(position)
        frac = position - lower
        k_u = (1.0 - frac) * self._node(theta_n, lower) + frac * self._node(theta_n, lower + 1)
        if rotate:
            k_u = k_u @ _rotation(theta_p).T
        return k_u

    def _node(self, theta_n: int, alpha_n: int) -> np.ndarray:
        key = (theta_n, alpha_n)
        k_u = self._gains.get(key)
        if k_u is None:
            K, _ = lq_gain(theta_n * self.gain_quantum, alpha_n * self.gain_quantum,
                           self.speed, self.wheelbase, self.q, self.r)
            k_u = -K[1]
            self._gains[key] = k_u
        return k_u

    # ------------------------------------------------------------------ law
    def compute(self, x_meas: float, y_meas: float, heading_meas: float, alpha_meas: float,
                fix_age: float = 0.0) -> dict[str, Any]:
        """Evaluate the law once (no sample-and-hold).

        Parameters
        ----------
        x_meas, y_meas : float
            Measured rear-axle centre [m] (last total-station fix).
        heading_meas : float
            Gyro heading [rad].
        alpha_meas : float
            Measured steering angle [rad].
        fix_age : float
            Age of the fix [s]; used only with ``dead_reckoning``.

        Returns
        -------
        dict
            ``alpha_ref`` [rad], ``target_x``, ``target_y``, ``preview_error`` [m].
        """
        x, y = x_meas, y_meas
        if self.dead_reckoning and fix_age > 0.0:
            w = self.speed * math.tan(alpha_meas) / self.wheelbase
            x, y, _ = arc_pose(x, y, heading_meas - w * fix_age, alpha_meas, self.speed,
                               self.wheelbase, fix_age)
        if not self.alpha_fixed_point:
            return self.law(x, y, heading_meas, alpha_meas)
        from scipy.optimize import brentq

        lo, hi = -self.alpha_max, self.alpha_max
        if self.law(x, y, heading_meas, lo, clip=False)["alpha_ref"] <= lo:
            return self.law(x, y, heading_meas, lo)
        if self.law(x, y, heading_meas, hi, clip=False)["alpha_ref"] >= hi:
            return self.law(x, y, heading_meas, hi)
        hint = self.hint
        alpha = brentq(lambda a: self._residual(x, y, heading_meas, a, hint), lo, hi,
                       xtol=1e-12, rtol=1e-12)
        self.hint = hint
        return self.law(x, y, heading_meas, alpha)

    def _residual(self, x: float, y: float, heading: float, alpha: float, hint: int | None
                  ) -> float:
        self.hint = hint  # every trial starts its search from the same vertex
        return self.law(x, y, heading, alpha, clip=False)["alpha_ref"] - alpha

    def law(self, x: float, y: float, heading: float, alpha: float, clip: bool = True
            ) -> dict[str, float]:
        """Eqs 5 and 12 for the pose (x, y [m], heading [rad]) and steering angle
        ``alpha`` [rad]: alpha_ref = alpha_p + tau k_u . dx (clipped if ``clip``).

        Returns
        -------
        dict
            ``alpha_ref`` [rad], ``target_x``, ``target_y``, ``preview_error`` [m].
        """
        xq, yq, thq, alq = future_point(x, y, heading, alpha, self.speed,
                                        self.wheelbase, self.tau)
        if self.hint is None:
            self.hint = self.discrete.initial_index(xq, yq)
        target = self.discrete.nearest(xq, yq, self.hint, self.search_radius)
        self.hint = target["index"]
        thp, alp = target["theta"], target["alpha"]
        delta = np.array([xq - target["x"], yq - target["y"], wrap_angle(thq - thp),
                          alq - alp])
        alpha_ref = alp + float(self.gain(thp, alp) @ delta) * self.tau
        if clip:
            alpha_ref = min(self.alpha_max, max(-self.alpha_max, alpha_ref))
        lateral = -math.sin(thp) * delta[0] + math.cos(thp) * delta[1]
        return {"alpha_ref": alpha_ref, "target_x": target["x"], "target_y": target["y"],
                "preview_error": float(lateral)}

    def update(self, t: float, x_meas: float, y_meas: float, heading_meas: float,
               alpha_meas: float, fix_age: float = 0.0) -> dict[str, Any]:
        """Output at time ``t`` [s], with sample-and-hold when ``sample_period`` > 0.

        The rule is :mod:`agv_core.numerics.sampling`'s: at an instant k T the law is evaluated
        on the current inputs (again at every call at that time); an instant inside a
        communication step is sampled from the inputs held over it by :meth:`step`;
        between instants the sample is held.
        """
        args = (x_meas, y_meas, heading_meas, alpha_meas, fix_age)
        return dict(self._hold.output(t, args, self.compute))

    def step(self, t: float, h: float, x_meas: float, y_meas: float, heading_meas: float,
             alpha_meas: float, fix_age: float = 0.0) -> None:
        """Commit the samples of the step from ``t`` to ``t + h`` [s] (inputs held)."""
        self._hold.step(t, h, (x_meas, y_meas, heading_meas, alpha_meas, fix_age),
                        self.compute)

    # ------------------------------------------------------------------ state
    def get_state(self) -> dict[str, Any]:
        """JSON-safe snapshot (search hint and held sample; the gain cache is a pure
        function of its keys and is not state)."""
        return {"hint": self.hint, "hold": self._hold.get_state()}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a snapshot from :meth:`get_state`."""
        self.hint = state["hint"]
        self._hold.set_state(state["hold"])
        if self._hold.value is not None:
            self._hold.value = dict(self._hold.value)
