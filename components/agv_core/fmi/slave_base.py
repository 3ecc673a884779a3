"""The FMI-version-independent half of the FMU slave adapters.

:mod:`agv_core.fmi_slave` (FMI 2.0, pythonfmu) and :mod:`agv_core.fmi3_slave` (FMI 3.0,
pythonfmu3) each define ``AgvSlave`` as ``SlaveLogic`` plus their library's slave class.
Everything a slave script sees is here: the ``input`` / ``output`` / ``parameter``
declarations, the hooks ``make_core`` / ``advance`` / ``publish``, initialisation,
stepping, lazy re-publication of feedthrough outputs, state save/restore, and the parts
of the model description both versions share (unit definitions, reference inputs). An
adapter supplies its variable types, enums and status values as class attributes, its
typed get/set methods (which call ``_fresh_outputs`` / ``_inputs_set``), and the rest of
``to_xml``. This module imports no FMI library, so it is bundled in both kinds of FMU.
"""

import json
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn, TypeVar, cast
from xml.etree.ElementTree import Element, SubElement

from .. import __version__
from ..errors import ModelLimitError, ParameterError
from ..units import base_unit_attributes
from .pythonfmu_workarounds import keep_for_pythonfmu

#: Name of the build-info file the build writes into every FMU's ``resources/``.
BUILD_INFO = "agv_build.json"

#: Tool name (FMI 2.0) / annotation type (FMI 3.0) that carries ``reference_inputs``.
REFERENCE_TOOL = "org.agv-cosim"

#: The modes a saved FMU state records (the state machine's, as the slave sees it):
#: before initialisation, in initialisation mode (no core yet in either), stepping,
#: terminated. Restoring a state restores its mode (the FMU bridge reads it).
STATE_MODES = ("instantiated", "initialization", "step", "terminated")
#: The keys of a saved state, exactly.
STATE_KEYS = frozenset(("mode", "variables", "time", "core"))

#: ``_fmi_variables`` codes: the variable's type (FMI 2.0 / FMI 3.0 name) ...
VAR_REAL, VAR_INTEGER, VAR_BOOLEAN, VAR_STRING = range(4)
#: ... and what a host may set: nothing (independent variable, constants), an input, an
#: output (never), a fixed parameter (until initialisation mode ends), a tunable one.
SET_NEVER, SET_INPUT, SET_OUTPUT, SET_FIXED, SET_TUNABLE = range(5)

_T = TypeVar("_T")


class CallRefused(Exception):
    """A call the FMU refuses because FMI forbids it (a non-finite input, a state that
    is not this FMU's): the host gets fmi2Error / fmi3Error, not Fatal, and the message
    through its logger; the instance is left as it was. Also a step whose model reached
    a limit of its validity (agv_core.errors.ModelLimitError, e.g. a wheel lifts): Error
    with the message, the time at the step's start, the core at the step's end. The FMU
    bridge
    (components/fmu_loader/agv_fmu_bridge.c) recognises it by ``fmi_error``."""

    fmi_error = True


def _canonical(value: Any) -> str:
    """``value`` as canonical JSON text (sorted keys, exact floats, NaN spelt out)."""
    return json.dumps(value, sort_keys=True, allow_nan=True)


def _first_not_finite(value: Any, where: str = "core") -> str | None:
    """Where the first number in ``value`` (nested lists and dicts) is NaN or infinite,
    or None."""
    if isinstance(value, float) and not math.isfinite(value):
        return where
    items: Iterable[tuple[Any, Any]]
    if isinstance(value, dict):
        items = value.items()
    elif isinstance(value, (list, tuple)):
        items = enumerate(value)
    else:
        return None
    for key, item in items:
        found = _first_not_finite(item, f"{where}[{key!r}]")
        if found is not None:
            return found
    return None



class SlaveLogic:
    """The adapters' common behaviour (see the module docstring).

    Subclasses (the adapters' ``AgvSlave``) set the class attributes below the line
    "supplied by the adapter". Slave classes set ``description``, ``default_experiment``
    (a ``DefaultExperiment`` with start, stop and step: the FMU's reference experiment)
    and, if the experiment drives inputs, ``reference_inputs``: input name -> breakpoints
    ``((t0, value0), (t1, value1), ...)``, each value held from its time on (the first
    time is the start time; inputs not named keep their start values). The build runs
    the experiment and ships its result in the FMU (fmi-ls-ref, see agv_cosim.build).
    """

    #: True in a slave whose ``publish`` is a function of the core's state, the inputs
    #: and ``self.time`` alone (calling it again, or once fewer, changes nothing): if
    #: some output depends directly on an input, the publication at exit from
    #: initialisation and after a step then waits for the next read (after the
    #: master's sets), which saves one per step
    lazy_publish = False

    author = "agv-cosim"
    license = "MIT"
    version = __version__
    description: str | None = None
    default_experiment: Any = None
    reference_inputs: Mapping[str, Sequence[tuple[float, float]]] = {}

    # supplied by the adapter
    #: the wrapper library's name, for messages
    _TOOL: str | None = None
    #: the Real (FMI 2.0) / Float64 (FMI 3.0) variable class, which needs a unit
    _REAL: Any = None
    #: variable class -> Python type of its value
    _PYTYPE: dict[Any, Any] = {}
    #: causality and variability enum members
    _INPUT: Any
    _OUTPUT: Any
    _PARAMETER: Any
    _CONTINUOUS: Any
    _DISCRETE: Any
    _FIXED: Any
    _TUNABLE: Any
    _INPUT = _OUTPUT = _PARAMETER = _CONTINUOUS = _DISCRETE = _FIXED = _TUNABLE = None
    #: status of a logged error
    _ERROR: Any = None
    #: the Real getter and setter the bridge's fast path stands for (_fmi_real_access)
    _FAST_METHODS: tuple[str, ...] = ()

    # given by the library's slave class (pythonfmu's Fmi2Slave, pythonfmu3's Fmi3Slave)
    resources: str | None
    vars: dict[int, Any]
    modelName: str
    instance_name: str
    if TYPE_CHECKING:
        def register_variable(self, var: Any) -> None: ...

        def log(self, msg: str, status: Any = None) -> None: ...

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self._units: dict[str, str] = {}
        self._dependencies: dict[str, tuple[str, ...]] = {}
        self._input_names: list[str] = []
        self._core_inputs: set[str] = set()
        self._output_names: list[str] = []
        self._parameter_names: list[str] = []
        self._stale = False
        self._initializing = False
        self._terminated = False
        #: value reference -> name of every Real input (the finite check of a set)
        self._real_inputs: dict[int, str] | None = None
        #: publish after a step at the next read (set at exit from initialisation)
        self._lazy_step = False
        #: value reference -> attribute (the adapter's fast get/set)
        self._real_names: dict[int, str] | None = None
        self._quiet_inputs: frozenset[int]  # set with _real_names
        self.core: Any = None
        self.time = 0.0
        self._check_bundle()

    def _check_bundle(self) -> None:
        """Refuse to run another build's slave code in this FMU's name.

        pythonfmu imports a slave module once per process by file name, so a second FMU
        with the same slave script but other sources would silently run the first one's
        code. The package this class came from is named ``agv_core_<tag>`` by the boot
        loader; the FMU's own bundle says its tag in ``agv_core_bundle/BUILD_ID``.
        """
        if self.resources is None:
            return
        build_id = Path(self.resources) / "agv_core_bundle" / "BUILD_ID"
        package = __name__.partition(".")[0]  # the root package, agv_core_<tag>
        if not build_id.is_file() or not package.startswith("agv_core_"):
            return
        bundled = "agv_core_" + build_id.read_text().strip()
        if bundled != package:
            raise RuntimeError(
                f"{type(self).__name__}: this FMU bundles {bundled}, but this process "
                f"already runs {type(self).__name__} from another build ({package}); "
                f"{self._TOOL} loads one slave module per name per process")

    # ------------------------------------------------------------------ declaration
    def _variable(self, kind: Any, name: str, causality: Any, variability: Any,
                  description: str, unit: str | None) -> Any:
        """The adapter's variable object (override where the library takes a unit)."""
        return kind(name, causality=causality, variability=variability,
                    description=description)

    def _declare(self, kind: Any, name: str, causality: Any, variability: Any, start: Any,
                 unit: str | None, description: str) -> None:
        if kind not in self._PYTYPE:
            raise ValueError(f"variable '{name}': unsupported kind {kind!r}")
        if not description:
            raise ValueError(f"variable '{name}' needs a description")
        if kind is self._REAL and unit is None:
            raise ValueError(f"{kind.__name__} variable '{name}' needs a unit")
        if unit is not None:
            base_unit_attributes(unit)  # KeyError for an undefined unit
            self._units[name] = unit
        setattr(self, name, self._PYTYPE[kind](start))
        self.register_variable(self._variable(kind, name, causality, variability,
                                              description, unit))

    def input(self, name: str, start: Any, unit: str | None, description: str, kind: Any = None,
              builds_core: bool = False) -> None:
        """Declare an input (a continuous Real by default) with its start value;
        ``builds_core`` when ``make_core`` reads it (the core starts from its value)."""
        kind = kind or self._REAL
        variability = self._CONTINUOUS if kind is self._REAL else self._DISCRETE
        self._declare(kind, name, self._INPUT, variability, start, unit, description)
        self._input_names.append(name)
        if builds_core:
            self._core_inputs.add(name)

    def output(self, name: str, unit: str | None, description: str,
               depends_on: Iterable[str] = (), kind: Any = None, start: Any = 0.0) -> None:
        """Declare an output; ``depends_on`` names the inputs it depends on directly."""
        kind = kind or self._REAL
        unknown = [d for d in depends_on if d not in self._input_names]
        if unknown:
            raise ValueError(f"output '{name}' depends on undeclared inputs {unknown}")
        variability = self._CONTINUOUS if kind is self._REAL else self._DISCRETE
        self._declare(kind, name, self._OUTPUT, variability, start, unit, description)
        self._output_names.append(name)
        self._dependencies[name] = tuple(depends_on)

    def parameter(self, name: str, start: Any, unit: str | None, description: str,
                  kind: Any = None, tunable: bool = False) -> None:
        """Declare a parameter: fixed (set before initialisation, then constant), or
        ``tunable`` (a master may change it between steps; the slave reads the attribute
        in ``advance``/``publish``, the core is not rebuilt)."""
        kind = kind or self._REAL
        variability = self._TUNABLE if tunable else self._FIXED
        self._declare(kind, name, self._PARAMETER, variability, start, unit, description)
        self._parameter_names.append(name)

    # ------------------------------------------------------------------ hooks
    def make_core(self) -> Any:
        """Build the core from the parameters (override)."""
        raise NotImplementedError

    def advance(self, t: float, h: float) -> None:
        """Advance the core from ``t`` to ``t + h`` (override)."""
        raise NotImplementedError

    def publish(self) -> None:
        """Copy the core's outputs onto the output attributes (override)."""
        raise NotImplementedError

    # ------------------------------------------------------------------ FMI calls
    def setup_experiment(self, start_time: float, stop_time: float | None = None,
                         tolerance: float | None = None) -> None:
        self.time = float(start_time)

    def enter_initialization_mode(self) -> None:
        self._initializing = True

    def exit_initialization_mode(self) -> None:
        self._initializing = False
        self._lazy_step = self.lazy_publish and any(self._dependencies.values())
        try:
            self.core = self.make_core()
            if self._lazy_step:
                # the master sets the inputs of t0 before it reads: publish at that read
                self._stale = True
                return
            self.publish()
        except ParameterError as error:
            self._fail(str(error))
        except ImportError as error:  # a package of requirements.txt is missing
            self._fail(f"initialisation failed: {type(error).__name__}: {error} (install "
                       "the packages of this FMU's resources/requirements.txt in the "
                       "Python that runs it)")
        except Exception as error:  # noqa: BLE001 - reported to the host, then re-raised
            self._fail(f"initialisation failed: {type(error).__name__}: {error}")
        self._stale = False

    def terminate(self) -> None:
        self._terminated = True

    def do_step(self, current_time: float, step_size: float) -> bool:
        t, h = float(current_time), float(step_size)
        try:
            self.advance(t, h)
            self.time = t + h
            if self._lazy_step:
                # outputs that depend on inputs are re-published after the master sets
                # them anyway: publish once, at the next read (a read without a set
                # publishes from the held inputs, what publishing here would give)
                self._stale = True
                return True
            self.publish()
        except Exception as error:  # noqa: BLE001 - reported to the host, then re-raised
            self._step_failed(t, error)
        self._stale = False
        return True

    def _step_failed(self, t: float, error: Exception) -> NoReturn:
        """Report ``error`` from the step that starts at ``t`` [s] and raise: a
        :class:`~agv_core.errors.ModelLimitError` (the model cannot go on) as a refusal
        (Error), anything else as a failure (Fatal)."""
        message = f"step at t={t:.9g} s failed: {type(error).__name__}: {error}"
        if isinstance(error, ModelLimitError):
            self._refuse(message)
        self._fail(message)

    def _guarded(self, call: Callable[..., _T], *args: Any) -> _T:
        try:
            return call(*args)
        except Exception:
            self._keep_for_pythonfmu()
            raise

    def _inputs_set(self, setter: Callable[..., Any], vrs: Any, values: Any) -> None:
        """Call the library's ``setter``; outputs are re-published before the next read."""
        self._guarded(setter, vrs, values)
        self._stale = True

    def _fresh_outputs(self) -> None:
        """Make the outputs current before a read (called by the adapter's getters)."""
        if self.core is None:
            if self._initializing:
                self._initial_outputs()
        elif self._stale:
            try:
                self.publish()
            except Exception as error:  # noqa: BLE001 - reported to the host, then re-raised
                self._outputs_failed(error)
            self._stale = False

    def _outputs_failed(self, error: Exception) -> NoReturn:
        """Report ``error`` from a publication of the outputs and raise."""
        self._fail(f"outputs at t={self.time:.9g} s failed: {type(error).__name__}: {error}")

    def _initial_outputs(self) -> None:
        """Outputs in initialisation mode, from the parameters and inputs set so far.

        FMI lets a master read outputs (the InitialUnknowns) before leaving
        initialisation mode, and masters that propagate values then (libcosim) do. A
        provisional core is built for the reading and dropped: the core that runs is
        built at exit from the final parameters. Invalid parameters leave the start
        values (the error is reported at exit, naming the parameter).
        """
        try:
            self.core = self.make_core()
            self.publish()
        except Exception:  # noqa: BLE001 - reported by exit_initialization_mode
            pass
        finally:
            self.core = None

    def _fail(self, message: str) -> NoReturn:
        text = f"{self.modelName} '{self.instance_name}': {message}"
        self.log(text, self._ERROR)
        self._keep_for_pythonfmu()
        raise RuntimeError(text)

    def _refusal(self, message: str) -> CallRefused:
        """The :class:`CallRefused` for ``message``, logged with error status."""
        text = f"{self.modelName} '{self.instance_name}': {message}"
        self.log(text, self._ERROR)
        return CallRefused(text)

    def _refuse(self, message: str) -> NoReturn:
        """Refuse the call under way: log ``message`` and raise :class:`CallRefused`."""
        error = self._refusal(message)
        self._keep_for_pythonfmu()
        raise error

    # ------------------------------------------------------------------ input checks
    def _check_finite_inputs(self, vrs: Sequence[int], values: Sequence[float]) -> None:
        """Refuse a set that gives a Real input a value that is not finite (NaN, inf),
        naming the input; nothing of the set is applied. Called by the adapters' Real
        setters when the values' sum is not finite (a sum is finite when every term is;
        an overflowed sum of finite values lands here and finds nothing)."""
        inputs = self._real_inputs
        if inputs is None:
            inputs = self._real_inputs = {
                vr: v.name for vr, v in self.vars.items()
                if isinstance(v, self._REAL) and v.name in self._input_names}
        for vr, value in zip(vrs, values):
            name = inputs.get(vr)
            if name is not None and not math.isfinite(value):
                self._refuse(f"input '{name}' set to {value!r}: an input must be a finite "
                             f"number; refused, '{name}' keeps {getattr(self, name)!r}")

    def _keep_for_pythonfmu(self) -> None:
        """Balance the wrapper's double release before an exception leaves (see
        pythonfmu_workarounds.py, entry 1)."""
        keep_for_pythonfmu(self)

    # ------------------------------------------------------------------ fast Real access
    def _map_real_names(self) -> dict[int, str]:
        """Value reference -> attribute name of every Real that the library reads and
        writes as a plain attribute of this slave (no nested name, not a constant, not an
        array); also the value references of the inputs no output depends on directly."""
        self._real_names = {vr: v.name for vr, v in self.vars.items()
                            if isinstance(v, self._REAL) and "." not in v.name
                            and getattr(v.variability, "name", None) != "constant"
                            and not getattr(v, "dimensions", None)}
        used = {d for deps in self._dependencies.values() for d in deps}
        self._quiet_inputs = frozenset(vr for vr, v in self.vars.items()
                                       if v.name in self._input_names
                                       and v.name not in used)
        return self._real_names

    def _fmi_real_access(self) -> tuple[dict[int, str], frozenset[int]]:
        """``(names, quiet)`` for the FMU bridge (components/fmu_loader/agv_fmu_bridge.c),
        which then reads and writes these Reals without calling get/set methods.

        ``names`` maps value references to the attributes that hold the values (floats);
        ``quiet`` holds the inputs no output depends on directly. The bridge's contract,
        the same as the FMI 2.0 adapter's ``get_real`` / ``set_real``: before a read, if
        ``_stale`` is true or ``core`` is None, it calls ``_fresh_outputs()``; after
        writing an input not in ``quiet`` it sets ``_stale`` true.
        """
        names = self._real_names or self._map_real_names()
        return dict(names), self._quiet_inputs

    def _fmi_step_access(self) -> bool:
        """True if the FMU bridge may step this slave without calling ``do_step``: it then
        does what :meth:`do_step` does (``advance(t, h)``, ``time = t + h``, then with
        ``_lazy_step`` ``_stale = True``, else ``publish()`` and ``_stale = False``; an
        exception from either goes to ``_step_failed(t, error)``). False when a subclass
        overrides ``do_step``."""
        return type(self).do_step is SlaveLogic.do_step

    def _fmi_variables(self) -> tuple[tuple[int, str, int, int], ...]:
        """For the FMU bridge's checks of every get and set: ``((value reference, name,
        type code, set code), ...)`` of every variable (the ``VAR_*`` and ``SET_*``
        codes above). The bridge refuses a value reference that is not a variable of
        the call's type, a set of an output, of the independent variable, of a fixed
        parameter after initialisation mode, and every set after initialisation in
        anything but an input or a tunable parameter."""
        types: dict[Any, int] = {float: VAR_REAL, int: VAR_INTEGER, bool: VAR_BOOLEAN,
                                 str: VAR_STRING}
        rows: list[tuple[int, str, int, int]] = []
        for vr, v in self.vars.items():
            kind = types.get(self._PYTYPE.get(type(v)))
            if kind is None:
                continue
            causality = getattr(v.causality, "name", None)
            variability = getattr(v.variability, "name", None)
            if causality == "input":
                access = SET_INPUT
            elif causality == "output":
                access = SET_OUTPUT
            elif causality == "parameter" and variability == "fixed":
                access = SET_FIXED
            elif causality == "parameter" and variability == "tunable":
                access = SET_TUNABLE
            else:
                access = SET_NEVER
            rows.append((vr, v.name, kind, access))
        return tuple(rows)

    # ------------------------------------------------------------------ state
    def _mode(self) -> str:
        """The state-machine mode a saved state records (one of STATE_MODES)."""
        if self._terminated:
            return "terminated"
        if self.core is not None:
            return "step"
        return "initialization" if self._initializing else "instantiated"

    def _get_fmu_state(self) -> dict[str, Any]:
        if self.core is not None and self._stale:
            self._fresh_outputs()  # the outputs the state holds are those a read shows
        variables = {v.name: v.getter() for v in self.vars.values()}
        core_state = self.core.get_state() if self.core is not None else None
        return {"mode": self._mode(), "variables": variables, "time": self.time,
                "core": core_state}

    @staticmethod
    def _fmu_state_from_bytes(data: bytes) -> Any:
        try:
            return json.loads(bytes(data).decode("utf-8"))
        except ValueError as error:  # UnicodeDecodeError is one
            raise CallRefused(f"a state that does not belong to this FMU: not a serialised "
                              f"state ({type(error).__name__}: {error})") from None

    def _set_fmu_state(self, state: Any) -> None:
        self._guarded(self._restore, state)

    def _restore(self, state: Any) -> None:
        """Restore ``state`` (from ``_get_fmu_state``), or refuse it whole.

        A state belongs to this FMU when it has exactly the keys of STATE_KEYS, a known
        mode, every variable of this FMU and no other, each value of its variable's type
        (Reals finite), a finite time, a core state (finite numbers) exactly when the
        mode has a core, and when the core built from its parameters (valid ones: the
        core's own checks) takes its core state as given (after
        ``set_state``, ``get_state`` returns the same: unknown keys and values a core
        would not keep are refused). The core is rebuilt from the state's parameters.
        """
        new_core, variables, mode = self._checked_state(state)
        self.core = new_core
        for name, value in variables.items():
            setattr(self, name, value)
        self.time = float(state["time"])
        self._initializing = mode == "initialization"
        self._terminated = mode == "terminated"
        self._lazy_step = self.lazy_publish and any(self._dependencies.values())
        self._stale = False

    def _checked_state(self, state: Any) -> tuple[Any, dict[str, Any], str]:
        """``(core, variables, mode)`` of a state that belongs to this FMU; else
        CallRefused saying why. The slave's attributes are as they were either way."""
        def refuse(why: str) -> CallRefused:
            return self._refusal(f"a state that does not belong to this FMU: {why}")

        if not isinstance(state, dict):
            raise refuse(f"a {type(state).__name__}, not a dict")
        keys = set(state)
        if keys != STATE_KEYS:
            unknown = sorted(str(k) for k in keys - STATE_KEYS)
            missing = sorted(STATE_KEYS - keys)
            raise refuse("; ".join(
                ([f"unknown keys {unknown}"] if unknown else [])
                + ([f"missing keys {missing}"] if missing else [])))
        mode = state["mode"]
        if mode not in STATE_MODES:
            raise refuse(f"mode {mode!r} is not one of {list(STATE_MODES)}")
        variables = state["variables"]
        if not isinstance(variables, dict):
            raise refuse("'variables' is not a dict")
        declared = {v.name: v for v in self.vars.values()}
        unknown = sorted(str(k) for k in set(variables) - set(declared))
        missing = sorted(set(declared) - set(variables))
        if unknown or missing:
            raise refuse("; ".join(
                ([f"unknown variables {unknown}"] if unknown else [])
                + ([f"missing variables {missing}"] if missing else [])))
        for name, value in variables.items():
            expected = self._PYTYPE.get(type(declared[name]))
            if expected is float:
                good = (isinstance(value, (int, float)) and not isinstance(value, bool)
                        and math.isfinite(value))
            elif expected is int:
                good = (isinstance(value, int) and not isinstance(value, bool)
                        and -2**31 <= value < 2**31)
            else:
                good = expected is None or type(value) is expected
            if not good:
                raise refuse(f"variable '{name}' = {value!r} is not a "
                             f"{'finite ' if expected is float else ''}"
                             f"{getattr(expected, '__name__', '?')}")
        time = state["time"]
        if not (isinstance(time, (int, float)) and not isinstance(time, bool)
                and math.isfinite(time)):
            raise refuse(f"time {time!r} is not a finite number")
        core_state = state["core"]
        has_core = mode in ("step", "terminated")
        if (core_state is not None) != has_core:
            raise refuse(f"mode '{mode}' {'needs' if has_core else 'has no'} core state")
        if not has_core:
            return None, variables, mode
        try:
            given = _canonical(core_state)
        except (TypeError, ValueError) as error:
            raise refuse(f"its core state is not JSON data ({error})") from None
        bad = _first_not_finite(core_state)
        if bad is not None:
            raise refuse(f"{bad} is not a finite number")
        names = list(variables)
        saved = [getattr(self, name) for name in names]
        try:
            for name in names:  # the core is built from the state's parameters
                setattr(self, name, variables[name])
            try:
                core = self.make_core()
            except Exception as error:  # noqa: BLE001 - the state's parameters are bad
                raise refuse(f"its parameters build no core: {type(error).__name__}: "
                             f"{error}") from None
            try:
                core.set_state(core_state)
                kept = _canonical(core.get_state())
            except Exception as error:  # noqa: BLE001 - a malformed core state
                raise refuse(f"its core state is malformed: {type(error).__name__}: "
                             f"{error}") from None
            if kept != given:
                raise refuse("its core state holds keys or values the core does not take "
                             "as given (unknown keys or out-of-range values)")
        finally:
            for name, value in zip(names, saved):
                setattr(self, name, value)
        return core, variables, mode

    # ------------------------------------------------------------------ model description
    def _build_info(self) -> Any:
        if self.resources is None:
            return None
        path = Path(self.resources) / BUILD_INFO
        if not path.is_file():
            return None
        return json.loads(path.read_text())

    def _insert_unit_definitions(self, root: Element) -> None:
        """Put ``<UnitDefinitions>`` of the units used right after ``<CoSimulation>``."""
        used = sorted(set(self._units.values()))
        if not used:
            return
        unit_defs = Element("UnitDefinitions")
        for unit in used:
            node = SubElement(unit_defs, "Unit", name=unit)
            attributes = base_unit_attributes(unit)
            if attributes:
                SubElement(node, "BaseUnit", attributes)
        cosimulation = cast(Element, root.find("CoSimulation"))  # in every description
        root.insert(list(root).index(cosimulation) + 1, unit_defs)

    def _initial_dependencies(self, name: str) -> tuple[str, ...]:
        """Names of the knowns that output ``name`` depends on in initialisation mode: the
        ``dependencies`` of its InitialUnknown.

        FMI 2.0 (2.2.8) and FMI 3.0 (2.4.8) list as knowns in Initialization Mode the
        inputs, the variables with initial="exact" (every parameter here) and the
        independent variable. An output read then comes from a core built from the
        parameters and the inputs set so far, published with those inputs
        (``_initial_outputs``): it depends on the inputs its declaration names
        (``depends_on``, the same as at a communication point) and, conservatively, on
        every input declared ``builds_core`` and every parameter. The FMI 3.0 adapter
        adds its declared independent variable.
        """
        direct = set(self._dependencies[name])
        inputs = [n for n in self._input_names if n in direct or n in self._core_inputs]
        return (*inputs, *self._parameter_names)

    def _reference_inputs_element(self) -> Element | None:
        """``<ReferenceInputs>`` of ``reference_inputs`` (None if there are none)."""
        if not self.reference_inputs:
            return None
        experiment = type(self).default_experiment  # the libraries set an instance None
        if experiment is None:
            raise ValueError("reference_inputs need a default_experiment")
        table = Element("ReferenceInputs")
        for name, breakpoints in self.reference_inputs.items():
            if name not in self._input_names:
                raise ValueError(f"reference_inputs: '{name}' is not an input")
            times = [float(t) for t, _ in breakpoints]
            if not times or times[0] != float(experiment.start_time) or times != sorted(
                    set(times)):
                raise ValueError(f"reference_inputs['{name}']: times must rise strictly "
                                 "from the start time")
            node = SubElement(table, "Input", name=name)
            for t, value in breakpoints:
                SubElement(node, "Hold", time=repr(float(t)), value=repr(float(value)))
        return table

    # ------------------------------------------------------------------ helpers
    def finite_or_fail(self, **values: float) -> None:
        """Raise naming the first non-finite value among ``values`` (name=value).

        Hot paths may test ``math.isfinite`` of the values' sum first and call this only
        when it fails: a sum is finite when every term is (an overflow lands here, which
        then finds nothing to report).
        """
        for name, value in values.items():
            if not math.isfinite(value):
                raise FloatingPointError(f"'{name}' became {value}")
