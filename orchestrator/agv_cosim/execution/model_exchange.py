"""Model Exchange FMUs as units: integrated by the orchestrator, stepped like the others.

A :class:`ModelExchangeUnit` behaves to the master exactly as a co-simulation
:class:`~.units.FmuUnit`: the same batched input sets and output gets, and a
``do_step(component, t, h, flag)`` that returns an FMI status (the FMI 2.0 calling
convention, for FMI 2.0 and 3.0 FMUs alike). It is chosen for a component whose
:class:`~agv_cosim.system.model.ModelInfo` carries an ``integration``: every
model-exchange-only FMU (:func:`agv_cosim.system.model.read_model` sets the default), or
one the caller asks for with :func:`use_model_exchange` (``interface =
"model-exchange"`` for an FMU with both interfaces). :func:`select_interface` maps a
component's ``interface``, ``solver`` and ``tolerance`` onto its ModelInfo (both live in
:mod:`agv_cosim.system.interface`, where the system stage applies them).

Semantics
---------
Initialisation
    After ``exitInitializationMode`` the unit runs the event iteration (FMI 2.0
    ``fmi2NewDiscreteStates``, FMI 3.0 ``fmi3UpdateDiscreteStates``, until no new
    discrete states are needed) and enters continuous-time mode, before the master's
    first exchange; the first row shows the values after that initial event.
At a communication point t_k
    Continuous inputs are set in continuous-time mode. An input group holding a discrete
    input (``variability`` other than continuous) whose values changed is set in event
    mode: ``enterEventMode``, the set, the event iteration, ``enterContinuousTimeMode``
    (an external event at t_k). Outputs read after a set show the FMU at t_k with those
    inputs (direct feedthrough is exact). A scenario event's value (any value set through
    fmpy's setters once in continuous time) is set in event mode the same way; the solver
    restarts after either.
The step from t_k to t_k + h (``do_step``)
    The inputs hold over the step. The solver integrates the continuous states from
    t_k, restarted (its history dropped) whenever an input changed or an event happened
    since the last step, and stops at the earliest of: t_k + h; the FMU's next time
    event (``nextEventTime``); a state event (an event indicator changing sign, located
    by the solver's root finding: CVODE's to 100 u (|t| + |h|), u the unit round-off;
    solve_ivp's by Brent's method on its dense output to 4 u, then moved forward to
    the first time past the sign change, which is where CVODE returns); after every
    stop (once per interval, as fmpy does, not after each internal solver step)
    ``completedIntegratorStep`` when the FMU needs it (a step event when it asks for
    event mode). At a time, state or step event the event iteration runs and the
    solver restarts. A time event within 1e-12 (relative, at least 1e-12 s) of t_k + h
    is handled at t_k + h, as fmpy does. The FMU is at t_k + h, with its states set, when
    ``do_step`` returns.
Limits
    :data:`MAX_EVENT_ITERATIONS` event iterations for one event: an FMU that still asks
    for new discrete states then fails the run (``SimulationError``, one line); so does
    one with more than :data:`MAX_EVENTS_PER_STEP` events in one communication step (a
    chattering model).
Stop and failure
    ``terminateSimulation`` (from the event iteration or ``completedIntegratorStep``) is
    a stop request at that time (as a co-simulation FMU's): the unit returns Discard and
    :meth:`ModelExchangeUnit.stop_requested` says when. A solver failure raises
    :class:`~agv_cosim.errors.SimulationError` naming the component, the solver, the time
    and the solver's reason (for solve_ivp also derivatives or a state that are not
    finite: LSODA would never return on them); an FMI call that fails raises fmpy's
    ``FMICallException``, which :func:`~.simulation.simulate` reports as for any FMU.
    The rows recorded before are kept either way.

Solvers (:data:`SOLVERS`; ``benchmarks/bench_model_exchange.py`` compares them)
    ``"cvode"`` (default): SUNDIALS CVODE (BDF, dense linear solver) through
    ``fmpy.sundials``, with its root finding for the event indicators and its stop time
    at the end of each interval. ``"scipy"``: ``scipy.integrate.solve_ivp`` (LSODA),
    one call per interval, each event indicator a terminal event. Both use the relative
    tolerance ``tolerance`` and the absolute tolerance ``tolerance`` x each state's
    nominal.
"""

from collections.abc import Callable
from ctypes import byref, c_double, c_int, c_void_p
from typing import Any

import numpy as np

from ..errors import SimulationError
from ..system.interface import (
    DEFAULT_SOLVER,
    DEFAULT_TOLERANCE,
    INTERFACES,
    SOLVERS,
    check_integration,
    select_interface,
    use_model_exchange,
)
from ..system.model import Integration, ModelExchangeInfo, Variable
from .instance import FmuInstance
from .units import FmuUnit

__all__ = ["DEFAULT_SOLVER", "DEFAULT_TOLERANCE", "INTERFACES", "MAX_EVENTS_PER_STEP",
           "MAX_EVENT_ITERATIONS", "SOLVERS", "Integration", "ModelExchangeUnit",
           "check_integration", "select_interface", "use_model_exchange"]

#: Event iterations (newDiscreteStates / updateDiscreteStates calls) allowed per event.
MAX_EVENT_ITERATIONS = 100
#: Events (time, state, step, input) allowed within one communication step.
MAX_EVENTS_PER_STEP = 10_000
#: Internal solver steps allowed per interval between two stops.
MAX_SOLVER_STEPS = 100_000


def _close(a: float, b: float) -> bool:
    return abs(a - b) <= 1e-12 * max(1.0, abs(a), abs(b))


class _Held:
    """The FMI inputs of the FMU as :class:`fmpy.sundials.CVodeSolver` wants them: the
    inputs are held over the step, so there is nothing to apply."""

    def apply(self, *args: Any, **kwargs: Any) -> None:
        pass


class _Model:
    """The FMU's continuous-time functions with the status checks of fmpy's wrappers
    (they raise fmpy's ``FMICallException`` above Warning)."""

    def __init__(self, slave: Any, fmi3: bool, nx: int, nz: int) -> None:
        self.slave, self.nx, self.nz = slave, nx, nz
        self.set_time: Callable[[float], Any] = slave.setTime
        self.get_x: Callable[[Any, int], Any] = slave.getContinuousStates
        self.set_x: Callable[[Any, int], Any] = slave.setContinuousStates
        self.get_dx: Callable[[Any, int], Any] = (
            slave.getContinuousStateDerivatives if fmi3 else slave.getDerivatives)
        self.get_z: Callable[[Any, int], Any] = slave.getEventIndicators
        self.get_nominals: Callable[[Any, int], Any] = slave.getNominalsOfContinuousStates


class _Cvode:
    """CVODE (BDF) through fmpy.sundials, with the FMU's event indicators as its root
    functions and a stop time at the end of each interval."""

    name = "CVODE"

    def __init__(self, model: _Model, t0: float, tolerance: float) -> None:
        from fmpy.sundials import CVodeSolver
        from fmpy.sundials.cvode import CV_NORMAL, CV_ROOT_RETURN, CVode
        from fmpy.sundials.libraries import sundials_cvode
        from fmpy.sundials.sundials_types import sunrealtype

        self._cvode, self._root_return, self._normal = CVode, CV_ROOT_RETURN, CV_NORMAL
        stop_time = sundials_cvode.CVodeSetStopTime
        stop_time.argtypes, stop_time.restype = [c_void_p, sunrealtype], c_int
        self._stop_time = stop_time
        self._realtype = sunrealtype
        self.model = model
        #: an exception a callback raised (CVODE is told the callback failed)
        self.raised: BaseException | None = None
        owner = self

        # fmpy's callbacks, with an FMU error held instead of lost in ctypes
        def f(solver: Any, t: float, y: Any, ydot: Any, user_data: Any) -> int:
            try:
                return int(CVodeSolver.f(solver, t, y, ydot, user_data))
            except Exception as error:  # noqa: BLE001 - re-raised by advance
                owner.raised = error
                return -1

        def g(solver: Any, t: float, y: Any, gout: Any, user_data: Any) -> int:
            try:
                return int(CVodeSolver.g(solver, t, y, gout, user_data))
            except Exception as error:  # noqa: BLE001 - re-raised by advance
                owner.raised = error
                return -1

        solver_class: Any = type("HeldErrorsCVodeSolver", (CVodeSolver,), {"f": f, "g": g})
        self.solver = solver_class(
            nx=model.nx, nz=model.nz, get_x=model.get_x, set_x=model.set_x,
            get_dx=model.get_dx, get_z=model.get_z, get_nominals=model.get_nominals,
            set_time=model.set_time, input=_Held(), startTime=t0,
            relativeTolerance=tolerance, maxNumSteps=MAX_SOLVER_STEPS)

    def advance(self, t: float, t_stop: float) -> tuple[float, bool]:
        """Integrate from ``t`` towards ``t_stop``: (time reached, a state event there)."""
        solver = self.solver
        if not solver.discrete:
            solver.get_x(solver.px, solver.nx)
        self._stop_time(solver.cvode_mem, t_stop)
        reached = self._realtype(0.0)
        self.raised = None
        flag = self._cvode(solver.cvode_mem, t_stop, solver.x, byref(reached), self._normal)
        if self.raised is not None:
            raise self.raised
        if flag < 0:
            info = solver.error_info
            reason = info[3] if info else f"flag {flag}"
            raise SimulationError(f"CVODE error {flag}: {' '.join(str(reason).split())}")
        if not solver.discrete:
            solver.set_x(solver.px, solver.nx)
        return float(reached.value), flag == self._root_return

    def reset(self, t: float) -> None:
        self.solver.reset(t)


class _Scipy:
    """scipy.integrate.solve_ivp (LSODA), one call per interval, each event indicator a
    terminal event function."""

    name = "solve_ivp"
    method = "LSODA"

    def __init__(self, model: _Model, t0: float, tolerance: float) -> None:
        self.model = model
        self.rtol = tolerance
        nx = max(model.nx, 1)
        self.x = (c_double * nx)()
        self.dx = (c_double * nx)()
        self.z = (c_double * max(model.nz, 1))()
        self._z_at: tuple[float, bytes] | None = None
        self.atol = np.full(nx, tolerance)
        self.first_step: float | None = None
        self.reset(t0)

    def reset(self, t: float) -> None:
        if self.model.nx:
            nominals = (c_double * self.model.nx)()
            self.model.get_nominals(nominals, self.model.nx)
            self.atol = self.rtol * np.abs(np.array(nominals[:]))
        self.first_step = None

    def _rhs(self, t: float, y: Any) -> Any:
        model = self.model
        if not model.nx:
            return np.zeros(1)
        model.set_time(t)
        self.x[:] = y.tolist()
        model.set_x(self.x, model.nx)
        model.get_dx(self.dx, model.nx)
        dx = np.array(self.dx[:model.nx])
        if not np.all(np.isfinite(dx)):
            # LSODA never returns on a derivative that is inf or NaN: it is a failure here
            raise SimulationError(
                f"solve_ivp ({self.method}): the derivatives are not finite at t={t!r} s "
                f"({', '.join(map(repr, dx.tolist()))})")
        return dx

    def _indicators(self, t: float, y: Any) -> Any:
        key = (t, y.tobytes())
        if key != self._z_at:
            model = self.model
            model.set_time(t)
            if model.nx:
                self.x[:] = y.tolist()
                model.set_x(self.x, model.nx)
            model.get_z(self.z, model.nz)
            self._z_at = key
        return self.z

    def _past_crossing(self, dense: Any, t: float, i: int, sign: float) -> tuple[float, Any]:
        """The first time from ``t`` (solve_ivp's root, within 4 u of the crossing, on
        either side) at which indicator ``i`` no longer has the ``sign`` it had at the
        start of the interval, and the state there: the event is then handled past the
        crossing, as CVODE's root finding returns it."""
        y = dense(t)
        for k in range(64):
            z = float(self._indicators(t, y)[i])
            if np.sign(z) != sign or sign == 0:
                break
            t += 2.0 ** k * 2.2e-16 * max(1.0, abs(t))
            y = dense(t)
        return t, y

    def advance(self, t: float, t_stop: float) -> tuple[float, bool]:
        from scipy.integrate import solve_ivp

        model = self.model
        if model.nx:
            model.get_x(self.x, model.nx)
            y0 = np.array(self.x[:model.nx])
        else:
            y0 = np.zeros(1)
        events = []
        for i in range(model.nz):
            def event(t: float, y: Any, i: int = i) -> float:
                return float(self._indicators(t, y)[i])
            event.terminal = True  # type: ignore[attr-defined]
            events.append(event)
        self._z_at = None
        options: dict[str, Any] = {}
        if self.first_step is not None and self.first_step < t_stop - t:
            options["first_step"] = self.first_step
        before = np.sign(np.array(self._indicators(t, y0)[:model.nz]))
        sol = solve_ivp(self._rhs, (t, t_stop), y0, method=self.method, rtol=self.rtol,
                        atol=self.atol, events=events or None, dense_output=bool(events),
                        **options)
        if sol.status == -1:
            raise SimulationError(f"solve_ivp ({self.method}): {sol.message}")
        reached, y, crossed = float(sol.t[-1]), sol.y[:, -1], False
        if sol.status == 1:
            found = [(float(times[0]), i) for i, times in enumerate(sol.t_events)
                     if len(times)]
            reached, first = min(found)
            reached, y = self._past_crossing(sol.sol, reached, first, before[first])
            crossed = True
        if not np.all(np.isfinite(y)):
            raise SimulationError(f"solve_ivp ({self.method}): the state is not finite at "
                               f"t={reached!r} s ({', '.join(map(repr, y.tolist()))})")
        if len(sol.t) > 1:
            self.first_step = float(sol.t[-1] - sol.t[-2]) or None
        model.set_time(reached)
        if model.nx:
            self.x[:] = y.tolist()
            model.set_x(self.x, model.nx)
        return reached, crossed


_SOLVER_CLASSES: dict[str, Any] = {"cvode": _Cvode, "scipy": _Scipy}

#: fmpy's convenience setters (FMI 2.0 and 3.0) that parameters and events go through.
_PY_SETTERS = ("setReal", "setInteger", "setBoolean", "setString", "setFloat32",
               "setFloat64", "setInt8", "setUInt8", "setInt16", "setUInt16", "setInt32",
               "setUInt32", "setInt64", "setUInt64", "setBinary")


class ModelExchangeUnit(FmuUnit):
    """A Model Exchange FMU instance integrated between communication points (see the
    module's docstring), with the interface of a co-simulation :class:`FmuUnit`."""

    def __init__(self, instance: FmuInstance, index: int, outputs: list[Variable],
                 inputs: list[Variable]) -> None:
        super().__init__(instance, index, outputs, inputs)
        info = instance.info
        assert info.integration is not None and info.model_exchange is not None
        self.integration: Integration = info.integration
        self.me: ModelExchangeInfo = info.model_exchange
        self.step_extra = None  # stepped with the FMI 2.0 convention (do_step below)
        self.in_continuous_time = False
        #: the FMU's next time event [s] (None: none declared)
        self.next_event: float | None = None
        self.solver: Any = None
        self.restart = True
        self.stop_time: float | None = None
        self.events = 0  # events handled in the run (time, state, step and input)
        #: continuous-input buffers and their values at the last step (a change restarts
        #: the solver)
        self._continuous: list[tuple[Any, list[Any]]] = []
        self._wrap_inputs(inputs)
        slave = self.slave
        self._now = 0.0  # the FMU's time [s] (the start time once initialised)
        enter_initialisation = slave.enterInitializationMode
        exit_initialisation = slave.exitInitializationMode

        def enter_at(*args: Any, **kwargs: Any) -> Any:
            if kwargs.get("startTime") is not None:  # FMI 3.0
                self._now = float(kwargs["startTime"])
            return enter_initialisation(*args, **kwargs)

        if not self.fmi3:
            setup = slave.setupExperiment

            def setup_at(*args: Any, **kwargs: Any) -> Any:
                if kwargs.get("startTime") is not None:
                    self._now = float(kwargs["startTime"])
                return setup(*args, **kwargs)

            slave.setupExperiment = setup_at
        slave.enterInitializationMode = enter_at

        def exit_then_event() -> Any:
            status = exit_initialisation()
            self._initial_event()
            return status

        # simulate() calls slave.exitInitializationMode(): the initial event iteration
        # and the switch to continuous-time mode follow it there
        slave.exitInitializationMode = exit_then_event
        # fmpy's setters (a parameter, a scenario event's value) set in event mode once
        # in continuous time (the unit's own input sets call the C functions directly)
        for name in _PY_SETTERS:
            setter = getattr(slave, name, None)
            if setter is not None:
                setattr(slave, name, self._in_event_mode(setter))

    # the master's interface -----------------------------------------------------------

    def _step_function(self) -> Any:
        return self._do_step

    def stop_requested(self) -> tuple[bool, float | None]:
        return self.stop_time is not None, self.stop_time

    # inputs ---------------------------------------------------------------------------

    def _wrap_inputs(self, inputs: list[Variable]) -> None:
        """Input groups with a discrete input are set through :meth:`_set_discrete`."""
        groups: dict[str, list[Variable]] = {}  # as FmuUnit groups them: by C setter
        for v in inputs:
            groups.setdefault(v.ftype.set, []).append(v)
        for i, variables in enumerate(groups.values()):
            fn, args, buf, links, fname = self._in_groups[i]
            if all(v.variability == "continuous" for v in variables):
                self._continuous.append((buf, list(buf)))
                continue
            self._in_groups[i] = (self._set_discrete(fn, buf), args, buf, links, fname)

    def _set_discrete(self, fn: Any, buf: Any) -> Callable[..., int]:
        last: list[list[Any] | None] = [None]

        def set_group(*args: Any) -> int:
            if not self.in_continuous_time:  # initialisation or event mode: as is
                last[0] = list(buf)
                return int(fn(*args))
            values = list(buf)
            if values == last[0]:
                return 0
            self.slave.enterEventMode()
            status = int(fn(*args))
            if status > 1:
                return status
            last[0] = values
            self.events += 1
            self._event_iteration(self._time())
            return status
        return set_group

    def _in_event_mode(self, setter: Callable[..., Any]) -> Callable[..., Any]:
        def set_in_event_mode(*args: Any, **kwargs: Any) -> Any:
            if not self.in_continuous_time:
                return setter(*args, **kwargs)
            self.slave.enterEventMode()
            self.in_continuous_time = False
            result = setter(*args, **kwargs)
            self.events += 1
            self._event_iteration(self._now)
            return result
        return set_in_event_mode

    def _time(self) -> float:
        return self._now

    # events ---------------------------------------------------------------------------

    def _initial_event(self) -> None:
        self._iterate(self._now)
        if self.stop_time is None:
            self.slave.enterContinuousTimeMode()
            self.in_continuous_time = True

    def _event_iteration(self, t: float) -> None:
        """In event mode at ``t``: iterate, then back to continuous-time mode."""
        self.in_continuous_time = False
        self._iterate(t)
        if self.stop_time is None:
            self.slave.enterContinuousTimeMode()
            self.in_continuous_time = True
        self.restart = True

    def _iterate(self, t: float) -> None:
        update = self.slave.updateDiscreteStates if self.fmi3 else \
            self.slave.newDiscreteStates
        for _ in range(MAX_EVENT_ITERATIONS):
            needed, terminate, _, _, defined, when = update()
            if terminate:
                self.stop_time = t
                return
            if not needed:
                self.next_event = float(when) if defined else None
                return
        call = "fmi3UpdateDiscreteStates" if self.fmi3 else "fmi2NewDiscreteStates"
        raise SimulationError(
            f"component '{self.name}': the FMU did not leave event mode at t={t!r} s: "
            f"{call} still asked for new discrete states after {MAX_EVENT_ITERATIONS} "
            "event iterations")

    # the step -------------------------------------------------------------------------

    def _make_solver(self, t: float) -> Any:
        slave = self.slave
        if self.fmi3:
            nx, nz = int(slave.getNumberOfContinuousStates()), \
                int(slave.getNumberOfEventIndicators())
        else:
            nx, nz = self.me.states, self.me.event_indicators
        self._model = _Model(slave, self.fmi3, nx, nz)
        if nx == 0 and nz == 0:
            return None
        return _SOLVER_CLASSES[self.integration.solver](self._model, t,
                                                        self.integration.tolerance)

    def _do_step(self, component: Any, t: float, h: float, flag: Any = 1) -> int:
        """From ``t`` to ``t + h`` [s]: 0, or 2 (Discard) when the FMU asked to stop."""
        if self.stop_time is not None:
            return 2
        end = t + h
        self._start_step(t)
        now, events = t, 0
        slave = self.slave
        while now < end and not _close(now, end):
            t_stop, time_event = self._next_stop(now, end)
            now, state_event = self._advance(now, t_stop, t)
            if time_event and state_event and not _close(now, t_stop):
                time_event = False
            slave.setTime(now)
            self._now = now
            step_event = self._completed_step(now)
            if self.stop_time is not None:
                return 2
            if time_event or state_event or step_event:
                events += 1
                self._event_in_step(now, events, t, end)
                if self.stop_time is not None:
                    return 2
        if now != end:
            slave.setTime(end)
        self._now = end
        return 0

    def _start_step(self, t: float) -> None:
        """Before a step from ``t``: the solver made (at the first step), and restarted
        at ``t`` when an input changed or an event happened since the last step."""
        if self.solver is None:
            self.solver = self._make_solver(t)
            self.restart = False
        for buf, held in self._continuous:
            values = list(buf)
            if values != held:
                held[:] = values
                self.restart = True
        if self.restart and self.solver is not None:
            self.solver.reset(t)
        self.restart = False

    def _next_stop(self, now: float, end: float) -> tuple[float, bool]:
        """Where the solver stops next from ``now`` in a step to ``end``, and whether that
        is the FMU's time event (within the step, or within 1e-12 of its end)."""
        when = self.next_event
        if when is not None and (when < end or _close(when, end)):
            return min(max(when, now), end), True
        return end, False

    def _advance(self, now: float, t_stop: float, t: float) -> tuple[float, bool]:
        """The states integrated from ``now`` towards ``t_stop``: where the solver stopped,
        and whether at a state event (no solver, or no time to go: at ``t_stop``, none).
        ``t``: the start of the communication step, for the message of a failure."""
        if self.solver is not None and t_stop > now and not _close(t_stop, now):
            try:
                found: tuple[float, bool] = self.solver.advance(now, t_stop)
                return found
            except SimulationError as failed:  # the solver's reason
                raise SimulationError(
                    f"component '{self.name}': the {self.solver.name} solver failed "
                    f"at t={now!r} s (step from t={t!r} s): {failed}") from None
        return t_stop, False

    def _completed_step(self, now: float) -> Any:
        """``completedIntegratorStep`` at ``now`` when the FMU needs it: whether it asks
        for event mode (a step event); a termination it asks for is a stop request at
        ``now`` (:attr:`stop_time`)."""
        if not self.me.needs_completed_integrator_step:
            return False
        step_event, terminate = self.slave.completedIntegratorStep()
        if terminate:
            self.stop_time = now
        return step_event

    def _event_in_step(self, now: float, events: int, t: float, end: float) -> None:
        """The ``events``-th event in the step from ``t`` to ``end``, at ``now``: event
        mode, the event iteration and the solver restarted there (unless the FMU asked
        to stop: :attr:`stop_time`); more than :data:`MAX_EVENTS_PER_STEP` fail the run."""
        if events > MAX_EVENTS_PER_STEP:
            raise SimulationError(
                f"component '{self.name}': more than {MAX_EVENTS_PER_STEP} events "
                f"in the step from t={t!r} s to t={end!r} s (stuck at "
                f"t={now!r} s)")
        self.events += 1
        self.slave.enterEventMode()
        self._event_iteration(now)
        if self.stop_time is not None:
            return
        if self.solver is not None:
            self.solver.reset(now)
        self.restart = False
