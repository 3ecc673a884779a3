"""An FMU instantiated for a run: extracted into a private folder, loaded with fmpy's
``FMU2Slave`` or ``FMU3Slave`` (fmpy passes the resources location: a ``file:`` URI for
FMI 2.0, a path for FMI 3.0), its log messages routed per instance (:func:`_logger`):
an instance holds none of them but its last error and last fatal message (each at most
:data:`MAX_MESSAGE` characters) and the count per status, however much the FMU logs.
:meth:`FmuInstance.close` frees it and removes the folder, also after a failure.

What an FMU declares (its model description) is read apart from this, by
:mod:`agv_cosim.system.model`.
"""

import itertools
import os
import re
import shutil
import stat
import sys
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from ..archive import FMU_LIMITS, extract
from ..system.model import IDENTIFIER, ModelInfo

__all__ = ["MAX_MESSAGE", "FmuInstance", "extract_ahead", "keep_extractions"]

#: Most characters of one FMU message passed on or held (the rest cut, marked).
MAX_MESSAGE = 4096


#: Instance key -> message list of that instance (see :func:`_logger`).
_ROUTES: dict[Any, Callable[[int, str], None]] = {}
_KEYS = itertools.count(1)
_ROUTER: list[Any] = []


def _route(environment: Any, instance_name: bytes | None, status: int, category: bytes | None,
           message: bytes | None) -> None:
    """The one logger every instance is given; hands a message to its own instance."""
    receive = _ROUTES.get(environment or 0)
    if receive is None:  # an FMU that does not pass its environment back
        name = instance_name.decode("utf-8", "replace") if instance_name else ""
        receive = _ROUTES.get(name)
    if receive is not None:
        receive(int(status), _text(message))


def _text(message: bytes | None) -> str:
    """A logged message as text, at most :data:`MAX_MESSAGE` characters."""
    if not message:
        return ""
    if len(message) <= MAX_MESSAGE:
        return message.decode("utf-8", "replace")
    return (message[:MAX_MESSAGE].decode("utf-8", "ignore")
            + f" [... {len(message) - MAX_MESSAGE} more bytes]")


def _logger() -> Any:
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


def _route3(environment: Any, status: int, category: bytes | None,
            message: bytes | None) -> None:
    receive = _ROUTES.get(environment or 0)
    if receive is not None:
        receive(int(status), _text(message))


def _logger3() -> Any:
    """The FMI 3.0 counterpart of :func:`_logger` (the environment names the instance)."""
    if len(_ROUTER) < 2:
        _logger()
        from fmpy.fmi3 import fmi3LogMessageCallback

        _ROUTER.append(fmi3LogMessageCallback(_route3))
    return _ROUTER[1]


#: Extracted FMUs kept for reuse in this process, ``(path, sha256) -> folder``; only in a
#: process that called :func:`keep_extractions` (a worker whose scratch folder its parent
#: deletes), so nothing is left behind elsewhere.
_EXTRACTED: dict[tuple[str, str], str] = {}
_EXTRACT_ROOT: list[str] = []


def keep_extractions(folder: str) -> None:
    """Extract each FMU once in this process, under ``folder``, and give every instance
    a folder of its own made from that extraction (its binaries hard-linked, the rest
    symbolic links: see :func:`_unpack`; far cheaper than unpacking the archive again).
    ``folder`` must be deleted by whoever owns it."""
    _EXTRACT_ROOT[:] = [folder]
    _EXTRACTED.clear()


def _link_or_copy(source: str, dest: str) -> None:
    try:
        os.link(source, dest)
    except OSError:  # no hard links here (another file system, ...): a copy
        shutil.copy2(source, dest)


def _extract(path: str | Path, dest: str) -> None:
    """Extract the FMU at ``path`` into ``dest``, private to this user (umask 077: its
    folders 0700, its files 0600; a binary needs no x bit to be loaded)."""
    old = os.umask(0o077)
    try:
        _unzip(path, dest)
    finally:
        os.umask(old)


def _unzip(path: str | Path, dest: str) -> None:
    """Unpack the FMU at ``path`` into the existing folder ``dest`` within
    :data:`~agv_cosim.archive.FMU_LIMITS` (:func:`agv_cosim.archive.extract`: refused
    with :class:`~agv_cosim.archive.ArchiveRefused` beyond them, what it wrote removed)."""
    extract(path, dest, FMU_LIMITS)


def extract_ahead(infos: Iterable[ModelInfo]) -> None:
    """In a process that keeps extractions (:func:`keep_extractions`), unpack the FMUs of
    ``infos`` not kept yet, up to 4 at once in threads: unpacking an FMU is mostly
    waiting for the file system to create its many small files, which one thread does
    one after the other. An FMU that fails to unpack here is left to its instance
    (which unpacks it again and reports the error where it belongs)."""
    if not _EXTRACT_ROOT:
        return
    todo: dict[tuple[str, str], ModelInfo] = {}
    for info in infos:
        key = (str(info.path), info.sha256)
        if info.table is None and key not in _EXTRACTED:
            todo.setdefault(key, info)
    if len(todo) < 2:
        return
    from concurrent.futures import ThreadPoolExecutor

    folders = {key: tempfile.mkdtemp(prefix="agv_cosim_fmu_", dir=_EXTRACT_ROOT[0])
               for key in todo}
    old = os.umask(0o077)  # the process's: set once, around every thread's unpacking
    try:
        with ThreadPoolExecutor(max_workers=min(4, len(todo))) as threads:
            done = {key: threads.submit(_unzip, info.path, folders[key])
                    for key, info in todo.items()}
    finally:
        os.umask(old)
    for key, future in done.items():
        if future.exception() is None:
            _EXTRACTED[key] = folders[key]
        else:
            shutil.rmtree(folders[key], ignore_errors=True)


def _kept(info: ModelInfo) -> str:
    """The kept extraction of FMU ``info`` (made on first use; see keep_extractions)."""
    key = (str(info.path), info.sha256)
    source = _EXTRACTED.get(key)
    if source is None:
        source = tempfile.mkdtemp(prefix="agv_cosim_fmu_", dir=_EXTRACT_ROOT[0])
        _extract(info.path, source)
        _EXTRACTED[key] = source
    return source


def _binaries(info: ModelInfo) -> str:
    """The folder of the FMU's binaries for this platform, relative to its extraction."""
    import fmpy

    return f"binaries/{fmpy.platform_tuple if info.fmi_version == '3.0' else fmpy.platform}"


def _unpack(info: ModelInfo, dest: str) -> None:
    """Put the contents of FMU ``info.path`` into the existing folder ``dest``.

    In a process that keeps extractions, ``dest`` gets this platform's binaries as hard
    links to the kept extraction's files, in folders of its own (a library loaded from a
    path of its own has globals of its own: each instance starts from the library's
    initial state), and every other entry (``resources/``, ``modelDescription.xml``, the
    other platforms' binaries, ...) as a symbolic link to the kept one."""
    if not _EXTRACT_ROOT:
        _extract(info.path, dest)
        return
    kept = _kept(info)
    own = _binaries(info)
    for entry in os.listdir(kept):
        if entry != "binaries":
            os.symlink(os.path.join(kept, entry), os.path.join(dest, entry))
    if not os.path.isdir(os.path.join(kept, "binaries")):
        return
    os.mkdir(os.path.join(dest, "binaries"), 0o700)
    for platform in os.listdir(os.path.join(kept, "binaries")):
        source = os.path.join(kept, "binaries", platform)
        if (f"binaries/{platform}" == own and os.path.isdir(source)
                and not os.path.islink(source)):
            shutil.copytree(source, os.path.join(dest, own), copy_function=_link_or_copy)
        else:
            os.symlink(source, os.path.join(dest, "binaries", platform))


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

    def __init__(self, info: ModelInfo, instance_name: str,
                 on_message: Callable[[str, int, str], None] | None = None,
                 shared: bool = False) -> None:
        from ctypes import byref

        from fmpy.fmi1 import calloc, free
        from fmpy.fmi2 import (
            FMU2Slave,
            fmi2CallbackAllocateMemoryTYPE,
            fmi2CallbackFreeMemoryTYPE,
            fmi2CallbackFunctions,
        )

        self.info = info
        self.name = instance_name
        #: messages logged, per status (0 OK .. 5 Pending; other values counted as 5)
        self.logged = [0] * 6
        #: the last message logged with status Error, and with a status above Error
        self._last: dict[int, str] = {}
        #: fmpy's FMU2Slave or FMU3Slave (None once closed)
        self.slave: Any = None
        self._key = next(_KEYS)
        self._on_message = on_message
        _ROUTES[self._key] = self._receive
        _ROUTES[instance_name] = self._receive
        tag = instance_name if re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]{0,63}",
                                            instance_name) else "fmu"
        self.unzip_dir: str | None = None
        self._own_dir = True
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
            # a component integrated as Model Exchange (info.integration set) is an
            # FMU2Model, which fmi2Instantiate makes with fmi2ModelExchange
            kind: Any = FMU2Slave
            if getattr(info, "integration", None) is not None:
                from fmpy.fmi2 import FMU2Model

                kind = FMU2Model
            slave = kind(guid=info.guid, unzipDirectory=self.unzip_dir,
                         modelIdentifier=info.identifier, instanceName=instance_name,
                         libraryPath=self._library(info))
            self.slave = slave
            slave.instantiate(callbacks=callbacks, loggingOn=True)
        except BaseException:
            self.close()
            raise

    def _library(self, info: ModelInfo) -> str:
        """The FMU's own binary for this platform, inside its extraction folder: a
        regular file (not a link) named by the modelIdentifier, else RuntimeError."""
        import fmpy

        if not IDENTIFIER.fullmatch(info.identifier):
            raise RuntimeError(f"modelIdentifier {info.identifier!r} is not a name")
        relative = f"{_binaries(info)}/{info.identifier}{fmpy.sharedLibraryExtension}"
        assert self.unzip_dir is not None  # extracted before the library is looked up
        library = os.path.join(self.unzip_dir, relative)
        try:
            mode = os.lstat(library).st_mode
        except OSError:
            raise RuntimeError(f"the FMU has no binary for this platform ({relative})") \
                from None
        if not stat.S_ISREG(mode):
            raise RuntimeError(f"the FMU's binary {relative} is not a regular file")
        return library

    def _instantiate_3(self, info: ModelInfo, instance_name: str) -> None:
        """FMI 3.0: ``fmi3InstantiateCoSimulation`` with our environment key and logger."""
        from fmpy.fmi3 import (
            FMU3Slave,
            fmi3Boolean,
            fmi3InstanceEnvironment,
            fmi3IntermediateUpdateCallback,
            fmi3ValueReference,
        )

        if getattr(info, "integration", None) is not None:
            self._instantiate_3_model_exchange(info, instance_name)
            return
        slave = FMU3Slave(guid=info.guid, unzipDirectory=self.unzip_dir,
                          modelIdentifier=info.identifier, instanceName=instance_name,
                          libraryPath=self._library(info))
        self.slave = slave
        resources = str(Path(str(self.unzip_dir), "resources")) + "/"
        slave.logMessage = _logger3()
        slave.intermediateUpdate = fmi3IntermediateUpdateCallback()
        slave.component = slave.fmi3InstantiateCoSimulation(
            instance_name.encode("utf-8"), info.guid.encode("utf-8"),
            resources.encode("utf-8"), fmi3Boolean(False), fmi3Boolean(True),
            fmi3Boolean(False), fmi3Boolean(False), (fmi3ValueReference * 0)(), 0,
            fmi3InstanceEnvironment(self._key), slave.logMessage, slave.intermediateUpdate)
        if not slave.component:
            raise RuntimeError("fmi3InstantiateCoSimulation failed")

    def _instantiate_3_model_exchange(self, info: ModelInfo, instance_name: str) -> None:
        """FMI 3.0: ``fmi3InstantiateModelExchange`` with our environment key and logger."""
        from fmpy.fmi3 import FMU3Model, fmi3Boolean, fmi3InstanceEnvironment

        slave = FMU3Model(guid=info.guid, unzipDirectory=self.unzip_dir,
                          modelIdentifier=info.identifier, instanceName=instance_name,
                          libraryPath=self._library(info))
        self.slave = slave
        resources = str(Path(str(self.unzip_dir), "resources")) + "/"
        slave.logMessage = _logger3()
        slave.component = slave.fmi3InstantiateModelExchange(
            instance_name.encode("utf-8"), info.guid.encode("utf-8"),
            resources.encode("utf-8"), fmi3Boolean(False), fmi3Boolean(True),
            fmi3InstanceEnvironment(self._key), slave.logMessage)
        if not slave.component:
            raise RuntimeError("fmi3InstantiateModelExchange failed")

    def _receive(self, status: int, text: str) -> None:
        self.logged[min(max(status, 0), 5)] += 1
        if status >= 3:  # held: the last of each kind only
            self._last[3 if status == 3 else 4] = text
        if self._on_message is not None:
            self._on_message(self.name, status, text)

    def last_error(self) -> str:
        """The FMU's own error message, one line ('' if none was logged).

        pythonfmu logs the slave's message with status error, then a generic fatal
        "PyObject_CallMethod" line; the last error-status message is the useful one, else
        the last message of a status above it.
        """
        text = self._last.get(3, self._last.get(4, ""))
        return " ".join(text.split())

    def close(self) -> None:
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
            # pythonfmu put the FMU's resources folder (a partial agv_core among its
            # files) on sys.path; left there, a later ``import agv_core`` of this process,
            # or of a fork server it starts, could find that copy first
            inside = os.path.join(self.unzip_dir, "")
            sys.path[:] = [p for p in sys.path if not os.path.join(p, "").startswith(inside)]
            if self._own_dir:
                shutil.rmtree(self.unzip_dir, ignore_errors=True)
            self.unzip_dir = None
        for key in (self._key, self.name):
            if _ROUTES.get(key) == self._receive:
                del _ROUTES[key]
