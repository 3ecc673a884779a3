"""The finite check of parameter values, written once for every core.

The FMI adapter's run-time check of outputs (``AgvSlave.finite_or_fail``, a
FloatingPointError that fails the step) is the adapter's own: a parameter error is raised
before the run, an output that becomes NaN during it.
"""

import math

from ..errors import ParameterError


def finite(name: str, value: float, parameter: str | None = None) -> float:
    """``value`` as a float if finite; else ParameterError.

    The error names ``name`` (``parameter 'name': must be finite, got nan``), or, where
    the value is one field of a larger parameter such as a path string, names
    ``parameter`` and says which field (``parameter 'path': x0 must be finite, got nan``).
    """
    if not math.isfinite(value):
        if parameter is None:
            raise ParameterError(name, f"must be finite, got {value}")
        raise ParameterError(parameter, f"{name} must be finite, got {value}")
    return float(value)
