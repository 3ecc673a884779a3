"""The pipeline end to end: :mod:`.prepare` (manifest -> plan -> system: the jobs),
:mod:`.run` (the jobs run by :mod:`agv_cosim.workers` and the output folder written),
:mod:`.resume` (the runs of an earlier folder kept by ``--resume``).
"""

from ..workers.initcheck import INIT_TIMEOUT
from ..workers.job import run_job
from ..workers.pool import check_initialisation
from .prepare import prepare
from .resume import reusable
from .run import check_options, default_out_dir, execute, run_manifest

__all__ = ["INIT_TIMEOUT", "check_initialisation", "check_options", "default_out_dir",
           "execute", "prepare", "reusable", "run_job", "run_manifest"]
