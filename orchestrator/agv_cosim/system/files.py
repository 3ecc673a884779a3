"""The files a run reads through its parameters: one mechanism for where they are, what
the FMU is given, and what ``--resume`` compares.

A String value (a parameter's, or an event's) names files when it is a path string
that names one (``"waypoints:file=wp.csv"``: :func:`agv_core.numerics.paths.path_files`).
Such a name is relative to the manifest's folder (:attr:`agv_cosim.manifest.Manifest.
base_dir`, the folder its FMUs and tables are relative to), never to the current folder:

- the check of the run (:func:`agv_cosim.system.check.check_parameters`) refuses a name
  that is not a regular file there (:func:`file_problem`);
- the FMU is given the value with the name made absolute (:func:`resolved`), and the
  metrics read a path string of ``[metrics]`` from the same folder;
- run.json records the value as the manifest gives it (``parameters``) and each file's
  SHA-256 by the name as written (``inputs.files``, :func:`hash_files`): the same
  manifest run from any current folder writes the same bytes, and a run whose file
  changed is not reused by ``--resume``.
"""

import errno
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from ..errors import UnreadableFile
from ..files import open_regular
from .model import file_sha256 as _file_sha256

__all__ = ["file_problem", "file_sha256", "hash_files", "named_files", "resolved"]

_T = TypeVar("_T")


def named_files(value: Any) -> list[str]:
    """The file names ``value`` names, as written (empty: it names none)."""
    from agv_core.numerics.paths import path_files

    return list(path_files(value)) if isinstance(value, str) else []


def resolved(value: Any, base_dir: str | Path) -> Any:
    """``value`` with each relative file name it names joined to ``base_dir``; any other
    value as it is. Raises ValueError (the problem) for a name a path string cannot hold."""
    if not named_files(value):
        return value
    from agv_core.errors import ParameterError
    from agv_core.numerics.paths import rebase_path

    try:
        return rebase_path(value, base_dir)
    except ParameterError as error:
        raise ValueError(str(error).removeprefix("path: ")) from None


def _regular(read: Callable[[Path], _T], path: Path) -> _T:
    """``read(path)`` of a regular file (:func:`agv_cosim.files.open_regular`: a link to
    one is followed, a FIFO is refused, not waited on); anything else is an OSError,
    as a missing file is."""
    try:
        return read(path)
    except UnreadableFile:
        raise OSError(errno.EINVAL, "not a regular file", str(path)) from None


def file_problem(value: Any, base_dir: str | Path) -> str | None:
    """Why a file ``value`` names cannot be read from ``base_dir`` (one line), or None."""
    for name in named_files(value):
        path = Path(base_dir) / name
        try:
            resolved(value, base_dir)
            _regular(lambda p: open_regular(p).close(), path)
        except ValueError as error:
            return str(error)
        except OSError as error:
            where = "" if Path(name).is_absolute() else " (relative to the manifest)"
            return f"file '{name}'{where}: {path}: {error.strerror or error}"
    return None


def file_sha256(path: str | Path) -> str:
    """SHA-256 (hex) of the regular file ``path``, read in blocks
    (:func:`agv_cosim.system.model.file_sha256`); OSError otherwise."""
    return _regular(_file_sha256, Path(path))


def hash_files(values: dict[str, Any], base_dir: str | Path,
               known: dict[Path, str] | None = None) -> dict[str, dict[str, str]]:
    """``{where: {name as written: SHA-256}}`` of the files each of ``values``
    (``{where: value}``) names, read from ``base_dir``; ``known`` caches the hashes by
    path across calls. OSError when a file cannot be read."""
    known = {} if known is None else known
    found: dict[str, dict[str, str]] = {}
    for where, value in values.items():
        for name in named_files(value):
            path = Path(base_dir) / name
            if path not in known:
                known[path] = file_sha256(path)
            found.setdefault(where, {})[name] = known[path]
    return found
