"""Standalone FMUs: an FMU that carries its own Python runtime (``agv-cosim build --standalone``).

The runtime goes into the FMU beside its binary, as ``binaries/<platform>/python/``:

``lib/libpython3.X.so.1.0``
    the building Python's shared library (it must be built with ``--enable-shared``),
    stripped, its run path ``$ORIGIN``;
``lib/*.so.*``
    the shared libraries that it and the shipped extension modules need beyond the C
    library (libffi, zlib, liblzma, ...; found with ``ldd``), stripped;
``lib/python3.X/``
    the standard-library modules the FMU's slave loads (and the ``encodings`` package),
    its extension modules in ``lib-dynload`` with run path ``$ORIGIN/../..``;
``lib/python3.X/site-packages/``
    of every distribution the FMU's slave imports, the files it loads, opens or maps
    (compiled files as the wheels installed them) and the distribution's metadata.

What the slave uses is found by importing it and running a few steps of its default
experiment in a child process of the building Python (:data:`_PROBE`): the files of the
modules loaded, the files opened (an audit hook) and the shared libraries mapped; every
standard-library module an import statement of the FMU's own sources names is imported
there first, so that an import inside a function the probe does not call is shipped too.

Every Python source shipped (the runtime's and the FMU's ``resources/``) comes with its
bytecode in ``__pycache__``, hash-based and checked (PEP 552: valid whatever time stamps
the extraction gives the files; the runtime is the building Python's version), so that a
run does not compile them first. The FMU declares ``needsExecutionTool="false"`` and holds
no binary of another platform than the runtime's. The FMU loader
(components/fmu_loader/agv_fmu_loader.c) starts this runtime, with ``home`` set to the
folder, when the host process has no Python; a host that has one (fmpy) runs the FMU in
its own interpreter, with this ``site-packages`` appended to ``sys.path`` for what the
host lacks. The runtime is assembled once per build in a temporary folder, removed when
the build ends.

Paths of the building machine are kept out: the run paths are rewritten (patchelf), the
libraries are stripped of debug information, and the building Python's prefix, which
``libpython`` and ``_sysconfigdata`` hold as text, is overwritten with a neutral one of the
same length (a compiled-in fallback that the loader never uses, since it sets ``home``).
"""

import atexit
import importlib.metadata
import importlib.util
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
from importlib import _bootstrap_external
from pathlib import Path

from ..errors import StandaloneError

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
#: resources the way the bridge does, step its default experiment a little, print every
#: file the process used: the files of the modules loaded (those of the interpreter's own
#: start too), the files opened (an audit hook: data files a package reads) and the
#: shared libraries mapped (/proc/self/maps: those an extension module links), with the
#: extension modules the runtime leaves out blocked (argv[2]). Besides,
#: every standard-library module that an import statement of the FMU's own sources names
#: (anywhere, a function's import too) is imported first, so that a call this probe does
#: not make still finds its module.
_PROBE = r"""
import ast, importlib, json, sys
from pathlib import Path
used = set()
def hook(event, args):
    if event in ("open", "ctypes.dlopen") and args and isinstance(args[0], str):
        used.add(args[0])
sys.addaudithook(hook)
resources = Path(sys.argv[1])
for blocked in json.loads(sys.argv[2]):  # not in the runtime: its fallbacks load instead
    sys.modules[blocked] = None
sys.path.insert(0, str(resources))
for source in sorted(resources.rglob("*.py")):
    try:
        tree = ast.parse(source.read_bytes())
    except (SyntaxError, ValueError):
        continue
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        for name in names:
            if name.partition(".")[0] in sys.stdlib_module_names:
                try:
                    importlib.import_module(name)
                except Exception:
                    pass
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
files = {getattr(m, "__file__", None) or "" for m in list(sys.modules.values())}
with open("/proc/self/maps") as maps:
    for line in maps:
        parts = line.split(None, 5)
        if len(parts) == 6 and parts[5].startswith("/"):
            files.add(parts[5].strip())
files |= used
print(json.dumps(sorted(f for f in files if f)))
"""


def imported_files(fmu_path: str | Path) -> list[Path]:
    """Files the FMU's slave uses when it runs: its modules, the files they open and the
    shared libraries they map (:data:`_PROBE`, a child process of this Python)."""
    with tempfile.TemporaryDirectory(prefix="agv_probe_") as tmp:
        with zipfile.ZipFile(fmu_path) as archive:
            archive.extractall(tmp)
        done = subprocess.run([sys.executable, "-c", _PROBE, str(Path(tmp) / "resources"),
                               json.dumps(_left_out_modules())],
                              capture_output=True, text=True, timeout=600)
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or [f"exit code {done.returncode}"])[-1]
        raise StandaloneError(f"{Path(fmu_path).name}: cannot find what its slave imports: "
                              f"{last}")
    return [Path(f) for f in json.loads(done.stdout.strip().splitlines()[-1])]


def _left_out_modules() -> list[str]:
    """Names of the extension modules of lib-dynload that the runtime leaves out
    (:data:`DYNLOAD_EXCLUDED`): the probe runs without them, so that the modules that
    stand in for them are found (hashlib's own md5, sha1, ... without OpenSSL's
    ``_hashlib``)."""
    dynload = Path(sysconfig.get_paths()["stdlib"]) / "lib-dynload"
    return sorted(path.name.split(".")[0] for path in dynload.glob("*.so")
                  if DYNLOAD_EXCLUDED.match(path.name))


def _site_packages() -> list[Path]:
    """The building environment's site-packages folders."""
    return [Path(p).resolve() for p in {sysconfig.get_paths()["purelib"],
                                        sysconfig.get_paths()["platlib"]}]


def needed_distributions(fmu_path: str | Path,
                         used: Iterable[Path] | None = None) -> list[str]:
    """Names of the installed distributions whose modules the FMU's slave imports
    (``used``: :func:`imported_files`, found again when not given)."""
    sites = _site_packages()
    top_names: set[str] = set()
    for path in (imported_files(fmu_path) if used is None else used):
        path = path.resolve()
        for site in sites:
            if site in path.parents:
                top_names.add(path.relative_to(site).parts[0].split(".")[0])
    owners = importlib.metadata.packages_distributions()
    names: set[str] = set()
    for top in top_names:
        for dist in owners.get(top, ()):
            names.add(dist)
    return sorted(names, key=str.lower)


def distribution_files(name: str) -> list[tuple[Path, str]]:
    """``[(absolute path, path inside site-packages)]`` of an installed distribution, less
    what a run never reads (PACKAGE_EXCLUDED)."""
    dist = importlib.metadata.distribution(name)
    files: list[tuple[Path, str]] = []
    for entry in dist.files or ():
        relative = entry.as_posix()
        if relative.startswith("..") or PACKAGE_EXCLUDED.search(relative):
            continue
        path = Path(str(dist.locate_file(entry)))
        if path.is_file():
            files.append((path, relative))
    return files


# ------------------------------------------------------------------------ the runtime
def _python_facts() -> tuple[str, Path, Path]:
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


def _tool(name: str) -> str:
    found = shutil.which(name) or shutil.which(name, path=str(Path(sys.executable).parent))
    if found is None:
        raise StandaloneError(f"'{name}' is not installed (needed for a standalone build)")
    return found


def _run(command: list[str]) -> str:
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        raise StandaloneError(f"{Path(command[0]).name} failed on {command[-1]}: "
                              + (done.stderr.strip().splitlines() or ["?"])[-1])
    return done.stdout


def _shared_dependencies(paths: Iterable[Path]) -> dict[str, Path]:
    """Resolved non-system libraries that the ELF files ``paths`` need (``ldd``)."""
    ldd = _tool("ldd")
    found: dict[str, Path] = {}
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


def _neutral(text: bytes) -> bytes:
    """``text`` (a path, bytes) with all but its last component overwritten by a neutral
    folder of the same length (/agv-cosim-python/, padded with slashes).

    The last component stays: a linker may store a string that ends a longer one inside it
    (the version "3.11.7" inside ".../versions/3.11.7"), and that string must survive.
    """
    cut = text.rstrip(b"/").rfind(b"/") + 1
    head = b"/agv-cosim-python/"
    return (head + b"/" * max(0, cut - len(head)))[:cut] + text[cut:]


def _scrubbed(data: bytes, prefixes: Iterable[str]) -> bytes:
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


#: The runtime folder assembled by this process (empty, or one temporary folder).
_RUNTIMES: list[Path] = []


def discard_runtimes() -> None:
    """Remove the temporary runtime folder of :func:`runtime_base` (also at exit)."""
    while _RUNTIMES:
        shutil.rmtree(_RUNTIMES.pop(), ignore_errors=True)


atexit.register(discard_runtimes)


def runtime_base() -> Path:
    """A temporary folder with the runtime less its packages, assembled once per process
    (removed by :func:`discard_runtimes`, which ``build_fmus`` calls when done): the files
    to put under ``binaries/<platform>/python/`` (the same for every platform folder: the
    runtime is the building Python's)."""
    if _RUNTIMES and _RUNTIMES[0].is_dir():
        return _RUNTIMES[0]
    discard_runtimes()
    version, libpython, stdlib = _python_facts()
    patchelf, strip = _tool("patchelf"), _tool("strip")
    root = Path(tempfile.mkdtemp(prefix="agv_runtime_"))
    try:
        _assemble_runtime(root, version, libpython, stdlib, patchelf, strip)
    except BaseException:
        shutil.rmtree(root, ignore_errors=True)
        raise
    _RUNTIMES.append(root)
    return root


def _assemble_runtime(root: Path, version: str, libpython: Path, stdlib: Path, patchelf: str,
                      strip: str) -> Path:
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


def runtime_files(fmu_path: str | Path, platform_dir: str) -> tuple[dict[str, Path], list[str]]:
    """``{path inside the FMU: file}`` of the standalone runtime for ``fmu_path``, and the
    distributions shipped (name==version).

    Only what the slave uses (:func:`imported_files`): the standard-library modules it
    loads (and the whole ``encodings`` package: the interpreter picks its codecs from the
    locale when it starts), the extension modules of lib-dynload it loads, libpython and
    the libraries these link; of each distribution it imports, the files it loads, opens
    or maps, and the distribution's metadata (``*.dist-info``, less RECORD).
    """
    base = runtime_base()
    prefix = f"binaries/{platform_dir}/{RUNTIME_FOLDER}/"
    version = sysconfig.get_python_version()
    _, libpython, stdlib = _python_facts()
    stdlib = stdlib.resolve()
    base_stdlib = base / "lib" / f"python{version}"
    used = {Path(p).resolve() for p in imported_files(fmu_path)}
    chosen = {p for p in (base_stdlib / "encodings").rglob("*") if p.is_file()}
    dynload: list[Path] = []
    for path in used:
        if not path.is_relative_to(stdlib):
            continue
        relative = path.relative_to(stdlib)
        copy = base_stdlib / relative
        if relative.parts[0] != "site-packages" and copy.is_file():
            chosen.add(copy)
            if relative.parts[0] == "lib-dynload":
                dynload.append(path)
    chosen.add(base / "lib" / libpython.name)
    for name in _shared_dependencies([libpython, *dynload]):
        if (base / "lib" / name).is_file():
            chosen.add(base / "lib" / name)
    files = {prefix + p.relative_to(base).as_posix(): p for p in sorted(chosen)}
    site = f"{prefix}lib/python{version}/site-packages/"
    shipped: list[str] = []
    for name in needed_distributions(fmu_path, used):
        dist = importlib.metadata.distribution(name)
        shipped.append(f"{dist.metadata['Name']}=={dist.version}")
        for installed, inside in distribution_files(name):
            metadata = ".dist-info/" in inside and not inside.endswith("/RECORD")
            if metadata or installed.resolve() in used:
                files[site + inside] = installed
    return files, shipped


def _packaged_bytes(path: Path, prefixes: Iterable[str]) -> bytes:
    """The bytes to ship for an installed file, build paths scrubbed. Packages' ELF files
    are shipped as installed: wheels come stripped, and ``strip`` breaks libraries that
    auditwheel has patched (measured: numpy's OpenBLAS no longer loads)."""
    return _scrubbed(path.read_bytes(), prefixes)


#: The list of shipped distributions, in the runtime folder.
SHIPPED_LIST = "distributions.txt"


def _bytecode(source: bytes, name: str) -> bytes | None:
    """The ``.pyc`` of ``source`` (compiled by this Python, which is the runtime's):
    hash-based and checked (PEP 552), so that it stays valid whatever time stamps the
    extracted files get; None when it does not compile. ``name`` (the file's path inside
    the FMU) is the code's file name until the import system sets the real one."""
    try:
        code = compile(source, name, "exec", dont_inherit=True, optimize=0)
    except (SyntaxError, ValueError):
        return None
    return bytes(_bootstrap_external._code_to_hash_pyc(  # type: ignore[attr-defined]
        code, importlib.util.source_hash(source), checked=True))


def _cached_name(name: str) -> str:
    """Where the import system looks for the bytecode of the source ``name``."""
    folder, _, file = name.rpartition("/")
    cached = f"__pycache__/{file[:-3]}.{sys.implementation.cache_tag}.pyc"
    return f"{folder}/{cached}" if folder else cached


def add_runtime(fmu_path: str | Path, platform_dir: str) -> list[str]:
    """Make the FMU at ``fmu_path`` standalone: add the runtime (:func:`runtime_files`)
    and the bytecode of every Python source it holds (the runtime's and the FMU's own
    resources), drop the binaries of other platforms (the runtime is this platform's) and
    declare ``needsExecutionTool="false"`` (the build passes that to pythonfmu). Returns
    the distributions shipped (name==version), also listed in the runtime's
    distributions.txt."""
    files, shipped = runtime_files(fmu_path, platform_dir)
    prefixes = build_prefixes()
    rewritten = Path(fmu_path).with_suffix(".standalone")
    with zipfile.ZipFile(fmu_path) as source, \
            zipfile.ZipFile(rewritten, "w", zipfile.ZIP_DEFLATED) as archive:
        for info in source.infolist():
            if info.filename.startswith("binaries/") and \
                    not info.filename.startswith(f"binaries/{platform_dir}/"):
                continue
            data = source.read(info)
            archive.writestr(info, data)
            if info.filename.startswith("resources/") and info.filename.endswith(".py"):
                compiled = _bytecode(data, info.filename)
                if compiled is not None:
                    _write_member(archive, _cached_name(info.filename), compiled, 0o644)
        present = set(source.namelist())
        for name in sorted(files):
            if name in present:
                continue
            data = _packaged_bytes(files[name], prefixes)
            mode = 0o755 if os.access(files[name], os.X_OK) else 0o644
            _write_member(archive, name, data, mode)
            if name.endswith(".py"):
                compiled = _bytecode(data, name)
                if compiled is not None:
                    _write_member(archive, _cached_name(name), compiled, 0o644)
        archive.writestr(f"binaries/{platform_dir}/{RUNTIME_FOLDER}/{SHIPPED_LIST}",
                         "".join(f"{line}\n" for line in shipped))
    rewritten.replace(fmu_path)
    return shipped


def _write_member(archive: zipfile.ZipFile, name: str, data: bytes, mode: int) -> None:
    info = zipfile.ZipInfo(name, date_time=(2020, 1, 1, 0, 0, 0))
    info.compress_type = zipfile.ZIP_DEFLATED
    info.external_attr = mode << 16
    archive.writestr(info, data)


def environment_tag() -> str:
    """What a standalone FMU's GUID adds: the Python version and every installed
    distribution with its version (no path)."""
    import platform

    names = sorted({f"{d.metadata['Name']}=={d.version}"
                    for d in importlib.metadata.distributions() if d.metadata['Name']})
    return "\n".join([platform.python_version(), *names])
