"""The thin FMI 2.0 co-simulation adapter that every agv-cosim FMU derives from.

A slave script subclasses :class:`AgvSlave`, declares its variables in ``__init__`` with
the ``input`` / ``output`` / ``parameter`` helpers (every Real with a unit and every
variable with a description; every output with the inputs it depends on directly), and
implements three hooks:

``make_core(self)``
    Build the plain-Python core from the parameter values. Called once at
    ``fmi2ExitInitializationMode``. Raise :class:`~agv_core.errors.ParameterError` for a
    bad parameter: the message is logged and the call fails (pythonfmu 0.7 reports any
    Python exception as ``fmi2Fatal``; it has no route to ``fmi2Error``).
``advance(self, t, h)``
    Advance the core from ``t`` to ``t + h`` with the inputs held constant.
``publish(self)``
    Copy the core's outputs onto the output attributes, using the current inputs for
    direct-feedthrough outputs. Called after initialisation, after every step, and
    lazily on ``fmi2GetReal`` after an input changed, so a Gauss-Seidel master sees a
    feedthrough output that is consistent with the inputs it has just set.

The adapter also writes what pythonfmu leaves out of ``modelDescription.xml``: units and
their definitions, output dependencies, ``InitialUnknowns``, a GUID derived from the
sources (written by the build into ``resources/agv_build.json``), and a deterministic
header. State save/restore covers the variables and the core's ``get_state()`` /
``set_state()`` (JSON-safe dicts).
"""

import json
import math
from pathlib import Path
from xml.etree.ElementTree import Element, SubElement

from pythonfmu import Boolean, Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real, String
from pythonfmu.default_experiment import DefaultExperiment
from pythonfmu.enums import Fmi2Status

from . import __version__
from .errors import ParameterError
from .units import base_unit_attributes

#: Name of the build-info file the build writes into every FMU's ``resources/``.
BUILD_INFO = "agv_build.json"

#: Tool name of the vendor annotation that carries ``reference_inputs``.
REFERENCE_TOOL = "org.agv-cosim"

_PYTYPE = {Real: float, Integer: int, Boolean: bool, String: str}

# pythonfmu 0.7: when a Python exception escapes a slave method, its C++ handler releases
# the slave's class, instance and log queue (cleanPyObject) without forgetting them, and
# fmi2FreeInstance releases the same three again. Before any exception leaves this adapter
# one extra reference to each is kept here, so the second release cannot free live
# objects (a failed instance is then never freed: a small leak instead of a corrupted
# heap). This balances the double release visible in pythonfmu's source. A host that runs
# several failing instances of one FMU can still see its heap damaged (measured with
# PYTHONMALLOC=debug, cause not located), which is why the orchestrator runs every
# simulation in a child process of its own (agv_cosim/runner.py).
_KEPT_FOR_PYTHONFMU = []


class AgvSlave(Fmi2Slave):
    """Base class of every agv-cosim FMU slave (see the module docstring).

    Subclasses set the class attributes ``description``, ``default_experiment`` (a
    ``DefaultExperiment`` with start, stop and step: the FMU's reference experiment) and,
    if the experiment drives inputs, ``reference_inputs``: input name -> breakpoints
    ``((t0, value0), (t1, value1), ...)``, each value held from its time on (the first
    time is the start time; inputs not named keep their start values). The build runs
    the experiment and ships its result in the FMU (fmi-ls-ref, see agv_cosim.build).
    """

    author = "agv-cosim"
    license = "MIT"
    version = __version__
    description = None
    default_experiment = None
    reference_inputs = {}

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self._units = {}
        self._dependencies = {}
        self._input_names = []
        self._output_names = []
        self._parameter_names = []
        self._stale = False
        self._initializing = False
        self.core = None
        self.time = 0.0
        self._check_bundle()

    def _check_bundle(self):
        """Refuse to run another build's slave code in this FMU's name.

        pythonfmu imports a slave module once per process by file name, so a second FMU
        with the same slave script but other sources would silently run the first one's
        code. The package this class came from is named ``agv_core_<tag>`` by the boot
        loader; the FMU's own bundle says its tag in ``agv_core/BUILD_ID``.
        """
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
                "pythonfmu loads one slave module per name per process")

    # ------------------------------------------------------------------ declaration
    def _declare(self, kind, name, causality, variability, start, unit, description):
        if not description:
            raise ValueError(f"variable '{name}' needs a description")
        if kind is Real and unit is None:
            raise ValueError(f"Real variable '{name}' needs a unit")
        if unit is not None:
            base_unit_attributes(unit)  # KeyError for an undefined unit
            self._units[name] = unit
        setattr(self, name, _PYTYPE[kind](start))
        self.register_variable(
            kind(name, causality=causality, variability=variability, description=description)
        )

    def input(self, name, start, unit, description, kind=Real):
        """Declare a continuous input (Real by default) with its start value."""
        variability = Fmi2Variability.continuous if kind is Real else Fmi2Variability.discrete
        self._declare(kind, name, Fmi2Causality.input, variability, start, unit, description)
        self._input_names.append(name)

    def output(self, name, unit, description, depends_on=(), kind=Real, start=0.0):
        """Declare an output; ``depends_on`` names the inputs it depends on directly."""
        unknown = [d for d in depends_on if d not in self._input_names]
        if unknown:
            raise ValueError(f"output '{name}' depends on undeclared inputs {unknown}")
        variability = Fmi2Variability.continuous if kind is Real else Fmi2Variability.discrete
        self._declare(kind, name, Fmi2Causality.output, variability, start, unit, description)
        self._output_names.append(name)
        self._dependencies[name] = tuple(depends_on)

    def parameter(self, name, start, unit, description, kind=Real, tunable=False):
        """Declare a parameter: fixed (set before initialisation, then constant), or
        ``tunable`` (a master may change it between steps; the slave reads the attribute
        in ``advance``/``publish``, the core is not rebuilt)."""
        variability = Fmi2Variability.tunable if tunable else Fmi2Variability.fixed
        self._declare(kind, name, Fmi2Causality.parameter, variability, start, unit,
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
    def setup_experiment(self, start_time, stop_time=None, tolerance=None):
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
            self._keep_for_pythonfmu()
            raise

    def _mark_set(self, vrs):
        self._stale = True

    def set_real(self, vrs, values):
        self._guarded(super().set_real, vrs, values)
        self._mark_set(vrs)

    def set_integer(self, vrs, values):
        self._guarded(super().set_integer, vrs, values)
        self._mark_set(vrs)

    def set_boolean(self, vrs, values):
        self._guarded(super().set_boolean, vrs, values)
        self._mark_set(vrs)

    def set_string(self, vrs, values):
        self._guarded(super().set_string, vrs, values)
        self._mark_set(vrs)

    def _fresh(self):
        if self.core is None and self._initializing:
            self._initial_outputs()
        elif self._stale and self.core is not None:
            self._guarded(self.publish)
            self._stale = False

    def get_real(self, vrs):
        self._fresh()
        return self._guarded(super().get_real, vrs)

    # a feedthrough output of any type is recomputed after a set, not only a Real one
    def get_integer(self, vrs):
        self._fresh()
        return self._guarded(super().get_integer, vrs)

    def get_boolean(self, vrs):
        self._fresh()
        return self._guarded(super().get_boolean, vrs)

    def get_string(self, vrs):
        self._fresh()
        return self._guarded(super().get_string, vrs)

    def _initial_outputs(self):
        """Outputs in initialisation mode, from the parameters and inputs set so far.

        FMI 2.0 lets a master read outputs (the InitialUnknowns) before
        fmi2ExitInitializationMode, and masters that propagate values then (libcosim)
        do. A provisional core is built for the reading and dropped: the core that runs
        is built at exit from the final parameters. Invalid parameters leave the start
        values (the error is reported at exit, naming the parameter).
        """
        try:
            self.core = self.make_core()
            self.publish()
        except Exception:  # noqa: BLE001 - reported by exit_initialization_mode
            pass
        finally:
            self.core = None

    def _fail(self, message):
        text = f"{self.modelName} '{self.instance_name}': {message}"
        self.log(text, Fmi2Status.error)
        self._keep_for_pythonfmu()
        raise RuntimeError(text)

    def _keep_for_pythonfmu(self):
        """Balance pythonfmu's double release before an exception leaves (see above)."""
        _KEPT_FOR_PYTHONFMU.extend((type(self), self, self.log_queue))

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
            root.set("guid", info["guid"])

        used = sorted(set(self._units.values()))
        if used:
            unit_defs = Element("UnitDefinitions")
            for unit in used:
                node = SubElement(unit_defs, "Unit", name=unit)
                attributes = base_unit_attributes(unit)
                if attributes:
                    SubElement(node, "BaseUnit", attributes)
            position = list(root).index(root.find("CoSimulation")) + 1
            root.insert(position, unit_defs)

        index = {}
        for number, scalar in enumerate(root.find("ModelVariables"), start=1):
            name = scalar.get("name")
            index[name] = number
            if name in self._units:
                scalar[0].set("unit", self._units[name])
            if scalar[0].tag == "Real" and scalar[0].get("start") is not None:
                # pythonfmu writes 16 significant digits, which does not round-trip every
                # double (radians(112) -> 1.954768762233649): the start a host reads and
                # writes back must be the value the FMU uses, so write repr's 17.
                scalar[0].set("start", repr(float(getattr(self, name))))

        self._annotate_reference_inputs(root)

        structure = root.find("ModelStructure")
        outputs = structure.find("Outputs")
        if outputs is not None:
            for unknown in outputs:
                name = self.vars[int(unknown.get("index")) - 1].name
                deps = " ".join(str(index[d]) for d in self._dependencies[name])
                unknown.set("dependencies", deps)
            initial = SubElement(structure, "InitialUnknowns")
            for unknown in outputs:
                SubElement(initial, "Unknown", index=unknown.get("index"))
        return root

    def _annotate_reference_inputs(self, root):
        """Write ``reference_inputs`` as a vendor annotation (the build reads it)."""
        if not self.reference_inputs:
            return
        experiment = type(self).default_experiment  # pythonfmu sets an instance None
        if experiment is None:
            raise ValueError("reference_inputs need a default_experiment")
        tool = Element("Tool", name=REFERENCE_TOOL)
        table = SubElement(tool, "ReferenceInputs")
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
        annotations = Element("VendorAnnotations")
        annotations.append(tool)
        root.insert(list(root).index(root.find("ModelVariables")), annotations)

    # ------------------------------------------------------------------ helpers
    def finite_or_fail(self, **values):
        """Raise naming the first non-finite value among ``values`` (name=value)."""
        for name, value in values.items():
            if not math.isfinite(value):
                raise FloatingPointError(f"'{name}' became {value}")
