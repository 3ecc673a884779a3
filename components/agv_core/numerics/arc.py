"""The exact arc of a kinematic single-track vehicle with steering and speed held.

With the yaw rate w held over a time h, the reference point moves on a circular arc: its
chord has length v h sinc(w h / 2) and points along the heading at mid-step,
beta + w h / 2. :class:`~agv_core.vehicle.vehicle.Vehicle` and the train integrate their
steps with it, the preview LQ controller predicts the pose over the measurement age with
:func:`arc_pose`.
"""

import math


def sinc(u: float) -> float:
    """sin(u) / u, with its limit 1 at u = 0 (accurate to rounding near 0)."""
    if abs(u) < 1e-4:
        return 1.0 - u * u / 6.0
    return math.sin(u) / u


def arc_pose(x: float, y: float, theta: float, alpha: float, speed: float, wheelbase: float,
             duration: float) -> tuple[float, float, float]:
    """Exact pose of the rear-axle centre after ``duration`` [s], ``alpha``, ``speed`` held.

    Parameters: rear-axle centre ``x``, ``y`` [m], heading ``theta`` [rad], steering angle
    ``alpha`` [rad], ``speed`` [m/s], ``wheelbase`` [m].

    Returns
    -------
    tuple of float
        (x [m], y [m], theta [rad]).
    """
    w = speed * math.tan(alpha) / wheelbase
    half = 0.5 * w * duration
    chord = speed * duration * sinc(half)
    return (x + chord * math.cos(theta + half), y + chord * math.sin(theta + half),
            theta + w * duration)
