"""Planar multibody dynamics of seed 003's three-car train with tyre forces on every axle:
a drop-in for the kinematic :class:`~agv_core.train.train.Train`.

Topology and geometry as the kinematic train (agv_core/train/README.md): head car with
axles 1, 2 at body x a1 = L1 + L2, a2 = L2 ahead of its hinge J1; floating car = a rigid
bar J1 -> J2 of length Lm with no running gear; tail car, the mirror image, axles 3, 4 at
a3 = -L2, a4 = -(L1 + L2) from its hinge J2. Frames and signs as in components/README.md.

Bodies (rigid, planar): end cars of mass m_e and yaw inertia I_e about their centre of
gravity, which lies on the car's centre line at g1 = ``cg_end`` ahead of J1 (head) and
g3 = -``cg_end`` behind J2 (tail); the floating car of mass m_f and inertia I_f with its
centre of gravity mid-bar. The hinges are ideal revolute joints.

Generalised coordinates q = (X, Y, psi1, psi2, psi3): J1 and the three headings (psi2 is
the bar's, J2 -> J1), so the hinge constraints hold by construction,
J2 = J1 - Lm e2 (e_k = (cos psi_k, sin psi_k), n_k = (-sin psi_k, cos psi_k)).
Generalised speeds: the head car's longitudinal speed u1 is prescribed (the input, as in
the kinematic train: the head car's drive holds it, a constraint force along its centre
line that does no work on the other speeds); the free speeds are
w = (v1, r1, r2, r3): J1's lateral velocity in the head-car frame and the yaw rates.

    J1' = u1 e1 + v1 n1,    J2' = J1' - Lm r2 n2,    psi_k' = r_k
    head CG:  P1' = J1' + g1 r1 n1        bar CG: P2' = J1' - (Lm/2) r2 n2
    tail CG:  P3' = J2' + g3 r3 n3

Equations of motion by Kane's method (virtual power of the free speeds), M(q) w' = Q - h:

    M11 = m1 + m2 + m3          M12 = m1 g1       M13 = -(m2/2 + m3) Lm cos(psi1 - psi2)
    M14 = m3 g3 cos(psi1 - psi3)                  M22 = m1 g1^2 + I1    M23 = M24 = 0
    M33 = m2 Lm^2/4 + m3 Lm^2 + I2                M34 = -m3 Lm g3 cos(psi2 - psi3)
    M44 = m3 g3^2 + I3

    h_v1 = (m1 + m2 + m3) u1 r1 + (m2/2 + m3) Lm r2^2 sin(psi2 - psi1)
           - m3 g3 r3^2 sin(psi3 - psi1)
    h_r1 = m1 g1 u1 r1
    h_r2 = -(m2/2 + m3) Lm (u1 r1 cos(psi1 - psi2) - v1 r1 sin(psi1 - psi2))
           + m3 Lm g3 r3^2 sin(psi3 - psi2)
    h_r3 = m3 g3 (u1 r1 cos(psi1 - psi3) - v1 r1 sin(psi1 - psi3) + Lm r2^2 sin(psi2 - psi3))

(m1 = m3 = m_e, m2 = m_f). Tyres (default): two per axle, at the wheel centres
(a_i, +-d/2) of the car frame, each turned by its own wheel angle delta_w (the wheel
inputs, or the Ackermann angles of the axle angle about the car's hinge baseline), slip
alpha_w = atan2(v_c + r_c a_i, u_c - r_c y) - delta_w with the car's hinge velocity
(head: (u1, v1, r1); tail: (u3, v3, r3), u3 = e3 . J2', v3 = n3 . J2'), lateral force
F_w = tyre(alpha_w) with the wheel's load (cornering stiffness c Fz_w, limit mu Fz_w),
perpendicular to the wheel (Fiala or linear, agv_core.dynamic_vehicle.tyres). A wheel's
force F_w n(psi_c + delta_w) at (a_i, y) gives the generalised forces

    head wheels:  Q_v1 += F_w cos(delta_w),   Q_r1 += F_w (a_i cos(delta_w) + y sin(delta_w))
    tail wheels:  Q_v1 += F_w cos(psi3 + delta_w - psi1),
                  Q_r2 -= Lm F_w cos(psi3 + delta_w - psi2),
                  Q_r3 += F_w (a_i cos(delta_w) + y sin(delta_w))

Wheel loads: half the static axle load -+ Fz_i a_y h / (g d) (left -, right +; h =
``cg_height``, a_y the lateral acceleration of the car's centre of gravity), solved with
the forces to a fixed point. ``lumped_axles``: one tyre per axle at its centre, turned by
the axle angle, at the static axle load (slip alpha_i = atan2(vy_i, u_c) - delta_i of the
axle centre; Q as above with y = 0 and delta_w = delta_i).

Static axle loads: each end car carries its own weight at its centre of gravity and half
the floating car's at its hinge; cornering stiffness C_i = c Fz_i (c =
``cornering_coefficient`` per rad), friction limit mu Fz_i. The tail car has no drive
(its wheels roll freely; the hinges pull it), no longitudinal tyre slip is modelled.

Integration for held inputs: RK4 with step doubling on (q, w) (agv_core.numerics.ode).
When the speed input changes between steps, w is kept (the head car's longitudinal speed
jumps, the other generalised speeds do not). Below ``kinematic_below`` the kinematic
train runs (its exact head-car arc and bounded-error articulation, w set to its no-slip
rates), as in the dynamic single-track vehicle.
"""

import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Self, cast

from ..ackermann.ackermann import wheel_angles
from ..dynamic_vehicle.dynamic_vehicle import WheelLiftError
from ..dynamic_vehicle.dynamic_vehicle import positive as _positive
from ..dynamic_vehicle.tyres import TYRES, fiala_force, linear_force
from ..errors import ParameterError
from ..numerics.ode import rk4_doubling
from ..train.train import Train, TrainGeometry

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

G = 9.81  # [m/s^2]
AXLES = 4

#: Four floats: w' = (v1', r1', r2', r3'), or one value per axle.
Four = tuple[float, float, float, float]
#: (left, right) wheel angles [rad] of axles 1-4.
WheelPairs = tuple[tuple[float, ...], ...]
#: What _wheel_accelerations' inner evaluation gives: (w', wheel loads, wheel forces).
_Evaluation = tuple[Four, list[float], list[float]]


class TrainDynamics:
    """Masses, inertias and tyres of the three-car train (SI units).

    Parameters
    ----------
    geometry : TrainGeometry
    mass_end, mass_float : float
        Mass of each end car and of the floating car [kg], > 0.
    inertia_end, inertia_float : float
        Their yaw inertias about their centres of gravity [kg m^2], > 0.
    cg_end : float
        Distance from an end car's hinge to its centre of gravity along its axis
        (towards its axles) [m], > 0.
    cornering_coefficient : float
        Cornering stiffness per unit vertical load of an axle [1/rad], > 0.
    mu : float
        Friction coefficient [-], > 0 (Fiala tyre).
    tyre : {"fiala", "linear"}
    cg_height : float
        Height of the cars' centres of gravity above the ground [m], >= 0 (lateral load
        transfer between the left and right wheels; two-tyre axles only).
    lumped_axles : bool
        One tyre per axle at its centre, turned by the axle angle, at the static axle
        load (the model without per-wheel tyres); default: two tyres per axle at
        (a_i, +-d/2) with their own wheel angles and loads.
    """

    def __init__(self, geometry: TrainGeometry, mass_end: float = 12000.0,
                 mass_float: float = 6000.0, inertia_end: float = 120000.0,
                 inertia_float: float = 44000.0, cg_end: float = 6.5,
                 cornering_coefficient: float = 6.875, mu: float = 0.8, tyre: str = "fiala",
                 cg_height: float = 1.2, lumped_axles: bool = False) -> None:
        self.g = geometry
        self.m_e = _positive("mass_end", mass_end)
        self.m_f = _positive("mass_float", mass_float)
        self.I_e = _positive("inertia_end", inertia_end)
        self.I_f = _positive("inertia_float", inertia_float)
        self.cg = _positive("cg_end", cg_end)
        self.c_alpha = _positive("cornering_coefficient", cornering_coefficient)
        self.mu = _positive("mu", mu)
        if tyre not in TYRES:
            raise ParameterError("tyre", f"must be one of {TYRES}, got '{tyre}'")
        self.tyre = tyre
        a_front, a_rear = geometry.axle_offsets[0], geometry.axle_offsets[1]
        weight = (self.m_e + 0.5 * self.m_f) * G
        moment = self.m_e * G * self.cg
        f_front = (moment - weight * a_rear) / (a_front - a_rear)
        f_rear = (weight * a_front - moment) / (a_front - a_rear)
        if not (f_front > 0.0 and f_rear > 0.0):
            raise ParameterError("cg_end", f"{cg_end} m puts no load on an axle (loads "
                                 f"{f_front:.0f} N, {f_rear:.0f} N): the centre of gravity "
                                 "with the floating car's share must lie between the axles")
        #: static axle loads [N], axles 1-4 (the tail car mirrors the head car)
        self.loads = (f_front, f_rear, f_rear, f_front)
        self.stiffness = tuple(self.c_alpha * f for f in self.loads)
        self.limits = tuple(self.mu * f for f in self.loads)
        if not (math.isfinite(cg_height) and cg_height >= 0.0):
            raise ParameterError("cg_height", f"must be a finite height >= 0 m, got {cg_height}")
        self.h = float(cg_height)
        self.lumped = bool(lumped_axles)
        #: lateral load transfer of axle i per unit lateral acceleration of its car [N s^2/m]
        self.transfer = tuple(f * self.h / (G * geometry.d) if geometry.d > 0.0 else 0.0
                              for f in self.loads)
        if self.h > 0.0 and not geometry.d > 0.0 and not self.lumped:
            raise ParameterError("cg_height", "needs a track d > 0 for the load transfer")

    def wheel_loads(self, ay_head: float, ay_tail: float) -> list[float]:
        """Vertical loads [N] of the eight wheels (axle 1 left, 1 right, ..., 4 right) for
        the lateral accelerations [m/s^2] of the head and tail cars' centres of gravity:
        half the static axle load -+ Fz_i a_y h / (g d) (left -, right +)."""
        out: list[float] = []
        for i in range(AXLES):
            shift = self.transfer[i] * (ay_head if i < 2 else ay_tail)
            half = 0.5 * self.loads[i]
            out.extend((half - shift, half + shift))
        return out

    def wheel_force(self, slip: float, load: float) -> float:
        """Lateral force [N] of one wheel at ``slip`` [rad] with vertical ``load`` [N]:
        cornering stiffness c Fz, friction limit mu Fz (0 for a lifted wheel)."""
        if not load > 0.0:
            return 0.0
        if self.tyre == "fiala":
            return fiala_force(slip, self.c_alpha * load, self.mu * load)
        return linear_force(slip, self.c_alpha * load)

    def force(self, i: int, slip: float) -> float:
        """Lateral force [N] of axle ``i`` (0-3) at ``slip`` [rad]."""
        if self.tyre == "fiala":
            return fiala_force(slip, self.stiffness[i], self.limits[i])
        return linear_force(slip, self.stiffness[i])


class DynamicTrain:
    """Three-car train state and error-bounded integration for held inputs.

    Parameters
    ----------
    dynamics : TrainDynamics
    x1, y1, psi1, psi2, psi3 : float
        Pose: hinge J1 [m] and headings [rad] (as :class:`~agv_core.train.train.Train`).
    v1, r1, r2, r3 : float
        Generalised speeds [m/s, rad/s] (module docstring).
    kinematic_below : float
        Below this head-car speed [m/s] (> 0) the kinematic train runs.
    tolerance : float
        Local error bound per step of every state, relative to 1 + |state|.
    """

    def __init__(self, dynamics: TrainDynamics, x1: float = 0.0, y1: float = 0.0,
                 psi1: float = 0.0, psi2: float = 0.0, psi3: float = 0.0, v1: float = 0.0,
                 r1: float = 0.0, r2: float = 0.0, r3: float = 0.0,
                 kinematic_below: float = 0.1, tolerance: float = 1e-9) -> None:
        for name, value in (("x1", x1), ("y1", y1), ("psi1", psi1), ("psi2", psi2),
                            ("psi3", psi3), ("v1", v1), ("r1", r1), ("r2", r2), ("r3", r3)):
            if not math.isfinite(value):
                raise ParameterError(name, f"must be finite, got {value}")
        if not (math.isfinite(kinematic_below) and kinematic_below > 0.0):
            raise ParameterError("kinematic_below", f"must be a positive speed in m/s (the "
                                 f"dynamic model is singular at 0), got {kinematic_below}")
        self.d = dynamics
        self.g = dynamics.g
        self.kinematic_below = float(kinematic_below)
        self.tolerance = _positive("tolerance", tolerance)
        self.x1, self.y1 = float(x1), float(y1)
        self.psi1, self.psi2, self.psi3 = float(psi1), float(psi2), float(psi3)
        self.v1, self.r1, self.r2, self.r3 = float(v1), float(r1), float(r2), float(r3)
        self.distance = 0.0
        self.u1 = 0.0
        self.deltas: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)
        self.wheels: WheelPairs | None = None
        self.substeps = 1
        self._pairs: WheelPairs | None
        self._pairs_key: tuple[float, ...] | None
        self._pairs, self._pairs_key = None, None
        self._current_key: tuple[Any, ...] | None
        self._current_value: tuple[Four, tuple[float, ...], list[float], list[float]] | None
        self._current_key, self._current_value = None, None

    @classmethod
    def straight(cls, dynamics: TrainDynamics, x_front: float = 0.0, y_front: float = 0.0,
                 heading: float = 0.0, kinematic_below: float = 0.1,
                 tolerance: float = 1e-9) -> Self:
        """A straight train along ``heading`` with axle 1's centre at (x_front, y_front)."""
        a1 = dynamics.g.axle_offsets[0]
        return cls(dynamics, x_front - a1 * math.cos(heading), y_front - a1 * math.sin(heading),
                   heading, heading, heading, kinematic_below=kinematic_below,
                   tolerance=tolerance)

    def start(self, u1: float, deltas: Sequence[float], wheels: WheelPairs | None = None
              ) -> None:
        """Set the inputs held before the first step and the speeds to the kinematic
        train's no-slip rates for them (a train started on an arc is already turning)."""
        self.u1, self.deltas = float(u1), tuple(float(d) for d in deltas)
        self.wheels = wheels
        self.v1, self.r1, self.r2, self.r3 = self.kinematic_speeds()

    # ------------------------------------------------------------------ kinematic train
    def _kinematic(self) -> Train:
        return Train(self.g, self.x1, self.y1, self.psi1, self.psi2, self.psi3)

    def kinematic_speeds(self, u1: float | None = None, deltas: Sequence[float] | None = None
                         ) -> Four:
        """(v1, r1, r2, r3) of the kinematic train at the current pose."""
        u1 = self.u1 if u1 is None else u1
        deltas = self.deltas if deltas is None else deltas
        kin = self._kinematic()
        _, vyj = kin.head_rates(u1, deltas)
        _, omega1, rate2, omega3 = kin.car_rates(u1, deltas)
        return vyj, omega1, rate2, omega3

    def is_kinematic(self, u1: float | None = None) -> bool:
        return abs(self.u1 if u1 is None else u1) < self.kinematic_below

    # ------------------------------------------------------------------ dynamics
    def tail_velocity(self, psi1: float, psi2: float, psi3: float, v1: float, r2: float,
                      u1: float | None = None) -> tuple[float, float]:
        """(u3, v3): J2's velocity in the tail-car frame [m/s]."""
        u1 = self.u1 if u1 is None else u1
        lm = self.g.Lm
        d13 = psi1 - psi3
        c13, s13 = math.cos(d13), math.sin(d13)
        d23 = psi2 - psi3
        return (u1 * c13 - v1 * s13 + lm * r2 * math.sin(d23),
                u1 * s13 + v1 * c13 - lm * r2 * math.cos(d23))

    def axle_slips(self, state: Sequence[float] | None = None
                   ) -> tuple[Four, float, float]:
        """Slip angles [rad] of axles 1-4 and (u3, v3) for the state (default: current)."""
        if state is None:
            state = self.state_vector()
        _, _, psi1, psi2, psi3, v1, r1, r2, r3 = state
        u1, a, dl = self.u1, self.g.axle_offsets, self.deltas
        u3, v3 = self.tail_velocity(psi1, psi2, psi3, v1, r2, u1)
        if not u3 > 0.0:
            raise FloatingPointError(f"the tail car moves backwards (u3 = {u3:.6g} m/s): "
                                     "jack-knife")
        return ((math.atan2(v1 + a[0] * r1, u1) - dl[0], math.atan2(v1 + a[1] * r1, u1) - dl[1],
                 math.atan2(v3 + a[2] * r3, u3) - dl[2], math.atan2(v3 + a[3] * r3, u3) - dl[3]),
                u3, v3)

    def wheel_pairs(self) -> WheelPairs:
        """(left, right) wheel angles [rad] of axles 1-4: the recorded wheel inputs, else
        the Ackermann angles of the axle angles about the car's hinge baseline."""
        if self.wheels is not None:
            return self.wheels
        key = self.deltas
        if self._pairs_key != key:
            a, d = self.g.axle_offsets, self.g.d
            self._pairs = tuple(wheel_angles(key[i], a[i], d) for i in range(AXLES))
            self._pairs_key = key
        return cast(WheelPairs, self._pairs)

    def wheel_slips(self, state: Sequence[float]) -> tuple[list[float], float, float]:
        """Slip angles [rad] of the eight wheels (axle 1 left, 1 right, ...): wheel at body
        (a_i, +-d/2), velocity (u_c - r_c y, v_c + r_c a_i) in its car's frame, minus the
        wheel's angle; and (u3, v3)."""
        _, _, psi1, psi2, psi3, v1, r1, r2, r3 = state
        u1, a, half = self.u1, self.g.axle_offsets, 0.5 * self.g.d
        u3, v3 = self.tail_velocity(psi1, psi2, psi3, v1, r2, u1)
        if not u3 > 0.0:
            raise FloatingPointError(f"the tail car moves backwards (u3 = {u3:.6g} m/s): "
                                     "jack-knife")
        slips = []
        for i, (left, right) in enumerate(self.wheel_pairs()):
            u, v, r = (u1, v1, r1) if i < 2 else (u3, v3, r3)
            vy = v + r * a[i]
            slips.append(math.atan2(vy, u - r * half) - left)
            slips.append(math.atan2(vy, u + r * half) - right)
        return slips, u3, v3

    def accelerations(self, state: Sequence[float]) -> tuple[Four, Sequence[float]]:
        """w' = (v1', r1', r2', r3') and the axle forces [N] (the sum of each axle's
        wheel forces, or the lumped axle force) for the state vector
        (X, Y, psi1, psi2, psi3, v1, r1, r2, r3), with the held inputs."""
        if self.d.lumped:
            return self._lumped_accelerations(state)
        return self._wheel_accelerations(state)[:2]

    def _wheel_accelerations(self, state: Sequence[float]
                             ) -> tuple[Four, tuple[float, ...], list[float], list[float]]:
        """Two tyres per axle: (w', axle forces, wheel loads, wheel forces). The loads
        depend on the cars' lateral accelerations, which depend on the forces: iterated
        to a fixed point (1e-12 relative; one pass for cg_height = 0)."""
        _, _, p1, p2, p3, v1, r1, r2, r3 = state
        d, a, lm = self.d, self.g.axle_offsets, self.g.Lm
        slips, u3, _ = self.wheel_slips(state)
        pairs = self.wheel_pairs()
        half = 0.5 * self.g.d
        def evaluate(ayh: float, ayt: float) -> _Evaluation:
            loads = d.wheel_loads(ayh, ayt)
            forces = [d.wheel_force(s, fz) for s, fz in zip(slips, loads)]
            q1 = q2 = q3 = q4 = 0.0
            for i in range(AXLES):
                for k, y in ((0, half), (1, -half)):
                    f, ang = forces[2 * i + k], pairs[i][k]
                    moment = f * (a[i] * math.cos(ang) + y * math.sin(ang))
                    if i < 2:
                        q1 += f * math.cos(ang)
                        q2 += moment
                    else:
                        q1 += f * math.cos(p3 + ang - p1)
                        q3 -= lm * f * math.cos(p3 + ang - p2)
                        q4 += moment
            wdot = self._solve(state, (q1, q2, q3, q4))
            return wdot, loads, forces

        ayh, ayt = self.u1 * r1, u3 * r3
        wdot, loads, forces = evaluate(ayh, ayt)
        if d.h > 0.0:
            ayh, ayt = self._fixed_point(state, evaluate, ayh, ayt, wdot)
            wdot, loads, forces = evaluate(ayh, ayt)
        axle = tuple(forces[2 * i] + forces[2 * i + 1] for i in range(AXLES))
        return wdot, axle, loads, forces

    def _fixed_point(self, state: Sequence[float], evaluate: Callable[[float, float], _Evaluation],
                     ayh: float, ayt: float, wdot: Four) -> tuple[float, float]:
        """(a_y head, a_y tail) [m/s^2] with evaluate(a_y) giving back the same lateral
        accelerations (1e-12 relative): fixed-point iteration, then Newton's method with a
        difference Jacobian where it does not contract (the map is linear in the loads)."""
        def tol(x: float) -> float:
            return 1e-12 * (1.0 + abs(x))

        for _ in range(8):
            new_h, new_t = self._car_lateral(state, wdot)
            if abs(new_h - ayh) <= tol(ayh) and abs(new_t - ayt) <= tol(ayt):
                return new_h, new_t
            ayh, ayt = new_h, new_t
            wdot = evaluate(ayh, ayt)[0]
        for _ in range(30):
            gh, gt = (x - y for x, y in zip(self._car_lateral(state, wdot), (ayh, ayt)))
            if abs(gh) <= tol(ayh) and abs(gt) <= tol(ayt):
                return ayh, ayt
            step = 1e-6 * (1.0 + abs(ayh) + abs(ayt))
            jac = []
            for dh, dt in ((step, 0.0), (0.0, step)):
                w = evaluate(ayh + dh, ayt + dt)[0]
                fh, ft = self._car_lateral(state, w)
                jac.append(((fh - ayh - dh - gh) / step, (ft - ayt - dt - gt) / step))
            (j11, j21), (j12, j22) = jac
            det = j11 * j22 - j12 * j21
            if det == 0.0:
                break
            ayh -= (j22 * gh - j12 * gt) / det
            ayt -= (-j21 * gh + j11 * gt) / det
            wdot = evaluate(ayh, ayt)[0]
        raise FloatingPointError("lateral load transfer found no fixed point")

    def _car_lateral(self, state: Sequence[float], wdot: Sequence[float]) -> tuple[float, float]:
        """Lateral accelerations [m/s^2] of the head and tail cars' centres of gravity in
        their frames for the state and w' (u1 held)."""
        _, _, p1, p2, p3, v1, r1, r2, r3 = state
        dv1, dr1, dr2, dr3 = wdot
        g1, g3, lm, u1 = self.d.cg, -self.d.cg, self.g.Lm, self.u1
        head = u1 * r1 + dv1 + g1 * dr1
        c13, s13 = math.cos(p1 - p3), math.sin(p1 - p3)
        tail = ((u1 * r1 + dv1) * c13 - v1 * r1 * s13 - lm * dr2 * math.cos(p2 - p3)
                + lm * r2 * r2 * math.sin(p2 - p3) + g3 * dr3)
        return head, tail

    def _lumped_accelerations(self, state: Sequence[float]) -> tuple[Four, list[float]]:
        d, dl, a, lm = self.d, self.deltas, self.g.axle_offsets, self.g.Lm
        _, _, p1, p2, p3, _, _, _, _ = state
        slips, _, _ = self.axle_slips(state)
        forces = [d.force(i, s) for i, s in enumerate(slips)]
        f0, f1, f2, f3 = forces
        k0, k1, k2, k3 = (math.cos(x) for x in dl)
        q1 = f0 * k0 + f1 * k1 + f2 * math.cos(p3 + dl[2] - p1) + f3 * math.cos(p3 + dl[3] - p1)
        q2 = a[0] * f0 * k0 + a[1] * f1 * k1
        q3 = -lm * (f2 * math.cos(p3 + dl[2] - p2) + f3 * math.cos(p3 + dl[3] - p2))
        q4 = a[2] * f2 * k2 + a[3] * f3 * k3
        return self._solve(state, (q1, q2, q3, q4)), forces

    def _solve(self, state: Sequence[float], q: Four) -> Four:
        """w' from M(q) w' = Q - h for the generalised forces ``q`` (u1 held)."""
        _, _, p1, p2, p3, v1, r1, r2, r3 = state
        d, u1, lm = self.d, self.u1, self.g.Lm
        q1, q2, q3, q4 = q
        m1 = m3 = d.m_e
        m2 = d.m_f
        g1, g3 = d.cg, -d.cg
        c12, s12 = math.cos(p1 - p2), math.sin(p1 - p2)
        c13, s13 = math.cos(p1 - p3), math.sin(p1 - p3)
        c23, s23 = math.cos(p2 - p3), math.sin(p2 - p3)
        # velocity-product (centripetal and Coriolis) terms
        half = 0.5 * m2 + m3
        h1 = (m1 + m2 + m3) * u1 * r1 - half * lm * r2 * r2 * s12 + m3 * g3 * r3 * r3 * s13
        h2 = m1 * g1 * u1 * r1
        h3 = -half * lm * (u1 * r1 * c12 - v1 * r1 * s12) - m3 * lm * g3 * r3 * r3 * s23
        h4 = m3 * g3 * (u1 * r1 * c13 - v1 * r1 * s13 + lm * r2 * r2 * s23)
        # mass matrix (M23 = M24 = 0) and its solution by elimination of r1'
        M11 = m1 + m2 + m3
        M12 = m1 * g1
        M13 = -half * lm * c12
        M14 = m3 * g3 * c13
        M22 = m1 * g1 * g1 + d.I_e
        M33 = 0.25 * m2 * lm * lm + m3 * lm * lm + d.I_f
        M34 = -m3 * lm * g3 * c23
        M44 = m3 * g3 * g3 + d.I_e
        b1, b2, b3, b4 = q1 - h1, q2 - h2, q3 - h3, q4 - h4
        # row 2: M12 x1 + M22 x2 = b2  ->  x2 = (b2 - M12 x1) / M22
        A11 = M11 - M12 * M12 / M22
        B1 = b1 - M12 * b2 / M22
        # 3x3 symmetric system [[A11, M13, M14], [M13, M33, M34], [M14, M34, M44]] x = B
        # by Gaussian elimination (the matrix is positive definite: no pivoting needed)
        l31 = M13 / A11
        l41 = M14 / A11
        S33 = M33 - l31 * M13
        S34 = M34 - l31 * M14
        S44 = M44 - l41 * M14
        B3 = b3 - l31 * B1
        B4 = b4 - l41 * B1
        l43 = S34 / S33
        T44 = S44 - l43 * S34
        x4 = (B4 - l43 * B3) / T44
        x3 = (B3 - S34 * x4) / S33
        x1 = (B1 - M13 * x3 - M14 * x4) / A11
        x2 = (b2 - M12 * x1) / M22
        return (x1, x2, x3, x4)

    def rates(self, state: Sequence[float]) -> list[float]:
        """Right-hand side of the ODE for the state vector, inputs held."""
        _, _, p1, _, _, v1, r1, r2, r3 = state
        (dv1, dr1, dr2, dr3), _ = self.accelerations(state)
        c, s = math.cos(p1), math.sin(p1)
        u1 = self.u1
        return [u1 * c - v1 * s, u1 * s + v1 * c, r1, r2, r3, dv1, dr1, dr2, dr3]

    def state_vector(self) -> list[float]:
        return [self.x1, self.y1, self.psi1, self.psi2, self.psi3, self.v1, self.r1, self.r2,
                self.r3]

    def step(self, u1: float, deltas: Sequence[float], h: float,
             wheels: Sequence[Sequence[float]] | None = None) -> None:
        """Advance by ``h`` [s] with head-car speed ``u1`` [m/s] and axle angles ``deltas``
        [rad] held; ``wheels`` (optional 4 (left, right) pairs [rad]) turns each axle's two
        tyres (without it: the Ackermann angles of ``deltas`` about the car's hinge
        baseline; the lumped axles act at the axle centres with ``deltas``)."""
        deltas = tuple(float(x) for x in deltas)
        u1 = float(u1)
        for x in deltas:
            if not abs(x) < 0.5 * math.pi:
                raise FloatingPointError(f"axle angle {x} rad is not within +/-pi/2")
        if u1 <= -self.kinematic_below:
            raise ValueError(f"speed {u1} m/s: reverse driving faster than kinematic_below "
                             f"= {self.kinematic_below} m/s is not modelled")
        self.u1, self.deltas = u1, deltas
        self.wheels = None if wheels is None else tuple(tuple(map(float, w)) for w in wheels)
        if h <= 0.0:
            return
        if self.is_kinematic():
            kin = self._kinematic()
            kin.step(u1, deltas, h)
            self.x1, self.y1 = kin.x1, kin.y1
            self.psi1, self.psi2, self.psi3 = kin.psi1, kin.psi2, kin.psi3
            self.v1, self.r1, self.r2, self.r3 = self.kinematic_speeds()
        else:
            y, self.substeps = rk4_doubling(self.rates, self.state_vector(), h, self.tolerance,
                                            start=max(1, self.substeps // 2))
            (self.x1, self.y1, self.psi1, self.psi2, self.psi3,
             self.v1, self.r1, self.r2, self.r3) = y
            if not self.d.lumped and self.d.h > 0.0:
                self.check_contact()
        self.distance += abs(u1) * h

    def check_contact(self) -> None:
        """Raise :class:`~agv_core.dynamic_vehicle.dynamic_vehicle.WheelLiftError` naming
        the wheel when a wheel's load is <= 0 (the car starts to tip over)."""
        for k, load in enumerate(self.wheel_loads()):
            if not load > 0.0:
                side = "left" if k % 2 == 0 else "right"
                raise WheelLiftError(f"axle {k // 2 + 1}'s {side} wheel lifts (vertical "
                                     f"load {load:.1f} N): the car tips over")

    # ------------------------------------------------------------------ outputs
    def hinge2(self) -> tuple[float, float]:
        """Hinge J2 [m]."""
        return (self.x1 - self.g.Lm * math.cos(self.psi2),
                self.y1 - self.g.Lm * math.sin(self.psi2))

    def axle_points(self) -> tuple[tuple[float, float], ...]:
        """Centres of axles 1-4 [m]: ((x1, y1), ..., (x4, y4))."""
        return self._kinematic().axle_points()

    def car_speeds(self) -> tuple[float, float, float, float, float, float]:
        """(u1, v_J1, r1, u3, v_J2, r3): each end car's hinge velocity in its frame [m/s]
        and its yaw rate [rad/s]."""
        u3, v3 = self.tail_velocity(self.psi1, self.psi2, self.psi3, self.v1, self.r2)
        return self.u1, self.v1, self.r1, u3, v3, self.r3

    def axle_forces(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """(slips [rad], forces [N]) of axles 1-4 for the last inputs and current state:
        the axle centre's slip against the axle angle, and the lumped axle force or the
        sum of the axle's two wheel forces; zero in the kinematic regime."""
        if self.is_kinematic():
            return (0.0,) * AXLES, (0.0,) * AXLES
        slips, _, _ = self.axle_slips()
        if self.d.lumped:
            return slips, tuple(self.d.force(i, s) for i, s in enumerate(slips))
        return slips, self._current()[1]

    def _current(self) -> tuple[Four, tuple[float, ...], list[float], list[float]]:
        """_wheel_accelerations for the current state and inputs (kept until they change:
        the outputs read it several times per step)."""
        key = (tuple(self.state_vector()), self.u1, self.deltas, self.wheels)
        if self._current_key != key:
            self._current_value = self._wheel_accelerations(list(key[0]))
            self._current_key = key
        return cast(tuple[Four, tuple[float, ...], list[float], list[float]],
                    self._current_value)

    def wheel_loads(self) -> list[float]:
        """Vertical loads [N] of the eight wheels (axle 1 left, 1 right, ..., 4 right) for
        the last inputs and the current state (static in the kinematic regime and with
        lumped axles)."""
        if self.is_kinematic() or self.d.lumped:
            return self.d.wheel_loads(0.0, 0.0)
        return self._current()[2]

    def lateral_accelerations(self) -> tuple[float, float]:
        """Lateral accelerations [m/s^2] of the head and tail cars' centres of gravity,
        each in its car's frame, positive left (kinematic regime: w' taken as 0)."""
        v1, r1, r2, r3 = self.v1, self.r1, self.r2, self.r3
        if self.is_kinematic():
            wdot = (0.0, 0.0, 0.0, 0.0)
        elif self.d.lumped:
            wdot, _ = self.accelerations(self.state_vector())
        else:
            wdot = self._current()[0]
        return self._car_lateral([0.0, 0.0, self.psi1, self.psi2, self.psi3, v1, r1, r2, r3],
                                 wdot)

    def wheel_states(self) -> list[tuple[float, float]]:
        """Per wheel (axle 1 left, 1 right, ..., 4 right): (speed [m/s], slip [rad]) as the
        kinematic train defines them, from the dynamic state: wheel at body (a_i, +-d/2),
        velocity (u_c - r_c (+-d/2), v_c + r_c a_i) in its car's frame; wheel angle = the
        recorded wheel input, else the Ackermann angle about the car's hinge baseline."""
        u1, vj1, r1, u3, vj2, r3 = self.car_speeds()
        half = 0.5 * self.g.d
        out = []
        for i in range(AXLES):
            u, v, r = (u1, vj1, r1) if i < 2 else (u3, vj2, r3)
            a = self.g.axle_offsets[i]
            if self.wheels is not None:
                pair = self.wheels[i]
            else:
                pair = wheel_angles(self.deltas[i], a, self.g.d)
            vy = v + r * a
            for y, angle in ((half, pair[0]), (-half, pair[1])):
                vx = u - r * y
                speed = math.hypot(vx, vy)
                if speed == 0.0:
                    out.append((0.0, 0.0))
                    continue
                sign = 1.0 if vx >= 0.0 else -1.0
                out.append((speed, math.atan2(sign * vy, sign * vx) - angle))
        return out

    # ------------------------------------------------------------------ state
    def get_state(self) -> dict[str, Any]:
        return {"q": [self.x1, self.y1, self.psi1, self.psi2, self.psi3],
                "w": [self.v1, self.r1, self.r2, self.r3], "distance": self.distance,
                "u1": self.u1, "deltas": list(self.deltas),
                "wheels": None if self.wheels is None else [list(w) for w in self.wheels],
                "substeps": self.substeps}

    def set_state(self, state: dict[str, Any]) -> None:
        self.x1, self.y1, self.psi1, self.psi2, self.psi3 = (float(v) for v in state["q"])
        self.v1, self.r1, self.r2, self.r3 = (float(v) for v in state["w"])
        self.distance = float(state["distance"])
        self.u1 = float(state["u1"])
        self.deltas = tuple(float(v) for v in state["deltas"])
        w = state["wheels"]
        self.wheels = None if w is None else tuple(tuple(p) for p in w)
        self.substeps = int(state["substeps"])


def _cross(r: Sequence[float], f: Sequence[float]) -> float:
    return r[0] * f[1] - r[1] * f[0]


def steady_circle(dynamics: TrainDynamics, radius: float, u1: float, phi: float = 0.0,
                  iterations: int = 60) -> dict[str, Any]:
    """Steady turn on a circle: every axle centre at ``radius`` [m] (positive: left turn,
    centre at the origin), the head car at longitudinal speed ``u1`` [m/s] > 0.

    The pose is the kinematic train's steady pose (agv_core.train.train.steady_pose);
    every body rotates about the centre at Omega = u1 / sqrt(R^2 - L1^2/4), so each
    centre of gravity accelerates by -Omega^2 P towards it and no body has an angular
    acceleration. Newton-Euler for the three bodies (9 equations) gives the four axle
    forces, the two hinge forces and the head car's drive force (9 unknowns, linear for
    given axle angles); each axle angle is then its centre's velocity direction in the
    car frame minus the slip at which the tyre law gives that force, and the angles and
    forces are iterated to a fixed point (the force directions depend on the angles).

    Returns
    -------
    dict
        ``deltas`` (4 axle angles [rad]), ``kinematic_deltas`` (the velocity directions,
        +-asin(L1 / 2R)), ``slips`` [rad], ``forces`` [N] (axles 1-4), ``hinge_forces``
        (on the floating car at J1, on the tail car at J2 [N]), ``drive`` [N], ``omega``
        [rad/s] and ``state`` (x1, y1, psi1, psi2, psi3, v1, r1, r2, r3) to start a
        :class:`DynamicTrain` on.
    """
    import numpy as np
    from scipy.optimize import brentq

    from ..dynamic_vehicle.tyres import sliding_slip
    from ..train.train import steady_pose

    g, d = dynamics.g, dynamics
    R, sgn = abs(radius), (1.0 if radius > 0 else -1.0)
    x1, y1, p1, p2, p3 = steady_pose(g, radius, phi)
    omega = sgn * u1 / math.sqrt(R * R - 0.25 * g.L1 * g.L1)
    e = [(math.cos(p), math.sin(p)) for p in (p1, p2, p3)]
    n = [(-s, c) for c, s in e]
    lm, a = g.Lm, g.axle_offsets
    j1 = (x1, y1)
    j2 = (x1 - lm * e[1][0], y1 - lm * e[1][1])
    cgs = [(j1[0] + d.cg * e[0][0], j1[1] + d.cg * e[0][1]),
           (j1[0] - 0.5 * lm * e[1][0], j1[1] - 0.5 * lm * e[1][1]),
           (j2[0] - d.cg * e[2][0], j2[1] - d.cg * e[2][1])]
    masses = (d.m_e, d.m_f, d.m_e)
    cars = (0, 0, 2, 2)        # body index of each axle
    refs = (j1, j1, j2, j2)
    axles = [(refs[i][0] + a[i] * e[cars[i]][0], refs[i][1] + a[i] * e[cars[i]][1])
             for i in range(AXLES)]
    # velocity direction of each axle centre in its car's frame (rigid rotation about 0)
    theta = []
    for i in range(AXLES):
        vx, vy = -omega * axles[i][1], omega * axles[i][0]
        c = cars[i]
        theta.append(math.atan2(vx * n[c][0] + vy * n[c][1], vx * e[c][0] + vy * e[c][1]))
    v1 = -omega * j1[1] * n[0][0] + omega * j1[0] * n[0][1]
    deltas = list(theta)
    for _ in range(iterations):
        A = np.zeros((9, 9))
        rhs = np.zeros(9)
        for i in range(AXLES):
            c = cars[i]
            row = 0 if c == 0 else 6
            ang = (p1 if c == 0 else p3) + deltas[i]
            f = (-math.sin(ang), math.cos(ang))
            arm = (axles[i][0] - cgs[c][0], axles[i][1] - cgs[c][1])
            A[row, i], A[row + 1, i], A[row + 2, i] = f[0], f[1], _cross(arm, f)
        # hinge forces lam1 (on the bar at J1; -lam1 on the head car), lam2 (on the tail
        # car at J2; -lam2 on the bar); drive D along e1 on the head car's centre line
        arm1h = (j1[0] - cgs[0][0], j1[1] - cgs[0][1])
        arm1b = (j1[0] - cgs[1][0], j1[1] - cgs[1][1])
        arm2b = (j2[0] - cgs[1][0], j2[1] - cgs[1][1])
        arm2t = (j2[0] - cgs[2][0], j2[1] - cgs[2][1])
        A[0, 4], A[1, 5], A[2, 4], A[2, 5] = -1.0, -1.0, arm1h[1], -arm1h[0]
        A[0, 8], A[1, 8] = e[0]
        A[3, 4], A[4, 5], A[5, 4], A[5, 5] = 1.0, 1.0, -arm1b[1], arm1b[0]
        A[3, 6], A[4, 7], A[5, 6], A[5, 7] = -1.0, -1.0, arm2b[1], -arm2b[0]
        A[6, 6], A[7, 7], A[8, 6], A[8, 7] = 1.0, 1.0, -arm2t[1], arm2t[0]
        for b in range(3):
            rhs[3 * b] = -masses[b] * omega * omega * cgs[b][0]
            rhs[3 * b + 1] = -masses[b] * omega * omega * cgs[b][1]
        x = np.linalg.solve(A, rhs)
        forces = [float(v) for v in x[:4]]
        slips = []
        for i, force in enumerate(forces):
            if d.tyre == "linear":
                slips.append(-force / d.stiffness[i])
                continue
            edge = sliding_slip(d.stiffness[i], d.limits[i])
            if not abs(force) < d.limits[i]:
                raise ValueError(f"axle {i + 1} would need {force:.0f} N, beyond its "
                                 f"friction limit {d.limits[i]:.0f} N: no steady turn")
            slips.append(brentq(lambda s, i=i, force=force: d.force(i, s) - force,
                                -edge, edge, xtol=1e-16, rtol=1e-15))
        new = [t - s for t, s in zip(theta, slips)]
        change = max(abs(p - q) for p, q in zip(new, deltas))
        deltas = new
        if change < 1e-15:
            break
    result = {"deltas": tuple(deltas), "kinematic_deltas": tuple(theta),
              "slips": tuple(slips), "forces": tuple(forces),
              "hinge_forces": ((float(x[4]), float(x[5])), (float(x[6]), float(x[7]))),
              "drive": float(x[8]), "omega": omega,
              "state": (x1, y1, p1, p2, p3, v1, omega, omega, omega)}
    if d.lumped:
        return result
    # two tyres per axle: the lumped solution is the start of a Newton solve of the nine
    # balance equations for the four axle angles, hinge forces and drive; the wheels turn
    # by the Ackermann angles of their axle angle, their loads follow from the cars'
    # (known) centripetal accelerations
    from scipy.optimize import fsolve

    from ..ackermann.ackermann import wheel_angles as _wheel_angles
    half = 0.5 * g.d
    acc = [(-omega * omega * c[0], -omega * omega * c[1]) for c in cgs]
    ay_head = acc[0][0] * n[0][0] + acc[0][1] * n[0][1]
    ay_tail = acc[2][0] * n[2][0] + acc[2][1] * n[2][1]
    loads = d.wheel_loads(ay_head, ay_tail)
    heading = (p1, p1, p3, p3)

    def wheels(dl: "Sequence[float] | NDArray[np.float64]"
               ) -> list[tuple[tuple[float, float], tuple[float, float], float, float]]:
        """World force vectors, points and slips of the eight wheels for axle angles."""
        out = []
        for i in range(AXLES):
            c = cars[i]
            pair = _wheel_angles(dl[i], a[i], g.d)
            for k, y in ((0, half), (1, -half)):
                px = axles[i][0] + y * n[c][0]
                py = axles[i][1] + y * n[c][1]
                vx, vy = -omega * py, omega * px
                ang = heading[i] + pair[k]
                slip = math.atan2(vx * n[c][0] + vy * n[c][1],
                                  vx * e[c][0] + vy * e[c][1]) - pair[k]
                f = d.wheel_force(slip, loads[2 * i + k])
                out.append(((-f * math.sin(ang), f * math.cos(ang)), (px, py), slip, f))
        return out

    def residual(z: "NDArray[np.float64]") -> list[float]:
        dl, lam1, lam2, drive = z[:4], z[4:6], z[6:8], z[8]
        force = [[0.0, 0.0], [0.0, 0.0], [0.0, 0.0]]
        moment = [0.0, 0.0, 0.0]
        for k, (f, p, _, _) in enumerate(wheels(dl)):
            b = cars[k // 2]
            force[b][0] += f[0]
            force[b][1] += f[1]
            moment[b] += _cross((p[0] - cgs[b][0], p[1] - cgs[b][1]), f)
        for b, f, point in ((0, (-lam1[0], -lam1[1]), j1), (1, (lam1[0], lam1[1]), j1),
                            (1, (-lam2[0], -lam2[1]), j2), (2, (lam2[0], lam2[1]), j2),
                            (0, (drive * e[0][0], drive * e[0][1]), j1)):
            force[b][0] += f[0]
            force[b][1] += f[1]
            moment[b] += _cross((point[0] - cgs[b][0], point[1] - cgs[b][1]), f)
        out = []
        for b in range(3):
            out += [force[b][0] - masses[b] * acc[b][0], force[b][1] - masses[b] * acc[b][1],
                    moment[b]]
        return out

    start = list(deltas) + [float(v) for v in x[4:9]]
    z, info, ier, msg = fsolve(residual, start, xtol=1e-15, full_output=True)
    scale = sum(masses) * omega * omega * R + 1.0
    if ier != 1 and max(abs(v) for v in residual(z)) > 1e-9 * scale:
        raise ValueError(f"no steady turn with two tyres per axle: {msg}")
    dl = [float(v) for v in z[:4]]
    found = wheels(dl)
    result.update({
        "deltas": tuple(dl), "slips": tuple(t - q for t, q in zip(theta, dl)),
        "forces": tuple(found[2 * i][3] + found[2 * i + 1][3] for i in range(AXLES)),
        "wheel_slips": tuple(w[2] for w in found), "wheel_forces": tuple(w[3] for w in found),
        "wheel_loads": tuple(loads),
        "hinge_forces": ((float(z[4]), float(z[5])), (float(z[6]), float(z[7]))),
        "drive": float(z[8])})
    return result


__all__ = ["DynamicTrain", "TrainDynamics", "TrainGeometry", "steady_circle"]
