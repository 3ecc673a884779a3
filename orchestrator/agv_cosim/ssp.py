"""SSP 1.0 (System Structure and Parameterization): what export and import share.

:mod:`agv_cosim.ssp_export` writes one run of a manifest as an ``.ssp`` package;
:mod:`agv_cosim.ssp_import` reads a package into the same in-memory
:class:`~agv_cosim.manifest.Manifest` a manifest file gives. This module holds their
common vocabulary: the XML namespaces and prefixes, the error type, the type names.
"""

import re
from pathlib import Path
from xml.etree import ElementTree

from . import fmitypes
from .manifest import ManifestError

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
_TYPES = fmitypes.SSP_VALUE_TYPES
PSET_MIME = "application/x-ssp-parameter-set"
_IDENTIFIER = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")

for _prefix, _uri in NS.items():
    ElementTree.register_namespace(_prefix, _uri)


class SspError(ManifestError):
    """An SSP package we cannot read or run; the text is ``<package>: <element>: <problem>``."""


def _q(prefix, tag):
    return f"{{{NS[prefix]}}}{tag}"


def _number_text(value):
    """Shortest text that reads back as the same double (``repr``)."""
    return repr(float(value))


def _ssp_type(var):
    """The SSP type name of an FMU variable (SSP's names are FMI 2.0's), or None."""
    return None if var.unsupported() else var.ftype.ssp_type


def is_ssp(path):
    """True when ``path`` names an SSP package (``.ssp`` file or ``.ssd``)."""
    return path is not None and Path(str(path)).suffix.lower() in (".ssp", ".ssd")
