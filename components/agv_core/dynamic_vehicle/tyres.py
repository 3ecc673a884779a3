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
friction coefficient for adhesion and sliding; no relaxation length.

Combined slip (:func:`combined_limit`): a wheel that transmits a longitudinal force F_x
has only the rest of its friction circle left for the lateral force; the Fiala law then
runs with the derated limit xi mu Fz, xi = sqrt((mu Fz)^2 - F_x^2) / (mu Fz), in place
of mu Fz (the "coupled" brush model with the longitudinal force as an input: friction
circle; the brush model under combined slip is Pacejka 2012, ch. 3; this derated form
is the one of Hindiyeh and Gerdes, "A controller framework for autonomous drifting",
J. Dyn. Sys. Meas. Control 136(5), 2014). The cornering stiffness is unchanged.
"""

import math


def linear_force(slip: float, stiffness: float) -> float:
    """Linear tyre: F = -C alpha [N] for slip ``alpha`` [rad], ``stiffness`` C [N/rad]."""
    return -stiffness * slip


def fiala_force(slip: float, stiffness: float, limit: float) -> float:
    """Fiala (brush) tyre force [N] for slip ``alpha`` [rad].

    Parameters
    ----------
    slip : float
        Slip angle [rad], velocity direction minus wheel angle, |slip| < pi/2 (beyond it
        the wheel rolls backwards over the ground: full sliding, -limit sign(slip)).
    stiffness : float
        Cornering stiffness C [N/rad], > 0.
    limit : float
        Friction limit mu Fz [N] (or the derated xi mu Fz of combined slip); a limit of
        0 (a lifted wheel, a wheel whose longitudinal force takes all its friction) gives
        no force.
    """
    if not limit > 0.0:
        return 0.0
    if abs(slip) >= 0.5 * math.pi:
        return -math.copysign(limit, slip)
    sigma = math.tan(slip)
    theta = stiffness / (3.0 * limit)
    a = theta * abs(sigma)
    if a >= 1.0:
        return -math.copysign(limit, sigma)
    return -stiffness * sigma * (1.0 - a + a * a / 3.0)


def combined_limit(limit: float, longitudinal: float) -> float:
    """Lateral friction limit [N] left on the friction circle of radius ``limit`` = mu Fz
    [N] by the longitudinal force ``longitudinal`` = F_x [N]: sqrt(limit^2 - F_x^2), 0
    when |F_x| >= limit (the wheel spins or locks: no lateral force)."""
    if longitudinal == 0.0:
        return limit
    rest = limit * limit - longitudinal * longitudinal
    return math.sqrt(rest) if rest > 0.0 else 0.0


def sliding_slip(stiffness: float, limit: float) -> float:
    """Slip angle [rad] at which the Fiala tyre reaches full sliding: atan(3 mu Fz / C)."""
    return math.atan(3.0 * limit / stiffness)


TYRES = ("fiala", "linear")
