"""``agv-cosim examples DIR``: copy the shipped experiment manifests into a folder of the
user's, pointed at the FMUs that ``agv-cosim build`` writes.

The shipped manifests name their FMUs relative to themselves (``"../fmus/AgvVehicle.fmu"``:
the repository's ``experiments/`` beside ``fmus/``). A copy names the same file in the
folder ``fmus`` given here (default ``fmus``, relative to the current folder: where
``agv-cosim build`` writes by default; ``agv-cosim build --out X`` pairs with ``--fmus X``),
written relative to DIR so that DIR and the FMU folder can move together (an absolute
``--fmus`` is written as it is). The relative path is computed between the real paths of
the two folders (symbolic links resolved), since that is where the system resolves it
from. Files the
manifests reference beside themselves (``table = "x.csv"``, a path
``"waypoints:file=x.csv"``) are copied along, at the same place relative to the manifest.

Every rewrite is checked: the copy, read back, must equal the shipped manifest with just
its FMU paths changed.

A user's files are never replaced: DIR keeps a record (``.agv-cosim-examples.json``) of
each file this command wrote and its content hash. A file that is in the way is replaced
only if the record names it and it is unchanged since; otherwise nothing is written and
the command fails naming the file.
"""

import hashlib
import json
import os
import re
import tempfile
import tomllib
from collections.abc import Callable, Iterator
from pathlib import Path, PurePosixPath
from typing import Any

from ..errors import ExamplesError
from .shipped import shipped_dir

__all__ = ["RECORD", "ExamplesError", "copy_examples", "example_files"]

#: The record of what this command wrote into a folder.
RECORD = ".agv-cosim-examples.json"

_WAYPOINTS = re.compile(r"waypoints:(?:[^\"']*,)?file=([^,\"']+)")


def _strings(value: object) -> Iterator[str]:
    if isinstance(value, str):
        yield value
    elif isinstance(value, dict):
        for item in value.values():
            yield from _strings(item)
    elif isinstance(value, list):
        for item in value:
            yield from _strings(item)


def _components(data: dict[str, Any]) -> Iterator[Any]:
    """Every component table of a manifest: the top-level ones and the variants'."""
    yield from (data.get("components") or {}).values()
    for variant in (data.get("variants") or {}).values():
        yield from ((variant or {}).get("components") or {}).values()


def _with_fmus(data: dict[str, Any], point: Callable[[str], str]) -> dict[str, Any]:
    """A deep copy of manifest ``data`` with each component's ``fmu`` replaced by
    ``point(fmu)``."""
    copy: dict[str, Any] = json.loads(json.dumps(data))
    for table in _components(copy):
        if isinstance(table, dict) and isinstance(table.get("fmu"), str):
            table["fmu"] = point(table["fmu"])
    return copy


def _referenced_files(data: dict[str, Any]) -> list[str]:
    """Relative file names the manifest refers to beside its FMUs (tables, waypoints)."""
    names = {table["table"] for table in _components(data)
             if isinstance(table, dict) and isinstance(table.get("table"), str)}
    for text in _strings(data):
        names.update(m.group(1) for m in _WAYPOINTS.finditer(text))
    return sorted(names)


def _localised(source: Path, fmu_folder: str) -> tuple[str, list[str]]:
    """Text of the shipped manifest ``source`` with its FMUs in ``fmu_folder`` (a posix
    path as the manifest should name it); its referenced files."""
    text = source.read_text(encoding="utf-8")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise ExamplesError(f"shipped manifest {source.name}: {error}") from None

    def point(fmu: str) -> str:
        return str(PurePosixPath(fmu_folder) / PurePosixPath(fmu).name)

    new = text
    for table in _components(data):
        fmu = table.get("fmu") if isinstance(table, dict) else None
        if isinstance(fmu, str):
            # every occurrence of the exact TOML string; checked by reading back below
            new = new.replace(json.dumps(fmu), json.dumps(point(fmu)))
    try:
        same = tomllib.loads(new) == _with_fmus(data, point)
    except tomllib.TOMLDecodeError:
        same = False
    if not same:
        raise ExamplesError(f"shipped manifest {source.name}: its FMU paths cannot be "
                            "rewritten safely (not plain double-quoted strings?)")
    return new, _referenced_files(data)


def _digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def example_files(fmu_folder: str) -> dict[str, bytes]:
    """What :func:`copy_examples` writes: relative path -> bytes (``fmu_folder``: the
    FMU folder as the manifests should name it)."""
    source_dir = shipped_dir("experiments")
    files: dict[str, bytes] = {}
    for source in sorted(source_dir.glob("*.toml")):
        text, referenced = _localised(source, fmu_folder)
        files[source.name] = text.encode("utf-8")
        for name in referenced:
            path = (source_dir / name).resolve()
            if not path.is_relative_to(source_dir.resolve()) or not path.is_file():
                raise ExamplesError(f"shipped manifest {source.name} refers to '{name}', "
                                    "which is not shipped beside it")
            files[path.relative_to(source_dir.resolve()).as_posix()] = path.read_bytes()
    return files


def _record_of(folder: Path) -> dict[str, str]:
    path = folder / RECORD
    if not path.exists():
        return {}
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
        written = record["written"]
        if not all(isinstance(k, str) and isinstance(v, str) for k, v in written.items()):
            raise ValueError
        return dict(written)
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        raise ExamplesError(f"{path}: not a record written by agv-cosim examples; "
                            "choose another folder") from None


def copy_examples(folder: str | Path, fmus: str = "fmus") -> list[Path]:
    """Copy the shipped manifests (and the files they reference) into ``folder``, their
    FMU paths pointed at the folder ``fmus`` (relative to the current folder, or
    absolute). Returns the paths written (files already identical are not rewritten,
    and are returned too). Raises :class:`ExamplesError` before writing anything if a
    file in the way is not one this command wrote, unchanged."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise ExamplesError(f"{folder}: exists and is not a folder")
    # from the real paths: the system resolves a relative path from the folder the
    # manifest is really in, whatever links the names given here go through
    fmu_folder = (Path(fmus).as_posix() if Path(fmus).is_absolute() else
                  Path(os.path.relpath(os.path.realpath(fmus),
                                       os.path.realpath(folder))).as_posix())
    files = example_files(fmu_folder)
    record = _record_of(folder) if folder.is_dir() else {}
    in_the_way: list[str] = []
    for name, data in files.items():
        path = folder / name
        if path.is_symlink() or (path.exists() and not path.is_file()):
            in_the_way.append(name)
        elif path.exists():
            current = _digest(path.read_bytes())
            if current != _digest(data) and record.get(name) != current:
                in_the_way.append(name)
    if in_the_way:
        first = folder / in_the_way[0]
        more = f" (and {len(in_the_way) - 1} more)" if len(in_the_way) > 1 else ""
        raise ExamplesError(f"{first}{more}: exists and was not written by agv-cosim "
                            "examples (or was changed since); nothing was copied: move it "
                            "away or choose another folder")
    folder.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    for name, data in files.items():
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if not (path.is_file() and path.read_bytes() == data):
            _write(path, data)
        record[name] = _digest(data)
        written.append(path)
    _write(folder / RECORD, (json.dumps({"written": dict(sorted(record.items()))}, indent=1)
                             + "\n").encode("utf-8"))
    return written


def _write(path: Path, data: bytes) -> None:
    """Write ``path`` whole or not at all (a temporary file of our own, then a rename)."""
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.",
                                         suffix=".partial")
    try:
        with os.fdopen(handle, "wb") as stream:
            stream.write(data)
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
