"""Runs, variants, sweeps and parallel workers.

:func:`prepare` loads and validates a manifest into a list of :class:`Job` (one per
variant x sweep point); :func:`execute` runs each of them in a child process of its own
(``forkserver`` context; up to ``workers`` at once) and writes the output folder::

    DIR/<run label>/timeseries.csv   time, then component.variable (repr floats)
    DIR/<run label>/metrics.json     metrics.compute_metrics(...) of the run
    DIR/<run label>/run.json         hashes, parameters, versions, wall time, status
    DIR/summary.csv                  one row per run: label, status, sweep values, metrics
    DIR/*.png                        plots.plot_runs(...) overlaying the runs

Each run is independent and deterministic, so the parallel and the serial results are
byte-identical. ``DIR`` is assembled under a temporary name and renamed into place.

Why a process per run: an FMU runs inside the process that loads it, and a failing
pythonfmu 0.7 FMU can damage its host's heap (see agv_core/fmi_slave.py). In a child of
its own, the damage ends with the run; a child that dies is reported as that run's
failure (partial if it had recorded rows), and the other runs go on.
"""

import importlib
import os
import platform
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass
from multiprocessing import get_context
from multiprocessing.connection import wait
from pathlib import Path

from . import __version__, metrics, plots
from .manifest import ManifestError, load_manifest, plan_runs, validate
from .master import Plan, SimulationError, simulate
from .results import AtomicDir, CsvSink, count_rows, write_json, write_summary


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


def _start_value(var):
    if var.start is None:
        return None
    if var.type == "Real":
        return float(var.start)
    if var.type in ("Integer", "Enumeration"):
        return int(var.start)
    if var.type == "Boolean":
        return var.start in ("true", "1")
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
    return sources


def prepare(manifest_path, variants=None, sets=()):
    """Load, expand and validate a manifest.

    Returns
    -------
    (Manifest, list of Job, list of str)
        The manifest, its jobs and the validation warnings.

    Raises
    ------
    ManifestError
    """
    manifest = load_manifest(manifest_path)
    runs = plan_runs(manifest, variants, sets)
    checked = validate(manifest, runs, _signal_sources(manifest))
    every = int(round(manifest.record_interval / manifest.step))
    jobs = []
    for run, models, order in zip(runs, checked.models, checked.orders):
        params = {c: dict(comp.parameters) for c, comp in run.components.items()}
        effective = {c: {v.name: params[c].get(v.name, _start_value(v))
                         for v in info.parameters} for c, info in models.items()}
        plan = Plan(models=models, parameters=params, connections=manifest.connections,
                    order=order, record=checked.record, start=manifest.start,
                    stop=manifest.stop, step=manifest.step, algorithm=manifest.algorithm,
                    record_every=every)
        jobs.append(Job(label=run.label, variant=run.variant, point=run.point, plan=plan,
                        parameters=effective,
                        fmu_sha256={c: info.sha256 for c, info in models.items()},
                        manifest_path=str(manifest.path), manifest_sha256=manifest.sha256,
                        metrics_spec=manifest.metrics))
    return manifest, jobs, checked.warnings


def versions():
    """Versions of the packages a result depends on."""
    found = {"python": platform.python_version(), "agv_cosim": __version__}
    for name in ("fmpy", "pythonfmu", "numpy", "scipy"):
        try:
            found[name] = importlib.import_module(name).__version__
        except Exception:  # noqa: BLE001
            found[name] = None
    return found


def run_job(job, run_dir, progress=None):
    """Run one job into ``run_dir`` (created); return its summary dict.

    Never raises for a simulation failure: the status is ``complete``, ``partial`` (some
    rows recorded, then a failure) or ``failed`` (nothing recorded).
    """
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    sink = CsvSink(run_dir / "timeseries.csv", job.plan.record)
    rows, error = 0, None
    begin = time.perf_counter()

    def write(row):
        nonlocal rows
        sink.write(row)
        rows += 1

    try:
        simulate(job.plan, write, progress)
    except SimulationError as failure:
        error = str(failure)
    finally:
        sink.close()
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
    return _finish(job, run_dir, rows, status, error, wall, values, metrics_error)


def _finish(job, run_dir, rows, status, error, wall, values, metrics_error):
    """Write metrics.json and run.json of a run; return its summary dict."""
    write_json(run_dir / "metrics.json", values)
    write_json(run_dir / "run.json", {
        "label": job.label, "variant": job.variant, "sweep_point": job.point,
        "manifest": job.manifest_path, "manifest_sha256": job.manifest_sha256,
        "fmu_sha256": job.fmu_sha256,
        "fmus": {c: str(info.path) for c, info in job.plan.models.items()},
        "parameters": job.parameters, "algorithm": job.plan.algorithm,
        "start": job.plan.start, "stop": job.plan.stop, "step": job.plan.step,
        "record_every": job.plan.record_every, "rows": rows,
        "versions": versions(), "wall_time_s": wall, "status": status, "error": error,
        "metrics_error": metrics_error, "partial": status != "complete"})
    return {"label": job.label, "status": status, "error": error, "rows": rows,
            "metrics": values, "metrics_error": metrics_error, "point": job.point,
            "variant": job.variant}


def _child(job, run_dir, channel, scratch):
    """Body of a run's child process: run it, report progress and the result.

    FMUs are extracted under ``scratch``, which the parent deletes however the child
    ends (a child that dies cannot clean up after itself).
    """
    tempfile.tempdir = scratch

    def progress(steps):
        channel.send(("progress", steps))

    result = run_job(job, run_dir, progress)
    channel.send(("done", result))
    channel.close()
    # Leave without interpreter shutdown: the result is delivered, and a heap that a
    # failed FMU damaged would only crash the collector now.
    os._exit(0)


def _died(job, run_dir, exitcode):
    """The summary of a run whose child process died before it reported."""
    csv = Path(run_dir) / "timeseries.csv"
    rows = count_rows(csv) if csv.is_file() else 0
    how = f"signal {-exitcode}" if exitcode < 0 else f"exit code {exitcode}"
    error = f"the run's process died ({how}) after {rows} recorded rows"
    Path(run_dir).mkdir(parents=True, exist_ok=True)
    return _finish(job, run_dir, rows, "partial" if rows else "failed", error, None, {}, None)


def _run_isolated(jobs, root, workers, on_progress, on_done):
    """Run every job in a child process of its own, ``workers`` at a time.

    Each child reports through a pipe of its own, so a child that dies mid-message
    cannot block the others (a shared queue's lock can stay held by a dead process).
    """
    context = get_context("forkserver")
    context.set_forkserver_preload([__name__])
    results = [None] * len(jobs)
    waiting = list(range(len(jobs)))
    running = {}  # job index -> (process, reading end of its pipe, scratch folder)
    try:
        while waiting or running:
            while waiting and len(running) < workers:
                index = waiting.pop(0)
                job = jobs[index]
                reader, writer = context.Pipe(duplex=False)
                scratch = tempfile.mkdtemp(prefix="agv_cosim_run_")
                process = context.Process(target=_child, name=f"agv-cosim {job.label}",
                                          args=(job, root / job.label, writer, scratch))
                process.start()
                writer.close()
                running[index] = (process, reader, scratch)
            ready = wait([reader for _, reader, _ in running.values()], timeout=1.0)
            for index, (process, reader, scratch) in list(running.items()):
                if reader not in ready:
                    continue
                try:
                    kind, payload = reader.recv()
                except EOFError:  # the child has ended, with or without its result
                    process.join()
                    reader.close()
                    shutil.rmtree(scratch, ignore_errors=True)
                    del running[index]
                    if results[index] is None:
                        results[index] = _died(jobs[index], root / jobs[index].label,
                                               process.exitcode)
                        on_done()
                    continue
                if kind == "progress":
                    on_progress(payload)
                else:
                    results[index] = payload
                    on_done()
    finally:
        for process, reader, scratch in running.values():
            process.kill()
            process.join()
            reader.close()
            shutil.rmtree(scratch, ignore_errors=True)
    return results


def default_out_dir(manifest):
    """``results/<manifest name>`` relative to the current folder."""
    return Path("results") / manifest.name


def execute(manifest, jobs, out_dir=None, workers=None, quiet=False):
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

    Returns
    -------
    (Path, list of dict)
        The output folder and one result dict per job (in job order).
    """
    from tqdm import tqdm

    out_dir = Path(out_dir) if out_dir else default_out_dir(manifest)
    workers = workers or os.cpu_count() or 1
    workers = max(1, min(workers, len(jobs)))
    with AtomicDir(out_dir) as folder:
        total = sum(int(round((job.plan.stop - job.plan.start) / job.plan.step))
                    for job in jobs)
        bar = tqdm(total=total, desc=manifest.name, unit="step", delay=2.0, disable=quiet,
                   file=sys.stderr, mininterval=0.5, postfix={"runs": f"0/{len(jobs)}"})
        finished = 0

        def run_done():
            nonlocal finished
            finished += 1
            bar.set_postfix(runs=f"{finished}/{len(jobs)}")

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
            runs.append(plots.read_run(out_dir / job.label / "timeseries.csv",
                                       manifest.plots, job.label, rows=result["rows"],
                                       partial=result["status"] != "complete"))
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
