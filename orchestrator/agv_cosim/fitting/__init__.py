"""The numerics of ``agv-cosim fit`` and ``agv-cosim tune`` (issue 34), on callables:
no manifest, no files but the measured data, no worker pool. The command, the API and
the manifest's ``[fit]``/``[tune]`` sections wrap these.

- :mod:`.data`: the measured data (a CSV file with a ``time`` column), checked;
- :mod:`.parameters`: the bounded parameters varied;
- :mod:`.outputerror`: :func:`fit`, output-error least squares over a batched
  ``simulate``;
- :mod:`.tuning`: :func:`tune`, a seeded global search over a batched ``evaluate`` of
  every run's metrics.
"""

from __future__ import annotations

from .data import MeasuredData, check_interval, measured_data, read_data
from .outputerror import FitResult, Signal, Simulate, default_weights, fit, interpolate
from .parameters import Parameter
from .tuning import Evaluate, Objective, Trial, TuneResult, tune

__all__ = ["Evaluate", "FitResult", "MeasuredData", "Objective", "Parameter", "Signal",
           "Simulate", "Trial", "TuneResult", "check_interval", "default_weights", "fit",
           "interpolate", "measured_data", "read_data", "tune"]
