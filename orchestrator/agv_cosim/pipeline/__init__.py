"""The pipeline end to end: :mod:`.prepare` (manifest -> plan -> system: the jobs),
:mod:`.job` (one job run into its folder), :mod:`.pool` (local worker processes),
:mod:`.distributed` (a Dask cluster), :mod:`.initcheck` (the initialisation check of
``validate`` and ``run``), :mod:`.run` (the jobs run and the output folder written),
:mod:`.resume` (the runs of an earlier folder kept by ``--resume``), :mod:`.channels` (how
a worker reports to its parent).
"""

from .initcheck import INIT_TIMEOUT
from .job import run_job
from .pool import check_initialisation
from .prepare import prepare
from .resume import reusable
from .run import check_options, default_out_dir, execute, run_manifest

__all__ = ["INIT_TIMEOUT", "check_initialisation", "check_options", "default_out_dir",
           "execute", "prepare", "reusable", "run_job", "run_manifest"]
