"""What runs a command's jobs: one :class:`Runner` contract, kept by the local worker
pool (:class:`LocalRunner`: :func:`~agv_cosim.workers.pool.run_isolated`) and by a Dask
cluster (:class:`DaskRunner`: :func:`~agv_cosim.workers.distributed.run_on_dask`)."""

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable

from ..report.records import RunResult
from ..system import Job
from . import distributed, pool
from .initcheck import InitChecks

__all__ = ["DaskRunner", "LocalRunner", "Runner"]


@runtime_checkable
class Runner(Protocol):
    """Runs jobs, each into its folder ``root / job.label``.

    :meth:`run` returns one result per job, in job order, once every job ended; a run
    that fails (its FMU, its process, its task) is a result with its status and reason,
    and the others go on. ``on_progress(steps)`` is called as steps are done,
    ``on_done()`` once per run ended. When the runs cannot go on (SIGINT, SIGTERM or
    SIGHUP; a cluster gone) after runs started, it raises a
    :class:`~agv_cosim.errors.RunsStopped` of the stop's kind carrying one result per
    job (the runs not finished ``interrupted`` or ``not run``), the termination signals
    ignored until its ``restore()``.
    """

    def run(self, jobs: list[Job], root: Path, on_progress: Callable[[int], None],
            on_done: Callable[[], None]) -> list[RunResult]:
        """Run ``jobs`` under ``root``; one result per job, in job order."""
        ...


@dataclass(frozen=True)
class LocalRunner:
    """The jobs in worker processes of this machine, ``workers`` at a time; ``checks``
    and ``meanwhile`` as :func:`~agv_cosim.workers.pool.run_isolated` takes them."""

    workers: int
    checks: InitChecks | None = None
    meanwhile: Callable[[], None] | None = None

    def run(self, jobs: list[Job], root: Path, on_progress: Callable[[int], None],
            on_done: Callable[[], None]) -> list[RunResult]:
        return pool.run_isolated(jobs, root, self.workers, on_progress, on_done,
                                 checks=self.checks, meanwhile=self.meanwhile)


@dataclass(frozen=True)
class DaskRunner:
    """The jobs on the Dask cluster whose scheduler is at ``address``."""

    address: str

    def run(self, jobs: list[Job], root: Path, on_progress: Callable[[int], None],
            on_done: Callable[[], None]) -> list[RunResult]:
        return distributed.run_on_dask(self.address, jobs, root, on_progress, on_done)
