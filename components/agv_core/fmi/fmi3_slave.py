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
  the inputs an output depends on directly, empty when none), ``InitialUnknown``
  ``dependencies`` (those inputs, every parameter and ``time``), a deterministic header
  (no clock, ``instantiationToken`` from ``resources/agv_build.json``) and
  ``reference_inputs`` as an ``org.agv-cosim`` annotation.
- The behaviour is the FMI 2.0 adapter's: the core is built at
  ``fmi3ExitInitializationMode``, outputs read in initialisation mode come from a
  provisional core, feedthrough outputs are re-published lazily after an input was set,
  state save/restore covers the variables and the core's ``get_state()``. Outputs are
  therefore bit-identical to the FMI 2.0 twin's (tests/packaging/test_fmi3.py).

The behaviour shared with the FMI 2.0 adapter, including the compensation for the
wrappers' double release of a failed slave (pythonfmu3 0.3.4 has pythonfmu 0.7's), is in
:mod:`agv_core.fmi.slave_base`. pythonfmu3's exit-time defect
(also pythonfmu 0.7's) is avoided in Python hosts by an ``atexit`` hook (see
:mod:`agv_core.fmi.pythonfmu_workarounds`, which lists every wrapper work-around).
"""

from collections.abc import Sequence
from math import isfinite
from typing import Any, cast
from xml.etree.ElementTree import Element

from pythonfmu3 import Boolean, Float64, Fmi3Causality, Fmi3Slave, Fmi3Variability, Int32, String
from pythonfmu3.default_experiment import DefaultExperiment
from pythonfmu3.enums import Fmi3Status

from .pythonfmu_workarounds import finalize_at_exit
from .slave_base import BUILD_INFO, REFERENCE_TOOL, SlaveLogic

#: The FMI 2.0 adapter's type names, for slave scripts written against it.
Real = Float64
Integer = Int32

__all__ = ["AgvSlave", "BUILD_INFO", "Boolean", "DefaultExperiment", "Fmi3Slave", "Float64",
           "Int32", "Integer", "REFERENCE_TOOL", "Real", "String"]


class AgvSlave(SlaveLogic, Fmi3Slave):
    """Base class of every agv-cosim FMI 3.0 slave (see the module docstring and SlaveLogic)."""

    _TOOL = "pythonfmu3"
    _REAL = Float64
    _PYTYPE = {Float64: float, Int32: int, Boolean: bool, String: str}
    _INPUT, _OUTPUT, _PARAMETER = (Fmi3Causality.input, Fmi3Causality.output,
                                   Fmi3Causality.parameter)
    _CONTINUOUS, _DISCRETE, _FIXED, _TUNABLE = (
        Fmi3Variability.continuous, Fmi3Variability.discrete, Fmi3Variability.fixed,
        Fmi3Variability.tunable)
    _ERROR = Fmi3Status.error
    _FAST_METHODS = ("get_float64", "set_float64")

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        # pythonfmu3 sets these on the instance (None); the class attributes say them.
        for name in ("author", "license", "version", "description", "default_experiment"):
            setattr(self, name, getattr(type(self), name))
        # FMI 3.0 wants its one independent variable declared: the adapter's own clock.
        self._units["time"] = "s"
        self.register_variable(Float64("time", causality=Fmi3Causality.independent,
                                       variability=Fmi3Variability.continuous,
                                       description="Simulation time", unit="s"))
        if self.resources is not None:
            finalize_at_exit(self.resources, self.modelName)

    def _initial_dependencies(self, name: str) -> tuple[str, ...]:
        # the independent variable is a known in Initialization Mode too (its start time);
        # conservatively, every initial output depends on it
        return (*super()._initial_dependencies(name), "time")

    def _variable(self, kind: Any, name: str, causality: Any, variability: Any,
                  description: str, unit: str | None) -> Any:
        extra = {"unit": unit} if kind is Float64 else {}
        return kind(name, causality=causality, variability=variability,
                    description=description, **extra)

    # ------------------------------------------------------------------ FMI calls
    def set_float64(self, vrs: Sequence[int], values: Sequence[float]) -> None:
        if not isfinite(sum(values)):
            self._check_finite_inputs(vrs, values)  # refuses a non-finite input
        self._inputs_set(super().set_float64, vrs, values)

    def set_int32(self, vrs: Sequence[int], values: Sequence[int]) -> None:
        self._inputs_set(super().set_int32, vrs, values)

    def set_boolean(self, vrs: Sequence[int], values: Sequence[bool]) -> None:
        self._inputs_set(super().set_boolean, vrs, values)

    def set_string(self, vrs: Sequence[int], values: Sequence[str]) -> None:
        self._inputs_set(super().set_string, vrs, values)

    def get_float64(self, vrs: Sequence[int]) -> list[float]:
        self._fresh_outputs()
        return self._guarded(super().get_float64, vrs)

    # a feedthrough output of any type is recomputed after a set, as in the FMI 2.0 twin
    def get_int32(self, vrs: Sequence[int]) -> list[int]:
        self._fresh_outputs()
        return self._guarded(super().get_int32, vrs)

    def get_boolean(self, vrs: Sequence[int]) -> list[bool]:
        self._fresh_outputs()
        return self._guarded(super().get_boolean, vrs)

    def get_string(self, vrs: Sequence[int]) -> list[str]:
        self._fresh_outputs()
        return self._guarded(super().get_string, vrs)

    # ------------------------------------------------------------------ model description
    def to_xml(self, model_options: dict[str, str] | None = None) -> Element:
        root = super().to_xml(model_options or {})
        root.attrib.pop("generationDateAndTime", None)  # a rebuild must not differ by clock
        info = self._build_info()
        if info is not None:
            root.set("instantiationToken", info["guid"])
        self._insert_unit_definitions(root)
        for node in root.find("ModelVariables"):
            if node.tag == "Float64" and node.get("start") is not None:
                # pythonfmu3 writes 16 significant digits, which do not round-trip every
                # double (radians(112)): write repr's shortest exact form, so a host that
                # writes the start value back sets the value the FMU uses.
                node.set("start", repr(float(getattr(self, node.get("name")))))
        reference = {v.name: v.value_reference for v in self.vars.values()}
        for unknown in root.find("ModelStructure").iterfind("Output"):
            name = self.vars[int(unknown.get("valueReference"))].name
            unknown.set("dependencies",
                        " ".join(str(reference[d]) for d in self._dependencies[name]))
        for unknown in root.find("ModelStructure").iterfind("InitialUnknown"):
            name = self.vars[int(unknown.get("valueReference"))].name
            deps = sorted(reference[d] for d in self._initial_dependencies(name))
            unknown.set("dependencies", " ".join(map(str, deps)))
        table = self._reference_inputs_element()
        if table is not None:  # an annotation (the build reads it), last in FMI 3.0
            annotation = Element("Annotation", type=REFERENCE_TOOL)
            annotation.append(table)
            annotations = Element("Annotations")
            annotations.append(annotation)
            root.append(annotations)
        return cast(Element, root)  # pythonfmu's tree (the library has no types)
