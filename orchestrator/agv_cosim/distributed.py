"""Runs on a Dask cluster (``agv-cosim run MANIFEST --dask tcp://HOST:PORT``).

The client (the machine running ``agv-cosim``) plans and validates the runs as for a
local run, then submits one Dask task per run and writes every result itself, into the
same :class:`~agv_cosim.results.AtomicDir` and ``summary.csv`` as a local run.

What a task does on a worker (:func:`run_remote`):

1. **FMUs shipped with the job.** The client reads each distinct FMU once, scatters its
   bytes to the cluster (``Client.scatter``, keyed by SHA-256) and hands the futures to
   the tasks; a worker stores each FMU once in a cache folder of its own
   (``<tmp>/agv-cosim-dask-fmus-<uid>/<sha256>.fmu``, written under a temporary name,
   its SHA-256 checked, then renamed) and every later run on that worker reuses it.
   Chosen over a shared path because the cluster then needs no shared file system and a
   worker can never run an FMU other than the one the client validated: the hash in
   ``run.json`` is the hash of the bytes that ran.
2. **The same crash isolation as locally.** The run goes through
   :func:`agv_cosim.runner._run_isolated`: a child process of its own (``forkserver``),
   so an FMU that aborts its process fails only its run, reported ``partial`` or
   ``failed`` with the same text as locally; the worker goes on.
3. The run's folder (``timeseries.csv``, ``run.json``, ``metrics.json``) goes back to the
   client as bytes; the client writes it, then computes the run's metrics from the
   ``timeseries.csv`` it wrote (the manifest's files, e.g. a waypoint file of a
   reference path, are on the client), with the same function as a local run.

Results are byte-identical to a local run (timeseries.csv, metrics.json, summary.csv);
``run.json`` differs only where it records the machine (wall time, versions).

Workers need: the project installed in the same Python environment as the client (same
versions of agv-cosim, numpy, scipy, pythonfmu), and permission to start child processes:
a Dask worker under a nanny is a daemonic process, which Python forbids to have
children, so start workers with ``DASK_DISTRIBUTED__WORKER__DAEMON=False`` (or
``--no-nanny``). See docs/dask.md.
"""

import dataclasses
import hashlib
import os
import tempfile
from pathlib import Path

#: How long the client waits for the scheduler [s] before giving up.
CONNECT_TIMEOUT = 10.0


class ClusterError(Exception):
    """The cluster cannot be used (unreachable scheduler, no workers, ...)."""


def connect(address, timeout=CONNECT_TIMEOUT):
    """A ``distributed.Client`` on the scheduler at ``address``.

    Raises
    ------
    ClusterError
        One line naming the address when the scheduler cannot be reached.
    """
    try:
        from distributed import Client
    except ImportError:  # pragma: no cover - a dependency of the project
        raise ClusterError("--dask: the 'distributed' package is not installed") from None
    if not isinstance(address, str) or "://" not in address:
        raise ClusterError(f"--dask: {address!r} is not a scheduler address "
                           "(e.g. tcp://HOST:8786)")
    try:
        return Client(address, timeout=timeout)
    except (OSError, TimeoutError, ValueError) as error:
        text = " ".join(str(error).split()) or type(error).__name__
        raise ClusterError(f"--dask: cannot reach the scheduler at {address}: "
                           f"{text}") from None


def _fmu_cache():
    folder = Path(tempfile.gettempdir()) / f"agv-cosim-dask-fmus-{os.getuid()}"
    folder.mkdir(mode=0o700, exist_ok=True)
    return folder


def cached_fmu(sha256, blob, cache=None):
    """The path of the FMU with this SHA-256 in the worker's cache (written once).

    Raises
    ------
    ValueError
        When ``blob`` does not have the SHA-256 the client validated.
    """
    cache = Path(cache) if cache is not None else _fmu_cache()
    path = cache / f"{sha256}.fmu"
    if path.is_file():
        return path
    if hashlib.sha256(blob).hexdigest() != sha256:
        raise ValueError(f"the FMU received does not have the SHA-256 {sha256}")
    handle, partial = tempfile.mkstemp(dir=cache, prefix=f".{sha256}.", suffix=".part")
    try:
        with os.fdopen(handle, "wb") as stream:
            stream.write(blob)
        os.replace(partial, path)  # atomic: a concurrent task sees all of it or nothing
    except BaseException:
        Path(partial).unlink(missing_ok=True)
        raise
    return path


def _allow_children():
    """Refuse clearly in a daemonic worker (multiprocessing would assert)."""
    import multiprocessing

    if multiprocessing.current_process().daemon:
        raise RuntimeError("this Dask worker is a daemonic process and cannot start a run's "
                           "child process: start the workers with "
                           "DASK_DISTRIBUTED__WORKER__DAEMON=False (or --no-nanny)")


def run_remote(job, blobs):
    """Body of a Dask task: run ``job`` isolated on this worker; return its folder.

    ``blobs``: SHA-256 -> FMU bytes of the job's FMUs. Returns ``(result dict, files)``,
    ``files`` mapping each file of the run's folder (relative POSIX path) to its bytes.
    Metrics are left to the client (``metrics_spec`` is dropped here).
    """
    from .runner import _run_isolated

    _allow_children()
    models = {}
    for cname, info in job.plan.models.items():
        if info.table is not None:  # a time table travels in the job itself
            models[cname] = info
        else:
            models[cname] = dataclasses.replace(
                info, path=cached_fmu(info.sha256, blobs[info.sha256]))
    local = dataclasses.replace(job, plan=dataclasses.replace(job.plan, models=models),
                                metrics_spec=None)
    with tempfile.TemporaryDirectory(prefix="agv-cosim-dask-run-") as folder:
        root = Path(folder)
        [result] = _run_isolated([local], root, 1, lambda steps: None, lambda: None)
        run_dir = root / job.label
        files = {p.relative_to(run_dir).as_posix(): p.read_bytes()
                 for p in sorted(run_dir.rglob("*")) if p.is_file()}
    return result, files


def _write_back(job, result, files, root):
    """Write a run's files under ``root`` and compute its metrics here (the client)."""
    from . import metrics
    from .results import write_json

    run_dir = Path(root) / job.label
    run_dir.mkdir(parents=True, exist_ok=True)
    for name, data in files.items():
        target = run_dir / name
        if run_dir.resolve() not in target.resolve().parents:
            raise ClusterError(f"a worker returned a file outside its run folder: {name!r}")
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(data)
    result = dict(result)
    if job.metrics_spec and result["rows"]:
        import json

        values, metrics_error = {}, None
        try:
            values = dict(metrics.compute_metrics_csv(
                run_dir / "timeseries.csv", job.metrics_spec,
                base_dir=Path(job.manifest_path).parent))
        except Exception as failure:  # noqa: BLE001 - reported in run.json, as locally
            metrics_error = f"{type(failure).__name__}: {failure}"
        write_json(run_dir / "metrics.json", values)
        info = json.loads((run_dir / "run.json").read_text(encoding="utf-8"))
        info["metrics_error"] = metrics_error
        write_json(run_dir / "run.json", info)
        result.update(metrics=values, metrics_error=metrics_error)
    return result


def run_on_dask(address, jobs, root, on_progress, on_done):
    """Run ``jobs`` on the cluster at ``address``; write each run under ``root``.

    Same contract as :func:`agv_cosim.runner._run_isolated`: one result dict per job, in
    job order. ``on_progress`` gets each finished run's steps at once.
    """
    from distributed import as_completed

    client = connect(address)
    try:
        if not client.scheduler_info().get("workers"):
            try:
                client.wait_for_workers(1, timeout=CONNECT_TIMEOUT)
            except (TimeoutError, OSError):
                raise ClusterError(f"--dask: the scheduler at {address} has no workers") \
                    from None
        blobs = {}
        for job in jobs:
            for info in job.plan.models.values():
                if info.table is None and info.sha256 not in blobs:
                    data = Path(info.path).read_bytes()
                    if hashlib.sha256(data).hexdigest() != info.sha256:
                        raise ClusterError(f"{info.path}: changed since it was validated")
                    blobs[info.sha256] = data
        shipped = {sha: client.scatter(data, hash=False, broadcast=False)
                   for sha, data in blobs.items()}
        futures = {}
        for index, job in enumerate(jobs):
            needed = {info.sha256: shipped[info.sha256] for info in job.plan.models.values()
                      if info.table is None}
            # pure=False: a run is not cached by Dask (two identical runs both run)
            future = client.submit(run_remote, job, needed, pure=False,
                                   key=f"agv-cosim-{os.getpid()}-{index}-{job.label}")
            futures[future] = index
        results = [None] * len(jobs)
        for future in as_completed(futures):
            index = futures[future]
            job = jobs[index]
            try:
                result, files = future.result()
            except Exception as error:  # noqa: BLE001 - a worker-side problem, one line
                text = " ".join(str(error).split()) or type(error).__name__
                raise ClusterError(f"--dask: run {job.label} could not run on the "
                                   f"cluster: {text}") from None
            results[index] = _write_back(job, result, files, root)
            on_progress(int(round((job.plan.stop - job.plan.start) / job.plan.step)))
            on_done()
        return results
    finally:
        client.close()
