"""Stage 4, execution: one run of a checked :class:`~agv_cosim.system.System`, composed
of parts as in libcosim.

- :mod:`.instance`: an FMU instantiated in a private extraction folder;
- :mod:`.units`: its value buffers, grouped by C getter / setter;
- :mod:`.model_exchange`: a Model Exchange FMU as a unit, integrated between
  communication points by a solver (CVODE or solve_ivp), events handled; chosen for a
  model-exchange-only FMU or by :func:`.model_exchange.use_model_exchange`;
- :mod:`.algorithm`: Gauss-Seidel or Jacobi, which moves the values; the stepper,
  which steps every FMU and collects stop requests;
- :mod:`.scenario`: the events, applied at their communication points;
- :mod:`.observers`: what takes each recorded row and the progress (CSV, callbacks);
- :mod:`.fastpath`: the opt-in generated per-step functions (the same calls);
- :mod:`.pacing`: the opt-in real-time pacing of the steps (the same results);
- :mod:`.simulation`: :func:`simulate`, the composition.
"""

from .observers import CsvObserver, Observer, ProgressObserver, RowObserver
from .pacing import Pacer
from .simulation import Outcome, simulate
from .track import PHASES, describe_track

__all__ = ["PHASES", "CsvObserver", "Observer", "Outcome", "Pacer", "ProgressObserver",
           "RowObserver", "describe_track", "simulate"]
