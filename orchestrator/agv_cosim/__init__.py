"""agv_cosim: the orchestrator that runs agv-cosim FMUs from experiment manifests.

A manifest goes through five stages, one module (or two) each:

1. manifest (:mod:`agv_cosim.manifest`): the TOML file read, its shape checked against
   one declarative schema (:mod:`agv_cosim.schema`, pydantic models of every table,
   ``[metrics]``, ``[plots]`` and ``[montecarlo]`` included), and built into a
   :class:`~agv_cosim.manifest.Manifest`; no FMU is opened. An SSP package is read into
   the same object (:mod:`agv_cosim.ssp_import`), and written from it
   (:mod:`agv_cosim.ssp_export`).
2. plan (:mod:`agv_cosim.plan`): variants x sweep points (and ``--set``) -> one
   :class:`~agv_cosim.plan.RunSpec` per run; with ``[montecarlo]`` each of them x the
   samples (:mod:`agv_cosim.montecarlo`: designs, distributions, per-run seeds).
3. system (:mod:`agv_cosim.system`): each run's components read from their model
   descriptions (:mod:`agv_cosim.model`, :mod:`agv_cosim.table`), parameters,
   connections (causality, type, unit), events and recorded signals checked, and the
   Gauss-Seidel schedule found (:mod:`graphlib`). Checked per run because a variant may
   swap an FMU.
4. run (:mod:`agv_cosim.runner` prepares the jobs and runs them in worker processes, a
   worker reused only after a run that ended complete, locally or on a Dask cluster
   (:mod:`agv_cosim.distributed`); :mod:`agv_cosim.master` steps one
   :class:`~agv_cosim.master.Plan`).
5. results (:mod:`agv_cosim.results` files, :mod:`agv_cosim.metrics`,
   :mod:`agv_cosim.plots`; ``montecarlo.json`` and its figure from
   :mod:`agv_cosim.montecarlo`).

Every error of stages 1-3 is one line, ``<manifest>: <key>: <problem>``.
"""

__version__ = "0.1.0"
