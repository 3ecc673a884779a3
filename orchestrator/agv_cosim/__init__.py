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
5. :mod:`agv_cosim.report`: the results: metrics, plots, Monte Carlo statistics, run records.

:mod:`agv_cosim.pipeline` runs the stages end to end (local worker processes or a Dask
cluster); :mod:`agv_cosim.ssp` reads and writes SSP packages; :mod:`agv_cosim.cli` is the
``agv-cosim`` command and :mod:`agv_cosim.api` its Python API (:func:`run`,
:func:`open_results`: results as pandas DataFrames); the package :mod:`agv_cosim.build`
(``fmus``, ``bundle``, ``standalone``, ``shipped``, ``examples``) builds the component FMUs.

Every error of stages 1-3 is one line, ``<manifest>: <key>: <problem>``; every error type
is in :mod:`agv_cosim.errors`.
"""

import importlib
from typing import Any

from .version import __version__

#: The public API, name -> the module that defines it. Imported on first use (PEP 562), so
#: that importing one part (e.g. ``agv_cosim.build`` for ``agv-cosim build``) does not
#: import every stage and its libraries (matplotlib, fmpy).
_API = {
    "AgvCosimError": "agv_cosim.errors",
    "ManifestError": "agv_cosim.errors", "ModelError": "agv_cosim.errors",
    "OutputError": "agv_cosim.errors", "SimulationError": "agv_cosim.errors",
    "SspError": "agv_cosim.errors", "TableError": "agv_cosim.errors",
    "Manifest": "agv_cosim.manifest", "load_manifest": "agv_cosim.manifest",
    "plan_runs": "agv_cosim.plan",
    "Job": "agv_cosim.system", "System": "agv_cosim.system", "validate": "agv_cosim.system",
    "simulate": "agv_cosim.execution",
    "read_timeseries": "agv_cosim.timeseries",
    "check_initialisation": "agv_cosim.pipeline", "execute": "agv_cosim.pipeline",
    "prepare": "agv_cosim.pipeline", "run_job": "agv_cosim.pipeline",
    "run_manifest": "agv_cosim.pipeline",
    "Results": "agv_cosim.api", "Run": "agv_cosim.api", "open_results": "agv_cosim.api",
    "run": "agv_cosim.api",
    "identify": "agv_cosim.api", "IdentifyError": "agv_cosim.errors",
    "tune": "agv_cosim.api", "TuneError": "agv_cosim.errors",
    "fit": "agv_cosim.api", "FitDataError": "agv_cosim.errors",
    "FitError": "agv_cosim.errors", "FitNotConverged": "agv_cosim.errors",
    "TrialFailed": "agv_cosim.errors",
}

__all__ = ["__version__", *sorted(_API)]


def __dir__() -> list[str]:
    """The module's names and the public API's (not imported yet): what ``dir()`` and a
    notebook's tab completion show."""
    return sorted(set(globals()) | set(_API))


def __getattr__(name: str) -> Any:
    module = _API.get(name)
    if module is None:
        raise AttributeError(f"module 'agv_cosim' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value
