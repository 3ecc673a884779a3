"""Angle wrapping [rad], written once for every core.

Two functions, because they round differently and the results pages are kept
bit-identical:

- :func:`wrap_angle` takes the IEEE remainder (exact): an angle already in (-pi, pi] comes
  back unchanged to the bit. The controllers use it (preview LQ, chained form).
- :func:`heading_error` is the path geometry's difference of two headings, wrapped with
  Python's float modulo (``d % 2 pi``, one rounding for negative d). The path projection,
  the sensors and the seed-001 MPC use it; switching them to :func:`wrap_angle` would move
  their results in the last bit.
"""

import math

TWO_PI = 2.0 * math.pi


def wrap_angle(angle: float) -> float:
    """Wrap ``angle`` [rad] to (-pi, pi] [rad] (exact)."""
    wrapped = math.remainder(angle, TWO_PI)
    return math.pi if wrapped == -math.pi else wrapped


def heading_error(vehicle_heading: float, path_heading: float) -> float:
    """Vehicle heading minus path heading [rad], wrapped to (-pi, pi]."""
    d = (float(vehicle_heading) - float(path_heading)) % TWO_PI
    return d - TWO_PI if d > math.pi else d
