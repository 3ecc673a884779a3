"""Build the component FMUs from ``components/slaves/*.py`` with pythonfmu.

Each FMU bundles its slave script, ``agv_boot.py`` and a copy of ``agv_core`` tagged with
a content hash (``agv_core/BUILD_ID``), a ``requirements.txt`` for the host Python, and
``agv_build.json`` with a GUID derived from every source that goes into the FMU. A
rebuild with unchanged sources is skipped (the FMU's GUID already matches), and a built
FMU that ``fmpy.validation`` finds fault with fails the build.
"""

import hashlib
import json
import shutil
import sys
import tempfile
import uuid
import zipfile
from dataclasses import dataclass
from pathlib import Path
from xml.etree import ElementTree

import pythonfmu
from pythonfmu.builder import FmuBuilder

#: Bumped whenever the way an FMU is assembled changes, so every FMU is rebuilt.
BUILD_FORMAT = 1

#: What the host Python needs to run the bundled core (shipped in every FMU).
HOST_REQUIREMENTS = "numpy>=1.24\nscipy>=1.10\nscikit-fuzzy>=0.5\n"

BOOT_SCRIPT = "agv_boot.py"
INDEX_FILE = "build-index.json"


class BuildError(RuntimeError):
    """An FMU could not be built, or the built FMU is not valid FMI 2.0."""


@dataclass(frozen=True)
class BuildResult:
    """What :func:`build_fmus` did for one slave script."""

    script: Path
    fmu: Path
    guid: str
    rebuilt: bool


def default_components_dir():
    """``components/`` of the checkout this package is installed from (editable install)."""
    import agv_core

    return Path(agv_core.__file__).resolve().parent.parent


def slave_scripts(components_dir):
    """The slave scripts in ``components_dir/slaves`` (every ``*.py`` but the boot loader)."""
    slaves = Path(components_dir) / "slaves"
    if not slaves.is_dir():
        raise BuildError(f"no slave scripts: '{slaves}' is not a folder")
    return sorted(p for p in slaves.glob("*.py") if p.name != BOOT_SCRIPT)


def _core_files(core_dir):
    return sorted(p for p in core_dir.rglob("*.py") if "__pycache__" not in p.parts)


def core_tag(core_dir):
    """Content hash (16 hex digits) of the ``agv_core`` sources in ``core_dir``."""
    digest = hashlib.sha256()
    for path in _core_files(core_dir):
        digest.update(path.relative_to(core_dir).as_posix().encode() + b"\0")
        digest.update(path.read_bytes() + b"\0")
    return digest.hexdigest()[:16]


def fmu_guid(script, boot, tag):
    """GUID of the FMU built from ``script``: a hash of all its sources and the tool chain."""
    digest = hashlib.sha256()
    for part in (script.name.encode(), script.read_bytes(), boot.read_bytes(), tag.encode(),
                 pythonfmu.__version__.encode(), str(BUILD_FORMAT).encode(),
                 HOST_REQUIREMENTS.encode()):
        digest.update(part + b"\0")
    return str(uuid.UUID(digest.hexdigest()[:32]))


def fmu_guid_of(fmu_path):
    """The GUID in an existing FMU's ``modelDescription.xml``, or None if unreadable."""
    try:
        with zipfile.ZipFile(fmu_path) as archive:
            root = ElementTree.fromstring(archive.read("modelDescription.xml"))
    except (OSError, KeyError, zipfile.BadZipFile, ElementTree.ParseError):
        return None
    return root.get("guid")


def _stage(script, core_dir, boot, tag, guid, stage_dir):
    shutil.copy2(script, stage_dir / script.name)
    shutil.copy2(boot, stage_dir / BOOT_SCRIPT)
    core_copy = stage_dir / "agv_core"
    for path in _core_files(core_dir):
        target = core_copy / path.relative_to(core_dir)
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(path, target)
    (core_copy / "BUILD_ID").write_text(tag + "\n")
    (stage_dir / "agv_build.json").write_text(
        json.dumps({"guid": guid, "core_tag": tag, "script": script.name,
                    "pythonfmu": pythonfmu.__version__, "build_format": BUILD_FORMAT},
                   indent=1) + "\n")
    (stage_dir / "requirements.txt").write_text(HOST_REQUIREMENTS)
    return [core_copy, stage_dir / BOOT_SCRIPT, stage_dir / "agv_build.json",
            stage_dir / "requirements.txt"]


def _validate(fmu_path):
    from fmpy.validation import validate_fmu

    problems = validate_fmu(str(fmu_path))
    if problems:
        raise BuildError(f"{fmu_path.name} is not valid FMI 2.0: " + "; ".join(problems))


def build_one(script, out_dir, core_dir=None, force=False, index=None):
    """Build the FMU of one slave script into ``out_dir`` (skipped if up to date)."""
    script = Path(script).resolve()
    core_dir = Path(core_dir) if core_dir else default_components_dir() / "agv_core"
    boot = default_components_dir() / "slaves" / BOOT_SCRIPT
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    tag = core_tag(core_dir)
    guid = fmu_guid(script, boot, tag)
    index = {} if index is None else index
    known = index.get(script.name)
    if not force and known and fmu_guid_of(out_dir / known) == guid:
        return BuildResult(script, out_dir / known, guid, rebuilt=False)

    with tempfile.TemporaryDirectory(prefix="agv_build_") as tmp:
        stage_dir = Path(tmp) / "stage"
        stage_dir.mkdir()
        project_files = _stage(script, core_dir, boot, tag, guid, stage_dir)
        staged_script = stage_dir / script.name
        saved_path = list(sys.path)
        try:
            fmu_path = FmuBuilder.build_FMU(
                staged_script, dest=Path(tmp) / "out", project_files=project_files,
                needsExecutionTool=True, canGetAndSetFMUstate=True, canSerializeFMUstate=True,
            )
        except Exception as error:  # noqa: BLE001 - pythonfmu raises many kinds
            raise BuildError(f"{script.name}: pythonfmu build failed: "
                             f"{type(error).__name__}: {error}") from error
        finally:
            sys.path[:] = saved_path
            for module in [m for m in sys.modules
                           if m == script.stem or m.startswith("agv_core_")]:
                del sys.modules[module]
        _validate(fmu_path)
        target = out_dir / fmu_path.name
        partial = target.with_suffix(".fmu.partial")
        shutil.copy2(fmu_path, partial)
        partial.replace(target)
    index[script.name] = target.name
    return BuildResult(script, target, guid, rebuilt=True)


def build_fmus(out_dir, scripts=None, force=False):
    """Build every slave script (or ``scripts``) into ``out_dir``; return the results."""
    out_dir = Path(out_dir)
    scripts = slave_scripts(default_components_dir()) if scripts is None else scripts
    index_path = out_dir / INDEX_FILE
    try:
        index = json.loads(index_path.read_text())
    except (OSError, ValueError):
        index = {}
    results = []
    try:
        for script in scripts:
            results.append(build_one(script, out_dir, force=force, index=index))
    finally:
        out_dir.mkdir(parents=True, exist_ok=True)
        index_path.write_text(json.dumps(index, indent=1, sort_keys=True) + "\n")
    return results
