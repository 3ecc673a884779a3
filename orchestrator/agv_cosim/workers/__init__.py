"""The jobs run: :mod:`.job` (one job run into its folder), :mod:`.pool` (local worker
processes), :mod:`.distributed` (a Dask cluster), :mod:`.host` (a Dask worker's run
host), :mod:`.initcheck` (the initialisation check of ``validate`` and ``run``),
:mod:`.channels` (how a worker reports to its parent). The local pool and Dask both
implement :class:`~.runner.Runner`.
"""

from .initcheck import INIT_TIMEOUT
from .job import run_job
from .pool import check_initialisation

__all__ = ["INIT_TIMEOUT", "check_initialisation", "run_job"]
