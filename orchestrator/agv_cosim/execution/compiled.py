"""The compiled call path: ``_fmicall.c`` (beside this file) built with gcc and loaded.

The master's generated per-step functions (:mod:`.fastpath`) call the FMI functions
through ctypes. With this extension they become :class:`Program` objects instead: the
same calls, with the same arguments, in the same order, the same status and finite checks
and the same track writes, made from C without ctypes (bit-identical results: the same
doubles reach the same C functions). :func:`run_stretch` runs whole macro steps (step,
exchange) in C between the points where Python has work to do (:mod:`.simulation`).

The extension is compiled on first use, by the toolchain that builds the FMU loader
(gcc, the running Python's headers; :mod:`agv_cosim.build`), into a per-user cache folder
(``$AGV_COSIM_CACHE`` or ``$XDG_CACHE_HOME/agv-cosim`` or ``~/.cache/agv-cosim``), under a
name made from the source's hash and the Python's ABI tag, written beside its place and
renamed onto it (so concurrent processes never load a half-written file).

Where it cannot be built or loaded (no gcc, no headers, a read-only cache) the master
keeps the ctypes path, silently; :func:`why_not` says why. ``AGV_COSIM_NO_C=1`` in the
environment switches it off (the ctypes path, e.g. to compare).
"""

import hashlib
import importlib.machinery
import importlib.util
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path
from types import ModuleType
from typing import Any

__all__ = ["DISABLE", "SOURCE", "available", "module", "why_not"]

#: Environment variable: set to 1 to switch the compiled path off.
DISABLE = "AGV_COSIM_NO_C"
#: The extension's C source.
SOURCE = Path(__file__).with_name("_fmicall.c")

_LOADED: list[ModuleType | None] = []
_REASON: list[str] = []


def _cache_dir() -> Path:
    explicit = os.environ.get("AGV_COSIM_CACHE")
    if explicit:
        return Path(explicit)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "agv-cosim"


def _target(source: bytes) -> Path:
    suffix = importlib.machinery.EXTENSION_SUFFIXES[0]
    digest = hashlib.sha256(source + sys.version.encode()).hexdigest()[:16]
    return _cache_dir() / f"_fmicall-{digest}{suffix}"


def _compile(source: bytes, target: Path) -> None:
    """Compile ``source`` into ``target`` (RuntimeError with gcc's last line if not)."""
    compiler = shutil.which("gcc") or shutil.which("cc")
    if compiler is None:
        raise RuntimeError("no C compiler (gcc) on PATH")
    include = sysconfig.get_paths()["include"]
    if not Path(include, "Python.h").is_file():
        raise RuntimeError(f"no Python.h in {include}")
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="agv_fmicall_") as tmp:
        c_file = Path(tmp) / "_fmicall.c"
        c_file.write_bytes(source)
        built = Path(tmp) / target.name
        # -ffp-contract=off: no fused multiply-add, so the grid's arithmetic is Python's
        command = [compiler, "-shared", "-fPIC", "-O2", "-Wall", "-Wextra", "-g0",
                   "-ffp-contract=off", f"-I{include}", "-o", str(built), str(c_file)]
        done = subprocess.run(command, capture_output=True, text=True, cwd=tmp)
        if done.returncode != 0:
            raise RuntimeError("gcc: " + (done.stderr.strip().splitlines() or ["failed"])[-1])
        fd, partial = tempfile.mkstemp(prefix=target.name + ".", dir=target.parent)
        try:
            with os.fdopen(fd, "wb") as out:
                out.write(built.read_bytes())
            os.replace(partial, target)
        except BaseException:
            Path(partial).unlink(missing_ok=True)
            raise


def _load(target: Path) -> ModuleType:
    loader = importlib.machinery.ExtensionFileLoader("_fmicall", str(target))
    spec = importlib.util.spec_from_file_location("_fmicall", target, loader=loader)
    if spec is None:
        raise RuntimeError(f"cannot load {target}")
    loaded = importlib.util.module_from_spec(spec)
    loader.exec_module(loaded)
    return loaded


def module() -> Any:
    """The loaded extension (built first if need be), or None: switched off
    (``AGV_COSIM_NO_C=1``) or not buildable here (:func:`why_not`)."""
    if os.environ.get(DISABLE, "") not in ("", "0"):
        return None
    if not _LOADED:
        try:
            source = SOURCE.read_bytes()
            target = _target(source)
            if not target.is_file():
                _compile(source, target)
            _LOADED.append(_load(target))
        except (OSError, RuntimeError, ImportError) as error:
            _REASON.append(f"{type(error).__name__}: {error}")
            _LOADED.append(None)
    return _LOADED[0]


def available() -> bool:
    """True when the compiled call path is in use."""
    return module() is not None


def why_not() -> str:
    """Why the compiled path is not in use ('' when it is)."""
    if os.environ.get(DISABLE, "") not in ("", "0"):
        return f"switched off by {DISABLE}"
    module()
    return _REASON[0] if _REASON else ""
