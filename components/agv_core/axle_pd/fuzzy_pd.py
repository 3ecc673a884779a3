"""Per-axle PD steering law with fixed gains or fuzzy-scheduled gains (seed 003 section 4).

PD law (one instance per axle; seed 003 gives neither sign nor units, see
components/README.md):

    delta = -(Kp e + Kd r),   saturated at +-delta_max

e [m] the axle's lateral error (positive left of the path), r [m/s] its rate, delta [rad]
the axle-equivalent steering angle (positive left). Kp [rad/m], Kd [rad s/m]. The rate is
a first-order filtered derivative r = (e - x) / tau_d with x' = (e - x) / tau_d (transfer
function s / (tau_d s + 1)), discretised exactly for e held over a step:
x <- x + (1 - exp(-h / tau_d)) (e - x); x starts at the e held over the first step (rate
0 until then: no derivative kick from the start value).

Fuzzy scheduling (seed 003 4.2): a Mamdani system with inputs e in [-e_max, e_max] m (five
sets NB NS ZE PS PB) and speed v in [0, v_max] km/h (low, mid, high) and outputs Kp in
[-kp_max, kp_max] deg/m and Kd in [-kd_max, kd_max] deg s/m (seven sets NB NM NS ZE PS PM
PB each), evenly spaced triangles (the end sets of the inputs are shoulders by clipping
the input to its universe), min for AND and implication, max aggregation, centroid. The
system is defined with scikit-fuzzy (``skfuzzy.control``); ``FuzzySchedule.control_system``
returns it. Since one ``skfuzzy.control`` evaluation costs ~4 ms, the two gain surfaces are
evaluated once at initialisation on a regular grid by :func:`mamdani_surface` (the same
inference, vectorised with numpy; the tests check it against ``skfuzzy.control`` at
random points; memberships from ``skfuzzy.trimf``) and interpolated bilinearly at run time
in plain floats. Grid nodes align with every membership breakpoint, so within a cell the
memberships are linear; the interpolation error bound is stated and tested in
components/README.md.
"""

import functools
import math
from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.integrate import trapezoid

from ..errors import ParameterError

INPUT_E = ("NB", "NS", "ZE", "PS", "PB")
INPUT_V = ("low", "mid", "high")
OUTPUT_SETS = ("NB", "NM", "NS", "ZE", "PS", "PM", "PB")

#: Rule tables (rows e = NB..PB, columns v = low, mid, high): a proposal following the
#: paper's principles 1-3 (its Tables 1-2 were lost); only ZE..PB, so the loop sign never
#: flips. See components/README.md.
DEFAULT_KP_RULES = "PB PM PS; PM PM PS; PS PS PS; PM PM PS; PB PM PS"
DEFAULT_KD_RULES = "ZE ZE ZE; PS PS ZE; ZE ZE ZE; PS PS ZE; ZE ZE ZE"
#: Default steering limit [rad] of :class:`FuzzyPD` (35 deg).
DEFAULT_DELTA_MAX = math.radians(35.0)

KMH = 3.6  # (km/h) / (m/s)

#: A parsed rule table: 5 rows (e = NB..PB) of 3 output labels (v = low, mid, high).
Rules = tuple[tuple[str, ...], ...]


def parse_rules(name: str, text: str) -> Rules:
    """A 5 x 3 rule table "r1c1 r1c2 r1c3; ...; r5c1 r5c2 r5c3" -> tuple of row tuples."""
    rows = [row.split() for row in str(text).split(";")]
    if len(rows) != len(INPUT_E) or any(len(r) != len(INPUT_V) for r in rows):
        raise ParameterError(name, f"needs 5 rows (e = NB..PB) of 3 labels (v = low, mid, "
                                   f"high) separated by ';', got '{text}'")
    for row in rows:
        for label in row:
            if label not in OUTPUT_SETS:
                raise ParameterError(name, f"unknown label '{label}'; expected one of "
                                           f"{' '.join(OUTPUT_SETS)}")
    return tuple(tuple(r) for r in rows)


def _tri_memberships(x: ArrayLike, lo: float, hi: float, n: int) -> NDArray[np.float64]:
    """Memberships (len(x), n) of n evenly spaced triangles on [lo, hi] (skfuzzy.trimf),
    x clipped to [lo, hi] as skfuzzy.control does."""
    import skfuzzy as fuzz

    x = np.clip(np.asarray(x, dtype=float), lo, hi)
    width = (hi - lo) / (n - 1)
    columns = []
    for k in range(n):
        c = lo + k * width
        columns.append(fuzz.trimf(x, [c - width, c, c + width]))
    return np.stack(columns, axis=1)


def mamdani_surface(e: ArrayLike, v: ArrayLike, rules: Sequence[Sequence[str]], e_max: float,
                    v_max: float, out_max: float, out_points: int = 3001
                    ) -> NDArray[np.float64]:
    """Mamdani min-max-centroid output at the points (e [m], v [km/h]).

    The aggregated output membership is sampled on ``out_points`` equally spaced points of
    [-out_max, out_max] and its centroid taken by the trapezoidal rule (exact for the
    piecewise-linear shape between samples; kinks between samples cost O(spacing^2)).
    Vectorised; memory ~ 8 len(e) out_points bytes per chunk of 512 points.
    """
    e = np.atleast_1d(np.asarray(e, dtype=float))
    v = np.atleast_1d(np.asarray(v, dtype=float))
    mu_e = _tri_memberships(e, -e_max, e_max, len(INPUT_E))
    mu_v = _tri_memberships(v, 0.0, v_max, len(INPUT_V))
    y = np.linspace(-out_max, out_max, out_points)
    # at most two adjacent output sets are non-zero at any y: k(y) and k(y) + 1
    n_out = len(OUTPUT_SETS)
    mu_y = _tri_memberships(y, -out_max, out_max, n_out)          # (Ny, 7)
    pos = (y + out_max) / (2.0 * out_max) * (n_out - 1)
    k_lo = np.minimum(np.floor(pos).astype(int), n_out - 2)
    columns = np.arange(len(y))
    mu_lo, mu_hi = mu_y[columns, k_lo], mu_y[columns, k_lo + 1]
    result = np.empty(len(e))
    for start in range(0, len(e), 512):
        sl = slice(start, start + 512)
        cut = np.zeros((len(e[sl]), len(OUTPUT_SETS)))
        for i, row in enumerate(rules):
            for j, label in enumerate(row):
                k = OUTPUT_SETS.index(label)
                cut[:, k] = np.maximum(cut[:, k], np.minimum(mu_e[sl, i], mu_v[sl, j]))
        agg = np.maximum(np.minimum(cut[:, k_lo], mu_lo[None, :]),
                         np.minimum(cut[:, k_lo + 1], mu_hi[None, :]))       # (n, Ny)
        area = trapezoid(agg, y, axis=1)
        moment = trapezoid(agg * y[None, :], y, axis=1)
        result[sl] = moment / area
    return result


def control_system(rules_kp: Sequence[Sequence[str]], rules_kd: Sequence[Sequence[str]],
                   e_max: float = 0.05, v_max: float = 80.0, kp_max: float = 1500.0,
                   kd_max: float = 800.0, points: int = 601) -> Any:
    """The scheduler as a scikit-fuzzy ``ControlSystem`` (its definition of record).

    Universes sampled with ``points`` points so that every triangle breakpoint is a sample.
    """
    import skfuzzy as fuzz
    from skfuzzy import control as ctrl

    e = ctrl.Antecedent(np.linspace(-e_max, e_max, 4 * 50 + 1), "e")
    v = ctrl.Antecedent(np.linspace(0.0, v_max, 2 * 80 + 1), "v")
    kp = ctrl.Consequent(np.linspace(-kp_max, kp_max, points), "kp")
    kd = ctrl.Consequent(np.linspace(-kd_max, kd_max, points), "kd")

    def triangles(var: Any, lo: float, hi: float, labels: Sequence[str]) -> None:
        step = (hi - lo) / (len(labels) - 1)
        for k, label in enumerate(labels):
            c = lo + k * step
            var[label] = fuzz.trimf(var.universe, [c - step, c, c + step])

    triangles(e, -e_max, e_max, INPUT_E)
    triangles(v, 0.0, v_max, INPUT_V)
    triangles(kp, -kp_max, kp_max, OUTPUT_SETS)
    triangles(kd, -kd_max, kd_max, OUTPUT_SETS)
    rules = []
    for i, le in enumerate(INPUT_E):
        for j, lv in enumerate(INPUT_V):
            rules.append(ctrl.Rule(e[le] & v[lv], kp[rules_kp[i][j]]))
            rules.append(ctrl.Rule(e[le] & v[lv], kd[rules_kd[i][j]]))
    return ctrl.ControlSystem(rules)


@functools.lru_cache(maxsize=16)
def _grid_table(rules: Rules, e_max: float, v_max: float, out_max: float, e_cells: int,
                v_cells: int) -> tuple[tuple[float, ...], ...]:
    """Surface values on the grid as nested tuples of plain floats [i_e][i_v].

    A pure function of its (hashable) arguments, cached per process: the four axle
    controllers of a train share one evaluation (~1 s per surface)."""
    ge = np.linspace(-e_max, e_max, e_cells + 1)
    gv = np.linspace(0.0, v_max, v_cells + 1)
    E, V = np.meshgrid(ge, gv, indexing="ij")
    values = mamdani_surface(E.ravel(), V.ravel(), rules, e_max, v_max, out_max)
    return tuple(tuple(float(x) for x in row) for row in values.reshape(E.shape))


class FuzzySchedule:
    """Gain surfaces Kp(e, v) [deg/m], Kd(e, v) [deg s/m] on a grid, bilinear at run time.

    Parameters
    ----------
    kp_rules, kd_rules : str
        Rule tables (see :func:`parse_rules`).
    e_max : float
        Lateral-error universe half-width [m] (seed 003: 0.05).
    v_max : float
        Speed universe [0, v_max] in km/h (seed 003: 80).
    kp_max, kd_max : float
        Output universe half-widths, deg/m and deg s/m (seed 003: 1500, 800).
    e_cells : int
        Grid cells across [-e_max, e_max]; a multiple of 4 (breakpoints every e_max/2).
    v_cells : int
        Grid cells across [0, v_max]; a multiple of 2 (breakpoints every v_max/2).
    """

    def __init__(self, kp_rules: str = DEFAULT_KP_RULES, kd_rules: str = DEFAULT_KD_RULES,
                 e_max: float = 0.05, v_max: float = 80.0, kp_max: float = 1500.0,
                 kd_max: float = 800.0, e_cells: int = 100, v_cells: int = 40) -> None:
        for name, value in (("e_max", e_max), ("v_max", v_max), ("kp_max", kp_max),
                            ("kd_max", kd_max)):
            if not (math.isfinite(value) and value > 0.0):
                raise ParameterError(name, f"must be positive, got {value}")
        if not (int(e_cells) == e_cells and e_cells >= 4 and e_cells % 4 == 0):
            raise ParameterError("e_cells", f"must be a positive multiple of 4, got {e_cells}")
        if not (int(v_cells) == v_cells and v_cells >= 2 and v_cells % 2 == 0):
            raise ParameterError("v_cells", f"must be a positive multiple of 2, got {v_cells}")
        self.kp_rules = parse_rules("kp_rules", kp_rules)
        self.kd_rules = parse_rules("kd_rules", kd_rules)
        self.e_max, self.v_max = float(e_max), float(v_max)
        self.kp_max, self.kd_max = float(kp_max), float(kd_max)
        self.e_cells, self.v_cells = int(e_cells), int(v_cells)
        self.de = 2.0 * self.e_max / self.e_cells
        self.dv = self.v_max / self.v_cells
        self.kp_table = _grid_table(self.kp_rules, self.e_max, self.v_max, self.kp_max,
                                    self.e_cells, self.v_cells)
        self.kd_table = _grid_table(self.kd_rules, self.e_max, self.v_max, self.kd_max,
                                    self.e_cells, self.v_cells)

    def direct(self, e: ArrayLike, v_kmh: ArrayLike
               ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(Kp, Kd) evaluated without the grid (arrays), for checks."""
        return (mamdani_surface(e, v_kmh, self.kp_rules, self.e_max, self.v_max, self.kp_max),
                mamdani_surface(e, v_kmh, self.kd_rules, self.e_max, self.v_max, self.kd_max))

    def control_system(self) -> Any:
        """The same scheduler as a scikit-fuzzy ControlSystem."""
        return control_system(self.kp_rules, self.kd_rules, self.e_max, self.v_max,
                              self.kp_max, self.kd_max)

    def gains(self, e: float, v_kmh: float) -> tuple[float, float]:
        """(Kp [deg/m], Kd [deg s/m]) by bilinear interpolation; inputs clipped to their
        universes (as scikit-fuzzy does)."""
        fe = (min(max(e, -self.e_max), self.e_max) + self.e_max) / self.de
        fv = min(max(v_kmh, 0.0), self.v_max) / self.dv
        i = min(int(fe), self.e_cells - 1)
        j = min(int(fv), self.v_cells - 1)
        a, b = fe - i, fv - j
        out = []
        for t in (self.kp_table, self.kd_table):
            r0, r1 = t[i], t[i + 1]
            out.append((1.0 - a) * ((1.0 - b) * r0[j] + b * r0[j + 1])
                       + a * ((1.0 - b) * r1[j] + b * r1[j + 1]))
        return out[0], out[1]


class FixedGains:
    """Constant gains with the interface of :class:`FuzzySchedule` (deg/m, deg s/m).

    Defaults: the fuzzy schedule's gains at e = 1 cm, 14 km/h (709.7, 111.8), rounded.
    """

    def __init__(self, kp_deg: float = 710.0, kd_deg: float = 112.0) -> None:
        for name, value in (("Kp", kp_deg), ("Kd", kd_deg)):
            if not math.isfinite(value):
                raise ParameterError(name, f"must be finite, got {value}")
        self.kp, self.kd = float(kp_deg), float(kd_deg)

    def gains(self, e: float, v_kmh: float) -> tuple[float, float]:
        return self.kp, self.kd


class GainSource(Protocol):
    """What :class:`AxlePD` asks of its schedule (:class:`FuzzySchedule`, :class:`FixedGains`)."""

    def gains(self, e: float, v_kmh: float) -> tuple[float, float]:
        """(Kp [deg/m], Kd [deg s/m]) at lateral error ``e`` [m] and speed ``v_kmh`` [km/h]."""
        ...


class AxlePD:
    """delta = -(Kp e + Kd r), filtered derivative, saturation (module docstring).

    Parameters
    ----------
    schedule : FuzzySchedule or FixedGains
        Gives (Kp [deg/m], Kd [deg s/m]) from (e [m], v [km/h]).
    tau_d : float
        Derivative filter time constant [s], > 0.
    delta_max : float
        Saturation [rad], 0 < delta_max < pi/2.
    """

    def __init__(self, schedule: GainSource, tau_d: float = 0.05,
                 delta_max: float = DEFAULT_DELTA_MAX) -> None:
        if not (math.isfinite(tau_d) and tau_d > 0.0):
            raise ParameterError("tau_d", f"must be positive, got {tau_d}")
        if not (0.0 < delta_max < 0.5 * math.pi):
            raise ParameterError("delta_max", f"must be in (0, pi/2) rad, got {delta_max}")
        self.schedule = schedule
        self.tau_d = float(tau_d)
        self.delta_max = float(delta_max)
        self.x: float | None = None  # filter state [m]; None until the first evaluation
        self.outputs: dict[str, float | bool] = {"delta": 0.0, "Kp": 0.0, "Kd": 0.0,
                                                 "error_rate": 0.0, "saturated": False}

    def evaluate(self, e: float, v: float) -> dict[str, float | bool]:
        """Outputs for lateral error ``e`` [m] and speed ``v`` [m/s] (SI gains)."""
        e = float(e)
        rate = 0.0 if self.x is None else (e - self.x) / self.tau_d
        kp, kd = self.schedule.gains(e, abs(v) * KMH)
        kp_si, kd_si = math.radians(kp), math.radians(kd)
        law = -(kp_si * e + kd_si * rate)
        delta = min(max(law, -self.delta_max), self.delta_max)
        self.outputs = {"delta": delta, "Kp": kp_si, "Kd": kd_si, "error_rate": rate,
                        "saturated": delta != law}
        return self.outputs

    def advance(self, e: float, h: float) -> None:
        """Advance the derivative filter by ``h`` [s] with ``e`` [m] held."""
        e = float(e)
        if self.x is None:
            self.x = e
        self.x += -math.expm1(-h / self.tau_d) * (e - self.x)

    def get_state(self) -> dict[str, Any]:
        return {"x": self.x, "outputs": dict(self.outputs)}

    def set_state(self, state: dict[str, Any]) -> None:
        self.x = None if state["x"] is None else float(state["x"])
        self.outputs = dict(state["outputs"])
