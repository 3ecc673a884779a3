"""``--resume``: the runs of an earlier result folder that can be kept, and keeping them.

A run of the earlier folder ``DIR/<label>`` is reused when its run.json says
``complete``, its recorded ``inputs`` equal the job's (:func:`~agv_cosim.report.records.
run_inputs`: variant, sweep point, every parameter and seed, FMU and time-table hashes,
each table's interpolation, the SHA-256 of every file a parameter or event names
(:mod:`agv_cosim.system.files`), simulation and record settings, connections, events,
package versions) leaving aside the manifest's own hash (so that a change to one run's
parameters reruns that run only), and its ``timeseries.csv`` is a regular file whose
SHA-256 is the ``timeseries_sha256`` run.json recorded when the run wrote it (a file
cut or changed since, even with as many rows, is not reused), and its ``output.txt``
(what the run's process printed) is as the run left it: a regular file whose size and
SHA-256 are run.json's ``output_bytes`` and ``output_sha256``, or, when run.json has
neither, no entry at all (a run that printed nothing). An output.txt cut, replaced,
grown, deleted, a link or anything but a regular file at its place (never followed nor
opened), or one that run.json does not vouch for (written by an earlier agv-cosim),
reruns the run, as a changed timeseries.csv does: the resumed folder is the one an
uninterrupted run writes. A reused run's ``timeseries.csv`` and ``output.txt`` are
hard-linked (copied across file systems) into the new folder, its metrics are computed
again from that file as a run computes them (so a changed ``[metrics]`` table applies),
and its run.json is written again from the job (with the output's hash and size). Its
row of the earlier ``timings.csv`` (wall time, pacing) is kept in the new one.

Resume touches only what the command runs (:func:`keep_others`): into the new folder
go, as they are,

- the runs of the manifest's variants that the command does not run (``--variant``
  chose others): every file of their folders, their rows of summary.csv (from their
  run.json and metrics.json) and of timings.csv;
- every file and folder that this tool does not write (:data:`FOLDER_FILES`,
  :data:`RUN_FILES`, the report's record), at the same place: a user's file is never
  deleted.

What is left out is ours and replaced: the files of the runs the command runs, runs of
the variants it runs (or of variants the manifest no longer has) at sweep points it no
longer has, and the folder's summary, figures, report and notes, written again. With
every variant run, the folder is then the one an uninterrupted run writes, byte for
byte, but for ``timings.csv``, the one file that holds measured times, and the user's
files kept.

The earlier folder must be ours (its marker, :func:`agv_cosim.files.marker_data`) and
written for a manifest of the same name; it is read, never changed: the new folder
replaces it only when committed (:class:`agv_cosim.files.AtomicDir`).
"""

import errno
import os
import shutil
import stat
from pathlib import Path
from typing import Any

from ..errors import ManifestError, OutputError
from ..files import MARKER, marker_data, read_json_object
from ..manifest import Manifest
from ..plan import plan_runs
from ..report import plots
from ..report.page import FIGURES_ERROR, RECORD, REPORT_FILE, STEP_CHECK_FILE
from ..report.records import (
    OUTPUT_FILE,
    TIMINGS,
    RunResult,
    finish_run,
    output_digest,
    read_timings,
    record_output,
    recorded_inputs,
)
from ..system import Job
from ..system.files import file_sha256

__all__ = ["FOLDER_FILES", "RUN_FILES", "check_resumable", "keep_others",
           "keep_user_files", "keep_users", "listed", "reusable", "reuse_runs"]

#: Files of a run folder a reused run keeps as they are (the others are written again).
KEPT_FILES = ("timeseries.csv", OUTPUT_FILE)
#: The files of a run folder that this tool writes.
RUN_FILES = ("timeseries.csv", "metrics.json", "run.json", OUTPUT_FILE)
#: The files at the top of a result folder that this tool writes (besides the figures
#: the report's record lists).
FOLDER_FILES = (MARKER, "summary.csv", TIMINGS, REPORT_FILE, RECORD, "partial.txt",
                FIGURES_ERROR, "plots_error.txt", "montecarlo.json", "montecarlo.png",
                "montecarlo_error.txt", plots.SIGNALS_FILE, plots.TRAJECTORY_FILE,
                plots.SWEEP_FILE, plots.MONTECARLO_SCATTER_FILE, STEP_CHECK_FILE)


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
    """run.json of ``run_dir`` when the run can be reused for ``job``, else None: a
    complete run of the same inputs whose timeseries.csv is, byte for byte, the file it
    wrote (its SHA-256 is run.json's ``timeseries_sha256``)."""
    try:
        if not stat.S_ISDIR(os.lstat(run_dir).st_mode):
            return None
        csv_info = os.lstat(run_dir / "timeseries.csv")
    except OSError:
        return None
    record = read_json_object(run_dir / "run.json")
    if (record is None or record.get("status") != "complete"
            or not stat.S_ISREG(csv_info.st_mode)
            or not isinstance(record.get("rows"), int)
            or not isinstance(record.get("timeseries_sha256"), str)
            or not isinstance(record.get("inputs"), dict)):
        return None
    if _comparable(record["inputs"]) != _comparable(recorded_inputs(job)):
        return None
    try:
        if file_sha256(run_dir / "timeseries.csv") != record["timeseries_sha256"]:
            return None
    except OSError:
        return None
    return record if _output_intact(run_dir, record) else None


def _output_intact(run_dir: Path, record: dict[str, Any]) -> bool:
    """Whether the run's output.txt is as the run left it (see the module docstring):
    absent when ``record`` (its run.json) records none, else a regular file of the
    recorded size and SHA-256 (the size is compared before a byte is read)."""
    sha256, size = record.get("output_sha256"), record.get("output_bytes")
    try:
        info = os.lstat(run_dir / OUTPUT_FILE)
    except FileNotFoundError:
        return sha256 is None and size is None
    except OSError:
        return False
    if not (isinstance(sha256, str) and isinstance(size, int) and not isinstance(size, bool)
            and stat.S_ISREG(info.st_mode) and info.st_size == size):
        return False
    return output_digest(run_dir / OUTPUT_FILE) == (sha256, size)


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
        result = finish_run(job, run_dir, rows, "complete", None, record.get("ended_by"),
                            record["timeseries_sha256"])
        record_output(run_dir)
        result["csv_bytes"] = (run_dir / "timeseries.csv").stat().st_size
        result["reused"] = True
        timing = timings.get(job.label, {})
        result["wall_time_s"] = timing.get("wall_time_s")
        if "real_time" in timing:
            result["real_time"] = timing["real_time"]
        found[index] = result
    return found


def keep_others(target: str | Path, manifest: Manifest, jobs: list[Job],
                root: Path) -> tuple[list[RunResult], list[str]]:
    """Carry into the new folder ``root`` what of the result folder ``target`` the
    command does not write (see the module docstring): the runs of the manifest's
    variants that ``jobs`` do not run, whole, and every file and folder this tool does
    not write, at the same place (hard links; copies across file systems). Returns the
    results of the runs kept (for summary.csv and timings.csv: from their run.json,
    metrics.json and earlier row of timings.csv) and the user's entries kept (paths
    relative to the folder). Call it after :func:`reuse_runs`. Raises
    :class:`OutputError` (one line, naming it) for an entry that cannot be kept."""
    previous = _previous(Path(os.path.abspath(target)), manifest)
    if previous is None:
        return [], []
    others = set(manifest.variants) - {job.variant for job in jobs}
    return _keep_from(previous, {job.label for job in jobs}, others, root)


def keep_users(target: str | Path, jobs: list[Job], root: Path) -> list[str]:
    """Carry into the new folder ``root`` every file and folder of the result folder
    ``target`` that this tool does not write, at the same place, for a run (not
    ``--resume``) that replaces it: a user's file is never deleted. The runs of the
    earlier folder are replaced, whatever their manifest. Nothing when ``target`` is
    not a result folder with our marker (a missing or empty one, or one replaced with
    ``--overwrite``). Returns the entries kept (paths relative to the folder)."""
    previous = Path(os.path.abspath(target))
    if previous.is_symlink() or not previous.is_dir() or marker_data(previous) is None:
        return []
    return _keep_from(previous, {job.label for job in jobs}, set(), root)[1]


def keep_user_files(target: str | Path, root: Path, ours: tuple[str, ...]) -> list[str]:
    """Carry into the new folder ``root`` every entry of the result folder ``target``
    that neither this command (its top-level names ``ours``) nor ``run`` writes (its
    files, figures and run folders), for a command other than ``run`` (``fit``) that
    replaces it: a user's file is never deleted. Nothing when ``target`` is not a folder
    with our marker. Returns the entries kept."""
    previous = Path(os.path.abspath(target))
    if previous.is_symlink() or not previous.is_dir() or marker_data(previous) is None:
        return []
    report = read_json_object(previous / RECORD) or {}
    figures = {name for name in report.get("files", []) if isinstance(name, str)}
    kept = []
    for entry in _names(previous):
        old = previous / entry
        if entry in ours or entry in FOLDER_FILES or entry in figures:
            continue
        if old.is_dir() and not old.is_symlink() and (old / "run.json").is_file():
            continue  # a run folder of ours
        _carry(old, root / entry)
        kept.append(entry)
    return kept


def _keep_from(previous: Path, labels: set[str], others: set[str],
               root: Path) -> tuple[list[RunResult], list[str]]:
    """:func:`keep_others` on the earlier folder ``previous``: the runs of variants in
    ``others`` whole, the entries not ours at the same place; ``labels`` are the runs
    the command writes."""
    report = read_json_object(previous / RECORD) or {}
    figures = {name for name in report.get("files", []) if isinstance(name, str)}
    timings = read_timings(previous / TIMINGS)
    kept: list[RunResult] = []
    users: list[str] = []
    for entry in _names(previous):
        old = previous / entry
        try:
            mode = os.lstat(old).st_mode
        except FileNotFoundError:
            continue
        if not stat.S_ISDIR(mode):
            if entry in labels:  # kept, the run would be written through it or beside it
                raise OutputError(f"{old}: not a run folder of agv-cosim, where run "
                                  f"'{entry}' is written; refusing to resume (move it "
                                  "away)")
            if entry not in FOLDER_FILES and entry not in figures:
                _carry(old, root / entry)
                users.append(entry)
            continue
        record = None if entry in labels else read_json_object(old / "run.json")
        if entry not in labels and record is None:  # not a run of ours
            _carry(old, root / entry)
            users.append(entry)
        elif record is not None and isinstance(record.get("variant"), str) \
                and record["variant"] in others:
            _carry(old, root / entry)
            kept.append(_kept_result(entry, record, old, timings))
        else:  # a run of ours the command writes again, or a stale one: the user's files
            for name in _names(old):
                if name not in RUN_FILES:
                    (root / entry).mkdir(exist_ok=True)
                    _carry(old / name, root / entry / name)
                    users.append(f"{entry}/{name}")
    return kept, users


def _names(folder: Path) -> list[str]:
    """The names in ``folder``, sorted; :class:`OutputError` when it cannot be read."""
    try:
        return sorted(os.listdir(folder))
    except OSError as error:
        raise OutputError(f"{folder}: cannot read it to keep what --resume does not "
                          f"write: {error.strerror or error}") from None


def _kept_result(label: str, record: dict[str, Any], run_dir: Path,
                 timings: dict[str, dict[str, Any]]) -> RunResult:
    """The :class:`RunResult` of a run kept as it is, from its run.json (``record``),
    metrics.json and row of timings.csv."""
    metrics = read_json_object(run_dir / "metrics.json") or {}
    point = record.get("sweep_point")
    rows = record.get("rows")
    result = RunResult(label=label, status=str(record.get("status")),
                       error=record.get("error"),
                       rows=rows if isinstance(rows, int) else 0, metrics=metrics,
                       metrics_error=record.get("metrics_error"),
                       point=point if isinstance(point, dict) else {},
                       variant=record.get("variant"))
    timing = timings.get(label, {})
    result["wall_time_s"] = timing.get("wall_time_s")
    if "real_time" in timing:
        result["real_time"] = timing["real_time"]
    return result


def _carry(source: Path, destination: Path) -> None:
    """``source`` (a file, a link, or a folder with everything in it, at any depth) at
    ``destination`` too: hard links, else copies; a link stays a link; a folder gets
    its permissions once filled."""
    folders: list[tuple[Path, int]] = []
    pending = [(source, destination)]
    try:
        while pending:
            old, new = pending.pop()
            info = os.lstat(old)
            if stat.S_ISDIR(info.st_mode):
                new.mkdir(exist_ok=True)
                folders.append((new, stat.S_IMODE(info.st_mode)))
                pending.extend((old / name, new / name) for name in _names(old))
                continue
            try:
                os.link(old, new, follow_symlinks=False)
            except OSError as error:
                if error.errno not in (errno.EXDEV, errno.EPERM, errno.EMLINK):
                    raise
                if stat.S_ISLNK(info.st_mode):
                    os.symlink(os.readlink(old), new)
                elif stat.S_ISREG(info.st_mode):
                    shutil.copy2(old, new, follow_symlinks=False)
                else:
                    raise
        for folder, mode in reversed(folders):
            os.chmod(folder, mode)
    except OSError as error:
        raise OutputError(f"{source}: cannot keep it in the new folder (a run keeps "
                          f"what it does not write): {error.strerror or error}") from None


def listed(manifest: Manifest, results: list[RunResult],
           kept: list[RunResult]) -> list[RunResult]:
    """``results`` and the runs ``kept`` (:func:`keep_others`) in the order the whole
    manifest plans its runs (summary.csv's order); ``results`` alone without kept runs."""
    if not kept:
        return results
    try:
        order = {run.label: i for i, run in enumerate(plan_runs(manifest))}
    except (ManifestError, ValueError):
        order = {}
    return sorted([*results, *kept], key=lambda r: order.get(r["label"], len(order)))
