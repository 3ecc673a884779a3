"""The bounded parameters ``fit`` and ``tune`` vary: a name, a start, a minimum and a
maximum, each checked (finite numbers, min < max, min <= start <= max)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import AgvCosimError

__all__ = ["Parameter", "check_parameters", "vector"]


@dataclass(frozen=True)
class Parameter:
    """One varied parameter: ``name`` (``"comp.param"`` in a manifest), its ``start``
    (the manifest's value) and its bounds ``min`` < ``max``."""

    name: str
    start: float
    min: float
    max: float


def _number(value: object) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating |
                                                 np.integer):
        return None
    number = float(value)
    return number if math.isfinite(number) else None


def check_parameters(parameters: Sequence[Parameter], error: type[AgvCosimError],
                     what: str) -> tuple[Parameter, ...]:
    """``parameters`` as a tuple, each checked; ``error`` (one line naming the
    parameter, ``what`` the section, e.g. ``"fit"``) for none, a name given twice, a
    bound or start that is not a finite number, min >= max, a start outside the
    bounds."""
    if not parameters:
        raise error(f"{what}: no parameter to vary (give at least one with min and max)")
    seen: set[str] = set()
    out = []
    for parameter in parameters:
        name = parameter.name
        if not isinstance(name, str) or not name:
            raise error(f"{what}: parameter name {name!r}: not a name")
        if name in seen:
            raise error(f"{what}: parameter '{name}' given twice")
        seen.add(name)
        numbers = {}
        for field in ("min", "max", "start"):
            number = _number(getattr(parameter, field))
            if number is None:
                raise error(f"{what}: parameter '{name}': {field} "
                            f"{getattr(parameter, field)!r} is not a finite number")
            numbers[field] = number
        low, high, start = numbers["min"], numbers["max"], numbers["start"]
        if not low < high:
            raise error(f"{what}: parameter '{name}': min {low!r} >= max {high!r}")
        if not low <= start <= high:
            raise error(f"{what}: parameter '{name}': start {start!r} is outside its "
                        f"bounds [{low!r}, {high!r}]")
        out.append(Parameter(name, start, low, high))
    return tuple(out)


def vector(parameters: Sequence[Parameter], values: Mapping[str, float]) -> np.ndarray:
    """``values`` (name -> value) as a vector in the order of ``parameters``."""
    return np.array([float(values[p.name]) for p in parameters], dtype=float)
