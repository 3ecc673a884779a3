"""``agv-cosim identify`` and :func:`agv_cosim.identify`: seed 000's identification of
the steering actuator (models a, b, c) from a measured input/output record. (The package
is ``identification`` so that ``agv_cosim.identify`` stays the function.)

:mod:`.numerics` is the procedure on arrays (no files); :mod:`.data` reads the CSV
record; :mod:`.output` writes the result folder. :func:`identify_file` runs the three.
"""

from __future__ import annotations

import hashlib
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import IdentifyError
from ..files import AtomicDir
from ..version import __version__

__all__ = ["Identification", "identify_file", "parse_models"]


@dataclass
class Identification:
    """What one identification found: identified.json's content (``result``), the
    settings and findings (``record``), the responses' columns and the folder written
    (None when none was asked for)."""

    result: dict[str, Any]
    record: dict[str, Any]
    responses: dict[str, Any]
    folder: Path | None


def parse_models(text: str | list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """``"a,b,c"`` (or a sequence) as a tuple of models, each once, in a, b, c order."""
    from .numerics import MODELS

    items = text.split(",") if isinstance(text, str) else list(text)
    chosen = [str(item).strip() for item in items if str(item).strip()]
    unknown = [m for m in chosen if m not in MODELS]
    if unknown or not chosen:
        raise IdentifyError(f"--models: {','.join(unknown) or repr(text)}: not a model "
                            "(models: a, b, c, comma-separated)")
    return tuple(m for m in MODELS if m in chosen)


def identify_file(data: str | Path, input: str, output: str, *, time: str = "time",
                  models: str | tuple[str, ...] = ("a", "b", "c"), cutoff: float = 30.0,
                  order: int = 3, out: str | Path | None = None,
                  overwrite: bool = False) -> Identification:
    """Read the record, identify, write the folder ``out`` (when given)."""
    from .data import check_time, read_columns
    from .numerics import identify_arrays
    from .output import responses_table, result_json, write_folder

    chosen = parse_models(models)
    names = [time, input, output]
    if len(set(names)) < 3:
        raise IdentifyError(f"--time {time}, --input {input}, --output {output}: three "
                            "different columns are needed")
    path = Path(data)
    (t, u, y), lines = read_columns(path, names)
    check_time(path, t, time, lines)
    folder = AtomicDir(out, overwrite=overwrite, about={"command": "identify"}) \
        if out is not None else None
    try:
        try:
            prep, settings, fits = identify_arrays(t, u, y, chosen, cutoff, order,
                                                   (time, input, output))
        except IdentifyError as error:
            raise IdentifyError(f"{path}: {error}") from None
        record = {"tool": "agv-cosim identify", "version": __version__,
                  "data": path.name, "data_path": str(path.resolve()),
                  "data_sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
                  "time": time, "input": input, "output": output, "models": list(chosen),
                  "settings": settings,
                  "fits": {m: {"values": f.values, "initial_output": f.initial,
                               "cost": f.cost, "evaluations": f.evaluations}
                           for m, f in fits.items()},
                  "versions": _versions()}
        written = None
        if folder is not None:
            written = write_folder(folder, prep, fits, record, (time, input, output))
    finally:
        if folder is not None:
            folder.discard()  # nothing left after a commit; the temporary folder otherwise
    return Identification(result=result_json(fits), record=record,
                          responses=responses_table(prep, fits), folder=written)


def _versions() -> dict[str, str]:
    import numpy
    import scipy

    return {"python": sys.version.split()[0], "numpy": numpy.__version__,
            "scipy": scipy.__version__}
