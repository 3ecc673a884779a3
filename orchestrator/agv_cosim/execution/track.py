"""Where a run is: the component being called, the phase and the time, kept in a
3-element float sequence (``track``) that may live in shared memory, so that a parent
can name the component, call and time of a run whose process died."""

from collections.abc import MutableSequence, Sequence

__all__ = ["DO_STEP", "EXCHANGE", "GET", "GS_PASS", "INITIALISATION", "INSTANTIATION",
           "PHASES", "PROPAGATION", "SET", "Track", "describe_track"]

#: index of the component called (in the system's model order; -1: none), phase code
#: (:data:`PHASES`), time [s]
Track = MutableSequence[float]

#: What a run is doing, by code (``track[1]``).
PHASES = ("instantiation", "initialisation", "initialisation exchange",
          "initial propagation", "doStep", "fmi2GetReal", "fmi2SetReal",
          "Gauss-Seidel pass")
(INSTANTIATION, INITIALISATION, EXCHANGE, PROPAGATION, DO_STEP, GET, SET,
 GS_PASS) = range(len(PHASES))


def describe_track(track: Sequence[float], names: Sequence[str]) -> str:
    """``"component 'X' during <phase> at t=<t> s"`` from a run's track."""
    unit, phase, t = int(track[0]), int(track[1]), float(track[2])
    name = names[unit] if 0 <= unit < len(names) else "?"
    return f"component '{name}' during {PHASES[phase]} at t={t!r} s"
