"""The thin FMI 3.0 co-simulation adapter of the agv-cosim FMUs' FMI 3.0 twins (pythonfmu3).

The slave scripts are written once, against the FMI 2.0 adapter's interface
(:mod:`agv_core.fmi_slave`): ``input`` / ``output`` / ``parameter`` declarations with
units, descriptions and direct dependencies, and the hooks ``make_core``, ``advance`` and
``publish``. This module offers the same interface on pythonfmu3's ``Fmi3Slave``, so the
same slave class body runs as an FMI 3.0 co-simulation FMU:

- ``Real`` is ``Float64`` and ``Integer`` is ``Int32``; ``Boolean`` and ``String`` keep
  their names. Real inputs are continuous, other inputs and outputs discrete, parameters
  fixed.
- The FMU's ``agv_core`` bundle carries this module also under the name ``fmi_slave``
  (``agv-cosim build --fmi 3`` writes that alias), so ``core.fmi_slave.AgvSlave`` in a
  slave script and ``from .fmi_slave import AgvSlave`` in ``actuator_fmi`` /
  ``tracking_fmi`` resolve to the class below; the FMI 2.0 adapter is not in FMI 3.0
  FMUs.
- FMI 3.0's independent variable ``time`` [s] is the adapter's clock ``self.time``.
- The model description gets what pythonfmu3 does not write by itself: the unit
  definitions and ``unit`` of every Float64, output ``dependencies`` (value references of
  the inputs an output depends on directly, empty when none), a deterministic header
  (no clock, ``instantiationToken`` from ``resources/agv_build.json``) and
  ``reference_inputs`` as an ``org.agv-cosim`` annotation.
- The behaviour is the FMI 2.0 adapter's: the core is built at
  ``fmi3ExitInitializationMode``, outputs read in initialisation mode come from a
  provisional core, feedthrough outputs are re-published lazily after an input was set,
  state save/restore covers the variables and the core's ``get_state()``. Outputs are
  therefore bit-identical to the FMI 2.0 twin's (tests/test_fmi3.py).

pythonfmu3 0.3.4's C++ wrapper releases the slave's class, instance and log queue when a
Python exception leaves a slave method and again in ``fmi3FreeInstance`` (the defect of
pythonfmu 0.7, see :mod:`agv_core.fmi_slave`); this adapter keeps one extra reference to
each before an exception leaves it, as the FMI 2.0 adapter does. Its exit-time defect
(also pythonfmu 0.7's) is avoided in Python hosts by an ``atexit`` hook (see
``_finalize_wrappers``).
"""

import atexit
import ctypes
import json
import math
import os
import sys
from pathlib import Path
from xml.etree.ElementTree import Element, SubElement

from pythonfmu3 import Boolean, Fmi3Causality, Fmi3Slave, Fmi3Variability, Float64, Int32, String
from pythonfmu3.default_experiment import DefaultExperiment
from pythonfmu3.enums import Fmi3Status

from . import __version__
from .errors import ParameterError
from .units import base_unit_attributes

#: Name of the build-info file the build writes into every FMU's ``resources/``.
BUILD_INFO = "agv_build.json"

#: Annotation type that carries ``reference_inputs`` (the FMI 2.0 twins' vendor tool name).
REFERENCE_TOOL = "org.agv-cosim"

#: The FMI 2.0 adapter's type names, for slave scripts written against it.
Real = Float64
Integer = Int32

_PYTYPE = {Float64: float, Int32: int, Boolean: bool, String: str}

# See the module docstring: one extra reference to class, instance and log queue per
# exception that leaves the adapter, so pythonfmu3's second release frees nothing live.
_KEPT_FOR_PYTHONFMU3 = []

# pythonfmu3 0.3.4's library has pythonfmu 0.7's exit-time defect: at process exit C++
# static destruction destroys its global shared_ptr<PyState>, then the library's unload
# hook (finalizePythonInterpreter) assigns to the destroyed pointer and releases its freed
# control block again (valgrind: invalid read in finalizePythonInterpreter from
# _dl_call_fini; 2 of 30 fmpy processes aborted with "corrupted double-linked list").
# In a Python host the adapter calls that hook itself from Python's atexit, while the
# pointer is alive: it is then empty when the static destructor and the unload hook run.
# The library handle kept here also keeps the library loaded until process exit, so a
# host's dlclose cannot run the faulty unload earlier. Library path -> ctypes handle.
_WRAPPERS_TO_FINALIZE = {}


def _finalize_wrappers():
    for library in _WRAPPERS_TO_FINALIZE.values():
        library.finalizePythonInterpreter()


def _finalize_at_exit(resources, identifier):
    """Register the FMU's loaded pythonfmu3 library (if any) for ``_finalize_wrappers``."""
    if not sys.platform.startswith("linux"):
        return
    path = str(Path(resources).parent / "binaries" / "x86_64-linux" / f"{identifier}.so")
    if path in _WRAPPERS_TO_FINALIZE:
        return
    try:  # only a library the host has loaded (not at build time)
        library = ctypes.CDLL(path, mode=os.RTLD_NOLOAD | os.RTLD_NOW)
        library.finalizePythonInterpreter.restype = None
    except (OSError, AttributeError):
        return
    if not _WRAPPERS_TO_FINALIZE:
        atexit.register(_finalize_wrappers)
    _WRAPPERS_TO_FINALIZE[path] = library


__all__ = ["AgvSlave", "Boolean", "DefaultExperiment", "Fmi3Slave", "Float64", "Int32",
           "Integer", "Real", "String"]


class AgvSlave(Fmi3Slave):
    """Base class of every agv-cosim FMI 3.0 slave (see the module docstring).

    Same class attributes as the FMI 2.0 adapter: ``description``, ``default_experiment``
    and ``reference_inputs``.
    """

    author = "agv-cosim"
    license = "MIT"
    version = __version__
    description = None
    default_experiment = None
    reference_inputs = {}

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        # pythonfmu3 sets these on the instance (None); the class attributes say them.
        for name in ("author", "license", "version", "description", "default_experiment"):
            setattr(self, name, getattr(type(self), name))
        self._units = {}
        self._dependencies = {}
        self._input_names = []
        self._output_names = []
        self._parameter_names = []
        self._stale = False
        self._initializing = False
        self.core = None
        self.time = 0.0
        # FMI 3.0 wants its one independent variable declared: the adapter's own clock.
        self._units["time"] = "s"
        self.register_variable(Float64("time", causality=Fmi3Causality.independent,
                                       variability=Fmi3Variability.continuous,
                                       description="Simulation time", unit="s"))
        self._check_bundle()
        if self.resources is not None:
            _finalize_at_exit(self.resources, self.modelName)

    def _check_bundle(self):
        """Refuse to run another build's slave code in this FMU's name (as in FMI 2.0)."""
        if self.resources is None:
            return
        build_id = Path(self.resources) / "agv_core" / "BUILD_ID"
        package = __name__.rpartition(".")[0]
        if not build_id.is_file() or not package.startswith("agv_core_"):
            return
        bundled = "agv_core_" + build_id.read_text().strip()
        if bundled != package:
            raise RuntimeError(
                f"{type(self).__name__}: this FMU bundles {bundled}, but this process "
                f"already runs {type(self).__name__} from another build ({package}); "
                "pythonfmu3 loads one slave module per name per process")

    # ------------------------------------------------------------------ declaration
    def _declare(self, kind, name, causality, variability, start, unit, description):
        if kind not in _PYTYPE:
            raise ValueError(f"variable '{name}': unsupported kind {kind!r}")
        if not description:
            raise ValueError(f"variable '{name}' needs a description")
        if kind is Float64 and unit is None:
            raise ValueError(f"Float64 variable '{name}' needs a unit")
        if unit is not None:
            base_unit_attributes(unit)  # KeyError for an undefined unit
            self._units[name] = unit
        setattr(self, name, _PYTYPE[kind](start))
        extra = {"unit": unit} if kind is Float64 else {}
        self.register_variable(kind(name, causality=causality, variability=variability,
                                    description=description, **extra))

    def input(self, name, start, unit, description, kind=Float64):
        """Declare an input (Float64 continuous by default) with its start value."""
        variability = (Fmi3Variability.continuous if kind is Float64
                       else Fmi3Variability.discrete)
        self._declare(kind, name, Fmi3Causality.input, variability, start, unit, description)
        self._input_names.append(name)

    def output(self, name, unit, description, depends_on=(), kind=Float64, start=0.0):
        """Declare an output; ``depends_on`` names the inputs it depends on directly."""
        unknown = [d for d in depends_on if d not in self._input_names]
        if unknown:
            raise ValueError(f"output '{name}' depends on undeclared inputs {unknown}")
        variability = (Fmi3Variability.continuous if kind is Float64
                       else Fmi3Variability.discrete)
        self._declare(kind, name, Fmi3Causality.output, variability, start, unit, description)
        self._output_names.append(name)
        self._dependencies[name] = tuple(depends_on)

    def parameter(self, name, start, unit, description, kind=Float64):
        """Declare a fixed parameter (set before initialisation, then constant)."""
        self._declare(kind, name, Fmi3Causality.parameter, Fmi3Variability.fixed, start, unit,
                      description)
        self._parameter_names.append(name)

    # ------------------------------------------------------------------ hooks
    def make_core(self):
        """Build the core from the parameters (override)."""
        raise NotImplementedError

    def advance(self, t, h):
        """Advance the core from ``t`` to ``t + h`` (override)."""
        raise NotImplementedError

    def publish(self):
        """Copy the core's outputs onto the output attributes (override)."""
        raise NotImplementedError

    # ------------------------------------------------------------------ FMI calls
    def setup_experiment(self, start_time):
        self.time = float(start_time)

    def enter_initialization_mode(self):
        self._initializing = True

    def exit_initialization_mode(self):
        self._initializing = False
        try:
            self.core = self.make_core()
            self.publish()
        except ParameterError as error:
            self._fail(str(error))
        except Exception as error:  # noqa: BLE001 - reported to the host, then re-raised
            self._fail(f"initialisation failed: {type(error).__name__}: {error}")
        self._stale = False

    def do_step(self, current_time, step_size):
        try:
            self.advance(float(current_time), float(step_size))
            self.time = float(current_time) + float(step_size)
            self.publish()
        except Exception as error:  # noqa: BLE001 - reported to the host, then re-raised
            self._fail(f"step at t={current_time:.9g} s failed: {type(error).__name__}: {error}")
        self._stale = False
        return True

    def _guarded(self, call, *args):
        try:
            return call(*args)
        except Exception:
            self._keep_for_pythonfmu3()
            raise

    def set_float64(self, vrs, values):
        self._guarded(super().set_float64, vrs, values)
        self._stale = True

    def set_int32(self, vrs, values):
        self._guarded(super().set_int32, vrs, values)
        self._stale = True

    def set_boolean(self, vrs, values):
        self._guarded(super().set_boolean, vrs, values)
        self._stale = True

    def set_string(self, vrs, values):
        self._guarded(super().set_string, vrs, values)
        self._stale = True

    def _fresh_outputs(self):
        if self.core is None and self._initializing:
            self._initial_outputs()
        elif self._stale and self.core is not None:
            self._guarded(self.publish)
            self._stale = False

    def get_float64(self, vrs):
        self._fresh_outputs()
        return self._guarded(super().get_float64, vrs)

    def get_int32(self, vrs):
        self._fresh_outputs()
        return self._guarded(super().get_int32, vrs)

    def get_boolean(self, vrs):
        self._fresh_outputs()
        return self._guarded(super().get_boolean, vrs)

    def _initial_outputs(self):
        """Outputs in initialisation mode from a provisional core (as in FMI 2.0)."""
        try:
            self.core = self.make_core()
            self.publish()
        except Exception:  # noqa: BLE001 - reported by exit_initialization_mode
            pass
        finally:
            self.core = None

    def _fail(self, message):
        text = f"{self.modelName} '{self.instance_name}': {message}"
        self.log(text, Fmi3Status.error)
        self._keep_for_pythonfmu3()
        raise RuntimeError(text)

    def _keep_for_pythonfmu3(self):
        """Balance pythonfmu3's double release before an exception leaves (see above)."""
        _KEPT_FOR_PYTHONFMU3.extend((type(self), self, self.log_queue))

    # ------------------------------------------------------------------ state
    def _get_fmu_state(self):
        variables = {v.name: v.getter() for v in self.vars.values()}
        core_state = self.core.get_state() if self.core is not None else None
        return {"variables": variables, "time": self.time, "core": core_state}

    def _set_fmu_state(self, state):
        self._guarded(self._restore, state)

    def _restore(self, state):
        for name, value in state["variables"].items():
            setattr(self, name, value)
        self.time = state["time"]
        if state["core"] is not None:
            if self.core is None:
                self.core = self.make_core()
            self.core.set_state(state["core"])
        self._stale = False

    # ------------------------------------------------------------------ model description
    def _build_info(self):
        if self.resources is None:
            return None
        path = Path(self.resources) / BUILD_INFO
        if not path.is_file():
            return None
        return json.loads(path.read_text())

    def to_xml(self, model_options=None):
        root = super().to_xml(model_options or {})
        root.attrib.pop("generationDateAndTime", None)  # a rebuild must not differ by clock
        info = self._build_info()
        if info is not None:
            root.set("instantiationToken", info["guid"])

        used = sorted(set(self._units.values()))
        if used:
            unit_defs = Element("UnitDefinitions")
            for unit in used:
                node = SubElement(unit_defs, "Unit", name=unit)
                SubElement(node, "BaseUnit", base_unit_attributes(unit))
            position = list(root).index(root.find("CoSimulation")) + 1
            root.insert(position, unit_defs)

        reference = {name: var.value_reference for name, var in
                     ((v.name, v) for v in self.vars.values())}
        for unknown in root.find("ModelStructure").iterfind("Output"):
            name = self.vars[int(unknown.get("valueReference"))].name
            unknown.set("dependencies",
                        " ".join(str(reference[d]) for d in self._dependencies[name]))
        self._annotate_reference_inputs(root)
        return root

    def _annotate_reference_inputs(self, root):
        """Write ``reference_inputs`` as an ``org.agv-cosim`` annotation (the build reads it)."""
        if not self.reference_inputs:
            return
        experiment = type(self).default_experiment
        if experiment is None:
            raise ValueError("reference_inputs need a default_experiment")
        annotation = Element("Annotation", type=REFERENCE_TOOL)
        table = SubElement(annotation, "ReferenceInputs")
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
        annotations = Element("Annotations")
        annotations.append(annotation)
        root.append(annotations)  # the last child of fmiModelDescription in FMI 3.0

    # ------------------------------------------------------------------ helpers
    def finite_or_fail(self, **values):
        """Raise naming the first non-finite value among ``values`` (name=value)."""
        for name, value in values.items():
            if not math.isfinite(value):
                raise FloatingPointError(f"'{name}' became {value}")
