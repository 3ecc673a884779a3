"""Stage 3, the system: each planned run's components read from their model
descriptions (:mod:`.model`) or time tables (:mod:`.table`) and checked as one system
(:mod:`.check`): parameters, connections (causality, type, unit), events, recorded
signals, and the Gauss-Seidel schedule (:mod:`.order`). Checked per run because a
variant may swap an FMU or rewire the system. :mod:`.checked` holds what it hands on.
"""

from .check import validate
from .checked import Checked, CheckedRun, Event, Job, System
from .model import ModelInfo, Variable, read_model
from .order import feedthrough_order
from .table import Table, read_table

__all__ = ["Checked", "CheckedRun", "Event", "Job", "ModelInfo", "System", "Table",
           "Variable", "feedthrough_order", "read_model", "read_table", "validate"]
