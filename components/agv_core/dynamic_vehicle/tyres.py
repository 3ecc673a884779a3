"""Lateral tyre force laws: linear, and Fiala's brush model with saturation.

Sign convention (the same as the trains' slip outputs): the slip angle alpha [rad] of a
wheel is the direction of its centre's velocity minus the wheel's own angle, both
counter-clockwise from the car's longitudinal axis; the lateral force F [N] acts on the
wheel, perpendicular to the wheel plane, positive to the left of the wheel. A wheel
pointing left of its velocity (alpha < 0) is pushed left: F = -C alpha for small alpha.

Fiala's model (the brush model with a parabolic contact pressure, Pacejka, Tire and
Vehicle Dynamics, 3rd ed. 2012, section 3.2.2; Fiala 1954), with sigma = tan(alpha),
theta = C / (3 mu Fz):

    F = -C sigma (1 - theta |sigma| + theta^2 sigma^2 / 3)    for |sigma| < 1 / theta
    F = -mu Fz sign(sigma)                                     beyond (full sliding)

Its slope at alpha = 0 is -C (the cornering stiffness), it reaches the friction limit
mu Fz with zero slope at tan(alpha_sl) = 3 mu Fz / C, and it is odd in alpha. One
friction coefficient for adhesion and sliding; no load transfer, no combined slip (the
longitudinal force the drive needs is not modelled), no relaxation length.
"""

import math


def linear_force(slip, stiffness):
    """Linear tyre: F = -C alpha [N] for slip ``alpha`` [rad], ``stiffness`` C [N/rad]."""
    return -stiffness * slip


def fiala_force(slip, stiffness, limit):
    """Fiala (brush) tyre force [N] for slip ``alpha`` [rad].

    Parameters
    ----------
    slip : float
        Slip angle [rad], velocity direction minus wheel angle, |slip| < pi/2 (beyond it
        the wheel rolls backwards over the ground: full sliding, -limit sign(slip)).
    stiffness : float
        Cornering stiffness C [N/rad], > 0.
    limit : float
        Friction limit mu Fz [N], > 0.
    """
    if abs(slip) >= 0.5 * math.pi:
        return -math.copysign(limit, slip)
    sigma = math.tan(slip)
    theta = stiffness / (3.0 * limit)
    a = theta * abs(sigma)
    if a >= 1.0:
        return -math.copysign(limit, sigma)
    return -stiffness * sigma * (1.0 - a + a * a / 3.0)


def sliding_slip(stiffness, limit):
    """Slip angle [rad] at which the Fiala tyre reaches full sliding: atan(3 mu Fz / C)."""
    return math.atan(3.0 * limit / stiffness)


TYRES = ("fiala", "linear")
