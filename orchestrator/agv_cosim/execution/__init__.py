"""Stage 4, execution: one run of a checked :class:`~agv_cosim.system.System`, composed
of parts as in libcosim.

- :mod:`.instance`: an FMU instantiated in a private extraction folder;
- :mod:`.units`: its value buffers, grouped by C getter / setter;
- :mod:`.model_exchange`: a Model Exchange FMU as a unit, integrated between
  communication points by a solver (CVODE or solve_ivp), events handled; chosen for a
  model-exchange-only FMU or by :func:`.model_exchange.use_model_exchange`;
- :mod:`.algorithm`: Gauss-Seidel or Jacobi, which moves the values; the stepper,
  which steps every FMU and collects stop requests;
- :mod:`.multirate`: components stepped at their own step, a whole multiple of the
  simulation's (libcosim's step-size multipliers): each steps, has its outputs read
  and its inputs set only at its own communication points, its outputs held between
  them; the exchange at a base point is the algorithm's over the components whose
  point it is (Jacobi: their outputs read, then their inputs set, as libcosim;
  Gauss-Seidel: they are visited in feedthrough order, the others' outputs held);
  an event off a component's points is refused, a recorded row between them shows
  its held outputs; the macro steps in which only base-rate components step and
  exchange run in the compiled stretches, the others in Python; details in that
  module;
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
