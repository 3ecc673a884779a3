"""FMU loading and model-description access (FMI 2.0 and 3.0 co-simulation).

:func:`read_model` checks the FMU archive (every entry's CRC) and maps fmpy's
``read_model_description`` (XML schema on; no extraction) onto a :class:`ModelInfo`; fmpy's
errors become one line naming the FMU. Own reading left (fmpy 0.3.32): only the root's
``fmiVersion`` before fmpy, so an FMI 1.0 FMU is named as such; fmpy's checks made after
parsing (undefined unit, input without start ..) are not errors, as before; FMI 3.0
``<Alias>`` variables fmpy adds are left out. :class:`ModelInfo` holds variables with
value reference, type (see
:mod:`agv_cosim.fmitypes`), causality, unit and description, and each output's direct
dependencies. An output whose ``<Unknown>`` (FMI 2.0) or ``<Output>`` (FMI 3.0) carries no
``dependencies`` attribute depends, per the standard, on every input. A model-exchange-only
FMU is refused with a message saying so.

The master steps with a fixed communication step and never saves or restores FMU state,
so ``canHandleVariableCommunicationStepSize="false"`` and ``canGetAndSetFMUstate="false"``
need nothing from it (both flags are read into :class:`ModelInfo` for the record).

:class:`FmuInstance` extracts an FMU into a private temporary folder, instantiates it with
fmpy's ``FMU2Slave`` or ``FMU3Slave`` (fmpy passes the resources location: a ``file:`` URI
for FMI 2.0, a path for FMI 3.0) and collects its own log messages (each instance its own, see
:func:`_logger`); :meth:`FmuInstance.close` frees it and
removes the folder, also after a failure.
"""

import hashlib
import itertools
import math
import os
import re
import shutil
import stat
import tempfile
import zipfile
import zlib
from dataclasses import dataclass, field, replace
from pathlib import Path

from . import fmitypes


class ModelError(Exception):
    """An FMU is missing, unreadable or not an FMI 2.0/3.0 co-simulation FMU."""


@dataclass(frozen=True)
class Variable:
    """One scalar variable of a model description."""

    name: str
    vr: int
    type: str
    causality: str
    variability: str
    unit: str | None
    description: str
    start: str | None
    fmi: str = "2.0"     # FMI version of the FMU (selects the fmitypes table)
    dims: tuple = ()     # FMI 3.0 array dimensions as written (empty: a scalar)
    shape: tuple = None  # the dimensions as integers (None: a dimension is unknown)
    element: tuple = None  # of an array element "y[2]": (array name, flat index)
    min: str | None = None   # as written (the variable's, else its declared type's)
    max: str | None = None

    @property
    def ftype(self):
        """Its :class:`~agv_cosim.fmitypes.FmiType`, or None (Binary, Clock)."""
        return fmitypes.of(self)

    @property
    def size(self):
        """Number of values (1 for a scalar or an element; None if unknown)."""
        if not self.dims:
            return 1
        return math.prod(self.shape) if self.shape is not None else None

    def unsupported(self, use="connect"):
        """Why this variable cannot be used for ``use`` ('' if it can).

        ``use`` is "connect" (connection, SSP connector, event), "record" or "parameter".
        A whole array with known dimensions may be set as a parameter (a flat list in
        row-major order); its elements ``name[i]`` / ``name[i,j]`` may be recorded.
        """
        if self.ftype is None:
            return f"of type {self.type} (not supported)"
        if self.dims:
            if self.shape is None:
                return "an array variable whose dimensions are not known (not supported)"
            if use == "parameter":
                return ""
            if use == "record" and self.causality == "output":
                return (f"an array variable (record its elements, "
                        f"'{element_names(self.name, self.shape)[0]}' ..)")
            return "an array variable (arrays can be set as parameters and their " \
                   "output elements recorded, not connected)"
        if self.element is not None and use != "record":
            return "an array element (only recorded; set the whole array as a parameter)"
        return ""


def element_names(name, shape):
    """Element names of an array in row-major (FMI 3.0 serialisation) order, 1-based:
    ``y[1]``, ``y[2]`` for a vector, ``A[1,1]``, ``A[1,2]`` .. for a matrix."""
    return [f"{name}[{','.join(str(i + 1) for i in index)}]"
            for index in itertools.product(*(range(n) for n in shape))]


@dataclass
class ModelInfo:
    """What the orchestrator needs from one FMU's model description.

    ``dependencies`` maps each output name to the input names it depends on directly.
    """

    path: Path
    sha256: str
    model_name: str
    identifier: str
    guid: str
    description: str
    variables: dict = field(default_factory=dict)
    dependencies: dict = field(default_factory=dict)
    fmi_version: str = "2.0"
    can_handle_variable_step: bool = True
    can_get_set_state: bool = False
    table: object = None  # a time table (agv_cosim.table.Table) instead of an FMU

    def of_causality(self, causality):
        """Variables with the given causality, in model-description order."""
        return [v for v in self.variables.values() if v.causality == causality]

    @property
    def inputs(self):
        return self.of_causality("input")

    @property
    def outputs(self):
        return self.of_causality("output")

    @property
    def parameters(self):
        return self.of_causality("parameter")


_CACHE = {}


def file_sha256(path):
    """SHA-256 (hex) of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as stream:
        for chunk in iter(lambda: stream.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def read_model(path):
    """Read the model description of the FMU at ``path`` (cached by path, size, mtime).

    Raises
    ------
    ModelError
        If the file is missing, not a zip archive, or has no valid FMI 2.0
        co-simulation model description.
    """
    path = Path(path).resolve()
    try:
        stat = path.stat()
    except OSError:
        raise ModelError(f"FMU not found: '{path}'") from None
    if not path.is_file():
        raise ModelError(f"not a file: '{path}'")
    key = (str(path), stat.st_size, stat.st_mtime_ns)
    if key in _CACHE:
        return _CACHE[key]
    try:
        with zipfile.ZipFile(path) as archive:
            archive.getinfo("modelDescription.xml")
            # every entry's CRC now, so a corrupt binary is named here, not mid-run
            bad = archive.testzip()
    except KeyError:
        raise ModelError(f"broken FMU (no modelDescription.xml): '{path}'") from None
    except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError) as error:
        reason = "not a zip archive" if "File is not a zip" in str(error) else \
            f"corrupt zip archive: {error}"
        raise ModelError(f"broken FMU ({reason}): '{path}'") from None
    except OSError as error:
        raise ModelError(f"cannot read FMU '{path}': {error.strerror or error}") from None
    if bad is not None:
        raise ModelError(f"broken FMU (entry '{bad}' is corrupt): '{path}'")
    info = _CACHE[key] = _parse_model(path)
    return info


#: A modelIdentifier: a C identifier (FMI 2.0 and 3.0), never a path.
_IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")

#: How fmpy 0.3.32 words an XML-schema problem (lxml's error log); its later checks differ.
_SCHEMA_PROBLEM = re.compile(r"[A-Z]+ \(line \d+, column \d+\): ")


def _parse_model(path):
    """Map fmpy's ModelDescription (``fmpy.read_model_description``, schema and fmpy's
    own checks on) onto a :class:`ModelInfo`; fmpy's errors become one line."""
    from fmpy.model_description import ValidationError, read_model_description
    from lxml.etree import XMLSyntaxError

    def broken(reason):
        reason = " ".join(str(reason).split())
        return ModelError(f"broken FMU (modelDescription.xml: {reason}): '{path}'")

    version = _fmi_version(path)
    if version is not None and version != "2.0" and not version.startswith("3."):
        raise ModelError(f"not an FMI 2.0 or 3.0 FMU (fmiVersion={version!r}): '{path}'")
    try:
        try:
            md = read_model_description(str(path), validate=True)
        except ValidationError as error:
            if any(_SCHEMA_PROBLEM.match(p) for p in error.problems):
                raise
            # only fmpy's checks after parsing (a unit missing from UnitDefinitions, an
            # input without start ..): accepted, as before fmpy read the description
            md = read_model_description(str(path), validate=False)
    except ValidationError as error:
        first = error.problems[0] if error.problems else "failed to validate"
        # lxml's schema problems read "ERROR (line 15, column 0): Element ..: ..."
        first = re.sub(r"^ERROR \(line (\d+), column \d+\): ", r"line \1: ", first)
        first = first.rstrip(".")
        more = f" (and {len(error.problems) - 1} more)" if len(error.problems) > 1 else ""
        raise broken(first + more) from None
    except XMLSyntaxError as error:
        raise broken(error) from None
    except (IndexError, KeyError) as error:  # fmpy resolving an index / reference
        raise broken(f"an index or value reference in ModelStructure or Dimension names "
                     f"no variable ({type(error).__name__}: {error})") from None
    except Exception as error:  # noqa: BLE001 - fmpy raises plain Exception too
        text = str(error)
        if text.startswith("Unsupported FMI version"):
            raise ModelError(f"not an FMI 2.0 or 3.0 FMU ({text}): '{path}'") from None
        raise broken(text or type(error).__name__) from None
    version = md.fmiVersion or ""
    version = "3.0" if version.startswith("3.") else version
    if version not in ("2.0", "3.0"):
        raise ModelError(f"not an FMI 2.0 or 3.0 FMU (fmiVersion={md.fmiVersion!r}): "
                         f"'{path}'")
    cosim = md.coSimulation
    if cosim is None or not cosim.modelIdentifier:
        if md.modelExchange is not None:
            raise ModelError(f"a model-exchange-only FMU: agv-cosim runs co-simulation FMUs "
                             f"only: '{path}'")
        raise ModelError(f"not a co-simulation FMU: '{path}'")
    if not _IDENTIFIER.fullmatch(cosim.modelIdentifier):
        raise ModelError(f"broken FMU (modelIdentifier {cosim.modelIdentifier!r} is not a "
                         "name: FMI wants a C identifier, which also names the FMU's binary "
                         f"inside it): '{path}'")
    info = ModelInfo(path=path, sha256=file_sha256(path), model_name=md.modelName or "",
                     identifier=cosim.modelIdentifier, guid=md.guid or "",
                     description=md.description or "", fmi_version=version,
                     can_handle_variable_step=bool(
                         cosim.canHandleVariableCommunicationStepSize),
                     can_get_set_state=bool(cosim.canGetAndSetFMUstate))
    # fmpy appends FMI 3.0 <Alias> entries as extra variables: agv-cosim does not list them
    own = [sv for sv in md.modelVariables if getattr(sv, "alias", None) is None]
    ordered = [_variable(sv, version) for sv in own]
    for variable in ordered:
        info.variables[variable.name] = variable
        if variable.causality == "output" and variable.shape:
            # each element of an output array is recordable as its own column
            starts = (variable.start or "").split()
            for i, ename in enumerate(element_names(variable.name, variable.shape)):
                info.variables.setdefault(ename, replace(
                    variable, name=ename, dims=(), shape=None, element=(variable.name, i),
                    start=starts[i] if len(starts) == variable.size else None))
    input_names = [v.name for v in ordered if v.causality == "input"]
    for unknown in md.outputs:
        name = unknown.variable.name
        if unknown.dependencies is None:  # no attribute: depends on every input
            info.dependencies[name] = list(input_names)
        else:
            info.dependencies[name] = [d.name for d in unknown.dependencies
                                       if d.name in input_names]
    for variable in ordered:
        if variable.causality == "output" and variable.name not in info.dependencies:
            info.dependencies[variable.name] = list(input_names)
    return info


def _fmi_version(path):
    """The root's ``fmiVersion`` (None if unreadable), read before fmpy so that an FMI 1.0
    FMU is named as such instead of failing fmpy's FMI 1.0 schema check."""
    from lxml import etree

    try:
        with zipfile.ZipFile(path) as archive, archive.open("modelDescription.xml") as xml:
            for _, root in etree.iterparse(xml, events=("start",)):
                return root.get("fmiVersion") or ""
    except etree.XMLSyntaxError:
        return None  # fmpy names the syntax error
    return None


def _variable(sv, version):
    """One fmpy ModelVariable as our :class:`Variable`."""
    dims = tuple(str(d.start) if d.start is not None else f"vr:{d.valueReference}"
                 for d in sv.dimensions)
    declared = sv.declaredType
    return Variable(name=sv.name, vr=sv.valueReference, type=sv.type,
                    causality=sv.causality, variability=sv.variability,
                    unit=sv.unit, description=sv.description or "", start=sv.start,
                    fmi=version, dims=dims,
                    shape=tuple(int(n) for n in sv.shape) if dims else None,
                    min=sv.min if sv.min is not None else getattr(declared, "min", None),
                    max=sv.max if sv.max is not None else getattr(declared, "max", None))


def find_fmus(path):
    """The FMUs at ``path``: the file itself, or every ``*.fmu`` in a folder (sorted)."""
    path = Path(path)
    if path.is_dir():
        return sorted(path.glob("*.fmu"))
    return [path]


def describe(info):
    """Human-readable listing of an FMU's variables (``agv-cosim list``)."""
    lines = [f"{info.path.name}  ({info.model_name}): {info.description}"]
    order = {"parameter": 0, "input": 1, "output": 2}
    variables = sorted((v for v in info.variables.values() if v.element is None),
                       key=lambda v: (order.get(v.causality, 3), v.vr))
    for v in variables:
        unit = f"[{v.unit}]" if v.unit else ""
        extra = ""
        if v.causality == "output":
            deps = info.dependencies.get(v.name, [])
            extra = f"  (feedthrough from {', '.join(deps)})" if deps else ""
        start = f" = {v.start}" if v.start is not None and v.causality != "output" else ""
        vtype = v.type
        if v.dims:  # an FMI 3.0 array: its shape (elements recorded as name[i])
            vtype += f"[{'x'.join(map(str, v.shape)) if v.shape else '?'}]"
        lines.append(f"  {v.causality:<9} {vtype:<7} {v.name}{start} {unit}  "
                     f"{v.description}{extra}")
    return "\n".join(lines)


#: Instance key -> message list of that instance (see :func:`_logger`).
_ROUTES = {}
_KEYS = itertools.count(1)
_ROUTER = []


def _route(environment, instance_name, status, category, message):
    """The one logger every instance is given; hands a message to its own instance."""
    receive = _ROUTES.get(environment or 0)
    if receive is None:  # an FMU that does not pass its environment back
        name = instance_name.decode("utf-8", "replace") if instance_name else ""
        receive = _ROUTES.get(name)
    if receive is not None:
        receive(int(status), message.decode("utf-8", "replace") if message else "")


def _logger():
    """The process's single C logger callback (created once, kept alive).

    fmpy's native proxy, which formats the printf-style message, keeps one logger per
    process, and with it each instance's own Python logger would get the messages of
    every instance created after it (the last one gets them all). So every instance
    gets this one router, and its ``componentEnvironment`` (a key unique in the
    process; the instance name when an FMU does not pass it back) says whose messages
    they are.
    """
    if not _ROUTER:
        from fmpy.fmi2 import fmi2CallbackLoggerTYPE

        _ROUTER.append(fmi2CallbackLoggerTYPE(_route))
    return _ROUTER[0]


def _route3(environment, status, category, message):
    receive = _ROUTES.get(environment or 0)
    if receive is not None:
        receive(int(status), message.decode("utf-8", "replace") if message else "")


def _logger3():
    """The FMI 3.0 counterpart of :func:`_logger` (the environment names the instance)."""
    if len(_ROUTER) < 2:
        _logger()
        from fmpy.fmi3 import fmi3LogMessageCallback

        _ROUTER.append(fmi3LogMessageCallback(_route3))
    return _ROUTER[1]


#: Extracted FMUs kept for reuse in this process, ``(path, sha256) -> folder``; only in a
#: process that called :func:`keep_extractions` (a worker whose scratch folder its parent
#: deletes), so nothing is left behind elsewhere.
_EXTRACTED = {}
_EXTRACT_ROOT = []


def keep_extractions(folder):
    """Extract each FMU once in this process, under ``folder``, and give every instance
    a folder of its own made of hard links to that extraction (far cheaper than
    unpacking the archive again). ``folder`` must be deleted by whoever owns it."""
    _EXTRACT_ROOT[:] = [folder]
    _EXTRACTED.clear()


def _link_or_copy(source, dest):
    try:
        os.link(source, dest)
    except OSError:  # no hard links here (another file system, ...): a copy
        shutil.copy2(source, dest)


def _extract(path, dest):
    """Extract the FMU at ``path`` into ``dest``, private to this user (umask 077: its
    folders 0700, its files 0600; a binary needs no x bit to be loaded)."""
    old = os.umask(0o077)
    try:
        with zipfile.ZipFile(path) as archive:
            archive.extractall(dest)
    finally:
        os.umask(old)


def _kept(info):
    """The kept extraction of FMU ``info`` (made on first use; see keep_extractions)."""
    key = (str(info.path), info.sha256)
    source = _EXTRACTED.get(key)
    if source is None:
        source = tempfile.mkdtemp(prefix="agv_cosim_fmu_", dir=_EXTRACT_ROOT[0])
        _extract(info.path, source)
        _EXTRACTED[key] = source
    return source


def _unpack(info, dest):
    """Put the contents of FMU ``info.path`` into the existing folder ``dest``."""
    if not _EXTRACT_ROOT:
        _extract(info.path, dest)
        return
    shutil.copytree(_kept(info), dest, copy_function=_link_or_copy, dirs_exist_ok=True)


class FmuInstance:
    """One instantiated FMU in a private extraction folder.

    Parameters
    ----------
    info : ModelInfo
        The FMU's model description.
    instance_name : str
        The component's instance name.
    on_message : callable, optional
        Also called as ``on_message(instance_name, status, text)`` for each message the
        FMU logs (e.g. to pass it on before a crash can lose it).
    shared : bool
        In a process that keeps extractions (:func:`keep_extractions`), use the kept
        extraction itself instead of a folder of the instance's own (for instances that
        never live at the same time, e.g. validate's initialisation check); it is not
        deleted on close.
    """

    def __init__(self, info, instance_name, on_message=None, shared=False):
        from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE,
                               fmi2CallbackFreeMemoryTYPE, fmi2CallbackFunctions)
        from fmpy.fmi1 import calloc, free
        from ctypes import byref

        self.info = info
        self.name = instance_name
        self.messages = []
        self.slave = None
        self._key = next(_KEYS)
        self._on_message = on_message
        _ROUTES[self._key] = self._receive
        _ROUTES[instance_name] = self._receive
        tag = instance_name if re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]{0,63}",
                                            instance_name) else "fmu"
        self.unzip_dir, self._own_dir = None, True
        try:
            if shared and _EXTRACT_ROOT:
                self.unzip_dir, self._own_dir = _kept(info), False
            else:
                self.unzip_dir = tempfile.mkdtemp(prefix=f"agv_cosim_{tag}_")
                _unpack(info, self.unzip_dir)

            if info.fmi_version == "3.0":
                self._instantiate_3(info, instance_name)
                return
            callbacks = fmi2CallbackFunctions()
            callbacks.logger = _logger()
            callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
            callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
            callbacks.componentEnvironment = self._key
            try:
                from fmpy.logging import addLoggerProxy

                addLoggerProxy(byref(callbacks))
            except Exception:  # noqa: BLE001 - messages then arrive unformatted
                pass
            self._callbacks = callbacks  # keep the ctypes callbacks alive
            slave = FMU2Slave(guid=info.guid, unzipDirectory=self.unzip_dir,
                              modelIdentifier=info.identifier, instanceName=instance_name,
                              libraryPath=self._library(info))
            self.slave = slave
            slave.instantiate(callbacks=callbacks, loggingOn=True)
        except BaseException:
            self.close()
            raise

    def _library(self, info):
        """The FMU's own binary for this platform, inside its extraction folder: a
        regular file (not a link) named by the modelIdentifier, else RuntimeError."""
        import fmpy

        if not _IDENTIFIER.fullmatch(info.identifier):
            raise RuntimeError(f"modelIdentifier {info.identifier!r} is not a name")
        platform = fmpy.platform_tuple if info.fmi_version == "3.0" else fmpy.platform
        relative = f"binaries/{platform}/{info.identifier}{fmpy.sharedLibraryExtension}"
        library = os.path.join(self.unzip_dir, relative)
        try:
            mode = os.lstat(library).st_mode
        except OSError:
            raise RuntimeError(f"the FMU has no binary for this platform ({relative})") \
                from None
        if not stat.S_ISREG(mode):
            raise RuntimeError(f"the FMU's binary {relative} is not a regular file")
        return library

    def _instantiate_3(self, info, instance_name):
        """FMI 3.0: ``fmi3InstantiateCoSimulation`` with our environment key and logger."""
        from fmpy.fmi3 import (FMU3Slave, fmi3Boolean, fmi3InstanceEnvironment,
                               fmi3IntermediateUpdateCallback, fmi3ValueReference)

        slave = FMU3Slave(guid=info.guid, unzipDirectory=self.unzip_dir,
                          modelIdentifier=info.identifier, instanceName=instance_name,
                          libraryPath=self._library(info))
        self.slave = slave
        resources = str(Path(self.unzip_dir, "resources")) + "/"
        slave.logMessage = _logger3()
        slave.intermediateUpdate = fmi3IntermediateUpdateCallback()
        slave.component = slave.fmi3InstantiateCoSimulation(
            instance_name.encode("utf-8"), info.guid.encode("utf-8"),
            resources.encode("utf-8"), fmi3Boolean(False), fmi3Boolean(True),
            fmi3Boolean(False), fmi3Boolean(False), (fmi3ValueReference * 0)(), 0,
            fmi3InstanceEnvironment(self._key), slave.logMessage, slave.intermediateUpdate)
        if not slave.component:
            raise RuntimeError("fmi3InstantiateCoSimulation failed")

    def _receive(self, status, text):
        self.messages.append((status, text))
        if self._on_message is not None:
            self._on_message(self.name, status, text)

    def last_error(self):
        """The FMU's own error message, one line ('' if none was logged).

        pythonfmu logs the slave's message with status error, then a generic fatal
        "PyObject_CallMethod" line; the first error-status message is the useful one.
        """
        errors = [text for status, text in self.messages if status == 3]
        if not errors:
            errors = [text for status, text in self.messages if status > 3]
        return " ".join(errors[-1].split()) if errors else ""

    def close(self):
        """Terminate and free the instance, then delete the extraction folder."""
        slave, self.slave = self.slave, None
        if slave is not None:
            try:
                if getattr(slave, "component", None) is not None:
                    try:
                        slave.terminate()
                    except Exception:  # noqa: BLE001 - may fail after an error
                        pass
                    slave.freeInstance()
                else:
                    slave.freeLibrary()
            except Exception:  # noqa: BLE001 - cleanup must go on
                pass
        if self.unzip_dir is not None:
            if self._own_dir:
                shutil.rmtree(self.unzip_dir, ignore_errors=True)
            self.unzip_dir = None
        for key in (self._key, self.name):
            if _ROUTES.get(key) == self._receive:
                del _ROUTES[key]
