"""What stage 3 hands on: a run checked as a system (:class:`CheckedRun`), and the
self-contained :class:`System` and :class:`Job` that the execution stage runs."""

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..fmitypes import FmiType
from ..manifest import Connection
from ..manifest.schema import MetricsTable
from ..plan import RunSpec
from .model import ModelInfo

__all__ = ["Checked", "CheckedRun", "Event", "Job", "System"]


@dataclass(frozen=True)
class Event:
    """A scenario event: at step ``k`` (time ``at`` = start + k step [s]) the values
    ``sets``, ``(component, variable, value)``, are set (a tunable parameter or an
    unconnected input)."""

    k: int
    at: float
    name: str
    sets: tuple[tuple[str, str, Any], ...]


@dataclass
class CheckedRun:
    """One planned run checked against its FMUs."""

    run: RunSpec
    models: dict[str, ModelInfo]
    #: component -> {parameter: value parsed to its variable's type} (the run's own)
    parameters: dict[str, dict[str, Any]]
    #: Gauss-Seidel order of the instance names
    order: list[str]
    #: sorted by step, then by the manifest's order
    events: list[Event]
    #: "component.variable" recorded (``[record] variables``, else every numeric output
    #: of the run's components: runs of variants with other components record others)
    record: list[str]


@dataclass
class Checked:
    """The result of :func:`agv_cosim.system.validate`."""

    runs: list[CheckedRun]
    #: one line each (unconnected inputs)
    warnings: list[str]


@dataclass
class System:
    """Everything :func:`agv_cosim.execution.simulate` needs for one run."""

    models: dict[str, ModelInfo]          # instance name -> ModelInfo (or a Table)
    parameters: dict[str, dict[str, Any]]  # instance name -> {parameter: value}
    connections: list[Connection]
    order: list[str]                       # Gauss-Seidel order of instance names
    record: list[str]                      # "component.variable" (outputs)
    start: float
    stop: float
    step: float
    algorithm: str
    record_every: int
    #: macro steps from start to stop
    steps: int
    #: applied at t_k = start + k step, before that instant's exchange
    events: list[Event] = field(default_factory=list)
    #: component -> its own communication step [s], for the components stepped at a
    #: whole multiple (> 1) of ``step`` (:mod:`agv_cosim.execution.multirate`); the
    #: others are stepped at ``step``
    component_steps: dict[str, float] = field(default_factory=dict)

    def record_types(self) -> list[FmiType]:
        """The FMI type of each ``record`` column."""
        found = []
        for name in self.record:
            cname, _, vname = name.partition(".")
            found.append(self.models[cname].variables[vname].ftype)
        return found


@dataclass
class Job:
    """One run, self-contained and picklable (sent to a worker process)."""

    label: str
    variant: str | None
    point: dict[str, Any]
    plan: System
    #: every parameter's value in the run (the manifest's, else the FMU's start value)
    parameters: dict[str, dict[str, Any]]
    fmu_sha256: dict[str, str]
    manifest_path: str
    manifest_sha256: str
    #: the manifest's ``[metrics]`` table (None: no metrics)
    metrics_spec: MetricsTable | None
    #: how run.json names each FMU (inside an unpacked .ssp: ``<ssp>!/<entry>``)
    fmu_paths: dict[str, str]
    #: wall-clock limit of the run [s] (``[simulation] timeout`` or ``--timeout``); None:
    #: no limit. A run still going then is stopped and reported ``timed out``.
    timeout: float | None = None
    #: real-time factor the run's steps are paced at (``--real-time``); None: unpaced.
    #: Pacing does not change the results, so it is not one of the run's inputs.
    real_time: float | None = None
    #: the folder relative file names are relative to
    #: (:attr:`agv_cosim.manifest.Manifest.files_dir`); None: the manifest's
    base_dir: Path | None = None
    #: the files the run's parameters and events name (:mod:`.files`):
    #: ``{"component.parameter" or "events.<name>.component.variable": {name as written:
    #: SHA-256}}``; ``plan`` holds the values with the names absolute
    files: dict[str, dict[str, str]] = field(default_factory=dict)

    @property
    def manifest_dir(self) -> Path:
        """The folder relative file names are relative to (the metrics' path strings,
        the files parameters name)."""
        return self.base_dir if self.base_dir is not None else Path(self.manifest_path).parent
