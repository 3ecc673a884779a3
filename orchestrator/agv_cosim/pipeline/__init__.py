"""The pipeline end to end: :mod:`.prepare` (manifest -> plan -> system: the jobs),
:mod:`.job` (one job run into its folder), :mod:`.pool` (local worker processes),
:mod:`.distributed` (a Dask cluster), :mod:`.initcheck` (``validate``'s initialisation
check), :mod:`.run` (the jobs run and the output folder written), :mod:`.channels` (how
a worker reports to its parent).
"""

from .initcheck import INIT_TIMEOUT, check_initialisation
from .job import run_job
from .prepare import prepare
from .run import default_out_dir, execute, run_manifest

__all__ = ["INIT_TIMEOUT", "check_initialisation", "default_out_dir", "execute", "prepare",
           "run_job", "run_manifest"]
