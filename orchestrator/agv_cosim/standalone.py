"""Standalone FMUs: an FMU that carries its own Python runtime (``agv-cosim build --standalone``).

The runtime goes into the FMU beside its binary, as ``binaries/<platform>/python/``:

``lib/libpython3.X.so.1.0``
    the building Python's shared library (it must be built with ``--enable-shared``),
    stripped, its run path ``$ORIGIN``;
``lib/*.so.*``
    the shared libraries that it and the bundled extension modules need beyond the C
    library (libffi, zlib, liblzma, ...; found with ``ldd``), stripped;
``lib/python3.X/``
    the standard library without what an FMU cannot use (tests, IDLE, Tk, curses,
    readline, dbm, sqlite, ssl, ensurepip, lib2to3, the static library and Makefile of
    ``config-*``), its extension modules in ``lib-dynload`` with run path ``$ORIGIN/../..``;
``lib/python3.X/site-packages/``
    the distributions of every module the FMU's slave imports (found by importing the slave
    and running a few steps of its default experiment in a child process of the building
    Python: the modules loaded from site-packages, mapped to their distributions), each as
    its installed files without tests, type stubs, C headers and Cython declarations
    (compiled files as the wheels installed them).

No ``__pycache__`` is shipped (Python compiles on first import, and writes the cache into
the extracted FMU when it may). The FMU loader (components/fmu_loader/agv_fmu_loader.c)
starts this runtime, with ``home`` set to the folder, when the host process has no
Python; a host that has one (fmpy) runs the FMU in its own interpreter, with this
``site-packages`` appended to ``sys.path`` for what the host lacks.

Paths of the building machine are kept out: the run paths are rewritten (patchelf), the
libraries are stripped of debug information, and the building Python's prefix, which
``libpython`` and ``_sysconfigdata`` hold as text, is overwritten with a neutral one of the
same length (a compiled-in fallback that the loader never uses, since it sets ``home``).
"""

import atexit
import importlib.metadata
import json
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import zipfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from .errors import StandaloneError

#: The runtime's folder inside ``binaries/<platform>/`` (the loader looks for it there).
RUNTIME_FOLDER = "python"

#: Standard-library parts an FMU cannot use (folders and modules, relative to lib/python3.X).
STDLIB_EXCLUDED = {"test", "idlelib", "tkinter", "turtledemo", "ensurepip", "lib2to3",
                   "pydoc_data", "site-packages", "curses", "dbm", "sqlite3", "venv",
                   "turtle.py", "__phello__", "unittest/test", "ctypes/test",
                   "distutils/tests"}
#: Extension modules left out of lib-dynload (GUI, terminal, databases, TLS, tests).
DYNLOAD_EXCLUDED = re.compile(r"^(_tkinter|_curses|_curses_panel|readline|_dbm|_gdbm|nis|"
                              r"_crypt|_ssl|_hashlib|_sqlite3|_test\w*|_ctypes_test|xx\w*|"
                              r"_xxtestfuzz|_xxsubinterpreters|audioop|ossaudiodev|spwd)\.")
#: Installed files of a distribution left out (tests, stubs, headers, Cython declarations).
PACKAGE_EXCLUDED = re.compile(r"(^|/)(tests?|__pycache__)/|\.(pyc|pyi|pxd|pyx|h|hpp|c|cpp|"
                              r"a)$|(^|/)include/|(^|/)py\.typed$")
#: Libraries of the C library itself: every Linux machine has them, they are not shipped.
SYSTEM_LIBRARIES = re.compile(r"^(libc|libm|libpthread|libdl|librt|libutil|ld-linux[-\w]*|"
                              r"libresolv|libgcc_s|libstdc\+\+|linux-vdso)\.so")


# ------------------------------------------------------------------------ what to ship
#: Run in a child of the building Python: import the slave from an extracted FMU's
#: resources the way the bridge does, step its default experiment a little, print the
#: files of the modules it loaded.
_PROBE = r"""
import json, sys
from pathlib import Path
resources = Path(sys.argv[1])
before = set(sys.modules)
sys.path.insert(0, str(resources))
name = (resources / "slavemodule.txt").read_text().strip()
module = __import__(name)
classes = [v for v in vars(module).values()
           if isinstance(v, type) and v.__module__ == name and hasattr(v, "do_step")]
slave = classes[0](instance_name="probe", resources=str(resources))
experiment = getattr(slave, "default_experiment", None)
h = float(getattr(experiment, "step_size", None) or 0.01)
slave.setup_experiment(0.0)
slave.enter_initialization_mode()
slave.exit_initialization_mode()
for k in range(20):
    slave.do_step(k * h, h)
files = sorted({getattr(m, "__file__", None) or "" for n, m in list(sys.modules.items())
                if n not in before})
print(json.dumps([f for f in files if f]))
"""


def imported_files(fmu_path: str | Path) -> list[Path]:
    """Files of the modules the FMU's slave imports (a child process of this Python)."""
    with tempfile.TemporaryDirectory(prefix="agv_probe_") as tmp:
        with zipfile.ZipFile(fmu_path) as archive:
            archive.extractall(tmp)
        done = subprocess.run([sys.executable, "-c", _PROBE, str(Path(tmp) / "resources")],
                              capture_output=True, text=True, timeout=600)
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or [f"exit code {done.returncode}"])[-1]
        raise StandaloneError(f"{Path(fmu_path).name}: cannot find what its slave imports: "
                              f"{last}")
    return [Path(f) for f in json.loads(done.stdout.strip().splitlines()[-1])]


def _site_packages():
    """The building environment's site-packages folders."""
    return [Path(p).resolve() for p in {sysconfig.get_paths()["purelib"],
                                        sysconfig.get_paths()["platlib"]}]


def needed_distributions(fmu_path: str | Path) -> list[str]:
    """Names of the installed distributions whose modules the FMU's slave imports."""
    sites = _site_packages()
    top_names = set()
    for path in imported_files(fmu_path):
        path = path.resolve()
        for site in sites:
            if site in path.parents:
                top_names.add(path.relative_to(site).parts[0].split(".")[0])
    owners = importlib.metadata.packages_distributions()
    names = set()
    for top in top_names:
        for dist in owners.get(top, ()):
            names.add(dist)
    return sorted(names, key=str.lower)


def distribution_files(name: str) -> list[tuple[Path, str]]:
    """``[(absolute path, path inside site-packages)]`` of an installed distribution, less
    what a run never reads (PACKAGE_EXCLUDED)."""
    dist = importlib.metadata.distribution(name)
    files = []
    for entry in dist.files or ():
        relative = entry.as_posix()
        if relative.startswith("..") or PACKAGE_EXCLUDED.search(relative):
            continue
        path = Path(str(dist.locate_file(entry)))
        if path.is_file():
            files.append((path, relative))
    return files


# ------------------------------------------------------------------------ the runtime
def _python_facts():
    version = sysconfig.get_python_version()
    libdir = Path(sysconfig.get_config_var("LIBDIR") or "")
    soname = sysconfig.get_config_var("INSTSONAME") or f"libpython{version}.so.1.0"
    libpython = libdir / soname
    if not sysconfig.get_config_var("Py_ENABLE_SHARED") or not libpython.is_file():
        raise StandaloneError(f"this Python ({sys.base_prefix}) has no shared library "
                              f"{libpython}: a standalone FMU needs a Python built with "
                              "--enable-shared")
    stdlib = Path(sysconfig.get_paths()["stdlib"])
    return version, libpython, stdlib


def _tool(name):
    found = shutil.which(name) or shutil.which(name, path=str(Path(sys.executable).parent))
    if found is None:
        raise StandaloneError(f"'{name}' is not installed (needed for a standalone build)")
    return found


def _run(command):
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        raise StandaloneError(f"{Path(command[0]).name} failed on {command[-1]}: "
                              + (done.stderr.strip().splitlines() or ["?"])[-1])
    return done.stdout


def _is_elf(path):
    with open(path, "rb") as handle:
        return handle.read(4) == b"\x7fELF"


def _shared_dependencies(paths):
    """Resolved non-system libraries that the ELF files ``paths`` need (``ldd``)."""
    ldd = _tool("ldd")
    found = {}
    for path in paths:
        for line in _run([ldd, str(path)]).splitlines():
            match = re.match(r"\s*(\S+) => (/\S+)", line)
            if match and not SYSTEM_LIBRARIES.match(match.group(1)) and \
                    not match.group(1).startswith("libpython"):
                found[match.group(1)] = Path(match.group(2))
    return found


def build_prefixes() -> list[str]:
    """Paths of this machine's Python that may appear as text in copied files."""
    prefixes = {sys.base_prefix, sys.base_exec_prefix, os.path.realpath(sys.base_prefix),
                sys.prefix,
                sysconfig.get_config_var("prefix") or "", sysconfig.get_config_var("LIBDIR")
                or "", sysconfig.get_config_var("abs_builddir") or "",
                sysconfig.get_config_var("abs_srcdir") or ""}
    return sorted((p for p in prefixes if len(p) > 4), key=len, reverse=True)


def _neutral(text):
    """``text`` (a path, bytes) with all but its last component overwritten by a neutral
    folder of the same length (/agv-cosim-python/, padded with slashes).

    The last component stays: a linker may store a string that ends a longer one inside it
    (the version "3.11.7" inside ".../versions/3.11.7"), and that string must survive.
    """
    cut = text.rstrip(b"/").rfind(b"/") + 1
    head = b"/agv-cosim-python/"
    return (head + b"/" * max(0, cut - len(head)))[:cut] + text[cut:]


def _scrubbed(data, prefixes):
    """``data`` with every prefix overwritten (:func:`_neutral`, same length)."""
    for prefix in prefixes:
        raw = prefix.encode()
        data = data.replace(raw, _neutral(raw))
    return data


def _scrub(path: Path, prefixes: Iterable[str]) -> None:
    """Overwrite every prefix in file ``path`` (:func:`_scrubbed`)."""
    data = path.read_bytes()
    changed = _scrubbed(data, prefixes)
    if changed != data:
        path.write_bytes(changed)


#: The runtime folders assembled by this process (platform folder -> temporary folder).
_RUNTIMES: dict[str, Path] = {}


def discard_runtimes() -> None:
    """Remove the temporary runtime folders of :func:`runtime_base` (also at exit)."""
    while _RUNTIMES:
        _, root = _RUNTIMES.popitem()
        shutil.rmtree(root, ignore_errors=True)


atexit.register(discard_runtimes)


def runtime_base(platform_dir: str) -> Path:
    """A temporary folder with the runtime less its packages, assembled once per process
    (removed by :func:`discard_runtimes`, which ``build_fmus`` calls when done):
    ``{relative path: absolute file}`` to put under ``binaries/<platform>/python/``."""
    if platform_dir in _RUNTIMES and _RUNTIMES[platform_dir].is_dir():
        return _RUNTIMES[platform_dir]
    version, libpython, stdlib = _python_facts()
    patchelf, strip = _tool("patchelf"), _tool("strip")
    root = Path(tempfile.mkdtemp(prefix="agv_runtime_"))
    try:
        _assemble_runtime(root, version, libpython, stdlib, patchelf, strip)
    except BaseException:
        shutil.rmtree(root, ignore_errors=True)
        raise
    _RUNTIMES[platform_dir] = root
    return root


def _assemble_runtime(root, version, libpython, stdlib, patchelf, strip):
    lib = root / "lib"
    target_stdlib = lib / f"python{version}"
    excluded = {stdlib / part for part in STDLIB_EXCLUDED}
    for path in sorted(stdlib.rglob("*")):
        if path.is_dir() or "__pycache__" in path.parts or path.suffix in (".pyc", ".pyo"):
            continue
        if any(part == path or part in path.parents for part in excluded):
            continue
        relative = path.relative_to(stdlib)
        if relative.parts[0].startswith("config-"):
            continue
        if relative.parts[0] == "lib-dynload" and DYNLOAD_EXCLUDED.match(path.name):
            continue
        target = target_stdlib / relative
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(path, target)
    shutil.copy2(libpython, lib / libpython.name)
    dynload = sorted((target_stdlib / "lib-dynload").glob("*.so"))
    for name, source in _shared_dependencies([libpython, *dynload]).items():
        shutil.copy2(source, lib / name)
    prefixes = build_prefixes()
    for path in lib.glob("lib*.so*"):
        _run([strip, "--strip-unneeded", str(path)])
        _run([patchelf, "--set-rpath", "$ORIGIN", str(path)])
    for path in dynload:
        _run([strip, "--strip-unneeded", str(path)])
        _run([patchelf, "--set-rpath", "$ORIGIN/../..", str(path)])
    for path in root.rglob("*"):
        if path.is_file():
            _scrub(path, prefixes)
    return root


def runtime_files(fmu_path: str | Path, platform_dir: str) -> tuple[dict[str, Path], Any]:
    """``{path inside the FMU: file}`` of the standalone runtime for ``fmu_path``, and the
    distributions shipped (name==version)."""
    base = runtime_base(platform_dir)
    prefix = f"binaries/{platform_dir}/{RUNTIME_FOLDER}/"
    files = {prefix + p.relative_to(base).as_posix(): p
             for p in sorted(base.rglob("*")) if p.is_file()}
    version = sysconfig.get_python_version()
    site = f"{prefix}lib/python{version}/site-packages/"
    shipped = []
    for name in needed_distributions(fmu_path):
        dist = importlib.metadata.distribution(name)
        shipped.append(f"{dist.metadata['Name']}=={dist.version}")
        for path, relative in distribution_files(name):
            files[site + relative] = path
    return files, shipped


def _packaged_bytes(path, prefixes):
    """The bytes to ship for an installed file, build paths scrubbed. Packages' ELF files
    are shipped as installed: wheels come stripped, and ``strip`` breaks libraries that
    auditwheel has patched (measured: numpy's OpenBLAS no longer loads)."""
    return _scrubbed(path.read_bytes(), prefixes)


#: The list of shipped distributions, in the runtime folder.
SHIPPED_LIST = "distributions.txt"


def add_runtime(fmu_path: str | Path, platform_dir: str) -> None:
    """Add the standalone runtime to the FMU at ``fmu_path`` (appended to the archive); the
    distributions shipped (name==version), also listed in the runtime's distributions.txt."""
    files, shipped = runtime_files(fmu_path, platform_dir)
    prefixes = build_prefixes()
    with zipfile.ZipFile(fmu_path, "a", zipfile.ZIP_DEFLATED) as archive:
        present = set(archive.namelist())
        for name in sorted(files):
            if name in present:
                continue
            info = zipfile.ZipInfo(name, date_time=(2020, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = (0o755 if os.access(files[name], os.X_OK) else 0o644) << 16
            archive.writestr(info, _packaged_bytes(files[name], prefixes))
        archive.writestr(f"binaries/{platform_dir}/{RUNTIME_FOLDER}/{SHIPPED_LIST}",
                         "".join(f"{line}\n" for line in shipped))
    return shipped


def environment_tag() -> str:
    """What a standalone FMU's GUID adds: the Python version and every installed
    distribution with its version (no path)."""
    import platform

    names = sorted({f"{d.metadata['Name']}=={d.version}"
                    for d in importlib.metadata.distributions() if d.metadata['Name']})
    return "\n".join([platform.python_version(), *names])
