"""``--resume``: the runs of an earlier result folder that can be kept, and keeping them.

A run of the earlier folder ``DIR/<label>`` is reused when its run.json says
``complete``, its recorded ``inputs`` equal the job's (:func:`~agv_cosim.report.records.
run_inputs`: variant, sweep point, every parameter and seed, FMU hashes, simulation and
record settings, connections, events, package versions) leaving aside the manifest's own
hash (so that a change to one run's parameters reruns that run only), and its
``timeseries.csv`` is a regular file holding the rows run.json counts. A reused run's
``timeseries.csv`` (and ``output.txt``) is hard-linked (copied across file systems) into
the new folder, its metrics are computed again from that file as a run computes them
(so a changed ``[metrics]`` table applies), and its run.json is written again from the
job. Its row of the earlier ``timings.csv`` (wall time, pacing) is kept in the new one.
The folder is then the one an uninterrupted run writes, byte for byte, but for
``timings.csv``, the one file that holds measured times.

The earlier folder must be ours (its marker, :func:`agv_cosim.files.marker_data`) and
written for a manifest of the same name; it is read, never changed: the new folder
replaces it only when committed (:class:`agv_cosim.files.AtomicDir`).
"""

import json
import os
import shutil
import stat
from pathlib import Path
from typing import Any

from ..errors import OutputError
from ..files import JSON_LIMIT, marker_data, read_bytes
from ..manifest import Manifest
from ..report.records import TIMINGS, RunResult, read_timings, recorded_inputs, write_run_files
from ..system import Job
from ..timeseries import count_rows
from .job import run_metrics

__all__ = ["check_resumable", "reusable", "reuse_runs"]

#: Files of a run folder a reused run keeps as they are (the others are written again).
KEPT_FILES = ("timeseries.csv", "output.txt")


def _comparable(inputs: dict[str, Any]) -> dict[str, Any]:
    """``inputs`` as run.json records them, without the manifest's hash."""
    return {k: v for k, v in inputs.items() if k != "manifest_sha256"}


def _previous(target: Path, manifest: Manifest) -> Path | None:
    """``target`` when it is a result folder to resume from; None when it does not
    exist. Raises :class:`OutputError` when it is not ours or of another manifest."""
    if not os.path.lexists(target):
        return None
    if target.is_symlink() or not target.is_dir():
        raise OutputError(f"{target}: exists and is not a folder; nothing to resume")
    marker = marker_data(target)
    if marker is None:
        raise OutputError(f"{target}: not a result folder of agv-cosim; refusing to "
                          "resume from it")
    name = marker.get("manifest")
    if name is None:
        raise OutputError(f"{target}: its manifest is not recorded (written by agv-cosim "
                          f"{marker.get('version', '?')}); cannot resume from it")
    if name != manifest.name:
        raise OutputError(f"{target}: written for manifest '{name}', not "
                          f"'{manifest.name}'; refusing to resume from it (choose "
                          "another --out)")
    return target


def check_resumable(target: str | Path, manifest: Manifest) -> None:
    """Raise :class:`OutputError` (one line) unless ``target`` is missing or a result
    folder of ours written for a manifest named as ``manifest``."""
    _previous(Path(os.path.abspath(target)), manifest)


def _complete_run(run_dir: Path, job: Job) -> dict[str, Any] | None:
    """run.json of ``run_dir`` when the run can be reused for ``job``, else None."""
    try:
        if not stat.S_ISDIR(os.lstat(run_dir).st_mode):
            return None
        csv_info = os.lstat(run_dir / "timeseries.csv")
        record = json.loads(read_bytes(run_dir / "run.json", JSON_LIMIT))
    except (OSError, ValueError, RecursionError):  # missing or damaged: run again (not
        return None  # a regular file, or larger than JSON_LIMIT: UnreadableFile, refused)
    if (not isinstance(record, dict) or record.get("status") != "complete"
            or not stat.S_ISREG(csv_info.st_mode)
            or not isinstance(record.get("inputs"), dict)):
        return None
    if _comparable(record["inputs"]) != _comparable(recorded_inputs(job)):
        return None
    try:
        if count_rows(run_dir / "timeseries.csv") != record.get("rows"):
            return None
    except (OSError, ValueError):
        return None
    return record


def reusable(target: str | Path, manifest: Manifest, jobs: list[Job]) -> list[int]:
    """Indices of the ``jobs`` whose complete run in the result folder ``target`` can
    be reused (see the module docstring); none when ``target`` does not exist. Raises
    :class:`OutputError` for a folder that is not ours or of another manifest."""
    previous = _previous(Path(os.path.abspath(target)), manifest)
    if previous is None:
        return []
    return [i for i, job in enumerate(jobs)
            if _complete_run(previous / job.label, job) is not None]


def _keep(source: Path, destination: Path) -> None:
    """``source`` at ``destination`` too: a hard link, else a copy."""
    try:
        os.link(source, destination, follow_symlinks=False)
    except OSError:
        shutil.copyfile(source, destination, follow_symlinks=False)


def reuse_runs(target: str | Path, manifest: Manifest, jobs: list[Job],
               root: Path) -> dict[int, RunResult]:
    """Put every reusable run of the result folder ``target`` into the new folder
    ``root`` (see the module docstring); return their results by job index (each with
    ``reused`` true, and the ``wall_time_s`` and ``real_time`` of its earlier row of
    timings.csv)."""
    previous = _previous(Path(os.path.abspath(target)), manifest)
    found: dict[int, RunResult] = {}
    if previous is None:
        return found
    timings = read_timings(previous / TIMINGS)
    for index, job in enumerate(jobs):
        old = previous / job.label
        record = _complete_run(old, job)
        if record is None:
            continue
        run_dir = root / job.label
        run_dir.mkdir()
        for name in KEPT_FILES:
            if (old / name).is_file() and not (old / name).is_symlink():
                _keep(old / name, run_dir / name)
        rows = record["rows"]
        values, metrics_error = run_metrics(job, run_dir, rows)
        result = write_run_files(job, run_dir, rows, "complete", None, values,
                                 metrics_error, record.get("ended_by"))
        result["csv_bytes"] = (run_dir / "timeseries.csv").stat().st_size
        result["reused"] = True
        timing = timings.get(job.label, {})
        result["wall_time_s"] = timing.get("wall_time_s")
        if "real_time" in timing:
            result["real_time"] = timing["real_time"]
        found[index] = result
    return found
