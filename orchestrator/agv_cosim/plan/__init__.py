"""Stage 2, the plan: a manifest's runs, one :class:`RunSpec` per variant x sweep point
(x Monte Carlo sample).

:mod:`.runs` expands variants, sweep points and ``--set`` overrides, :mod:`.sampling`
draws the ``[montecarlo]`` samples, :mod:`.spec` holds the run and its label,
:mod:`.experiment` what every run of the manifest shares (the system stage's view of
it). Nothing here opens an FMU.
"""

from .experiment import Experiment
from .runs import parse_set, plan_runs
from .spec import MAX_LABEL, MAX_RUNS, Origin, Override, RunSpec, run_label

__all__ = ["MAX_LABEL", "MAX_RUNS", "Experiment", "Origin", "Override", "RunSpec",
           "parse_set", "plan_runs", "run_label"]
