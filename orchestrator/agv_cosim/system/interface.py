"""Which FMI interface a component runs through, and how an integrated one is solved.

A component's ``interface``, ``solver`` and ``tolerance`` (``[components.<name>]``,
docs/manifest.md) are mapped onto its :class:`~.model.ModelInfo` by
:func:`select_interface`: an FMU with a co-simulation interface runs through it unless
``interface = "model-exchange"``; a model-exchange-only FMU, or one asked for as Model
Exchange, gets an :class:`~.model.Integration` (solver and tolerance), and the execution
stage integrates it (:mod:`agv_cosim.execution.model_exchange`).
"""

from dataclasses import replace
from math import isfinite

from ..errors import ModelError
from .model import Integration, ModelInfo, model_exchange_refusal

__all__ = ["DEFAULT_SOLVER", "DEFAULT_TOLERANCE", "INTERFACES", "SOLVERS",
           "check_integration", "select_interface", "use_model_exchange"]

#: What a component's ``interface`` may name (None: the FMU's own choice).
INTERFACES = ("co-simulation", "model-exchange")
#: Solver names a component may ask for.
SOLVERS = ("cvode", "scipy")
DEFAULT_SOLVER = Integration().solver
DEFAULT_TOLERANCE = Integration().tolerance


def check_integration(solver: str, tolerance: float) -> str:
    """Why ``solver`` / ``tolerance`` cannot be used ('' if they can)."""
    if solver not in SOLVERS:
        return f"solver {solver!r} is not one of {', '.join(map(repr, SOLVERS))}"
    if isinstance(tolerance, bool) or not isinstance(tolerance, (int, float)) or \
            not isfinite(tolerance) or not 0 < tolerance < 1:
        return f"tolerance {tolerance!r} is not a number between 0 and 1 (exclusive)"
    return ""


def use_model_exchange(info: ModelInfo, solver: str | None = None,
                       tolerance: float | None = None) -> ModelInfo:
    """``info`` for a component run through the FMU's Model Exchange interface (a copy;
    ``info`` itself, shared by every component of that FMU, is unchanged): what
    ``interface = "model-exchange"`` and the component's ``solver`` / ``tolerance``
    select. Solver and tolerance default to the FMU's current integration (a
    model-exchange-only FMU's) or :data:`DEFAULT_SOLVER` / :data:`DEFAULT_TOLERANCE`.

    Raises
    ------
    ModelError
        One line naming the FMU: it has no Model Exchange interface, it needs its
        exporting tool, or the solver or tolerance cannot be used.
    """
    me = info.model_exchange
    problem = model_exchange_refusal(info)
    if problem or me is None:
        raise ModelError(f"'{info.path}': it {problem}: it cannot be run with "
                         "interface = \"model-exchange\"")
    base = info.integration or Integration()
    chosen = Integration(solver=base.solver if solver is None else solver,
                         tolerance=base.tolerance if tolerance is None else tolerance)
    problem = check_integration(chosen.solver, chosen.tolerance)
    if problem:
        raise ModelError(f"'{info.path}': Model Exchange {problem}")
    return replace(info, identifier=me.identifier, integration=chosen)


def select_interface(info: ModelInfo, interface: str | None = None,
                     solver: str | None = None,
                     tolerance: float | None = None) -> ModelInfo:
    """``info`` for one component, as its ``interface``, ``solver`` and ``tolerance``
    ask (the entry point for a manifest's component keys).

    ``interface`` None: an FMU with a co-simulation interface runs through it, a
    model-exchange-only one is integrated; "model-exchange": integrated
    (:func:`use_model_exchange`); "co-simulation": through its co-simulation interface.
    ``solver`` and ``tolerance`` apply to an integrated component only.

    Raises
    ------
    ModelError
        One line naming the FMU and the reason.
    """
    if interface is not None and interface not in INTERFACES:
        raise ModelError(f"'{info.path}': interface {interface!r} is not one of "
                         f"{', '.join(map(repr, INTERFACES))}")
    integrated = interface == "model-exchange" or (
        interface is None and info.integration is not None)
    if integrated:
        return use_model_exchange(info, solver, tolerance)
    if solver is not None or tolerance is not None:
        raise ModelError(f"'{info.path}': solver and tolerance apply to a component "
                         "integrated as Model Exchange (interface = \"model-exchange\"), "
                         "and this one runs as co-simulation")
    if "co-simulation" not in info.interfaces:
        raise ModelError(f"'{info.path}': has no co-simulation interface (it declares "
                         f"{', '.join(info.interfaces)}): it cannot be run with "
                         "interface = \"co-simulation\"")
    return info
