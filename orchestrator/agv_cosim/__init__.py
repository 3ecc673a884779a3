"""agv_cosim: the orchestrator that runs agv-cosim FMUs from experiment manifests.

A manifest goes through five stages, one subpackage each; a stage imports only from the
stages before it and from the foundation modules (``errors``, ``fmitypes``,
``lifetime``, ``files``, ``timeseries``, ``version``):

1. :mod:`agv_cosim.manifest`: the TOML file read, its shape checked against one
   declarative schema (pydantic models of every table) and built into a
   :class:`~agv_cosim.manifest.Manifest`; no FMU is opened.
2. :mod:`agv_cosim.plan`: variants x sweep points (and ``--set``) -> one
   :class:`~agv_cosim.plan.RunSpec` per run; with ``[montecarlo]`` each of them x the
   samples.
3. :mod:`agv_cosim.system`: each run's components read from their model descriptions
   (or time tables) and checked as one system (parameters, connections, events,
   recorded signals, the Gauss-Seidel schedule) into a :class:`~agv_cosim.system.Job`
   holding its :class:`~agv_cosim.system.System`.
4. :mod:`agv_cosim.execution`: one run simulated, composed of parts: the FMU units, the
   algorithm (Gauss-Seidel, Jacobi), the scenario's events, the observers that record,
   the stop-request rule.
5. :mod:`agv_cosim.results`: metrics, plots, Monte Carlo statistics, run records.

:mod:`agv_cosim.pipeline` runs the stages end to end (local worker processes or a Dask
cluster); :mod:`agv_cosim.ssp` reads and writes SSP packages; :mod:`agv_cosim.cli` is the
``agv-cosim`` command; :mod:`agv_cosim.build` (with ``bundle``, ``standalone``,
``shipped``, ``examples``) builds the component FMUs.

Every error of stages 1-3 is one line, ``<manifest>: <key>: <problem>``; every error type
is in :mod:`agv_cosim.errors`.
"""

from .errors import ManifestError, ModelError, OutputError, SimulationError, SspError, TableError
from .execution import simulate
from .manifest import Manifest, load_manifest
from .pipeline import check_initialisation, execute, prepare, run_job, run_manifest
from .plan import plan_runs
from .system import Job, System, validate
from .timeseries import read_timeseries
from .version import __version__

__all__ = ["Job", "Manifest", "ManifestError", "ModelError", "OutputError",
           "SimulationError", "SspError", "System", "TableError", "__version__",
           "check_initialisation", "execute", "load_manifest", "plan_runs", "prepare",
           "read_timeseries", "run_job", "run_manifest", "simulate", "validate"]
