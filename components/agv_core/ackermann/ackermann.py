"""Per-axle Ackermann coordination (seed 003, section 3 and Figs 3-4).

Each steered axle has its own turning centre O on a lateral *baseline* of its car (seed
003: the lateral line through the car's hinge). In the car frame (x forward, y left, origin
on the baseline at the car's centre line) axle i sits at x = l (signed: positive ahead of
the baseline), its wheels at y = +d/2 (left) and -d/2 (right). O lies at (0, R) with R
signed (positive left). Every wheel rolls perpendicular to its line to O, so

    tan(delta)   = l / R              axle-equivalent angle (axle centre)
    tan(delta_L) = l / (R - d/2)      left wheel
    tan(delta_R) = l / (R + d/2)      right wheel

Angles are positive steering left (counter-clockwise). Eliminating R (no division by
tan(delta), so delta = 0 is regular):

    tan(delta_L) = l t / (l - (d/2) t),   tan(delta_R) = l t / (l + (d/2) t),   t = tan(delta)

In cotangents: cot(delta_L) = cot(delta) - d/(2l), cot(delta_R) = cot(delta) + d/(2l), hence
the Ackermann condition cot(outer) - cot(inner) = d / |l| (inner = the wheel nearer O), and
the exact inverse cot(delta) = (cot(delta_L) + cot(delta_R)) / 2, i.e.

    tan(delta) = 2 tan(delta_L) tan(delta_R) / (tan(delta_L) + tan(delta_R))

which needs neither d nor l. The formulas hold for both signs of l (axles behind the
baseline, as on seed 003's tail car) and of delta. A wheel reaches 90 deg when O reaches
it (|R| = d/2); that and beyond is rejected.
"""

import math
from collections.abc import Iterable, Sequence
from typing import Any


def wheel_angles(delta: float, l: float, d: float  # noqa: E741 - l: the axle offset (paper)
                 ) -> tuple[float, float]:
    """Left and right wheel angles [rad] of an axle with axle-equivalent angle ``delta``.

    Parameters
    ----------
    delta : float
        Axle-equivalent steering angle [rad], positive left, |delta| < pi/2.
    l : float
        Signed longitudinal distance [m] from the baseline to the axle, positive ahead of
        it; l != 0.
    d : float
        Track width [m], >= 0.

    Returns
    -------
    (float, float)
        delta_L, delta_R [rad], each in (-pi/2, pi/2).

    Raises
    ------
    ValueError
        When the turning centre is at or inside a wheel (|R| <= d/2).
    """
    t = math.tan(delta)
    sign = 1.0 if l > 0.0 else -1.0
    a = abs(l)
    half = 0.5 * d * t * sign
    den_left, den_right = a - half, a + half
    if den_left <= 0.0 or den_right <= 0.0:
        raise ValueError(f"turning centre within the track: delta={delta} rad, l={l} m, "
                         f"d={d} m")
    return math.atan(a * t / den_left), math.atan(a * t / den_right)


def axle_angle(delta_left: float, delta_right: float) -> float:
    """Exact inverse of :func:`wheel_angles`: the axle-equivalent angle [rad].

    tan(delta) = 2 tL tR / (tL + tR) (the mean of the cotangents); 0 when both wheels are
    straight. Raises ValueError for a pair that no turning centre explains (opposite
    signs, or tL + tR = 0 with tL != 0).
    """
    tl, tr = math.tan(delta_left), math.tan(delta_right)
    if tl == 0.0 and tr == 0.0:
        return 0.0
    if tl * tr < 0.0 or tl + tr == 0.0:
        raise ValueError(f"wheel angles {delta_left}, {delta_right} rad have no common "
                         "turning centre on one side")
    return math.atan(2.0 * tl * tr / (tl + tr))


def turning_curvature(delta: float, l: float) -> float:  # noqa: E741 - l as in wheel_angles
    """1 / R [1/m]: signed inverse lateral position of the axle's turning centre on the
    baseline (positive left; 0 when the axle is straight and O is at infinity)."""
    return math.tan(delta) / l


def wheel_distances(delta: float, l: float, d: float  # noqa: E741 - l as in wheel_angles
                    ) -> tuple[float, float]:
    """Distances [m] from the left and right wheel centres to the turning centre O.

    Seed 003's e1, e2 are these distances for axle 2 (inner, outer). Infinite for a
    straight axle.
    """
    t = math.tan(delta)
    if t == 0.0:
        return math.inf, math.inf
    r = l / t
    return math.hypot(l, r - 0.5 * d), math.hypot(l, r + 0.5 * d)


class TrainCoordination:
    """Wheel angles of seed 003's four axles: baselines through each powered car's hinge.

    Axle offsets from the baselines: (L1 + L2, L2) on the head car, (-L2, -(L1 + L2)) on
    the tail car (agv_core.train). A static map: no state.

    Parameters
    ----------
    offsets : sequence of float
        Signed axle-to-baseline distances l_i [m] (non-zero).
    d : float
        Track width [m].
    """

    def __init__(self, offsets: Iterable[float], d: float) -> None:
        self.offsets = tuple(float(offset) for offset in offsets)
        self.d = float(d)

    def wheels(self, deltas: Sequence[float]) -> list[tuple[float, float]]:
        """[(delta_L, delta_R), ...] [rad] for the axle angles ``deltas`` [rad]."""
        return [wheel_angles(delta, offset, self.d)
                for delta, offset in zip(deltas, self.offsets)]

    def get_state(self) -> dict[str, Any]:
        return {}

    def set_state(self, state: dict[str, Any]) -> None:
        pass
