"""Stage 5, the report: the results made of the runs' time series. :mod:`.metrics` (tracking
metrics, streamed from ``timeseries.csv``), :mod:`.plots` (the runs overlaid),
:mod:`.montecarlo` (``montecarlo.json`` and its figure), :mod:`.records` (``run.json``,
``metrics.json``, ``summary.csv``, ``timings.csv``), :mod:`.page` (``index.html``, the
result folder's HTML report, and the figures that compare the runs). The time series file itself is
:mod:`agv_cosim.timeseries`; output folders are :mod:`agv_cosim.files`.
"""

from .metrics import compute_metrics, compute_metrics_csv
from .page import terminal_summary, write_report, write_report_quietly
from .plots import plot_runs
from .records import RunResult

__all__ = ["RunResult", "compute_metrics", "compute_metrics_csv", "plot_runs", "terminal_summary",
           "write_report",
           "write_report_quietly"]
