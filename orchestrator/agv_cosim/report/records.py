"""The records of a run and of a sweep: ``run.json``, ``metrics.json``, ``summary.csv``,
``timings.csv``, and the result of a run as the pipeline passes it on
(:class:`RunResult`).

Every record but ``timings.csv`` is reproducible: the same manifest, FMUs and seeds give
the same bytes. What the machine's timing decides (each run's wall time; a paced run's
achieved real-time factor, overruns and lateness) goes into ``timings.csv`` only, one row
per run (:data:`TIMING_COLUMNS`)."""

import csv
import hashlib
import importlib
import io
import json
import math
import os
import platform
import stat
from pathlib import Path
from typing import Any, NotRequired, TypedDict

from ..errors import UnreadableFile
from ..files import (
    CSV_LIMIT,
    create_beside,
    create_file,
    json_text,
    read_bytes,
    read_json_object,
    write_json,
    write_summary,
)
from ..lifetime import signals_blocked
from ..system import Job
from ..version import __version__
from . import metrics

__all__ = ["OUTPUT_FILE", "REAL_TIME_FIELDS", "TIMINGS", "TIMING_COLUMNS", "RunResult",
           "finish_remote_run", "finish_run", "inputs_sha256", "output_digest", "read_timings",
           "record_output", "record_units", "recorded_inputs",
           "run_inputs", "run_integration", "run_interfaces", "run_metrics", "run_result",
           "summary_rows", "timing_rows",
           "versions", "write_run_files", "write_summary", "write_timings"]

#: The result folder's file of the runs' timings: the one file that is not reproducible.
TIMINGS = "timings.csv"
#: What a run's process printed, in its folder (written by the local workers:
#: :class:`agv_cosim.workers.channels.OutputLog`; only when it printed).
OUTPUT_FILE = "output.txt"
#: The keys of a paced run's report (:meth:`agv_cosim.execution.Pacer.report`).
REAL_TIME_FIELDS = ("target", "achieved", "overruns", "max_lateness_s", "steps", "wall_s")
#: timings.csv's columns: the run's label, its wall time [s], then its pacing report
#: (empty for a run that was not paced).
TIMING_COLUMNS = ("run", "wall_time_s", *(f"real_time_{k}" for k in REAL_TIME_FIELDS))


class RunResult(TypedDict):
    """The result of one run (what a worker sends back; one row of summary.csv)."""

    label: str
    #: complete, partial, failed, timed out, interrupted or not run
    status: str
    error: str | None
    rows: int
    metrics: dict[str, Any]
    metrics_error: str | None
    point: dict[str, Any]
    variant: str | None
    #: bytes of the timeseries.csv written (a run that wrote one)
    csv_bytes: NotRequired[int]
    #: the run's wall time [s] (timings.csv; None or absent when not measured)
    wall_time_s: NotRequired[float | None]
    #: a paced run's report, :data:`REAL_TIME_FIELDS` (timings.csv)
    real_time: NotRequired[dict[str, Any]]
    #: true for a run kept from an earlier result folder (``--resume``)
    reused: NotRequired[bool]


def run_result(job: Job, status: str, *, rows: int = 0, error: str | None = None,
               metrics: dict[str, Any] | None = None,
               metrics_error: str | None = None) -> RunResult:
    """The :class:`RunResult` of ``job``."""
    return RunResult(label=job.label, status=status, error=error, rows=rows,
                     metrics={} if metrics is None else metrics,
                     metrics_error=metrics_error, point=job.point, variant=job.variant)


def summary_rows(results: list[RunResult]) -> list[dict[str, Any]]:
    """summary.csv's rows: run, variant, status, the sweep point, the metrics."""
    rows = []
    for result in results:
        row: dict[str, Any] = {"run": result["label"], "variant": result["variant"] or "",
                               "status": result["status"]}
        row.update(result["point"])
        row.update(result["metrics"])
        rows.append(row)
    return rows


def versions() -> dict[str, str | None]:
    """Versions of the packages a result depends on."""
    found: dict[str, str | None] = {"python": platform.python_version(), "agv_cosim": __version__}
    for name in ("fmpy", "pythonfmu", "numpy", "scipy"):
        try:
            found[name] = importlib.import_module(name).__version__
        except Exception:  # noqa: BLE001
            found[name] = None
    return found


def run_inputs(job: Job) -> dict[str, Any]:
    """Everything a run's result depends on, as plain data (``run.json``'s ``inputs``):
    the manifest's hash, the run's variant, sweep point (and Monte Carlo sample),
    parameters (seeds included), FMU and time-table hashes, each table's interpolation
    per column (``tables``), the SHA-256 of every file a parameter or event names
    (``files``, :mod:`agv_cosim.system.files`), simulation settings (with
    ``component_steps``, each multirate component's own step, when there is one),
    connections, events and package versions; ``integration`` (:func:`run_integration`)
    only when a component is integrated as Model Exchange. Equal inputs
    (:func:`inputs_sha256`) give an equal result."""
    plan = job.plan
    simulation: dict[str, Any] = {
        "start": plan.start, "stop": plan.stop, "step": plan.step,
        "algorithm": plan.algorithm, "record_every": plan.record_every,
        "record": list(plan.record), "order": list(plan.order)}
    if plan.component_steps:  # only a multirate run has the key: others keep their hash
        simulation["component_steps"] = dict(plan.component_steps)
    inputs: dict[str, Any] = {
        "manifest_sha256": job.manifest_sha256, "label": job.label,
        "variant": job.variant, "point": job.point, "parameters": job.parameters,
        "fmu_sha256": job.fmu_sha256,
        "tables": {cname: {"interpolation": dict(zip(info.table.names, info.table.modes))}
                   for cname, info in plan.models.items() if info.table is not None},
        "files": job.files,
        "simulation": simulation,
        "connections": [str(c) for c in plan.connections],
        "events": [{"name": event.name, "at": event.at,
                    "set": {f"{c}.{v}": value for c, v, value in event.sets}}
                   for event in plan.events],
        "versions": versions(),
    }
    integration = run_integration(job)
    if integration:
        inputs["integration"] = integration
    return inputs


def run_integration(job: Job) -> dict[str, dict[str, Any]]:
    """Each component integrated as Model Exchange (:mod:`agv_cosim.system.interface`):
    ``{"solver": .., "tolerance": ..}``; the others run through their co-simulation
    interface (or are time tables)."""
    return {cname: {"solver": info.integration.solver,
                    "tolerance": info.integration.tolerance}
            for cname, info in job.plan.models.items() if info.integration is not None}


def run_interfaces(job: Job) -> dict[str, str]:
    """The FMI interface each FMU component runs through ("co-simulation" or
    "model-exchange"; time tables left out)."""
    return {cname: "model-exchange" if info.integration is not None else "co-simulation"
            for cname, info in job.plan.models.items() if info.table is None}


def record_units(job: Job) -> dict[str, str | None]:
    """The unit of each column of the run's timeseries.csv (``time``: s), from the model
    descriptions (None: the variable declares none)."""
    units: dict[str, str | None] = {"time": "s"}
    for name in job.plan.record:
        cname, _, vname = name.partition(".")
        variable = job.plan.models[cname].variables.get(vname)
        units[name] = variable.unit if variable is not None else None
    return units


def recorded_inputs(job: Job) -> dict[str, Any]:
    """:func:`run_inputs` of ``job`` as run.json records them (``inputs``, read back):
    what compares equal to the ``inputs`` of an earlier run's run.json."""
    inputs: dict[str, Any] = json.loads(json_text(_exact(run_inputs(job))))
    return inputs


def inputs_sha256(inputs: dict[str, Any]) -> str:
    """SHA-256 of :func:`run_inputs` in a canonical JSON form (keys sorted; NaN and inf
    kept apart from null)."""
    text = json.dumps(inputs, sort_keys=True, separators=(",", ":"), allow_nan=True,
                      default=repr)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def _exact(value: Any) -> Any:
    """``value`` with its non-finite floats as text ("nan", "inf", "-inf"): a value an
    FMU declares legal is recorded as given, not as JSON's null."""
    if isinstance(value, dict):
        return {k: _exact(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_exact(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return repr(value)
    return value


def write_run_files(job: Job, run_dir: Path, rows: int, status: str, error: str | None,
                    values: dict[str, Any], metrics_error: str | None,
                    ended_by: str | None = None,
                    timeseries_sha256: str | None = None) -> RunResult:
    """Write metrics.json and run.json of a run (replacing ours); return its result.
    Neither file holds a timing: they are the same for the same inputs.
    ``timeseries_sha256``: the SHA-256 of the run's timeseries.csv as written (run.json's
    ``timeseries_sha256``, which ``--resume`` checks the file against)."""
    write_json(run_dir / "metrics.json", values, replace=True)
    inputs = run_inputs(job)
    digest = inputs_sha256(inputs)
    inputs = _exact(inputs)
    record: dict[str, Any] = {
        "label": job.label, "variant": job.variant, "sweep_point": _exact(job.point),
        "manifest": job.manifest_path, "manifest_sha256": job.manifest_sha256,
        "fmu_sha256": job.fmu_sha256,
        "fmus": job.fmu_paths or {c: str(info.path) for c, info in job.plan.models.items()},
        "parameters": _exact(job.parameters), "algorithm": job.plan.algorithm,
        "start": job.plan.start, "stop": job.plan.stop, "step": job.plan.step,
        "record_every": job.plan.record_every, "rows": rows,
        "timeseries_sha256": timeseries_sha256,
        "versions": inputs["versions"], "status": status,
        "error": error, "metrics_error": metrics_error, "partial": status != "complete",
        "ended_by": ended_by or ("stop time" if status == "complete" else None),
        "timeout_s": job.timeout, "inputs": inputs, "inputs_sha256": digest,
        "events": inputs["events"], "units": record_units(job),
        "interfaces": run_interfaces(job), "integration": run_integration(job)}
    if job.plan.component_steps:
        record["component_steps"] = dict(job.plan.component_steps)
    write_json(run_dir / "run.json", record, replace=True)
    return run_result(job, status, rows=rows, error=error, metrics=values,
                      metrics_error=metrics_error)


def output_digest(path: str | Path) -> tuple[str, int] | None:
    """``(SHA-256 in hex, size in bytes)`` of the regular file ``path`` (a run's
    output.txt), opened without following a link and without waiting on a FIFO; None when
    there is no regular file there or it cannot be read."""
    flags = os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC
    try:
        fd = os.open(path, flags)
    except OSError:
        return None
    with os.fdopen(fd, "rb") as stream:
        try:
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                return None
            digest, size = hashlib.sha256(), 0
            while block := stream.read(1 << 16):
                digest.update(block)
                size += len(block)
        except OSError:
            return None
    return digest.hexdigest(), size


def record_output(run_dir: str | Path) -> None:
    """Add to the run's run.json the SHA-256 and size of its output.txt as it is now
    (``output_sha256``, ``output_bytes``: what ``--resume`` checks a kept output.txt
    against); nothing when the run has no output.txt (a regular file) or no run.json it
    can read. run.json is replaced whole (a new file renamed onto it)."""
    run_dir = Path(run_dir)
    found = output_digest(run_dir / OUTPUT_FILE)
    if found is None:
        return
    try:
        record = read_json_object(run_dir / "run.json")
        if record is None:
            return
    except (OSError, UnreadableFile):
        return
    record["output_sha256"], record["output_bytes"] = found
    with signals_blocked():  # never a run folder left with the temporary file
        try:
            path, stream = create_beside(run_dir / "run.json")
        except OSError:
            return
        try:
            with stream:
                stream.write(json_text(record).encode("utf-8"))
            os.replace(path, run_dir / "run.json")
        except OSError:
            path.unlink(missing_ok=True)


def run_metrics(job: Job, run_dir: Path, rows: int) -> tuple[dict[str, Any], str | None]:
    """The metrics of a run from its timeseries.csv (streamed in chunks: memory does not
    grow with the run's length), and the error that stopped them (None); nothing for a
    run without ``[metrics]`` or without rows."""
    if not job.metrics_spec or not rows:
        return {}, None
    try:
        return dict(metrics.compute_metrics_csv(run_dir / "timeseries.csv", job.metrics_spec,
                                                base_dir=job.manifest_dir)), None
    except Exception as failure:  # noqa: BLE001 - reported in run.json
        return {}, f"{type(failure).__name__}: {failure}"


def finish_run(job: Job, run_dir: Path, rows: int, status: str, error: str | None,
               ended_by: str | None = None, timeseries_sha256: str | None = None,
               measure: bool = True) -> RunResult:
    """A run's record finished: its metrics from its timeseries.csv (:func:`run_metrics`;
    none unless ``measure``), then metrics.json and run.json (:func:`write_run_files`);
    return its result. What a worker reports (status, rows, error, how it ended) is all
    it takes."""
    values, metrics_error = run_metrics(job, run_dir, rows) if measure else ({}, None)
    return write_run_files(job, run_dir, rows, status, error, values, metrics_error,
                           ended_by, timeseries_sha256)


def finish_remote_run(job: Job, run_dir: Path, result: RunResult,
                      record: dict[str, Any]) -> RunResult:
    """The record of a run that ran on another machine (a Dask worker) finished here,
    where the manifest's files are: its metrics from the timeseries.csv written into
    ``run_dir`` (:func:`run_metrics`), metrics.json, and run.json as the worker wrote it
    (``record``: it names the worker's FMU copies and package versions) with the metrics'
    error. Returns ``result`` with the metrics."""
    values, metrics_error = run_metrics(job, run_dir, result["rows"])
    write_json(run_dir / "metrics.json", values)
    record["metrics_error"] = metrics_error
    write_json(run_dir / "run.json", record)
    result["metrics"], result["metrics_error"] = values, metrics_error
    return result


def timing_rows(results: list[RunResult]) -> list[dict[str, Any]]:
    """timings.csv's rows (:data:`TIMING_COLUMNS`), one per result: None where a value
    was not measured."""
    rows = []
    for result in results:
        paced = result.get("real_time") or {}
        row: dict[str, Any] = {"run": result["label"],
                               "wall_time_s": result.get("wall_time_s")}
        row.update({f"real_time_{k}": paced.get(k) for k in REAL_TIME_FIELDS})
        rows.append(row)
    return rows


def write_timings(path: str | Path, results: list[RunResult]) -> None:
    """Write timings.csv (:func:`timing_rows`; floats as ``repr``, None as empty) into
    a new file (:func:`~agv_cosim.files.create_file`)."""
    with create_file(path) as stream:
        writer = csv.DictWriter(stream, fieldnames=TIMING_COLUMNS)
        writer.writeheader()
        for row in timing_rows(results):
            writer.writerow({k: (repr(v) if isinstance(v, float) else v)
                             for k, v in row.items()})


def _number(text: str) -> int | float | None:
    """A cell of timings.csv read back: empty is None, else the int or float written."""
    if not text:
        return None
    try:
        return int(text)
    except ValueError:
        return float(text)


def read_timings(path: str | Path) -> dict[str, dict[str, Any]]:
    """The rows of a timings.csv by run label, each ``{"wall_time_s": ...,
    "real_time": {...}}`` (``real_time`` only for a paced run), as :func:`timing_rows`
    made them. Empty when the file is missing; rows that cannot be read are left out.
    A file that must not be read (not a regular file, larger than
    :data:`~agv_cosim.files.CSV_LIMIT`) raises :class:`~agv_cosim.errors.UnreadableFile`."""
    try:
        text = read_bytes(path, CSV_LIMIT).decode("utf-8")
        rows = list(csv.DictReader(io.StringIO(text, newline="")))
    except (OSError, UnicodeDecodeError, csv.Error):
        return {}
    found: dict[str, dict[str, Any]] = {}
    for row in rows:
        try:
            wall = _number(row.get("wall_time_s") or "")
            paced = {k: _number(row.get(f"real_time_{k}") or "") for k in REAL_TIME_FIELDS}
        except ValueError:
            continue
        entry: dict[str, Any] = {"wall_time_s": wall}
        if paced["target"] is not None:
            entry["real_time"] = paced
        if row.get("run"):
            found[row["run"]] = entry
    return found
