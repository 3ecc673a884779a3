"""Runs, variants, sweeps and parallel workers.

:func:`prepare` loads and validates a manifest into a list of :class:`Job` (one per
variant x sweep point); :func:`execute` runs them in worker processes (``forkserver``
context; up to ``workers`` at once) and writes the output folder::

    DIR/<run label>/timeseries.csv   time, then component.variable (repr floats)
    DIR/<run label>/metrics.json     metrics.compute_metrics(...) of the run
    DIR/<run label>/run.json         hashes, parameters, versions, wall time, status
    DIR/summary.csv                  one row per run: label, status, sweep values, metrics
    DIR/*.png                        plots.plot_runs(...) overlaying the runs

Each run is independent and deterministic, so the parallel and the serial results are
byte-identical. ``DIR`` is assembled under a temporary name and renamed into place.

Why worker processes: an FMU runs inside the process that loads it, and a failing
pythonfmu 0.7 FMU can damage its host's heap (see agv_core/fmi/pythonfmu_workarounds.py).
A worker runs the next job only after a run that ended ``complete``; after any other
ending it exits and a fresh worker takes the next job, so the damage ends with the run.
A worker that dies is reported as its run's failure (partial if it had recorded rows),
and the other runs go on. Reusing a worker after clean runs spares each later run the
process start and the import of the FMUs' bundled cores.
"""

import importlib
import os
import platform
import shutil
import signal
import sys
import tempfile
import time
from dataclasses import dataclass
from multiprocessing import get_context
from multiprocessing.connection import wait
from pathlib import Path

from . import __version__, fmitypes, metrics, plots
from .lifetime import die_with_parent, scratch_dir
from .model import keep_extractions
from .manifest import Manifest, ManifestError, load_manifest
from .plan import plan_runs
from .system import validate
from .master import Plan, SimulationError, describe_track, record_types, simulate
from .results import AtomicDir, CsvSink, count_rows, write_json, write_summary


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


def prepare(manifest, variants=None, sets=(), source=None):
    """Load, expand and validate a manifest.

    ``manifest``: a manifest file, or a :class:`~agv_cosim.manifest.Manifest` already
    loaded (an SSP package read by :func:`agv_cosim.ssp_import.opened`: messages and
    run.json then name the package, its SHA-256, and its FMUs as
    ``<package>!/<path inside it>``). ``source`` is accepted for older callers and
    ignored (the package is the Manifest's own path now).

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
                                   for c, info in models.items()}))
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
    """Run one job into ``run_dir`` (created); return its summary dict.

    Never raises for a simulation failure: the status is ``complete``, ``partial`` (some
    rows recorded, then a failure) or ``failed`` (nothing recorded). ``track`` and
    ``on_message`` are passed to :func:`~agv_cosim.master.simulate`.
    """
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
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
    return _finish(job, run_dir, rows, status, error, wall, values, metrics_error,
                   outcome.get("ended_by"))


def _finish(job, run_dir, rows, status, error, wall, values, metrics_error, ended_by=None):
    """Write metrics.json and run.json of a run; return its summary dict."""
    write_json(run_dir / "metrics.json", values)
    write_json(run_dir / "run.json", {
        "label": job.label, "variant": job.variant, "sweep_point": job.point,
        "manifest": job.manifest_path, "manifest_sha256": job.manifest_sha256,
        "fmu_sha256": job.fmu_sha256,
        "fmus": job.fmu_paths or {c: str(info.path) for c, info in job.plan.models.items()},
        "parameters": job.parameters, "algorithm": job.plan.algorithm,
        "start": job.plan.start, "stop": job.plan.stop, "step": job.plan.step,
        "record_every": job.plan.record_every, "rows": rows,
        "versions": versions(), "wall_time_s": wall, "status": status, "error": error,
        "metrics_error": metrics_error, "partial": status != "complete",
        "ended_by": ended_by or ("stop time" if status == "complete" else None),
        "events": [{"name": name, "at": at, "set": {f"{c}.{v}": value
                                                    for c, v, value in sets}}
                   for _, at, name, sets in job.plan.events]})
    return {"label": job.label, "status": status, "error": error, "rows": rows,
            "metrics": values, "metrics_error": metrics_error, "point": job.point,
            "variant": job.variant}


def _worker(jobs, channel, scratch, track):
    """Body of a worker process: run the jobs the parent sends, one at a time.

    ``jobs`` is the reading end of a pipe that brings ``(job, run_dir)`` or None (stop);
    ``channel`` carries progress, FMU messages and each result back. A worker runs the
    next job only after a run that ended ``complete``: any other ending (a failed or
    partial run, an FMU error) may have left the process damaged (pythonfmu, see
    agv_core/fmi/pythonfmu_workarounds.py), so the worker then exits and the parent
    starts a fresh one. Reusing a worker spares each later run the process start and the
    import of the FMUs' bundled cores (benchmarks/bench_runs.py).

    FMUs are extracted under ``scratch``, which the parent deletes however the worker
    ends (a process that dies cannot clean up after itself). The worker dies with its
    parent (:func:`~agv_cosim.lifetime.die_with_parent`), ignores SIGINT (the parent,
    which a Ctrl-C reaches too, stops it) and ends quietly when the parent is gone.
    """
    die_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    tempfile.tempdir = scratch
    keep_extractions(scratch)  # each FMU unpacked once per worker (the parent deletes it)

    def send(message):
        try:
            channel.send(message)
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
        send(("done", result))
        if result["status"] != "complete":
            break
    channel.close()


def _died(job, run_dir, exitcode, track, last_message):
    """The summary of a run whose child process died before it reported.

    ``track`` (shared with the child) names the component, call and time it died in;
    ``last_message`` is the last message an FMU of the run logged (or None).
    """
    csv = Path(run_dir) / "timeseries.csv"
    rows = count_rows(csv) if csv.is_file() else 0
    how = f"signal {-exitcode}" if exitcode < 0 else f"exit code {exitcode}"
    error = (f"the run's process died ({how}) in {describe_track(track, list(job.plan.models))}"
             f" after {rows} recorded rows"
             + (f"; last FMU message: {last_message}" if last_message else ""))
    Path(run_dir).mkdir(parents=True, exist_ok=True)
    return _finish(job, run_dir, rows, "partial" if rows else "failed", error, None, {}, None)


def _run_isolated(jobs, root, workers, on_progress, on_done):
    """Run every job in a worker process, ``workers`` processes at a time.

    A worker runs one job at a time and gets the next one only if its last run ended
    ``complete`` (see :func:`_worker`); otherwise it exits and a fresh worker takes the
    next job, so a failing or crashing FMU affects its own run only. Each worker reports
    through a pipe of its own, so one that dies mid-message cannot block the others (a
    shared queue's lock can stay held by a dead process).
    """
    context = get_context("forkserver")
    context.set_forkserver_preload(list(FORKSERVER_PRELOAD))
    results = [None] * len(jobs)
    last_message = [None] * len(jobs)
    waiting = list(range(len(jobs)))
    pool = []  # each: dict(process, send, reader, scratch, track, index)

    def start_worker():
        job_reader, job_writer = context.Pipe(duplex=False)
        reader, writer = context.Pipe(duplex=False)
        scratch = scratch_dir("run")
        track = context.RawArray("d", 3)  # where the worker is (master.simulate)
        process = context.Process(target=_worker, name="agv-cosim worker",
                                  args=(job_reader, writer, scratch, track))
        process.start()
        job_reader.close()
        writer.close()
        worker = {"process": process, "send": job_writer, "reader": reader,
                  "scratch": scratch, "track": track, "index": None}
        pool.append(worker)
        return worker

    def give(worker):
        index = waiting.pop(0)
        worker["index"] = index
        try:
            worker["send"].send((jobs[index], root / jobs[index].label))
        except OSError:  # the worker is already gone: its end is read below as EOF
            pass

    def retire(worker):
        worker["send"].close()
        worker["reader"].close()
        worker["process"].join()
        shutil.rmtree(worker["scratch"], ignore_errors=True)
        pool.remove(worker)

    try:
        while waiting or pool:
            while waiting and len(pool) < workers:
                give(start_worker())
            ready = wait([w["reader"] for w in pool], timeout=1.0)
            for worker in [w for w in pool if w["reader"] in ready]:
                index = worker["index"]
                try:
                    kind, payload = worker["reader"].recv()
                except EOFError:  # the worker has ended, with or without its result
                    if index is not None and results[index] is None:
                        worker["process"].join()
                        results[index] = _died(jobs[index], root / jobs[index].label,
                                               worker["process"].exitcode, worker["track"],
                                               last_message[index])
                        on_done()
                    retire(worker)
                    continue
                if kind == "progress":
                    on_progress(payload)
                elif kind == "message":
                    last_message[index] = payload
                else:
                    results[index] = payload
                    worker["index"] = None
                    on_done()
                    if payload["status"] != "complete":
                        continue  # the worker exits by itself: its EOF retires it
                    if waiting:
                        give(worker)
                    else:  # nothing left for it: let it exit
                        try:
                            worker["send"].send(None)
                        except OSError:
                            pass
    finally:
        for worker in pool:
            worker["process"].kill()
            worker["process"].join()
            worker["send"].close()
            worker["reader"].close()
            shutil.rmtree(worker["scratch"], ignore_errors=True)
    return results


def _check_child(checks, channel, scratch):
    """Body of the initialisation check's child: instantiate and initialise each FMU."""
    from .master import _set_parameter
    from .model import FmuInstance

    die_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    tempfile.tempdir = scratch
    keep_extractions(scratch)  # an FMU checked with several parameter sets: unpacked once
    for index, (cname, info, values, start, stop) in enumerate(checks):
        try:
            channel.send(("checking", index))
        except OSError:
            os._exit(1)
        instance, failure = None, None
        try:
            instance = FmuInstance(info, cname)
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
            try:
                channel.send(("failed", (index, failure)))
            except OSError:
                pass
            os._exit(0)  # a failed pythonfmu instance may have damaged the heap
    try:
        channel.send(("done", None))
    except OSError:
        pass
    os._exit(0)


def check_initialisation(manifest, jobs):
    """Instantiate and initialise each FMU once with each run's parameters.

    Catches what only the FMU knows (a parameter value it refuses), without running.
    The FMUs run in a child process of their own (see the module docstring); each
    distinct (FMU, parameters) pair is checked once, and the first refusal stops.

    Raises
    ------
    ManifestError
        Naming the component, the run, the FMI call and the FMU's own message.
    """
    checks, where, seen = [], [], set()
    for job in jobs:
        for cname, info in job.plan.models.items():
            values = job.plan.parameters.get(cname, {})
            key = (info.sha256, cname, repr(sorted(values.items())))
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
    scratch = scratch_dir("check")
    process = context.Process(target=_check_child, name="agv-cosim check",
                              args=(checks, writer, scratch))
    current, failure = None, None
    try:
        process.start()
        writer.close()
        while True:
            try:
                kind, payload = reader.recv()
            except EOFError:
                process.join()
                if current is not None and failure is None:
                    code = process.exitcode
                    how = f"signal {-code}" if code and code < 0 else f"exit code {code}"
                    failure = (current, f"the FMU's process died ({how}) while it was "
                                        "instantiated and initialised")
                break
            if kind == "checking":
                current = payload
            elif kind == "failed":
                failure = payload
            else:
                current = None
    finally:
        if process.is_alive():
            process.kill()
        if process.pid is not None:
            process.join()
        reader.close()
        shutil.rmtree(scratch, ignore_errors=True)
    if failure is not None:
        index, text = failure
        cname, label = where[index]
        raise ManifestError(manifest.path, f"components.{cname}",
                            f"the FMU refuses to initialise (run {label}): {text}")


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
    from tqdm import tqdm

    out_dir = Path(out_dir) if out_dir else default_out_dir(manifest)
    workers = workers or os.cpu_count() or 1
    workers = max(1, min(workers, len(jobs)))
    with AtomicDir(out_dir, overwrite=overwrite) as folder:
        total = sum(int(round((job.plan.stop - job.plan.start) / job.plan.step))
                    for job in jobs)
        bar = tqdm(total=total, desc=manifest.name, unit="step", delay=2.0, disable=quiet,
                   file=sys.stderr, mininterval=0.5, postfix={"runs": f"0/{len(jobs)}"})
        finished = 0

        def run_done():
            nonlocal finished
            finished += 1
            bar.set_postfix(runs=f"{finished}/{len(jobs)}")

        if dask:
            from .distributed import run_on_dask

            results = run_on_dask(dask, jobs, folder.path, bar.update, run_done)
        else:
            results = _run_isolated(jobs, folder.path, workers, bar.update, run_done)
        bar.close()
        rows = []
        for result in results:
            row = {"run": result["label"], "variant": result["variant"] or "",
                   "status": result["status"]}
            row.update(result["point"])
            row.update(result["metrics"])
            rows.append(row)
        write_summary(folder.path / "summary.csv", rows)
        if getattr(manifest, "montecarlo", None) is not None:
            from . import montecarlo

            figure_error = montecarlo.write_outputs(manifest.montecarlo, jobs, results,
                                                    folder.path, manifest.name)
            if figure_error:
                (folder.path / "montecarlo_error.txt").write_text(figure_error + "\n")
                print(f"agv-cosim: warning: {manifest.path}: montecarlo figure: "
                      f"{figure_error}", file=sys.stderr)
        plot_error = _plots(manifest, jobs, results, folder.path)
        if plot_error:
            (folder.path / "plots_error.txt").write_text(plot_error + "\n")
            print(f"agv-cosim: warning: {manifest.path}: plots: {plot_error}",
                  file=sys.stderr)
        target = folder.commit()
    return target, results


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
