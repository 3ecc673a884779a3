"""FMU loading and model-description access.

:func:`read_model` reads ``modelDescription.xml`` straight from the FMU archive (no
extraction) into a :class:`ModelInfo`: variables with value reference, type, causality,
unit and description, and each output's direct dependencies. An output whose
``<Unknown>`` carries no ``dependencies`` attribute depends, per FMI 2.0, on every input.

:class:`FmuInstance` extracts an FMU into a private temporary folder, instantiates it with
fmpy's ``FMU2Slave`` and collects its own log messages (each instance its own, see
:func:`_logger`); :meth:`FmuInstance.close` frees it and
removes the folder, also after a failure.
"""

import hashlib
import itertools
import re
import shutil
import tempfile
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from xml.etree import ElementTree

TYPES = ("Real", "Integer", "Boolean", "String", "Enumeration")


class ModelError(Exception):
    """An FMU is missing, unreadable or not an FMI 2.0 co-simulation FMU."""


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
            xml = archive.read("modelDescription.xml")
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
    try:
        return _parse_model(path, xml)
    except (TypeError, ValueError, IndexError) as error:
        raise ModelError(f"broken FMU (modelDescription.xml: {error}): '{path}'") from None


def _integer(node, attr, what):
    text = node.get(attr)
    if text is None:
        raise ValueError(f"{what} has no {attr}")
    try:
        return int(text)
    except ValueError:
        raise ValueError(f"{what}: {attr}={text!r} is not an integer") from None


def _parse_model(path, xml):
    stat = path.stat()
    key = (str(path), stat.st_size, stat.st_mtime_ns)
    try:
        root = ElementTree.fromstring(xml)
    except ElementTree.ParseError as error:
        raise ModelError(f"broken FMU (modelDescription.xml: {error}): '{path}'") from None
    if root.get("fmiVersion") != "2.0":
        raise ModelError(f"not an FMI 2.0 FMU (fmiVersion={root.get('fmiVersion')!r}): "
                         f"'{path}'")
    cosim = root.find("CoSimulation")
    if cosim is None or not cosim.get("modelIdentifier"):
        raise ModelError(f"not a co-simulation FMU: '{path}'")
    info = ModelInfo(path=path, sha256=file_sha256(path), model_name=root.get("modelName", ""),
                     identifier=cosim.get("modelIdentifier"), guid=root.get("guid", ""),
                     description=root.get("description", ""))
    ordered = []
    for scalar in root.find("ModelVariables") if root.find("ModelVariables") is not None else []:
        kind = next((child for child in scalar if child.tag in TYPES), None)
        if kind is None:
            raise ModelError(f"broken FMU (variable '{scalar.get('name')}' has no type): "
                             f"'{path}'")
        if not scalar.get("name"):
            raise ValueError(f"ScalarVariable {len(ordered) + 1} has no name")
        variable = Variable(name=scalar.get("name"),
                            vr=_integer(scalar, "valueReference",
                                        f"variable '{scalar.get('name')}'"),
                            type=kind.tag, causality=scalar.get("causality", "local"),
                            variability=scalar.get("variability", "continuous"),
                            unit=kind.get("unit"), description=scalar.get("description", ""),
                            start=kind.get("start"))
        info.variables[variable.name] = variable
        ordered.append(variable)
    input_names = [v.name for v in ordered if v.causality == "input"]
    outputs = root.find("ModelStructure/Outputs")
    def indexed(text, what):
        try:
            index = int(text)
        except (TypeError, ValueError):
            raise ValueError(f"{what} {text!r} is not an integer") from None
        if not 1 <= index <= len(ordered):
            raise ValueError(f"{what} {index} is not a variable index (1..{len(ordered)})")
        return ordered[index - 1]

    for unknown in outputs if outputs is not None else []:
        variable = indexed(unknown.get("index"), "Outputs/Unknown index")
        deps = unknown.get("dependencies")
        if deps is None:
            info.dependencies[variable.name] = list(input_names)
        else:
            names = [indexed(i, "Outputs/Unknown dependency").name for i in deps.split()]
            info.dependencies[variable.name] = [n for n in names if n in input_names]
    for variable in ordered:
        if variable.causality == "output" and variable.name not in info.dependencies:
            info.dependencies[variable.name] = list(input_names)
    _CACHE[key] = info
    return info


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
    variables = sorted(info.variables.values(), key=lambda v: (order.get(v.causality, 3), v.vr))
    for v in variables:
        unit = f"[{v.unit}]" if v.unit else ""
        extra = ""
        if v.causality == "output":
            deps = info.dependencies.get(v.name, [])
            extra = f"  (feedthrough from {', '.join(deps)})" if deps else ""
        start = f" = {v.start}" if v.start is not None and v.causality != "output" else ""
        lines.append(f"  {v.causality:<9} {v.type:<7} {v.name}{start} {unit}  "
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
    """

    def __init__(self, info, instance_name, on_message=None):
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
        self.unzip_dir = tempfile.mkdtemp(prefix=f"agv_cosim_{tag}_")
        try:
            with zipfile.ZipFile(info.path) as archive:
                archive.extractall(self.unzip_dir)

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
                              modelIdentifier=info.identifier, instanceName=instance_name)
            self.slave = slave
            slave.instantiate(callbacks=callbacks, loggingOn=True)
        except BaseException:
            self.close()
            raise

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
            shutil.rmtree(self.unzip_dir, ignore_errors=True)
            self.unzip_dir = None
        for key in (self._key, self.name):
            if _ROUTES.get(key) == self._receive:
                del _ROUTES[key]
