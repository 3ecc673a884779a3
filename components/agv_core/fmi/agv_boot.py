"""Load the ``agv_core`` package bundled beside a slave script (part of every FMU).

pythonfmu appends each FMU's ``resources/`` to ``sys.path`` and imports modules by file
name once per process, so a plain ``import agv_core`` would take whichever copy came
first: the host's installed package, or another FMU's older bundle. This loader instead
imports the bundle that sits next to the given slave script under the name
``agv_core_<tag>``, where ``<tag>`` is the content hash the build wrote into
``agv_core_bundle/BUILD_ID``. FMUs built from the same sources share one module; FMUs built
from different sources each get their own. The bundle's folder is not named ``agv_core``:
with ``resources/`` on ``sys.path`` a folder of that name would shadow the installed
package for every later ``import agv_core`` in the host's process, and a bundle holds only
the modules its slave needs.

Which bundle: pythonfmu 0.7 inserts the instantiated FMU's ``resources/`` folder at
``sys.path[0]`` immediately before it executes the slave script (the builder does the same
with its staging folder), and it re-executes the script with the globals of the first
import, so the script's ``__file__`` may name another FMU's (even a deleted) folder.
``sys.path[0]`` is therefore the reliable pointer to this FMU's bundle.

This file is itself imported once per process from whichever FMU comes first, so its
behaviour must depend on ``sys.path[0]`` and its arguments only. Never change it without
changing BOOT_ABI.
"""

import importlib.util
import sys
from importlib.machinery import ModuleSpec
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any, cast

if TYPE_CHECKING:
    from importlib.abc import Loader

#: 3: the bundle's folder is resources/agv_core_bundle (2: resources/agv_core, still read)
BOOT_ABI = 3

#: The bundle's folder in resources/, then the one of FMUs built before BOOT_ABI 3.
BUNDLE_FOLDERS = ("agv_core_bundle", "agv_core")

# pythonfmu 0.7's findClass executes the slave script again at every instantiation, with
# the module's globals, and then calls Py_DECREF on that globals dict although it only
# borrowed it (PyModule_GetDict). Each instantiation thus drops one reference the module
# owns: a slave module whose dict has few other references (no functions of its own) has
# its globals freed after one or two instantiations, and the host fails or crashes. Every
# execution of a slave script calls load_core, which keeps one more reference here, so the
# stray decrement is balanced (one list slot per instantiation).
_PINNED_GLOBALS: list[dict[str, Any]] = []


def load_core(*submodules: str) -> ModuleType:
    """Import the ``agv_core`` bundled in the FMU being instantiated, with ``submodules``.

    Returns the package; each named submodule is imported and is an attribute of it.
    Call it at module level of the slave script (it pins the caller's globals, see above).
    """
    _PINNED_GLOBALS.append(sys._getframe(1).f_globals)
    root = next((Path(sys.path[0]) / folder for folder in BUNDLE_FOLDERS
                 if (Path(sys.path[0]) / folder / "BUILD_ID").is_file()),
                Path(sys.path[0]) / BUNDLE_FOLDERS[0])
    build_id = root / "BUILD_ID"
    if not build_id.is_file():
        raise ImportError(f"agv_boot: '{root}' holds no BUILD_ID; slave scripts run only "
                          "inside an FMU made by 'agv-cosim build'")
    tag = build_id.read_text().strip()
    name = f"agv_core_{tag}"
    module = sys.modules.get(name)
    if module is not None:
        # Same tag, same content: point the package and its loaded subpackages at this
        # bundle, since the folder they were first loaded from may be gone (hosts delete
        # extracted FMUs), and a submodule that no earlier FMU needed is imported from here.
        module.__path__[:] = [str(root)]
        prefix = name + "."
        for loaded, sub in list(sys.modules.items()):
            if loaded.startswith(prefix) and hasattr(sub, "__path__"):
                sub.__path__[:] = [str(root.joinpath(*loaded[len(prefix):].split(".")))]
    else:
        spec = cast(ModuleSpec, importlib.util.spec_from_file_location(  # a file: a spec
            name, root / "__init__.py", submodule_search_locations=[str(root)]
        ))
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        try:
            cast("Loader", spec.loader).exec_module(module)  # a file's spec has a loader
        except BaseException:
            del sys.modules[name]
            raise
    for submodule in submodules:
        importlib.import_module(f"{name}.{submodule}")
    return module
