"""``agv-cosim fit``: a manifest's run fitted to measured data (docs/fit.md), wrapping
the numerics of :mod:`agv_cosim.fitting` with the manifest, the runs
(:mod:`agv_cosim.pipeline.trials`) and the output folder.

- :mod:`.checks`: the ``[fit]`` table checked against the run and the data;
- :mod:`.command`: :func:`fit_manifest`, the fit over batches of runs and its folder;
- :mod:`.output`: the fitted variant, the figure, the page.
"""

from .checks import FitSetup, setup
from .command import OURS, FitOutcome, fit_manifest

__all__ = ["OURS", "FitOutcome", "FitSetup", "fit_manifest", "setup"]
