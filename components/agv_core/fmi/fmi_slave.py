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
    feedthrough output that is consistent with the inputs it has just set. A slave
    whose ``publish`` is a function of the core's state, the inputs and ``self.time``
    alone may say so (``lazy_publish = True``): if it has a direct-feedthrough output,
    the calls after initialisation and after a step then wait for the next read (or
    state save) too.

The behaviour shared with the FMI 3.0 twins is in :mod:`agv_core.fmi.slave_base`. This
adapter also writes what pythonfmu leaves out of ``modelDescription.xml``: units and
their definitions, output dependencies, ``InitialUnknowns`` with their dependencies (see
``SlaveLogic._initial_dependencies``), a GUID derived from the
sources (written by the build into ``resources/agv_build.json``), and a deterministic
header. State save/restore covers the variables and the core's ``get_state()`` /
``set_state()`` (JSON-safe dicts). The workaround for pythonfmu 0.7's double release of a
failed slave is in :mod:`agv_core.fmi.slave_base`.
"""

from collections.abc import Sequence
from math import isfinite
from typing import cast
from xml.etree.ElementTree import Element, SubElement

from pythonfmu import Boolean, Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real, String
from pythonfmu.default_experiment import DefaultExperiment
from pythonfmu.enums import Fmi2Status

from .slave_base import BUILD_INFO, REFERENCE_TOOL, SlaveLogic

__all__ = ["AgvSlave", "BUILD_INFO", "Boolean", "DefaultExperiment", "Integer", "REFERENCE_TOOL",
           "Real", "String"]


class AgvSlave(SlaveLogic, Fmi2Slave):
    """Base class of every agv-cosim FMU slave (see the module docstring and SlaveLogic)."""

    _TOOL = "pythonfmu"
    _REAL = Real
    _PYTYPE = {Real: float, Integer: int, Boolean: bool, String: str}
    _INPUT, _OUTPUT, _PARAMETER = (Fmi2Causality.input, Fmi2Causality.output,
                                   Fmi2Causality.parameter)
    _CONTINUOUS, _DISCRETE, _FIXED, _TUNABLE = (
        Fmi2Variability.continuous, Fmi2Variability.discrete, Fmi2Variability.fixed,
        Fmi2Variability.tunable)
    _ERROR = Fmi2Status.error
    _FAST_METHODS = ("get_real", "set_real")

    # ------------------------------------------------------------------ FMI calls
    def set_real(self, vrs: Sequence[int], values: Sequence[float]) -> None:
        # hot path (every input, every step): attribute names by value reference, looked
        # up once; pythonfmu's own setter (one isinstance and one lambda per variable)
        # only for what is not a plain Real attribute, which raises its own error
        if not isfinite(sum(values)):
            self._check_finite_inputs(vrs, values)  # refuses a non-finite input
        names = self._real_names or self._map_real_names()
        try:
            for vr, value in zip(vrs, values):
                setattr(self, names[vr], value)
        except KeyError:
            self._inputs_set(super().set_real, vrs, values)
            return
        except Exception:
            self._keep_for_pythonfmu()
            raise
        # inputs no output depends on directly leave the outputs as they are (a step
        # changes them): no re-publication before the next read
        if not self._quiet_inputs.issuperset(vrs):
            self._stale = True

    def set_integer(self, vrs: Sequence[int], values: Sequence[int]) -> None:
        self._inputs_set(super().set_integer, vrs, values)

    def set_boolean(self, vrs: Sequence[int], values: Sequence[bool]) -> None:
        self._inputs_set(super().set_boolean, vrs, values)

    def set_string(self, vrs: Sequence[int], values: Sequence[str]) -> None:
        self._inputs_set(super().set_string, vrs, values)

    def get_real(self, vrs: Sequence[int]) -> list[float]:
        if self._stale or self.core is None:
            self._fresh_outputs()
        names = self._real_names or self._map_real_names()
        try:
            return [float(getattr(self, names[vr])) for vr in vrs]
        except KeyError:
            return self._guarded(super().get_real, vrs)
        except Exception:
            self._keep_for_pythonfmu()
            raise

    # a feedthrough output of any type is recomputed after a set, not only a Real one
    def get_integer(self, vrs: Sequence[int]) -> list[int]:
        self._fresh_outputs()
        return self._guarded(super().get_integer, vrs)

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
            root.set("guid", info["guid"])
        self._insert_unit_definitions(root)

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

        table = self._reference_inputs_element()
        if table is not None:  # a vendor annotation (the build reads it)
            tool = Element("Tool", name=REFERENCE_TOOL)
            tool.append(table)
            annotations = Element("VendorAnnotations")
            annotations.append(tool)
            root.insert(list(root).index(root.find("ModelVariables")), annotations)

        structure = root.find("ModelStructure")
        outputs = structure.find("Outputs")
        if outputs is not None:
            for unknown in outputs:
                name = self.vars[int(unknown.get("index")) - 1].name
                deps = " ".join(str(index[d]) for d in self._dependencies[name])
                unknown.set("dependencies", deps)
            initial = SubElement(structure, "InitialUnknowns")
            for unknown in outputs:
                name = self.vars[int(unknown.get("index")) - 1].name
                known = sorted(index[d] for d in self._initial_dependencies(name))
                SubElement(initial, "Unknown", index=unknown.get("index"),
                           dependencies=" ".join(map(str, known)))
        return cast(Element, root)  # pythonfmu's tree (the library has no types)
