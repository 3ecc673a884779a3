"""Work-arounds for defects of the FMU wrappers pythonfmu 0.7 and pythonfmu3 0.3.4, in one place.

On Linux the FMUs no longer contain those wrappers' libraries: the FMU bridge
(components/fmu_loader/agv_fmu_bridge.c) implements the FMI API over the slave and has
none of defects 1-3 (1 then leaks a failed slave's few objects, 2 finds no wrapper library
loaded and does nothing, 3 keeps one reference per instantiation). They stay for the
Windows DLL, which is still pythonfmu's; 4-6 hold for every FMU.

Each entry says what the wrapper does wrong and what we do about it. Those that must
live elsewhere (they run before this package is imported, or at build time) are listed
with where they are.

1. Double release of a failed slave (here: :func:`keep_for_pythonfmu`). When a Python
   exception escapes a slave method, the wrappers' C++ handler releases the slave's
   class, instance and log queue (cleanPyObject) without forgetting them, and
   FreeInstance releases the same three again. Before any exception leaves an adapter one
   extra reference to each is kept in :data:`KEPT_FOR_PYTHONFMU`, so the second release
   cannot free live objects (a failed instance is then never freed: a small leak instead
   of a corrupted heap). A host that runs several failing instances of one FMU can still
   see its heap damaged (measured with PYTHONMALLOC=debug, cause not located), which is
   why the orchestrator runs simulations in worker processes and retires a worker after
   any run that did not end complete (agv_cosim/workers/pool.py).
2. Exit-time use after free (here: :func:`finalize_at_exit`, used by the FMI 3.0
   adapter; the FMI 2.0 FMUs avoid it with the C loader, components/fmu_loader). At
   process exit C++ static destruction destroys the library's global
   ``shared_ptr<PyState>``, then its unload hook (finalizePythonInterpreter) assigns to
   the destroyed pointer and releases its freed control block again (valgrind: invalid
   read in finalizePythonInterpreter from _dl_call_fini; 2 of 30 fmpy processes aborted
   with "corrupted double-linked list"). In a Python host the adapter calls that hook
   itself from Python's atexit, while the pointer is alive: it is then empty when the
   static destructor and the unload hook run. The library handle kept here also keeps the
   library loaded until process exit, so a host's dlclose cannot run the faulty unload
   earlier.
3. The slave script's globals released once per instantiation (the pinned globals, in
   ``agv_boot.py``: it runs before the package is loaded). pythonfmu 0.7 re-executes the
   slave script at every instantiation with the module's globals and then decrements the
   reference count of that borrowed dict; ``agv_boot.load_core`` keeps one reference per
   execution.
4. One slave module per file name per process, and ``__file__`` naming another FMU's
   folder (the content-hash tag, in ``agv_boot.py`` and ``slave_base.SlaveLogic
   ._check_bundle``): each FMU loads its own ``agv_core`` bundle as ``agv_core_<tag>``
   from ``sys.path[0]``, and refuses to run another build's slave code in its name.
5. pythonfmu3 finds the slave class only from a ``class`` line naming ``Fmi3Slave`` (the
   FMI 3.0 alias, in ``agv_cosim/build/fmus.py``): the build bundles the slave script
   unchanged, writes a two-line wrapper script, and makes the bundle's ``fmi/fmi_slave.py``
   an alias of ``fmi/fmi3_slave.py``.
6. Model-description fixes (in the adapters' ``to_xml``): no ``generationDateAndTime``
   (a rebuild must not differ by clock), Real start values with repr's 17 digits
   (pythonfmu writes 16, which do not round-trip every double), units, output
   dependencies and ``InitialUnknowns`` (pythonfmu writes none), and the dependencies of
   the initial unknowns (pythonfmu3 writes none).
"""

import atexit
import ctypes
import os
import sys
from pathlib import Path
from typing import Any

#: Objects of failed slaves, kept for the wrappers' second release (entry 1).
KEPT_FOR_PYTHONFMU: list[Any] = []

#: Loaded pythonfmu3 libraries to finalise at exit: library path -> ctypes handle (entry 2).
_WRAPPERS_TO_FINALIZE: dict[str, ctypes.CDLL] = {}


def keep_for_pythonfmu(slave: Any) -> None:
    """Balance the wrapper's double release before an exception leaves ``slave`` (entry 1)."""
    KEPT_FOR_PYTHONFMU.extend((type(slave), slave, slave.log_queue))


def _finalize_wrappers() -> None:
    for library in _WRAPPERS_TO_FINALIZE.values():
        library.finalizePythonInterpreter()


def finalize_at_exit(resources: str | Path, identifier: str) -> None:
    """Register the FMU's loaded pythonfmu3 library (if any) for finalisation (entry 2)."""
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
