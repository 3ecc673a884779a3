"""Runs, variants, sweeps and parallel workers.

:func:`prepare` loads and validates a manifest into a list of :class:`Job` (one per
variant x sweep point); :func:`execute` runs them in worker processes (``forkserver``
context; up to ``workers`` at once) and writes the output folder::

    DIR/<run label>/timeseries.csv   time, then component.variable (csv module; repr floats)
    DIR/<run label>/metrics.json     metrics.compute_metrics(...) of the run
    DIR/<run label>/run.json         hashes, parameters, versions, wall time, status, and
                                     the run's inputs with their SHA-256
    DIR/<run label>/output.txt       what the run's process printed (only if it did)
    DIR/summary.csv                  one row per run: label, status, sweep values, metrics
    DIR/*.png                        plots.plot_runs(...) overlaying the runs
    DIR/partial.txt                  only in a folder kept after an interruption

A run's status is ``complete``, ``partial`` (rows recorded, then a failure), ``failed``,
``timed out`` (stopped at its wall-clock limit), ``interrupted`` (under way when a
signal came) or ``not run``.

Each run is independent and deterministic, so the parallel and the serial results are
byte-identical. ``DIR`` is assembled under a temporary name and renamed into place; on
SIGINT, SIGTERM or SIGHUP it is renamed into place marked partial when any run has rows.

Why worker processes: an FMU runs inside the process that loads it, and a failing
pythonfmu 0.7 FMU can damage its host's heap (see agv_core/fmi/pythonfmu_workarounds.py).
A worker runs the next job only after a run that ended ``complete``; after any other
ending it exits and a fresh worker takes the next job, so the damage ends with the run.
A worker that dies is reported as its run's failure (partial if it had recorded rows),
and the other runs go on. Reusing a worker after clean runs spares each later run the
process start and the import of the FMUs' bundled cores. Each worker leads a process
group of its own, so a run that exceeds its limit is ended with every process its FMUs
started.
"""
import importlib
import math
import os
import pickle
import platform
import shutil
import signal
import struct
import sys
import tempfile
import time
from dataclasses import dataclass
from multiprocessing import get_context
from multiprocessing.connection import wait
from pathlib import Path

from . import __version__, fmitypes, metrics, plots
from .lifetime import (Interrupted, die_with_parent, drop_helper_channels,
                       ignore_termination, kill_group, own_process_group, scratch_dir)
from .model import keep_extractions
from .manifest import Manifest, ManifestError, load_manifest
from .plan import plan_runs
from .system import validate
from .master import Plan, SimulationError, describe_track, record_types, simulate
from .results import (AtomicDir, CsvSink, FolderLost, count_rows, create_file, printable,
                      write_json, write_summary, write_text)


#: Modules the fork server imports once (issue 16: cheap extra runs), so that each run's
#: child starts with them instead of importing them again: this module (and with it
#: fmpy's wrapper, numpy, matplotlib) and the third-party modules the component cores
#: import at instantiation (scipy.signal alone took ~1 s a run on a 2-core machine).
#: Third-party only: the cores (agv_core) must still come from each FMU's own resources,
#: as the FMU was built. A module missing here is skipped by the fork server.
FORKSERVER_PRELOAD = (__name__, "fmpy.fmi2", "numpy", "scipy.signal", "scipy.linalg",
                      "scipy.optimize", "scipy.special", "scipy.integrate")


@dataclass
class Job:
    """One run, self-contained and picklable (sent to a worker process)."""

    label: str
    variant: str | None
    point: dict
    plan: Plan
    parameters: dict
    fmu_sha256: dict
    manifest_path: str
    manifest_sha256: str
    metrics_spec: dict
    fmu_paths: dict = None
    #: wall-clock limit of the run [s] (``[simulation] timeout`` or ``--timeout``); None:
    #: no limit. A run still going then is stopped and reported ``timed out``.
    timeout: float | None = None


def _start_value(var):
    if var.start is None or var.unsupported():
        return None
    try:
        return fmitypes.parse_text(var.ftype, var.start)
    except ValueError:
        return var.start


def _signal_sources(manifest):
    sources = []
    for name, spec, module in (("metrics", manifest.metrics, metrics),
                               ("plots", manifest.plots, plots)):
        if spec:
            try:
                sources.append((name, list(module.referenced_signals(spec))))
            except Exception as error:  # noqa: BLE001 - a bad spec is a manifest error
                raise ManifestError(manifest.path, name, str(error)) from None
    # a path string is checked now, not after the runs (it would leave metrics empty)
    base_dir = Path(manifest.path).parent
    for key, text in (("metrics.reference.path",
                       (manifest.metrics.get("reference") or {}).get("path")),
                      ("plots.trajectory.path",
                       (manifest.plots.get("trajectory") or {}).get("path"))):
        if isinstance(text, str):
            try:
                metrics.load_path(text, key, base_dir)
            except Exception as error:  # noqa: BLE001 - a bad path is a manifest error
                problem = str(error).removeprefix(f"{key}: ")
                raise ManifestError(manifest.path, key, problem) from None
    return sources


def prepare(manifest, variants=None, sets=(), source=None, timeout=None):
    """Load, expand and validate a manifest.

    ``manifest``: a manifest file, or a :class:`~agv_cosim.manifest.Manifest` already
    loaded (an SSP package read by :func:`agv_cosim.ssp_import.opened`: messages and
    run.json then name the package, its SHA-256, and its FMUs as
    ``<package>!/<path inside it>``). ``source`` is accepted for older callers and
    ignored (the package is the Manifest's own path now). ``timeout``: each run's
    wall-clock limit [s], instead of the manifest's ``[simulation] timeout``.

    Returns
    -------
    (Manifest, list of Job, list of str)
        The manifest, its jobs and the validation warnings.

    Raises
    ------
    ManifestError
    """
    if not isinstance(manifest, Manifest):
        manifest = load_manifest(manifest)
    runs = plan_runs(manifest, variants, sets)
    checked = validate(manifest, runs, _signal_sources(manifest))
    every = int(round(manifest.record_interval / manifest.step))
    jobs = []
    for run, models, order, events in zip(runs, checked.models, checked.orders,
                                          checked.events):
        params = {c: dict(comp.parameters) for c, comp in run.components.items()}
        effective = {c: {v.name: params[c].get(v.name, _start_value(v))
                         for v in info.parameters} for c, info in models.items()}
        plan = Plan(models=models, parameters=params, connections=manifest.connections,
                    order=order, record=checked.record, start=manifest.start,
                    stop=manifest.stop, step=manifest.step, algorithm=manifest.algorithm,
                    record_every=every, events=events)
        jobs.append(Job(label=run.label, variant=run.variant, point=run.point, plan=plan,
                        parameters=effective,
                        fmu_sha256={c: info.sha256 for c, info in models.items()},
                        manifest_path=str(manifest.path), manifest_sha256=manifest.sha256,
                        metrics_spec=manifest.metrics,
                        fmu_paths={c: _shown_path(info.path, manifest)
                                   for c, info in models.items()},
                        timeout=manifest.timeout if timeout is None else timeout))
    return manifest, jobs, checked.warnings


def _shown_path(path, manifest):
    """How run.json names an FMU: inside an unpacked .ssp as ``<ssp>!/<entry>``."""
    if manifest.unpacked is not None and manifest.unpacked in Path(path).parents:
        return f"{manifest.path}!/{Path(path).relative_to(manifest.unpacked).as_posix()}"
    return str(path)


def versions():
    """Versions of the packages a result depends on."""
    found = {"python": platform.python_version(), "agv_cosim": __version__}
    for name in ("fmpy", "pythonfmu", "numpy", "scipy"):
        try:
            found[name] = importlib.import_module(name).__version__
        except Exception:  # noqa: BLE001
            found[name] = None
    return found


def run_job(job, run_dir, progress=None, track=None, on_message=None):
    """Run one job into ``run_dir`` (created; its parent must exist); return its summary.

    Never raises for a simulation failure: the status is ``complete``, ``partial`` (some
    rows recorded, then a failure) or ``failed`` (nothing recorded). ``track`` and
    ``on_message`` are passed to :func:`~agv_cosim.master.simulate`. ``csv_bytes`` in
    the summary is the size of the ``timeseries.csv`` written.
    """
    run_dir = Path(run_dir)
    run_dir.mkdir(exist_ok=True)  # never its parents: a removed result folder stays gone
    types = record_types(job.plan)
    sink = CsvSink(run_dir / "timeseries.csv", job.plan.record,
                   None if all(t.is_float for t in types) else
                   [fmitypes.record_format(t) for t in types])
    rows, error, outcome = 0, None, {}
    begin = time.perf_counter()

    def write(row):
        nonlocal rows
        sink.write(row)
        rows += 1

    try:
        simulate(job.plan, write, progress, track, on_message, outcome)
    except SimulationError as failure:
        error = str(failure)
    except OSError as failure:  # writing the results failed (disk full, ...)
        error = f"cannot write {failure.filename or sink.path}: {failure.strerror or failure}"
    finally:
        try:
            sink.close()
        except OSError as failure:
            error = error or f"cannot write {sink.path}: {failure.strerror or failure}"
    wall = time.perf_counter() - begin
    status = "complete" if error is None else ("partial" if rows else "failed")
    values, metrics_error = {}, None
    if job.metrics_spec and rows:
        try:
            # streamed from the file in chunks: memory does not grow with the run's length
            values = dict(metrics.compute_metrics_csv(run_dir / "timeseries.csv",
                                                      job.metrics_spec,
                                                      base_dir=Path(job.manifest_path).parent))
        except Exception as failure:  # noqa: BLE001 - reported in run.json
            metrics_error = f"{type(failure).__name__}: {failure}"
    result = _finish(job, run_dir, rows, status, error, wall, values, metrics_error,
                     outcome.get("ended_by"))
    result["csv_bytes"] = sink.bytes
    return result


def run_inputs(job):
    """Everything a run's result depends on, as plain data (``run.json``'s ``inputs``):
    the manifest's hash, the run's variant, sweep point (and Monte Carlo sample),
    parameters (seeds included), FMU hashes, simulation settings, connections, events
    and package versions. Equal inputs (:func:`inputs_sha256`) give an equal result."""
    plan = job.plan
    return {
        "manifest_sha256": job.manifest_sha256, "label": job.label,
        "variant": job.variant, "point": job.point, "parameters": job.parameters,
        "fmu_sha256": job.fmu_sha256,
        "simulation": {"start": plan.start, "stop": plan.stop, "step": plan.step,
                       "algorithm": plan.algorithm, "record_every": plan.record_every,
                       "record": list(plan.record), "order": list(plan.order)},
        "connections": [str(c) for c in plan.connections],
        "events": [{"name": name, "at": at, "set": {f"{c}.{v}": value
                                                    for c, v, value in sets}}
                   for _, at, name, sets in plan.events],
        "versions": versions(),
    }


def inputs_sha256(inputs):
    """SHA-256 of :func:`run_inputs` in a canonical JSON form (keys sorted; NaN and inf
    kept apart from null)."""
    import hashlib
    import json

    text = json.dumps(inputs, sort_keys=True, separators=(",", ":"), allow_nan=True,
                      default=repr)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def _exact(value):
    """``value`` with its non-finite floats as text ("nan", "inf", "-inf"): a value an
    FMU declares legal is recorded as given, not as JSON's null."""
    if isinstance(value, dict):
        return {k: _exact(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_exact(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return repr(value)
    return value


def _finish(job, run_dir, rows, status, error, wall, values, metrics_error, ended_by=None):
    """Write metrics.json and run.json of a run (replacing ours); return its summary."""
    write_json(run_dir / "metrics.json", values, replace=True)
    inputs = run_inputs(job)
    digest = inputs_sha256(inputs)
    inputs = _exact(inputs)
    write_json(run_dir / "run.json", {
        "label": job.label, "variant": job.variant, "sweep_point": _exact(job.point),
        "manifest": job.manifest_path, "manifest_sha256": job.manifest_sha256,
        "fmu_sha256": job.fmu_sha256,
        "fmus": job.fmu_paths or {c: str(info.path) for c, info in job.plan.models.items()},
        "parameters": _exact(job.parameters), "algorithm": job.plan.algorithm,
        "start": job.plan.start, "stop": job.plan.stop, "step": job.plan.step,
        "record_every": job.plan.record_every, "rows": rows,
        "versions": inputs["versions"], "wall_time_s": wall, "status": status,
        "error": error, "metrics_error": metrics_error, "partial": status != "complete",
        "ended_by": ended_by or ("stop time" if status == "complete" else None),
        "timeout_s": job.timeout, "inputs": inputs, "inputs_sha256": digest,
        "events": inputs["events"]}, replace=True)
    return {"label": job.label, "status": status, "error": error, "rows": rows,
            "metrics": values, "metrics_error": metrics_error, "point": job.point,
            "variant": job.variant}


# --------------------------------------------------------------------------- channels
#
# A worker reports to the parent through a pipe of its own, in frames the parent reads
# without ever blocking: a 4-byte length, then a pickle of (kind, payload). A worker
# whose FMU writes into that pipe (it inherited the descriptor) is told apart: a frame
# that is too long, does not unpickle or is not a message of ours ends the worker, and
# its run is reported with a reason. The run process's stdout and stderr (fds 1 and 2)
# go to another pipe the parent reads into the run's folder (:class:`_OutputLog`).

_FRAME = struct.Struct("!I")
#: Longest frame accepted from a worker [bytes] (a result dict is a few kB).
MAX_FRAME = 16 << 20
_KINDS = ("progress", "message", "done", "checking", "failed")
#: Output of a run's process (FMU prints, Python warnings) kept in its folder [bytes];
#: what comes after is counted, not kept.
MAX_OUTPUT = 1 << 20
#: The file in a run's folder that holds its process's stdout and stderr (only when the
#: process wrote anything).
OUTPUT_FILE = "output.txt"


def _send_frame(fd, message):
    """Write one frame (see above) to ``fd``, whole."""
    data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
    view = memoryview(_FRAME.pack(len(data)) + data)
    while view:
        view = view[os.write(fd, view):]


class _PipeReader:
    """The parent's end of a pipe from a worker, read without ever blocking."""

    def __init__(self, connection):
        self.connection = connection  # keeps the descriptor open
        self.fd = connection.fileno()
        os.set_blocking(self.fd, False)
        self.closed = False

    def chunks(self, limit=1 << 22):
        """What the pipe holds now, in pieces (at most ``limit`` bytes in all); sets
        ``closed`` at its end."""
        got = 0
        while not self.closed and got < limit:
            try:
                chunk = os.read(self.fd, 1 << 16)
            except BlockingIOError:
                return
            except OSError:
                chunk = b""
            if not chunk:
                self.closed = True
                return
            got += len(chunk)
            yield chunk

    def close(self):
        self.connection.close()


class _Frames(_PipeReader):
    """A worker's frame pipe: complete messages, or ``broken`` set when it holds bytes
    that are not ours."""

    def __init__(self, connection):
        super().__init__(connection)
        self.buffer = bytearray()
        self.broken = None  # why the pipe's content cannot be ours

    def read(self):
        """The complete messages now in the pipe."""
        for chunk in self.chunks():
            self.buffer += chunk
        messages = []
        while self.broken is None and len(self.buffer) >= _FRAME.size:
            (size,) = _FRAME.unpack_from(self.buffer)
            if size > MAX_FRAME:
                self.broken = f"a frame of {size} bytes"
                break
            if len(self.buffer) < _FRAME.size + size:
                break
            data = bytes(self.buffer[_FRAME.size:_FRAME.size + size])
            del self.buffer[:_FRAME.size + size]
            try:
                message = pickle.loads(data)  # noqa: S301 - our own worker's process
            except Exception:  # noqa: BLE001 - anything: the pipe holds foreign bytes
                message = None
            if not (isinstance(message, tuple) and len(message) == 2
                    and message[0] in _KINDS):
                self.broken = "bytes that are no message of agv-cosim"
                break
            messages.append(message)
        return messages


class _OutputLog(_PipeReader):
    """A run process's stdout and stderr, read from a pipe into ``output.txt`` of the
    run's folder: at most :data:`MAX_OUTPUT` bytes kept, the rest counted. The file is
    created (``O_EXCL | O_NOFOLLOW``) only when there is output."""

    def __init__(self, connection):
        super().__init__(connection)
        self.path = None
        self.stream = None
        self.kept = 0
        self.dropped = 0

    def attach(self, run_dir):
        """Output from now on belongs to the run whose folder is ``run_dir``."""
        self.detach()
        self.path = Path(run_dir) / OUTPUT_FILE

    def read(self):
        for chunk in self.chunks():
            self._keep(chunk)

    def _keep(self, chunk):
        room = MAX_OUTPUT - self.kept
        if self.path is None or room <= 0:
            self.dropped += len(chunk)
            return
        if self.stream is None:
            try:
                self.path.parent.mkdir(exist_ok=True)
                self.stream = create_file(self.path, binary=True)
            except OSError:
                self.path = None
                self.dropped += len(chunk)
                return
        part = chunk[:room]
        try:
            self.stream.write(part)
        except OSError:
            pass
        self.kept += len(part)
        self.dropped += len(chunk) - len(part)

    def detach(self):
        """Close the current run's file (noting what was not kept)."""
        if self.stream is not None:
            try:
                if self.dropped:
                    self.stream.write(f"\n[agv-cosim: {self.dropped} more bytes of output "
                                      f"were not kept (at most {MAX_OUTPUT} bytes a run)]\n"
                                      .encode())
                self.stream.close()
            except OSError:
                pass
        self.stream, self.path, self.kept, self.dropped = None, None, 0, 0

    def close(self):
        self.detach()
        super().close()


def _flush_c_stdio():
    """Flush C stdio buffers of this process (an FMU's printf to a pipe is buffered)."""
    import ctypes
    import ctypes.util

    sys.stdout.flush()
    sys.stderr.flush()
    try:
        ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").fflush(None)
    except (OSError, AttributeError):
        pass


def _child_setup(output, life):
    """Common start of a process that runs FMUs: it drops multiprocessing's helper
    channels (an FMU cannot write into them), dies with its parent, leads a process
    group of its own with a guard that ends the group when this process ends or when
    ``life`` (the reading end of a pipe only the command's process writes) closes,
    ignores SIGINT (the parent stops it) and writes its stdout and stderr to
    ``output`` (a pipe Connection, or None for /dev/null)."""
    drop_helper_channels()
    die_with_parent()
    own_process_group(life.fileno())
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    target = os.open(os.devnull, os.O_WRONLY) if output is None else output.fileno()
    for fd in (1, 2):
        os.dup2(target, fd)
    if output is None:
        os.close(target)
    else:
        output.close()


def _worker(jobs, channel, output, life, scratch, track):
    """Body of a worker process: run the jobs the parent sends, one at a time.

    ``jobs`` is the reading end of a pipe that brings ``(job, run_dir)`` or None (stop);
    ``channel`` (frames, see above) carries progress, FMU messages and each result back;
    ``output`` receives the process's stdout and stderr; ``life`` closes when the
    command's process ends (see :func:`_child_setup`). A worker runs the next job
    only after a run that ended ``complete``: any other ending (a failed or partial
    run, an FMU error) may have left the process damaged (pythonfmu, see
    agv_core/fmi/pythonfmu_workarounds.py), so the worker then exits and the parent
    starts a fresh one. Reusing a worker spares each later run the process start and the
    import of the FMUs' bundled cores (benchmarks/bench_runs.py).

    FMUs are extracted under ``scratch``, which the parent deletes however the worker
    ends (a process that dies cannot clean up after itself). See :func:`_child_setup`
    for how the worker lives and ends.
    """
    _child_setup(output, life)
    tempfile.tempdir = scratch
    keep_extractions(scratch)  # each FMU unpacked once per worker (the parent deletes it)
    fd = channel.fileno()

    def send(message):
        try:
            _send_frame(fd, message)
        except OSError:  # the parent is gone (BrokenPipeError): nobody to report to
            os._exit(1)

    def progress(steps):
        send(("progress", steps))

    while True:
        try:
            task = jobs.recv()
        except (EOFError, OSError):  # the parent is gone
            os._exit(1)
        if task is None:
            break
        job, run_dir = task
        track[:] = [0.0] * len(track)
        warnings = [0]

        def message(component, status, text):
            # errors (and the first 100 warnings) reach the parent before a crash loses them
            if status >= 3 or (status >= 1 and warnings[0] < 100):
                warnings[0] += status < 3
                send(("message", f"{component}: {' '.join(text.split())}"))

        try:
            result = run_job(job, run_dir, progress, track, message)
        except Exception as failure:  # noqa: BLE001 - e.g. a full disk: report, no traceback
            result = {"label": job.label, "status": "failed", "rows": 0, "metrics": {},
                      "error": f"{type(failure).__name__}: {failure}",
                      "metrics_error": None, "point": job.point, "variant": job.variant}
        _flush_c_stdio()  # the run's output is in the pipe before its result
        send(("done", result))
        if result["status"] != "complete":
            break
    channel.close()


def _ended(job, run_dir, status, how, track, last_message):
    """The summary of a run whose process ended before it reported: ``how`` says what
    happened; ``track`` (shared with the process) names the component, call and time;
    ``last_message`` is the last message an FMU of the run logged (or None). ``status``
    None means ``partial`` with rows recorded, else ``failed``."""
    run_dir = Path(run_dir)
    csv_file = run_dir / "timeseries.csv"
    rows = count_rows(csv_file) if csv_file.is_file() else 0
    if status is None:
        status = "partial" if rows else "failed"
    error = (f"{how} in {describe_track(track, list(job.plan.models))} after {rows} "
             "recorded rows" + (f"; last FMU message: {last_message}" if last_message else ""))
    values, metrics_error = {}, None
    if job.metrics_spec and rows and status != "interrupted":  # as for any partial run
        try:
            values = dict(metrics.compute_metrics_csv(
                csv_file, job.metrics_spec, base_dir=Path(job.manifest_path).parent))
        except Exception as failure:  # noqa: BLE001 - reported in run.json
            metrics_error = f"{type(failure).__name__}: {failure}"
    try:
        run_dir.mkdir(exist_ok=True)  # not its parents: a removed result folder stays gone
        return _finish(job, run_dir, rows, status, error, None, values, metrics_error)
    except OSError:  # the result folder is gone: the summary only
        return {"label": job.label, "status": status, "error": error, "rows": rows,
                "metrics": {}, "metrics_error": None, "point": job.point,
                "variant": job.variant}


def _not_run(job, why="not run"):
    """The summary of a run that never started."""
    return {"label": job.label, "status": why, "error": None, "rows": 0, "metrics": {},
            "metrics_error": None, "point": job.point, "variant": job.variant}


def _process_end(exitcode):
    if exitcode is None:
        return "the run's process ended"
    how = f"signal {-exitcode}" if exitcode < 0 else f"exit code {exitcode}"
    return f"the run's process died ({how})"


def _run_isolated(jobs, root, workers, on_progress, on_done):
    """Run every job in a worker process, ``workers`` processes at a time.

    A worker runs one job at a time and gets the next one only if its last run ended
    ``complete`` (see :func:`_worker`); otherwise it exits and a fresh worker takes the
    next job, so a failing or crashing FMU affects its own run only. Each worker reports
    through a pipe of its own, read without blocking (one that dies mid-message, or
    whose FMU writes into the pipe, cannot block the others), and its end is seen from
    the process itself (not from the pipe, which a process the FMU forked may hold).

    A run longer than its ``job.timeout`` [s] is stopped (its process group killed) and
    reported ``timed out``; the other runs go on. On SIGINT, SIGTERM or SIGHUP the
    workers are stopped, the runs under way reported ``interrupted`` and the waiting
    ones ``not run``; the exception is re-raised with those results (``.results``) and
    the termination signals ignored until ``.restore()`` is called, so that the caller
    can keep what was done.
    """
    context = get_context("forkserver")
    context.set_forkserver_preload(list(FORKSERVER_PRELOAD))
    results = [None] * len(jobs)
    last_message = [None] * len(jobs)
    waiting = list(range(len(jobs)))
    pool = []  # each: dict(process, send, frames, output, scratch, track, index, deadline)
    # closes when this process ends, however: each worker's guard then ends its group
    life_reader, life_writer = context.Pipe(duplex=False)

    def start_worker():
        job_reader, job_writer = context.Pipe(duplex=False)
        reader, writer = context.Pipe(duplex=False)
        out_reader, out_writer = context.Pipe(duplex=False)
        scratch = scratch_dir("run")
        track = context.RawArray("d", 3)  # where the worker is (master.simulate)
        track[0] = -1.0  # no component yet
        process = context.Process(target=_worker, name="agv-cosim worker",
                                  args=(job_reader, writer, out_writer, life_reader, scratch,
                                        track))
        process.start()
        for end in (job_reader, writer, out_writer):
            end.close()
        worker = {"process": process, "send": job_writer, "frames": _Frames(reader),
                  "output": _OutputLog(out_reader), "scratch": scratch, "track": track,
                  "index": None, "deadline": None}
        pool.append(worker)
        return worker

    def give(worker):
        index = waiting.pop(0)
        worker["index"] = index
        job = jobs[index]
        worker["deadline"] = time.monotonic() + job.timeout if job.timeout else None
        worker["output"].attach(root / job.label)
        try:
            worker["send"].send((job, root / job.label))
        except OSError:  # the worker is already gone: its end is seen below
            pass

    def end(worker, status=None, how=None):
        """Stop a worker (its whole process group) and clean up after it; a run it was
        doing gets ``how`` as its reason (default: how its process ended)."""
        process = worker["process"]
        kill_group(process)
        process.join()
        worker["output"].read()
        index = worker["index"]
        if index is not None and results[index] is None:
            job = jobs[index]
            results[index] = _ended(job, root / job.label, status,
                                    how or _process_end(process.exitcode),
                                    worker["track"], last_message[index])
            on_done()
        worker["output"].close()
        worker["send"].close()
        worker["frames"].close()
        shutil.rmtree(worker["scratch"], ignore_errors=True)
        if worker in pool:  # (an interruption may have come in the middle of an end)
            pool.remove(worker)

    def handle(worker, kind, payload):
        index = worker["index"]
        if kind == "progress":
            on_progress(payload)
        elif kind == "message" and index is not None:
            last_message[index] = payload
        elif kind == "done" and index is not None:
            worker["output"].read()  # the run's output was written before its result
            results[index] = payload
            worker["index"] = worker["deadline"] = None
            on_done()
            if payload["status"] != "complete":
                return  # the worker exits by itself: its end retires it
            if waiting:
                give(worker)
            else:  # nothing left for it: let it exit
                try:
                    worker["send"].send(None)
                except OSError:
                    pass

    try:
        while waiting or pool:
            while waiting and len(pool) < workers:
                give(start_worker())
            now = time.monotonic()
            deadlines = [w["deadline"] for w in pool if w["deadline"] is not None]
            pause = min([1.0] + [max(0.0, d - now) for d in deadlines])
            handles = [w["process"].sentinel for w in pool]
            handles += [w["frames"].fd for w in pool if not w["frames"].closed]
            handles += [w["output"].fd for w in pool if not w["output"].closed]
            wait(handles, timeout=pause)
            now = time.monotonic()
            for worker in list(pool):
                worker["output"].read()
                for kind, payload in worker["frames"].read():
                    handle(worker, kind, payload)
                if worker["frames"].broken:
                    end(worker, how="the run's process wrote data that is no message of "
                                    "agv-cosim into its result channel (an FMU writing into "
                                    "a file descriptor it does not own) and was stopped")
                elif not worker["process"].is_alive():
                    for kind, payload in worker["frames"].read():  # its last words
                        handle(worker, kind, payload)
                    end(worker)
                elif worker["deadline"] is not None and now >= worker["deadline"]:
                    job = jobs[worker["index"]]
                    end(worker, "timed out", f"the run exceeded its wall-clock limit of "
                                             f"{job.timeout!r} s and was stopped")
    except BaseException as stop:
        if isinstance(stop, (KeyboardInterrupt, Interrupted)):
            stop.restore = ignore_termination()
            name = getattr(stop, "name", "SIGINT")
            for worker in list(pool):
                end(worker, "interrupted", f"interrupted by {name}")
            stop.results = [r if r is not None else _not_run(jobs[i])
                            for i, r in enumerate(results)]
        raise
    finally:
        for worker in list(pool):
            end(worker)
        life_reader.close()
        life_writer.close()
    return results


def _check_child(checks, channel, life, scratch):
    """Body of the initialisation check's child: instantiate and initialise each FMU."""
    from .master import _set_parameter
    from .model import FmuInstance

    _child_setup(None, life)  # an FMU's prints go nowhere: validate writes no results
    tempfile.tempdir = scratch
    keep_extractions(scratch)  # an FMU checked with several parameter sets: unpacked once
    fd = channel.fileno()

    def send(message):
        try:
            _send_frame(fd, message)
        except OSError:
            os._exit(1)

    for index, (cname, info, values, start, stop) in enumerate(checks):
        send(("checking", index))
        instance, failure = None, None
        try:
            # instances one after the other: the FMU's one extraction serves them all
            instance = FmuInstance(info, cname, shared=True)
            slave = instance.slave
            call = "fmi2SetupExperiment"
            slave.setupExperiment(startTime=start, stopTime=stop)
            for pname, value in values.items():
                call = f"setting parameter '{pname}'"
                _set_parameter(slave, info.variables[pname], value)
            call = "fmi2EnterInitializationMode"
            slave.enterInitializationMode()
            call = "fmi2ExitInitializationMode"
            slave.exitInitializationMode()
        except Exception as error:  # noqa: BLE001 - the FMU's refusal is the result
            detail = instance.last_error() if instance is not None else ""
            call = getattr(error, "function", None) or (call if instance else
                                                         "fmi2Instantiate")
            failure = f"{call} failed" + (f": {detail}" if detail else f" ({error})")
        finally:
            if instance is not None:
                instance.close()
        if failure:
            send(("failed", (index, failure)))
            os._exit(0)  # a failed pythonfmu instance may have damaged the heap
    send(("done", None))
    os._exit(0)


#: Default limit [s] of ``validate``'s initialisation check, per FMU instance (its
#: instantiation and initialisation), when neither ``--timeout`` nor the manifest's
#: ``[simulation] timeout`` gives one. Far above what a sound FMU needs (a component
#: FMU of this project takes about a second on a loaded 2-core machine).
INIT_TIMEOUT = 60.0


def check_initialisation(manifest, jobs, timeout=None):
    """Instantiate and initialise each FMU once with each run's parameters.

    Catches what only the FMU knows (a parameter value it refuses), without running.
    The FMUs run in a child process of their own (see the module docstring); each
    distinct (FMU, parameter values) pair is checked once (for the first component
    that has it), and the first refusal stops. An
    FMU that takes longer than ``timeout`` [s] (default: the manifest's ``[simulation]
    timeout``, else :data:`INIT_TIMEOUT`) to instantiate and initialise is stopped.

    Raises
    ------
    ManifestError
        Naming the component, the run, the FMI call and the FMU's own message.
    """
    if timeout is None:
        timeout = manifest.timeout if getattr(manifest, "timeout", None) else INIT_TIMEOUT
    checks, where, seen = [], [], set()
    for job in jobs:
        for cname, info in job.plan.models.items():
            values = job.plan.parameters.get(cname, {})
            key = (info.sha256, repr(sorted(values.items())))
            if key in seen:
                continue
            seen.add(key)
            checks.append((cname, info, values, job.plan.start, job.plan.stop))
            where.append((cname, job.label))
    if not checks:
        return
    context = get_context("forkserver")
    context.set_forkserver_preload(list(FORKSERVER_PRELOAD))
    reader, writer = context.Pipe(duplex=False)
    life_reader, life_writer = context.Pipe(duplex=False)
    scratch = scratch_dir("check")
    process = context.Process(target=_check_child, name="agv-cosim check",
                              args=(checks, writer, life_reader, scratch))
    frames = _Frames(reader)
    current, failure, finished = None, None, False
    deadline = time.monotonic() + timeout
    try:
        process.start()
        writer.close()
        while failure is None and not finished:
            now = time.monotonic()
            handles = [process.sentinel] + ([frames.fd] if not frames.closed else [])
            wait(handles, timeout=min(1.0, max(0.0, deadline - now)))
            for kind, payload in frames.read():
                if kind == "checking":
                    current, deadline = payload, time.monotonic() + timeout
                elif kind == "failed":
                    failure = (*payload, True)
                elif kind == "done":
                    finished = True
            if failure is not None or finished:
                break
            if frames.broken:
                failure = (current if current is not None else 0,
                           "the FMU's process wrote data that is no message of agv-cosim "
                           "into its channel (an FMU writing into a file descriptor it does "
                           "not own)", False)
            elif not process.is_alive():
                for kind, payload in frames.read():
                    if kind == "failed":
                        failure = (*payload, True)
                    elif kind == "done":
                        finished = True
                if failure is None and not finished:
                    process.join()
                    code = process.exitcode
                    how = f"signal {-code}" if code and code < 0 else f"exit code {code}"
                    failure = (current if current is not None else 0,
                               f"the FMU's process died ({how}) while it was instantiated "
                               "and initialised", False)
            elif time.monotonic() >= deadline:
                failure = (current if current is not None else 0,
                           f"the FMU did not finish instantiating and initialising within "
                           f"{timeout!r} s and was stopped (--timeout sets the limit)",
                           False)
    finally:
        kill_group(process)
        if process.pid is not None:
            process.join()
        frames.close()
        life_reader.close()
        life_writer.close()
        shutil.rmtree(scratch, ignore_errors=True)
    if failure is not None:
        index, text, refused = failure
        cname, label = where[index]
        raise ManifestError(manifest.path, f"components.{cname}",
                            f"the FMU refuses to initialise (run {label}): {text}"
                            if refused else f"run {label}: {text}")


def default_out_dir(manifest):
    """``results/<manifest name>`` relative to the current folder."""
    return Path("results") / manifest.name


def execute(manifest, jobs, out_dir=None, workers=None, quiet=False, overwrite=False,
            dask=None):
    """Run ``jobs`` and write the output folder (see the module docstring).

    Parameters
    ----------
    manifest : Manifest
    jobs : list of Job
    out_dir : path, optional
        Default :func:`default_out_dir`.
    workers : int, optional
        Runs at once, each in its own process (default: one per core).
    quiet : bool
        No progress bars.
    overwrite : bool
        Replace ``out_dir`` even when it is not a result folder of ours (see
        :class:`~agv_cosim.results.AtomicDir`; without it such a folder is refused).
    dask : str, optional
        Address of a Dask scheduler (``tcp://HOST:PORT``): run the jobs on that cluster
        (see :mod:`agv_cosim.distributed`) instead of local processes; ``workers`` is
        then unused. Raises :class:`~agv_cosim.distributed.ClusterError`.

    Returns
    -------
    (Path, list of dict)
        The output folder and one result dict per job (in job order).
    """
    out_dir = Path(out_dir) if out_dir else default_out_dir(manifest)
    workers = workers or os.cpu_count() or 1
    workers = max(1, min(workers, len(jobs)))
    with AtomicDir(out_dir, overwrite=overwrite) as folder:
        total = sum(int(round((job.plan.stop - job.plan.start) / job.plan.step))
                    for job in jobs)
        bar = _progress_bar()(total=total, desc=manifest.name, unit="step", delay=2.0, disable=quiet,
                   file=sys.stderr, mininterval=0.5, postfix={"runs": f"0/{len(jobs)}"})
        finished = 0

        def run_done():
            nonlocal finished
            finished += 1
            bar.set_postfix(runs=f"{finished}/{len(jobs)}")

        try:
            if dask:
                from .distributed import run_on_dask

                results = run_on_dask(dask, jobs, folder.path, bar.update, run_done)
            else:
                results = _run_isolated(jobs, folder.path, workers, bar.update, run_done)
        except BaseException as stop:
            bar.close()  # before any message: the error is the last line on stderr
            _keep_partial(manifest, jobs, folder, stop)
            raise
        bar.close()
        folder.check_intact()
        results = [_checked_files(job, result, folder.path)
                   for job, result in zip(jobs, results)]
        _write_summary(folder, results)
        if getattr(manifest, "montecarlo", None) is not None:
            from . import montecarlo

            figure_error = montecarlo.write_outputs(manifest.montecarlo, jobs, results,
                                                    folder.path, manifest.name)
            if figure_error:
                write_text(folder.path / "montecarlo_error.txt", figure_error + "\n")
                print(printable(f"agv-cosim: warning: {manifest.path}: montecarlo figure: "
                                f"{figure_error}"), file=sys.stderr)
        plot_error = _plots(manifest, jobs, results, folder.path)
        if plot_error:
            write_text(folder.path / "plots_error.txt", plot_error + "\n")
            print(printable(f"agv-cosim: warning: {manifest.path}: plots: {plot_error}"),
                  file=sys.stderr)
        target = folder.commit()
    return target, results


def _progress_bar():
    """tqdm whose ``close`` ends the bar's line whenever the bar was drawn.

    tqdm's ``close`` leaves the line open when no ``update`` drew the bar after its
    ``delay``, although ``set_postfix`` and tqdm's monitor thread draw it through
    ``refresh``; a message printed after ``close`` then lands on the bar's line."""
    from tqdm import tqdm

    class Bar(tqdm):
        drawn = False

        def display(self, *args, **kwargs):
            self.drawn = True
            return super().display(*args, **kwargs)

        def close(self):
            if self.drawn and not self.disable and hasattr(self, "last_print_t"):
                self.last_print_t = max(self.last_print_t, self.start_t + self.delay)
            super().close()

    return Bar


def _write_summary(folder, results):
    rows = []
    for result in results:
        row = {"run": result["label"], "variant": result["variant"] or "",
               "status": result["status"]}
        row.update(result["point"])
        row.update(result["metrics"])
        rows.append(row)
    write_summary(folder.path / "summary.csv", rows)


def _checked_files(job, result, root):
    """``result``, unless the run's files are not what its process wrote (its folder
    removed or changed during the sweep): then the run is ``failed`` and says why."""
    if result["status"] not in ("complete", "partial"):
        return result
    run_dir = Path(root) / job.label
    problem = None
    try:
        size = (run_dir / "timeseries.csv").stat().st_size
        if not (run_dir / "run.json").is_file():
            problem = "its run.json is missing"
        elif result.get("csv_bytes") is not None and size != result["csv_bytes"]:
            problem = (f"its timeseries.csv has {size} bytes, {result['csv_bytes']} were "
                       "written")
    except OSError:
        problem = "its timeseries.csv is missing"
    if problem is None:
        return result
    return dict(result, status="failed", metrics={},
                error=f"its folder was removed or changed during the sweep ({problem}); "
                      "its results are lost")


def _keep_partial(manifest, jobs, folder, stop):
    """After an interruption (or a cluster that went away), commit the folder marked
    partial when a run has results (``stop.results``, one per job); ``stop.kept`` is
    then the folder. Termination signals stay ignored meanwhile (``stop.restore``)."""
    restore = getattr(stop, "restore", None)
    try:
        results = getattr(stop, "results", None)
        if results is None or not any(r["rows"] for r in results):
            return
        if not folder.intact():
            return
        results = [_checked_files(job, result, folder.path)
                   for job, result in zip(jobs, results)]
        complete = sum(r["status"] == "complete" for r in results)
        reason = getattr(stop, "reason", None) or (
            f"interrupted by {getattr(stop, 'name', 'SIGINT')}")
        try:
            _write_summary(folder, results)
            folder.mark_partial(reason, complete, len(results))
            stop.kept = folder.commit()
        except (OSError, FolderLost):  # nothing to keep: the first error is the story
            return
        stop.results = results
    finally:
        if restore is not None:
            restore()


def _plots(manifest, jobs, results, out_dir):
    if not manifest.plots:
        return None
    try:
        runs = []
        for job, result in zip(jobs, results):
            if not result["rows"]:
                continue
            # read in chunks and decimated: the parent never holds a run's time series
            run = plots.read_run(out_dir / job.label / "timeseries.csv", manifest.plots,
                                 job.label, rows=result["rows"],
                                 partial=result["status"] != "complete")
            run.events = [(at, name) for _, at, name, _ in job.plan.events]
            runs.append(run)
        if runs:
            plots.plot_runs(runs, manifest.plots, out_dir,
                            base_dir=Path(manifest.path).parent)
    except Exception as failure:  # noqa: BLE001 - a plot must not lose the results
        return f"{type(failure).__name__}: {failure}"
    return None


def run_manifest(manifest_path, out_dir=None, variants=None, sets=(), workers=None,
                 quiet=False):
    """Validate and run a manifest; return (out folder, results, warnings)."""
    manifest, jobs, warnings = prepare(manifest_path, variants, sets)
    target, results = execute(manifest, jobs, out_dir, workers, quiet)
    return target, results, warnings
