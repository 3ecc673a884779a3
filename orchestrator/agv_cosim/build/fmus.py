"""Build the component FMUs from the slave scripts in ``components/agv_core/<component>/``.

A slave script is a module named ``agv_*.py`` in a component folder of ``agv_core`` (one
folder per component: its core, its slave scripts, its README and reference result; see
components/README.md). Each FMU bundles its slave script, the boot loader
``agv_core/fmi/agv_boot.py`` (at the top of ``resources/``) and the part of the ``agv_core``
package that the script reaches (its modules and package ``__init__`` files, tagged with a
content hash in ``agv_core_bundle/BUILD_ID``), a ``requirements.txt`` that pins the Python
distributions that code imports (both derived from the imports: agv_cosim/build/bundle.py), and
``agv_build.json`` with a GUID derived from every source that goes into the FMU. A rebuild
with unchanged sources is skipped (the FMU's GUID already matches, computed with the
requirement list the FMU ships as long as exactly those versions are installed), and a
built FMU that ``fmpy.validation`` finds fault with fails the build.

The out folder's ``build-index.json`` records each FMU this command wrote there and the
hash of its bytes; only such an FMU, unchanged, is replaced (:func:`check_replaceable`):
a user's file or a symbolic link at an FMU's place is refused (OutputError, before
anything is built). Each FMU is written as a new file (O_EXCL | O_NOFOLLOW) beside its
place and renamed onto it, as ``run`` writes its files.

pythonfmu writes the model description; its Linux binary is not shipped. The build
compiles ``components/fmu_loader/agv_fmu_loader.c`` (the loader: finds or starts a
Python, no Python symbol of its own) and ``agv_fmu_bridge.c`` (the FMI 2.0 and 3.0 C API
over the Python slave) with gcc, the build Python's headers and fmpy's FMI headers, from a
temporary folder, and puts them into each FMU as ``binaries/<platform>/<modelIdentifier>.so``
and ``<modelIdentifier>.bridge.so`` (see the C sources for how a Python is found). Neither
holds a path of this machine; the GUID hashes contents only. ``standalone=True`` adds a
Python runtime (agv_cosim.build.standalone).

``fmi_version=3`` builds the FMI 3.0 twin of each slave script with pythonfmu3 instead
(``agv-cosim build --fmi 3``): the same slave script and core, run on the FMI 3.0 adapter
``agv_core/fmi/fmi3_slave.py``. pythonfmu3 takes the slave class from a ``class`` line that
names ``Fmi3Slave``, so the build bundles the slave script unchanged under the name
``<stem>_fmi3_body.py`` and writes a two-line wrapper script ``<stem>_fmi3.py`` whose class
derives from the script's class and names ``Fmi3Slave``. The bundled ``agv_core`` has
``fmi/fmi_slave.py`` as an alias of ``fmi/fmi3_slave.py`` (and a BUILD_ID of its own), so
the script's ``core.fmi.fmi_slave.AgvSlave`` is the FMI 3.0 adapter. FMI 3.0 twins get the
same loader and bridge as the FMI 2.0 FMUs.
"""

import ast
import errno
import functools
import hashlib
import json
import os
import shutil
import stat
import subprocess
import sys
import sysconfig
import tempfile
import uuid
import zipfile
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

import pythonfmu
from pythonfmu.builder import FmuBuilder

from ..errors import BuildError, BundleError, OutputError, did_you_mean
from ..files import create_beside
from .bundle import Bundle, Requirements, bundle_of, installed_requirements, requirements_text
from .shipped import shipped_dir

__all__ = ["BOOT_SCRIPT", "BOOT_SOURCE", "BRIDGE_SOURCE", "BRIDGE_SUFFIX", "BUILD_FORMAT",
           "BUNDLE_FOLDER", "FMI3_ALIAS", "FMI3_BODY_SUFFIX", "FMI3_WRAPPER_SUFFIX",
           "FMI_VERSIONS", "INDEX_FILE", "LOADER_SOURCE", "RECORD_FORMAT", "REFERENCE_DIR",
           "REFERENCE_MANIFEST", "SLAVE_PATTERN", "BuildError", "BuildResult",
           "build_fmus", "build_one", "check_replaceable", "component_scripts",
           "default_components_dir", "fmi3_wrapper_source", "fmu_guid", "fmu_guid_of",
           "host_python", "loader_binary", "read_record", "reference_experiment",
           "reference_input_rows", "simulate_reference", "slave_class_name",
           "slave_script", "slave_scripts"]

#: The folder in resources/ that holds the bundled part of agv_core (agv_boot.py).
BUNDLE_FOLDER = "agv_core_bundle"

#: Bumped whenever the way an FMU is assembled changes, so every FMU is rebuilt.
BUILD_FORMAT = 5

BOOT_SCRIPT = "agv_boot.py"
#: Where the boot loader lives, relative to ``components/``.
BOOT_SOURCE = Path("agv_core") / "fmi" / BOOT_SCRIPT
#: Slave scripts (and the boot loader) are the ``agv_*.py`` files of ``agv_core``: they run
#: as top-level modules of an FMU, never as part of the bundled package.
SLAVE_PATTERN = "agv_*.py"
LOADER_SOURCE = Path("fmu_loader") / "agv_fmu_loader.c"
#: The bridge's source, beside the loader's.
BRIDGE_SOURCE = "agv_fmu_bridge.c"
#: The bridge is shipped under this suffix beside the loader.
BRIDGE_SUFFIX = ".bridge.so"
INDEX_FILE = "build-index.json"

#: FMI versions ``build_fmus`` can write.
FMI_VERSIONS = (2, 3)
#: Suffixes of the generated FMI 3.0 wrapper script and of the bundled slave script.
FMI3_WRAPPER_SUFFIX = "_fmi3"
FMI3_BODY_SUFFIX = "_fmi3_body"
#: The FMI 3.0 bundle's ``agv_core/fmi/fmi_slave.py``: the FMI 3.0 adapter under the FMI 2.0
#: name.
FMI3_ALIAS = ('"""In FMI 3.0 twins agv_core.fmi.fmi_slave is the FMI 3.0 adapter '
              '(written by agv-cosim build)."""\n\n'
              "from .fmi3_slave import *  # noqa: F401,F403\n"
              "from .fmi3_slave import AgvSlave, DefaultExperiment  # noqa: F401\n")


@dataclass(frozen=True)
class BuildResult:
    """What :func:`build_fmus` did for one slave script."""

    script: Path
    fmu: Path
    guid: str
    rebuilt: bool


def default_components_dir() -> Path:
    """``components/`` of the checkout this package is installed from (editable install)."""
    import agv_core

    return Path(agv_core.__file__).resolve().parent.parent


def slave_scripts(components_dir: str | Path) -> list[Path]:
    """The slave scripts of every component folder ``components_dir/agv_core/<component>/``.

    Every ``agv_*.py`` there but the boot loader, sorted by file name (the file name is the
    slave's module name in a host process, so it is unique across components).
    """
    core = Path(components_dir) / "agv_core"
    if not core.is_dir():
        raise BuildError(f"no slave scripts: '{core}' is not a folder")
    scripts = sorted((p for p in core.glob(f"*/{SLAVE_PATTERN}") if p.name != BOOT_SCRIPT),
                     key=lambda p: p.name)
    names = [p.name for p in scripts]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise BuildError(f"slave script names must be unique: {', '.join(twice)}")
    return scripts


def slave_script(stem: str, components_dir: str | Path | None = None) -> Path:
    """The slave script named ``stem`` (e.g. ``"agv_vehicle"``), in whichever component folder."""
    for script in slave_scripts(components_dir or default_components_dir()):
        if script.stem == stem:
            return script
    raise BuildError(f"no slave script named '{stem}.py'")


def host_python() -> dict[str, Any]:
    """What the building Python says about itself, as a dict (nothing of it goes into an FMU
    but ``version``).

    ``version`` is ``major.minor`` (the FMUs' binaries are compiled for it and start only a
    Python of that version); ``executable`` the building interpreter as invoked (a venv's
    ``bin/python`` keeps its site-packages); ``libpython`` its shared library (``sysconfig``
    LIBDIR and INSTSONAME, which may not exist: a Python built without --enable-shared).
    """
    libdir = sysconfig.get_config_var("LIBDIR") or ""
    soname = (sysconfig.get_config_var("INSTSONAME")
              or f"libpython{sysconfig.get_python_version()}.so.1.0")
    return {"version": sysconfig.get_python_version(), "executable": sys.executable,
            "libpython": str(Path(libdir) / soname)}


def _binary_sources() -> dict[str, str]:
    """The C sources of the FMU binary: ``{file name: text}`` (the loader and the bridge)."""
    folder = shipped_dir("fmu_loader")
    return {name: (folder / name).read_text() for name in (LOADER_SOURCE.name, BRIDGE_SOURCE)}


@functools.lru_cache(maxsize=4)
def _compile_binaries(sources: tuple[tuple[str, str], ...], python_include: str
                      ) -> tuple[bytes, bytes]:
    """Compile the loader and the bridge; ``(loader bytes, bridge bytes)``.

    ``sources`` is ``_binary_sources()`` as a tuple of items. Neither binary holds a path of
    this machine: both are compiled from a temporary folder, with the Python headers (types
    and version only; the bridge's Python symbols stay undefined, the loader uses none) and
    fmpy's FMI headers, ``-ffile-prefix-map`` maps these folders away and ``-DNDEBUG``
    leaves out the headers' assertions (which would name the header files).
    """
    import fmpy

    compiler = shutil.which("gcc") or shutil.which("cc")
    if compiler is None:
        raise BuildError("cannot build the FMU binaries: no C compiler (gcc) on PATH")
    fmi_headers = Path(fmpy.__file__).parent / "c-code"
    built: list[bytes] = []
    with tempfile.TemporaryDirectory(prefix="agv_loader_") as tmp:
        for name, text in sources:
            (Path(tmp) / name).write_text(text)
        for name, libraries in ((LOADER_SOURCE.name, ["-ldl", "-lpthread"]),
                                (BRIDGE_SOURCE, ["-lpthread"])):
            target = Path(tmp) / (Path(name).stem + ".so")
            command = [compiler, "-shared", "-fPIC", "-O2", "-Wall", "-g0", "-s", "-DNDEBUG",
                       f"-ffile-prefix-map={tmp}=.",
                       f"-ffile-prefix-map={python_include}=python",
                       f"-ffile-prefix-map={fmi_headers}=fmi", f"-I{python_include}",
                       f"-I{fmi_headers}", "-o", str(target), str(Path(tmp) / name),
                       *libraries]
            done = subprocess.run(command, capture_output=True, text=True, cwd=tmp)
            if done.returncode != 0:
                raise BuildError(f"cannot build the FMU binary {name}: "
                                 + (done.stderr.strip().splitlines() or ["gcc failed"])[-1])
            built.append(target.read_bytes())
    loader, bridge = built
    return loader, bridge


def loader_binary() -> tuple[bytes, bytes]:
    """``(loader, bridge)``: the FMU binaries compiled for the building Python's version
    (cached per process)."""
    return _compile_binaries(tuple(sorted(_binary_sources().items())),
                             sysconfig.get_paths()["include"])


def _install_loader(fmu_path: Path, binaries: tuple[bytes, bytes], fmi_version: int = 2) -> None:
    """Put the loader in the FMU as its Linux binary and the bridge beside it; pythonfmu's
    own Linux library is left out (the bridge takes its place)."""
    loader, bridge = binaries
    with zipfile.ZipFile(fmu_path) as archive:
        entries = [(info, archive.read(info)) for info in archive.infolist()]
    identifier = _model_description(fmu_path).coSimulation.modelIdentifier
    platform_dir = "x86_64-linux" if fmi_version == 3 else "linux64"
    binary = f"binaries/{platform_dir}/{identifier}.so"
    if binary not in {info.filename for info, _ in entries}:
        raise BuildError(f"{fmu_path.name}: the FMI library wrote no {binary}")
    rewritten = fmu_path.with_suffix(".loader")
    with zipfile.ZipFile(rewritten, "w", zipfile.ZIP_DEFLATED) as archive:
        for info, data in entries:
            if info.filename == binary:
                archive.writestr(binary, loader)
                archive.writestr(binary[:-3] + BRIDGE_SUFFIX, bridge)
            else:
                archive.writestr(info, data)
    rewritten.replace(fmu_path)


REFERENCE_DIR = "extra/org.fmi-standard.fmi-ls-ref"
REFERENCE_MANIFEST = """<?xml version="1.0" encoding="UTF-8"?>
<fmiReferences
    xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance"
    xmlns:fmi-ls="http://fmi-standard.org/fmi-ls-manifest"
    fmi-ls:fmi-ls-name="org.fmi-standard.fmi-ls-ref"
    fmi-ls:fmi-ls-version="1.0.0-alpha.1">
{related}</fmiReferences>
"""


def reference_experiment(model_description_xml: str | bytes) -> dict[str, Any] | None:
    """The reference experiment an FMU declares, or None if it declares none.

    Returns ``{"start", "stop", "step", "inputs"}`` from ``DefaultExperiment`` and the
    ``org.agv-cosim`` vendor annotation the slave adapter writes from its
    ``reference_inputs`` (input name -> [(time, value held from that time), ...]).
    ElementTree, not fmpy: fmpy 0.3.32 does not read vendor annotations.
    """
    root = ElementTree.fromstring(model_description_xml)
    experiment = root.find("DefaultExperiment")
    if experiment is None:
        return None
    try:
        start = float(experiment.get("startTime", "0"))
        stop = float(experiment.get("stopTime"))  # type: ignore[arg-type]  # None: TypeError
        step = float(experiment.get("stepSize"))  # type: ignore[arg-type]  # None: TypeError
    except (TypeError, ValueError):
        raise BuildError("DefaultExperiment needs numeric startTime, stopTime and "
                         "stepSize") from None
    inputs = {}
    nodes = root.iterfind("VendorAnnotations/Tool[@name='org.agv-cosim']/"  # FMI 2.0
                          "ReferenceInputs/Input")
    if root.get("fmiVersion", "").startswith("3"):
        nodes = root.iterfind("Annotations/Annotation[@type='org.agv-cosim']/"
                              "ReferenceInputs/Input")
    for node in nodes:
        inputs[node.get("name")] = [(float(h.get("time")),  # type: ignore[arg-type]
                                     float(h.get("value")))  # type: ignore[arg-type]
                                    for h in node.iterfind("Hold")]
    return {"start": start, "stop": stop, "step": step, "inputs": inputs}


def reference_input_rows(experiment: dict[str, Any]
                         ) -> tuple[list[str], list[tuple[float, ...]]]:
    """Rows (time, value per input) of the held inputs: a step is two rows at one time."""
    names = list(experiment["inputs"])
    start, stop = experiment["start"], experiment["stop"]

    def held(name: str, t: float) -> float:
        value: float = [v for time, v in experiment["inputs"][name] if time <= t][-1]
        return value

    rows = [(start, *(held(n, start) for n in names))]
    steps = sorted({t for n in names for t, _ in experiment["inputs"][n] if start < t < stop})
    for t in steps:
        rows.append((t, *rows[-1][1:]))  # the values up to the step
        rows.append((t, *(held(n, t) for n in names)))
    rows.append((stop, *rows[-1][1:]))
    return names, rows


def _csv(header: list[str], rows: Iterable[Iterable[float]]) -> str:
    lines = [",".join(header)]
    lines += [",".join(repr(float(x)) for x in row) for row in rows]
    return "\n".join(lines) + "\n"


def simulate_reference(fmu_path: str | Path, input_csv: str | Path | None,
                       output_csv: str | Path) -> None:
    """Run an FMU's reference experiment with fmpy; write its Real outputs as CSV.

    The build calls this in a child process (pythonfmu loads a slave module once per
    process, so a build must not run the FMUs it builds in its own process).
    """
    import fmpy
    from fmpy.util import read_csv

    with zipfile.ZipFile(fmu_path) as archive:
        experiment = reference_experiment(archive.read("modelDescription.xml"))
    assert experiment is not None, f"{fmu_path}: no DefaultExperiment"
    md = fmpy.read_model_description(str(fmu_path))
    outputs = [v.name for v in md.modelVariables
               if v.causality == "output" and v.type in ("Real", "Float64")]
    signals = read_csv(input_csv) if input_csv else None
    errors: list[str] = []

    # FMI 2.0: (env, instance, status, category, message); FMI 3.0: no instance
    def logger(*args: Any) -> None:
        status, message = args[-3], args[-1]
        if status >= 3:  # error, fatal
            errors.append(message.decode(errors="replace").strip())

    try:
        result = fmpy.simulate_fmu(str(fmu_path), start_time=experiment["start"],
                                   stop_time=experiment["stop"],
                                   step_size=experiment["step"],
                                   output_interval=experiment["step"], input=signals,
                                   output=outputs, debug_logging=True, logger=logger)
    except Exception as error:  # noqa: BLE001 - re-raised with the FMU's own message
        reason = errors[0].splitlines()[0] if errors else str(error)
        raise SystemExit(f"{type(error).__name__}: {error} ({reason})") from None
    rows = zip(*(result[name] for name in ["time", *outputs]))
    Path(output_csv).write_text(_csv(["time", *outputs], rows))


def _ship_reference(fmu_path: Path) -> None:
    """Run the FMU's reference experiment and put it in the FMU (fmi-ls-ref layout)."""
    with zipfile.ZipFile(fmu_path) as archive:
        md_xml = archive.read("modelDescription.xml")
    experiment = reference_experiment(md_xml)
    if experiment is None:
        return
    model = _model_description(fmu_path).modelName
    files = {}
    with tempfile.TemporaryDirectory(prefix="agv_ref_") as tmp:
        in_csv = None
        related = []
        if experiment["inputs"]:
            names, rows = reference_input_rows(experiment)
            in_csv = Path(tmp) / f"{model}_in.csv"
            in_csv.write_text(_csv(["time", *names], rows))
            files[in_csv.name] = in_csv.read_bytes()
            related.append(f'    <Related type="text/csv" source="{in_csv.name}" role="input" '
                           'description="Inputs of the default experiment (held)"/>\n')
        out_csv = Path(tmp) / f"{model}_out.csv"
        code = ("import sys; from agv_cosim.build import simulate_reference; "
                "simulate_reference(sys.argv[1], sys.argv[2] or None, sys.argv[3])")
        done = subprocess.run([sys.executable, "-c", code, str(fmu_path),
                               str(in_csv or ""), str(out_csv)],
                              capture_output=True, text=True, timeout=600)
        if done.returncode != 0:
            last = (done.stderr.strip().splitlines() or [f"exit code {done.returncode}"])[-1]
            raise BuildError(f"{fmu_path.name}: its default experiment failed: {last}")
        files[out_csv.name] = out_csv.read_bytes()
        related.append(f'    <Related type="text/csv" source="{out_csv.name}" role="result" '
                       'description="Output of the default experiment"/>\n')
    files["fmi-ls-manifest.xml"] = REFERENCE_MANIFEST.format(related="".join(related)).encode()
    with zipfile.ZipFile(fmu_path, "a", zipfile.ZIP_DEFLATED) as archive:
        for name, data in files.items():
            archive.writestr(f"{REFERENCE_DIR}/{name}", data)


def fmu_guid(script: Path, boot: Path, tag: str, fmi_version: int = 2,
             standalone: bool = False) -> str:
    """GUID of the FMU built from ``script``: a hash of all its sources and the tool chain
    (content only: the same sources give the same GUID wherever they are built)."""
    digest = hashlib.sha256()
    parts = [script.name.encode(), script.read_bytes(), boot.read_bytes(), tag.encode(),
             pythonfmu.__version__.encode(), str(BUILD_FORMAT).encode(),
             host_python()["version"].encode()]
    parts += [text.encode() for _, text in sorted(_binary_sources().items())]
    if fmi_version == 3:  # FMI 2.0 GUIDs stay as they were
        import pythonfmu3

        parts += [b"fmi3", pythonfmu3.__version__.encode(), FMI3_ALIAS.encode()]
    if standalone:
        from . import standalone as assembly
        from .standalone import environment_tag

        parts += [b"standalone", environment_tag().encode(),
                  Path(assembly.__file__).read_bytes()]
    for part in parts:
        digest.update(part + b"\0")
    return str(uuid.UUID(digest.hexdigest()[:32]))


def _model_description(fmu_path: str | Path) -> Any:
    """fmpy's reading of an FMU's model description (no schema check: the build checks
    a new FMU with fmpy's ``validate_fmu``)."""
    from fmpy import read_model_description

    return read_model_description(str(fmu_path), validate=False)


def fmu_guid_of(fmu_path: str | Path) -> str | None:
    """The GUID (FMI 2.0) or instantiationToken (FMI 3.0, fmpy's ``guid`` too) in an
    existing FMU's ``modelDescription.xml``, or None if unreadable."""
    try:
        return _model_description(fmu_path).guid or None
    except Exception:  # noqa: BLE001 - fmpy raises plain Exception too; then rebuild
        return None


def slave_class_name(script: str | Path) -> str:
    """Name of the one top-level class a slave script defines (BuildError otherwise)."""
    try:
        tree = ast.parse(Path(script).read_text(), filename=str(script))
    except SyntaxError as error:
        raise BuildError(f"{Path(script).name}: {error}") from None
    names = [node.name for node in tree.body if isinstance(node, ast.ClassDef)]
    if len(names) != 1:
        raise BuildError(f"{Path(script).name}: a slave script defines exactly one class "
                         f"at top level, found {len(names)}")
    return names[0]


def fmi3_wrapper_source(script: Path) -> str:
    """Source of the FMI 3.0 wrapper script of ``script`` (see the module docstring).

    If the body cannot be imported (e.g. a package of requirements.txt missing from the
    Python that runs the FMU), the wrapper still defines the slave class, whose
    construction raises saying why (naming a missing module): pythonfmu3 0.3.4 reports that as an
    error of fmi3InstantiateCoSimulation, where a slave module that fails to import
    makes it dereference a null class (the host dies with SIGSEGV).
    """
    name = slave_class_name(script)
    body = script.stem + FMI3_BODY_SUFFIX
    return (f'"""FMI 3.0 twin of the slave script {script.name}, written by '
            "'agv-cosim build --fmi 3'.\n\n"
            "pythonfmu3 takes the slave class from a class line naming Fmi3Slave; the class\n"
            f"body is {script.name}'s, bundled beside this file as {body}.py, whose\n"
            "core.fmi.fmi_slave is the FMI 3.0 adapter (agv_core/fmi/fmi3_slave.py) in this\n"
            "FMU. If the body cannot be imported, constructing the class raises why.\n"
            '"""\n\n'
            "from pythonfmu3 import Fmi3Slave\n\n"
            "try:\n"
            f"    from {body} import {name} as _Body\n"
            "except Exception as _error:  # noqa: BLE001 - raised again when instantiated\n"
            '    _REASON = f"{type(_error).__name__}: {_error}"\n\n'
            "    class _Body:\n"
            '        """Stands in for the slave class, whose code could not be loaded."""\n\n'
            "        def __init__(self, **kwargs):\n"
            f'            raise ImportError(f"{name}: cannot load its code: {{_REASON}} '
            "(a module missing? install the packages of this FMU's resources/requirements.txt "
            'in the Python that runs it)")\n\n\n'
            f"class {name}(_Body, Fmi3Slave):\n"
            "    __doc__ = _Body.__doc__\n")


def _bundle(script: Path, core_dir: Path, boot: Path, fmi_version: int,
            requirements: Requirements | None = None) -> Bundle:
    """The part of ``agv_core`` the FMU of ``script`` ships, and its requirements
    (agv_cosim.build.bundle); ``requirements`` as there."""
    overrides = (("fmi/fmi_slave.py", FMI3_ALIAS),) if fmi_version == 3 else ()
    try:
        return bundle_of(script, core_dir, overrides, extra_sources=[boot],
                         local=[script.stem + FMI3_WRAPPER_SUFFIX,
                                script.stem + FMI3_BODY_SUFFIX],
                         shipped=["pythonfmu3" if fmi_version == 3 else "pythonfmu"],
                         requirements=requirements)
    except BundleError as error:
        raise BuildError(f"{script.name}: {error}") from None


def _shipped_requirements(fmu_path: Path) -> Requirements | None:
    """The requirements of a built FMU, if still what this Python has installed."""
    try:
        with zipfile.ZipFile(fmu_path) as archive:
            text = archive.read("resources/requirements.txt").decode()
    except (OSError, KeyError, zipfile.BadZipFile, UnicodeDecodeError):
        return None
    return installed_requirements(text)


def _stage(script: Path, core_dir: Path, boot: Path, tag: str, guid: str, stage_dir: Path,
           bundle: Bundle, fmi_version: int = 2) -> tuple[Path, list[Path]]:
    """Stage the FMU's files (``bundle``: what :func:`_bundle` says the FMU ships); return
    (the script to build from, the project files)."""
    if fmi_version == 3:
        staged_script = stage_dir / f"{script.stem}{FMI3_WRAPPER_SUFFIX}.py"
        staged_script.write_text(fmi3_wrapper_source(script))
        shutil.copy2(script, stage_dir / f"{script.stem}{FMI3_BODY_SUFFIX}.py")
        extra = [stage_dir / f"{script.stem}{FMI3_BODY_SUFFIX}.py"]
    else:
        staged_script = stage_dir / script.name
        shutil.copy2(script, staged_script)
        extra = []
    shutil.copy2(boot, stage_dir / BOOT_SCRIPT)
    core_copy = stage_dir / BUNDLE_FOLDER
    for relative in bundle.files:
        target = core_copy / relative
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(core_dir / relative, target)
    if fmi_version == 3:
        (core_copy / "fmi" / "fmi_slave.py").write_text(FMI3_ALIAS)
    (core_copy / "BUILD_ID").write_text(tag + "\n")
    info = {"guid": guid, "core_tag": tag, "script": script.name,
            "pythonfmu": pythonfmu.__version__, "build_format": BUILD_FORMAT,
            "python_version": host_python()["version"]}
    if fmi_version == 3:
        import pythonfmu3

        info.update(fmi_version=3, pythonfmu3=pythonfmu3.__version__)
    (stage_dir / "agv_build.json").write_text(json.dumps(info, indent=1) + "\n")
    (stage_dir / "requirements.txt").write_text(requirements_text(bundle.direct,
                                                                  bundle.indirect))
    return staged_script, [core_copy, stage_dir / BOOT_SCRIPT, stage_dir / "agv_build.json",
                           stage_dir / "requirements.txt", *extra]


def _validate(fmu_path: Path, fmi_version: int = 2) -> None:
    from fmpy.validation import validate_fmu

    problems = validate_fmu(str(fmu_path))
    if problems:
        raise BuildError(f"{fmu_path.name} is not valid FMI {fmi_version}.0: "
                         + "; ".join(problems))


def _fmi_version_of(fmu_path: Path) -> str | None:
    """The fmiVersion an existing FMU declares, or None if unreadable.

    ElementTree, not fmpy: fmpy 0.3.32 refuses a version it does not know (and this FMU
    must then still not be overwritten).
    """
    try:
        with zipfile.ZipFile(fmu_path) as archive:
            return ElementTree.fromstring(archive.read("modelDescription.xml")).get(
                "fmiVersion")
    except (OSError, KeyError, zipfile.BadZipFile, ElementTree.ParseError):
        return None


# ------------------------------------------------------------------------ the build record
#: What ``build`` keeps in its out folder (:data:`INDEX_FILE`): slave script name ->
#: ``{"fmu": file name, "sha256": [hash of the FMU's bytes, ...]}``, one entry per FMU this
#: command wrote there. During a replacement both the old and the new hash are listed, so
#: a build killed between the rename and the record's update still knows its file. A
#: record of an earlier format names the FMU only (``script -> file name``): the file is
#: then taken as built here when it is an FMU of agv-cosim build of that script.
RECORD_FORMAT = 2


def _recorded_name(entry: Any) -> str | None:
    if isinstance(entry, str):
        return entry
    if isinstance(entry, dict) and isinstance(entry.get("fmu"), str):
        return str(entry["fmu"])
    return None


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as stream:
        for block in iter(lambda: stream.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _regular(path: Path) -> os.stat_result | None:
    """``path``'s lstat if it is a regular file (not a symbolic link), else None."""
    try:
        info = os.lstat(path)
    except FileNotFoundError:
        return None
    return info if stat.S_ISREG(info.st_mode) else None


def _built_here(path: Path, script_name: str, entry: Any) -> bool:
    """True when ``path`` is the regular file the record ``entry`` of ``script_name``
    says this command wrote (its hash listed; for an entry of the earlier format: an
    FMU of agv-cosim build of that script)."""
    if _regular(path) is None or _recorded_name(entry) != path.name:
        return False
    if isinstance(entry, dict):
        hashes = entry.get("sha256")
        return isinstance(hashes, list) and _sha256(path) in hashes
    try:
        with zipfile.ZipFile(path) as archive:
            info = json.loads(archive.read("resources/agv_build.json"))
    except (OSError, KeyError, ValueError, zipfile.BadZipFile):
        return False
    return isinstance(info, dict) and info.get("script") == script_name


def read_record(out_dir: str | Path) -> dict[str, Any]:
    """The build record in ``out_dir`` (empty when there is none); OutputError when the
    file at its place is a link, not a regular file, or not a record of this command."""
    path = Path(out_dir) / INDEX_FILE
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        return {}
    except OSError as error:
        if error.errno == errno.ELOOP:
            raise OutputError(f"{path}: is a symbolic link, not the build record of agv-cosim "
                              "build; refusing to use it (choose another --out)") from None
        raise OutputError(f"{path}: cannot read the build record: {error.strerror}") from None
    try:
        with os.fdopen(fd, "rb") as stream:
            if not stat.S_ISREG(os.fstat(stream.fileno()).st_mode):
                raise ValueError
            data = json.loads(stream.read(1 << 22).decode("utf-8"))
        if not isinstance(data, dict) or not all(
                isinstance(k, str) and _recorded_name(v) is not None for k, v in data.items()):
            raise ValueError
    except (ValueError, OSError):
        raise OutputError(f"{path}: not a build record of agv-cosim build; refusing to "
                          "replace it (choose another --out)") from None
    return data


def _write_record(out_dir: Path, index: dict[str, Any]) -> None:
    """Write the build record whole (a new file of ours renamed in); never through a
    link or over a file that is not a record (read_record refused that first)."""
    path = out_dir / INDEX_FILE
    if os.path.lexists(path) and _regular(path) is None:
        raise OutputError(f"{path}: is not a regular file; refusing to replace it")
    temporary, stream = create_beside(path)
    try:
        with stream:
            stream.write((json.dumps(index, indent=1, sort_keys=True) + "\n").encode())
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise


def check_replaceable(target: Path, index: dict[str, Any]) -> None:
    """OutputError (naming ``target``) unless ``target`` is missing or an FMU this
    command wrote there (the record says so and the file is unchanged since)."""
    if not os.path.lexists(target):
        return
    if os.path.islink(target):
        raise OutputError(f"{target}: is a symbolic link, not an FMU agv-cosim build wrote "
                          "here; refusing to replace it (move it away or choose another "
                          "--out)")
    if _regular(target) is None:
        raise OutputError(f"{target}: exists and is not a file; refusing to replace it")
    if not any(_built_here(target, script, entry) for script, entry in index.items()):
        raise OutputError(f"{target}: exists and was not written by agv-cosim build (or was "
                          "changed since); refusing to replace it (move it away or choose "
                          "another --out)")


def _install(built: Path, target: Path, script_name: str, index: dict[str, Any],
             fmi_version: int) -> None:
    """Put the FMU ``built`` at ``target``: a new file of ours beside it (O_EXCL |
    O_NOFOLLOW), renamed onto it; only over a file this command wrote (the record), and
    the record updated around the rename."""
    if os.path.lexists(target) and not os.path.islink(target):
        other = _fmi_version_of(target)
        if other is not None and other != f"{fmi_version}.0":
            raise BuildError(f"'{target}' is an FMI {other} FMU; build the FMI "
                             f"{fmi_version}.0 twins into another folder")
    check_replaceable(target, index)
    old = [_sha256(target)] if os.path.lexists(target) else []
    new = _sha256(built)
    temporary, stream = create_beside(target, ".fmu.partial")
    try:
        with stream, open(built, "rb") as source:
            shutil.copyfileobj(source, stream, 1 << 20)
        index[script_name] = {"fmu": target.name, "sha256": [*old, new]}
        _write_record(target.parent, index)
        check_replaceable(target, index)  # again: nothing else took the place meanwhile
        os.replace(temporary, target)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    index[script_name] = {"fmu": target.name, "sha256": [new]}
    _write_record(target.parent, index)


def build_one(script: str | Path, out_dir: str | Path, core_dir: str | Path | None = None,
              force: bool = False, index: dict[str, Any] | None = None,
              fmi_version: int = 2, standalone: bool = False) -> "BuildResult":
    """Build the FMU (FMI ``fmi_version``) of one slave script into ``out_dir``.

    ``standalone`` adds a Python runtime with the packages the slave imports
    (agv_cosim.build.standalone), so that the FMU needs no Python on the machine that runs it.
    Skipped if up to date. An FMU of the other FMI version of the same name in
    ``out_dir`` is never replaced (BuildError): the twins go into separate folders.
    """
    if fmi_version not in FMI_VERSIONS:
        raise BuildError(f"FMI version {fmi_version!r}: must be one of "
                         + ", ".join(map(str, FMI_VERSIONS)))
    script = Path(script).resolve()
    core_dir = Path(core_dir) if core_dir else default_components_dir() / "agv_core"
    boot = default_components_dir() / BOOT_SOURCE
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    index = read_record(out_dir) if index is None else index
    entry = index.get(script.name)
    known = _recorded_name(entry)
    if known is not None and not _built_here(out_dir / known, script.name, entry):
        known = None  # not the file this command wrote: rebuilt, and then refused
    # Up to date: the FMU there has the GUID of these sources with its own requirement
    # list, and that list is what this Python has installed (no child process needed).
    shipped = _shipped_requirements(out_dir / known) if known and not force else None
    if shipped is not None and known:
        bundle = _bundle(script, core_dir, boot, fmi_version, requirements=shipped)
        guid = fmu_guid(script, boot, bundle.tag, fmi_version, standalone)
        if fmu_guid_of(out_dir / known) == guid:
            return BuildResult(script, out_dir / known, guid, rebuilt=False)
    bundle = _bundle(script, core_dir, boot, fmi_version)
    tag = bundle.tag
    guid = fmu_guid(script, boot, tag, fmi_version, standalone)

    with tempfile.TemporaryDirectory(prefix="agv_build_") as tmp:
        stage_dir = Path(tmp) / "stage"
        stage_dir.mkdir()
        staged_script, project_files = _stage(script, core_dir, boot, tag, guid, stage_dir,
                                              bundle, fmi_version)
        saved_path = list(sys.path)
        own_modules = {script.stem, script.stem + FMI3_WRAPPER_SUFFIX,
                       script.stem + FMI3_BODY_SUFFIX}
        try:
            if fmi_version == 3:
                from pythonfmu3.builder import FmuBuilder as Fmu3Builder

                fmu_path = Fmu3Builder.build_FMU(
                    staged_script, dest=Path(tmp) / "out", project_files=project_files,
                    needsExecutionTool=not standalone, canGetAndSetFMUState=True,
                    canSerializeFMUState=True,
                    # pythonfmu3 0.3.4 writes another option's value here unless given
                    canHandleVariableCommunicationStepSize=True,
                )
            else:
                fmu_path = FmuBuilder.build_FMU(
                    staged_script, dest=Path(tmp) / "out", project_files=project_files,
                    needsExecutionTool=not standalone, canGetAndSetFMUstate=True,
                    canSerializeFMUstate=True,
                )
        except BuildError:
            raise
        except Exception as error:  # noqa: BLE001 - pythonfmu raises many kinds
            tool = "pythonfmu3" if fmi_version == 3 else "pythonfmu"
            raise BuildError(f"{script.name}: {tool} build failed: "
                             f"{type(error).__name__}: {error}") from error
        finally:
            sys.path[:] = saved_path
            for module in [m for m in sys.modules
                           if m in own_modules or m.startswith("agv_core_")]:
                del sys.modules[module]
        _install_loader(fmu_path, loader_binary(), fmi_version)
        _validate(fmu_path, fmi_version)
        _ship_reference(fmu_path)
        if standalone:
            from ..errors import StandaloneError
            from .standalone import add_runtime

            try:
                add_runtime(fmu_path, "x86_64-linux" if fmi_version == 3 else "linux64")
            except StandaloneError as error:
                raise BuildError(f"{script.name}: standalone runtime: {error}") from None
        target = out_dir / fmu_path.name
        _install(fmu_path, target, script.name, index, fmi_version)
    return BuildResult(script, target, guid, rebuilt=True)


def component_scripts(names: list[str], components_dir: str | Path | None = None
                      ) -> list[Path]:
    """The slave scripts of the components ``names`` (each a model identifier as in the
    FMU's file name, ``AgvVehicle`` or ``AgvVehicle.fmu``, or a slave script's name,
    ``agv_vehicle`` or ``agv_vehicle.py``), in the order given, each once; OutputError
    naming an unknown one and listing the valid names."""
    scripts = slave_scripts(components_dir or default_components_dir())
    by_name: dict[str, Path] = {}
    for script in scripts:
        identifier = slave_class_name(script)
        for name in (identifier, f"{identifier}.fmu", script.stem, script.name):
            by_name[name] = script
    chosen: list[Path] = []
    for name in names:
        if name not in by_name:
            valid = sorted(slave_class_name(s) for s in scripts)
            raise OutputError(f"build: no component '{name}'{did_you_mean(name, by_name)}; "
                              f"valid names: {', '.join(valid)}")
        if by_name[name] not in chosen:
            chosen.append(by_name[name])
    return chosen


def build_fmus(out_dir: str | Path, scripts: list[Path] | None = None, force: bool = False,
               fmi_version: int = 2, standalone: bool = False,
               progress: Callable[[int, int, Path, "BuildResult | None"], None] | None = None
               ) -> list["BuildResult"]:
    """Build every slave script (or ``scripts``) into ``out_dir``; return the results.

    ``fmi_version`` 3 builds the FMI 3.0 twins (see the module docstring); ``standalone``
    FMUs carry their own Python runtime (:func:`build_one`). ``progress(k, n, script,
    result)`` is called before the k-th of n scripts is built (``result`` None) and after
    (its result). Every FMU's place in ``out_dir`` is checked before anything is built:
    only FMUs this command wrote there are replaced (:func:`check_replaceable`).
    """
    out_dir = Path(out_dir)
    scripts = slave_scripts(default_components_dir()) if scripts is None else scripts
    index = read_record(out_dir)
    for script in scripts:  # refused before anything is built
        check_replaceable(out_dir / f"{slave_class_name(script)}.fmu", index)
    results = []
    try:
        for k, script in enumerate(scripts, 1):
            if progress is not None:
                progress(k, len(scripts), script, None)
            results.append(build_one(script, out_dir, force=force, index=index,
                                     fmi_version=fmi_version, standalone=standalone))
            if progress is not None:
                progress(k, len(scripts), script, results[-1])
    finally:
        if standalone:
            from .standalone import discard_runtimes

            discard_runtimes()
    return results
