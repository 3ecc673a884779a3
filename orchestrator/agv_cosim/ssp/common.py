"""SSP 1.0 (System Structure and Parameterization): what export and import share.

:mod:`agv_cosim.ssp.exporter` writes one run of a manifest as an ``.ssp`` package;
:mod:`agv_cosim.ssp.importer` reads a package into the same in-memory
:class:`~agv_cosim.manifest.Manifest` a manifest file gives. This module holds their
common vocabulary: the XML namespaces and prefixes, the type names, the units.
"""

import re
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

from .. import fmitypes
from ..errors import SspError
from ..system import Variable

__all__ = ["AGV_ANNOTATION", "BASE_UNITS", "FMU_MIME", "IDENTIFIER", "NS", "OSP_ANNOTATION",
           "PSET_MIME", "SSD_NAME", "TYPES", "SspError", "is_ssp", "model_description",
           "number_text", "q", "ssp_type", "unit_definitions"]

NS = {
    "ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
    "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
    "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
    "osp": "http://opensimulationplatform.com/SSP/OSPAnnotations",
    "agv": "https://agv-cosim.org/SSP/Experiment",
}
OSP_ANNOTATION = "com.opensimulationplatform"
AGV_ANNOTATION = "org.agv-cosim"
FMU_MIME = "application/x-fmu-sharedlibrary"
SSD_NAME = "SystemStructure.ssd"
TYPES = fmitypes.SSP_VALUE_TYPES
PSET_MIME = "application/x-ssp-parameter-set"
IDENTIFIER = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")

for _prefix, _uri in NS.items():
    ElementTree.register_namespace(_prefix, _uri)


def q(prefix: str, tag: str) -> str:
    return f"{{{NS[prefix]}}}{tag}"


def number_text(value: float) -> str:
    """Shortest text that reads back as the same double (``repr``)."""
    return repr(float(value))


def ssp_type(var: Variable) -> str | None:
    """The SSP type name of an FMU variable (SSP's names are FMI 2.0's), or None."""
    return None if var.unsupported() else var.ftype.ssp_type


def is_ssp(path: object) -> bool:
    """True when ``path`` names an SSP package (``.ssp`` file or ``.ssd``)."""
    return path is not None and Path(str(path)).suffix.lower() in (".ssp", ".ssd")


def model_description(fmu_path: str | Path) -> Any:
    """fmpy's reading of an FMU's modelDescription.xml (schema not re-validated: the
    FMU was read by :func:`agv_cosim.system.read_model` already)."""
    from fmpy import read_model_description

    return read_model_description(str(fmu_path), validate=False)


#: SI base-unit exponents of a BaseUnit, in the order FMI and SSP write them.
BASE_UNITS = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")


def unit_definitions(fmu_path: str | Path) -> dict[str, dict[str, str]]:
    """``{unit name: {BaseUnit attribute: text}}`` of an FMU's unit definitions (the
    attributes that differ from their defaults: exponent 0, factor 1, offset 0)."""
    units = {}
    for unit in model_description(fmu_path).unitDefinitions:
        base, attrs = unit.baseUnit, {}
        if base is not None:
            attrs = {b: str(int(getattr(base, b))) for b in BASE_UNITS if getattr(base, b)}
            if float(base.factor) != 1.0:
                attrs["factor"] = number_text(base.factor)
            if float(base.offset) != 0.0:
                attrs["offset"] = number_text(base.offset)
        units[unit.name] = attrs
    return units
