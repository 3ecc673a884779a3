"""Stage 3, the system: each planned run's components read from their model
descriptions (:mod:`.model`) or time tables (:mod:`.table`) and checked as one system
(:mod:`.check`): parameters, connections (causality, type, unit), events, recorded
signals, and the Gauss-Seidel schedule (:mod:`.order`). Checked per run because a
variant may swap an FMU or rewire the system. :mod:`.checked` holds what it hands on.

The names below are imported on first use (PEP 562): reading a model description
(``agv-cosim list``) does not import the manifest's schema that :mod:`.check` needs.
"""

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .check import validate
    from .checked import Checked, CheckedRun, Event, Job, System
    from .model import ModelInfo, Variable, read_model
    from .order import feedthrough_order
    from .table import Table, read_table

#: Public name -> the module of this package that defines it.
_API = {
    "validate": "check",
    "Checked": "checked", "CheckedRun": "checked", "Event": "checked", "Job": "checked",
    "System": "checked",
    "ModelInfo": "model", "Variable": "model", "read_model": "model",
    "feedthrough_order": "order",
    "Table": "table", "read_table": "table",
}

__all__ = ["Checked", "CheckedRun", "Event", "Job", "ModelInfo", "System", "Table",
           "Variable", "feedthrough_order", "read_model", "read_table", "validate"]


def __getattr__(name: str) -> Any:
    module = _API.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value
