"""Benchmark: runs on a Dask cluster of stock workers against local runs, CPU and runs/s.

Two measurements, both in one invocation, each comparing the same manifest run locally
and on a local Dask cluster (a scheduler and ``--workers`` stock ``dask worker``
processes, one thread each, under a nanny, no ``DASK_*`` setting), the result folders
compared file by file (but ``timings.csv``, the wall times):

sweep
    ``experiments/seed000_models_abc.toml`` variant ``a`` (5 FMUs), ``stop`` = one step
    (1 ms), swept over ``--runs`` values of ``vehicle.v0``: nearly all fixed cost.
    Local is ``agv-cosim run --jobs 1``. Rounds alternate local / Dask; the first Dask
    round meets workers that have not run anything yet (cold: each starts its run host
    and fork server), the later ones warm workers.
montecarlo (``--montecarlo SAMPLES``, 0 = skip)
    ``experiments/seed004_montecarlo.toml`` (7 FMUs, 2 variants) with ``samples`` =
    SAMPLES (2 x SAMPLES runs) and ``stop`` = ``--mc-stop``; local is ``--jobs
    --workers`` (the same number of processes as the cluster's workers).

CPU is counted for every process that did the work: the ``agv-cosim`` command and its
descendants (this process is made a child subreaper, so the fork server, orphaned when
the command exits, is reaped here and counted), plus, for Dask, what the cluster's
processes (scheduler, nannies, workers, run hosts and their children) used while the
command ran (psutil: each live process's own and reaped children's CPU time, summed
over the tree, after minus before; the idle cluster's heartbeat included).

Run: ``.venv/bin/python benchmarks/bench_dask.py [--runs 32] [--rounds 3]
[--montecarlo 512 --mc-stop 0.05]``

Older code, for a before/after: ``git archive COMMIT orchestrator | tar -x -C DIR``, then
``--code DIR/orchestrator`` (put first on PYTHONPATH of the commands and the cluster;
the FMUs stay this checkout's); ``--no-daemon`` starts the workers with
``DASK_DISTRIBUTED__WORKER__DAEMON=False``, which code that refuses daemonic workers
needs.
"""

import argparse
import ctypes
import ctypes.util
import json
import os
import re
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil

ROOT = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent


def _subreaper():
    """Orphaned descendants (the command's fork server) become children of this process,
    so that their CPU time is counted when they are reaped."""
    libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
    if libc.prctl(36, 1, 0, 0, 0) != 0:  # PR_SET_CHILD_SUBREAPER
        raise OSError(ctypes.get_errno(), "prctl(PR_SET_CHILD_SUBREAPER) failed")


def _sweep_manifest(folder, runs):
    text = (ROOT / "experiments" / "seed000_models_abc.toml").read_text()
    text = re.sub(r"(?m)^stop = .*$", "stop = 0.001", text)
    text = text.replace('"../fmus/', f'"{ROOT / "fmus"}/')
    values = ", ".join(repr(1.0 + 0.01 * i) for i in range(runs))
    text += f'\n[sweep]\n"vehicle.v0" = [{values}]\n'
    path = Path(folder) / "dask_sweep.toml"
    path.write_text(text)
    return path


def _mc_manifest(folder, samples, stop):
    text = (ROOT / "experiments" / "seed004_montecarlo.toml").read_text()
    text = re.sub(r"(?m)^stop = .*$", f"stop = {stop!r}", text)
    text = re.sub(r"(?m)^samples = .*$", f"samples = {samples}", text)
    text = text.replace('"../fmus/', f'"{ROOT / "fmus"}/')
    path = Path(folder) / "dask_montecarlo.toml"
    path.write_text(text)
    return path


class Cluster:
    """A scheduler and stock workers, each started through a ``python -c`` wrapper that
    waits for it (so that the cluster's processes are never this process's orphans).
    The wrapper and its process get SIGTERM when their parent ends (prctl
    PR_SET_PDEATHSIG), so a benchmark killed midway leaves no cluster running."""

    WRAP = ("import ctypes, signal, subprocess, sys\n"
            "libc = ctypes.CDLL(None)\n"
            "def guard(): libc.prctl(1, int(signal.SIGTERM), 0, 0, 0)\n"
            "guard()\n"
            "sys.exit(subprocess.call(sys.argv[1:], preexec_fn=guard))")

    def __init__(self, folder, workers, daemon=True):
        self.folder = Path(folder)
        scheduler_file = self.folder / "scheduler.json"
        env = {k: v for k, v in os.environ.items() if not k.startswith("DASK_")}
        env["TMPDIR"] = str(self.folder)
        if not daemon:
            env["DASK_DISTRIBUTED__WORKER__DAEMON"] = "False"
        self.log = open(self.folder / "cluster.log", "w")
        self.wrappers = []

        def start(*args):
            self.wrappers.append(subprocess.Popen(
                [sys.executable, "-c", self.WRAP, str(BIN / "dask"), *args], env=env,
                stdout=self.log, stderr=subprocess.STDOUT, cwd=self.folder,
                start_new_session=True))

        start("scheduler", "--scheduler-file", str(scheduler_file), "--host", "127.0.0.1",
              "--port", "0", "--no-dashboard")
        deadline = time.monotonic() + 60
        while not scheduler_file.is_file():
            if time.monotonic() > deadline:
                raise SystemExit("the scheduler did not start")
            time.sleep(0.2)
        for _ in range(workers):
            start("worker", "--scheduler-file", str(scheduler_file), "--nthreads", "1",
                  "--no-dashboard", "--local-directory", str(self.folder))
        from distributed import Client

        with Client(scheduler_file=str(scheduler_file), timeout=30) as client:
            client.wait_for_workers(workers, timeout=90)
            self.address = client.scheduler.address

    def cpu(self):
        """CPU seconds used so far by the cluster's processes (wrappers excluded)."""
        total = 0.0
        for wrapper in self.wrappers:
            try:
                tree = psutil.Process(wrapper.pid).children(recursive=True)
            except psutil.NoSuchProcess:
                continue
            for process in tree:
                try:
                    t = process.cpu_times()
                except psutil.NoSuchProcess:
                    continue
                total += t.user + t.system + t.children_user + t.children_system
        return total

    def stop(self):
        for wrapper in reversed(self.wrappers):
            try:
                os.killpg(wrapper.pid, 15)
            except ProcessLookupError:
                pass
        for wrapper in self.wrappers:
            try:
                wrapper.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(wrapper.pid, 9)
                wrapper.wait()
        self.log.close()


def _reap_orphans(keep, timeout=30.0):
    """Wait for every child of this process that is not one of ``keep`` (pids)."""
    deadline = time.monotonic() + timeout
    while True:
        others = [c for c in psutil.Process().children() if c.pid not in keep]
        if not others:
            return
        for child in others:
            try:
                if os.waitpid(child.pid, os.WNOHANG)[0] == 0 and time.monotonic() > deadline:
                    raise SystemExit(f"a process left by the command does not end: "
                                     f"{child.pid} {child.cmdline()}")
            except ChildProcessError:
                pass
        time.sleep(0.05)


def _command(args, cluster, on_cluster=False):
    """Run ``agv-cosim ARGS``; return (wall s, CPU s of the command and its descendants,
    CPU s of the cluster meanwhile when ``on_cluster``, else 0)."""
    keep = {w.pid for w in cluster.wrappers}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    cluster_before = cluster.cpu() if on_cluster else 0.0
    begin = time.perf_counter()
    # python -m: the module's own entry, which also older code (--code) has
    done = subprocess.run([sys.executable, "-m", "agv_cosim.cli", *args],
                          capture_output=True, text=True)
    wall = time.perf_counter() - begin
    _reap_orphans(keep)
    cluster_after = cluster.cpu() if on_cluster else 0.0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"agv-cosim {' '.join(args)} failed ({done.returncode}):\n"
                         f"{done.stderr[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, cluster_after - cluster_before


def _files(root):
    """The CSV and JSON files of a result folder but timings.csv (the wall times); a
    run.json without ``wall_time_s`` (which code before timings.csv wrote, ``--code``)."""
    out = {}
    for path in sorted(Path(root).rglob("*")):
        if path.is_file() and path.suffix in (".csv", ".json") and path.name != "timings.csv":
            data = path.read_bytes()
            if path.name == "run.json":
                info = json.loads(data)
                if "wall_time_s" in info:
                    info.pop("wall_time_s")
                    data = json.dumps(info, sort_keys=True).encode()
            out[path.relative_to(root).as_posix()] = data
    return out


def _same(local, remote):
    mine, theirs = _files(local), _files(remote)
    if mine != theirs:
        differ = sorted(k for k in set(mine) | set(theirs) if mine.get(k) != theirs.get(k))
        raise SystemExit(f"Dask results differ from local ones: {differ[:5]}")
    return len(mine)


def _line(name, runs, wall, cpu, cluster_cpu=0.0):
    total = cpu + cluster_cpu
    extra = f" (command {cpu:.2f} + cluster {cluster_cpu:.2f})" if cluster_cpu else ""
    print(f"  {name:<22} {runs / wall:6.2f} runs/s  wall {wall:7.2f} s  CPU {total:7.2f} s"
          f"{extra}  = {total / runs:.3f} s CPU/run", flush=True)
    return total / runs, runs / wall


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=32)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--montecarlo", type=int, default=0, metavar="SAMPLES")
    parser.add_argument("--mc-stop", type=float, default=0.05)
    parser.add_argument("--skip-sweep", action="store_true")
    parser.add_argument("--code", type=Path, help="a folder put first on PYTHONPATH")
    parser.add_argument("--no-daemon", action="store_true")
    options = parser.parse_args()
    if options.code:
        os.environ["PYTHONPATH"] = str(options.code.resolve())
    _subreaper()
    folder = Path(tempfile.mkdtemp(prefix="agvbd", dir="/tmp"))  # short: socket paths
    cluster = None
    try:
        cluster = Cluster(folder, options.workers, not options.no_daemon)
        print(f"cluster: {cluster.address}, {options.workers} workers (nanny, 1 thread"
              f"{', DAEMON=False' if options.no_daemon else ', stock'}); code: "
              f"{options.code or 'this checkout'}; load average {os.getloadavg()[0]:.1f}",
              flush=True)
        if not options.skip_sweep:
            manifest = _sweep_manifest(folder, options.runs)
            print(f"sweep: {options.runs} runs of 1 step (seed000 variant a, 5 FMUs)")
            ratios = []
            for round_ in range(options.rounds):
                local, remote = folder / "sweep_local", folder / "sweep_dask"
                common = ["run", str(manifest), "--variant", "a", "--quiet", "--overwrite"]
                lw, lc, _ = _command([*common, "--jobs", "1", "--out", str(local)],
                                    cluster)
                dw, dc, cc = _command([*common, "--dask", cluster.address, "--out",
                                       str(remote)], cluster, True)
                files = _same(local, remote)
                state = "cold" if round_ == 0 else "warm"
                print(f" round {round_ + 1} ({files} files identical):")
                l_cpu, l_rate = _line("local --jobs 1", options.runs, lw, lc)
                d_cpu, d_rate = _line(f"dask ({state} workers)", options.runs, dw, dc, cc)
                print(f"  ratio dask/local: CPU/run {d_cpu / l_cpu:.2f}x, "
                      f"runs/s {d_rate / l_rate:.2f}x")
                if round_:
                    ratios.append(d_cpu / l_cpu)
            if ratios:
                print(f" median CPU/run ratio, warm rounds: {statistics.median(ratios):.2f}x")
        if options.montecarlo:
            manifest = _mc_manifest(folder, options.montecarlo, options.mc_stop)
            runs = 2 * options.montecarlo
            print(f"montecarlo: {runs} runs (seed004, 7 FMUs, stop {options.mc_stop:g} s)")
            local, remote = folder / "mc_local", folder / "mc_dask"
            common = ["run", str(manifest), "--quiet", "--overwrite"]
            lw, lc, _ = _command([*common, "--jobs", str(options.workers), "--out",
                                  str(local)], cluster)
            dw, dc, cc = _command([*common, "--dask", cluster.address, "--out",
                                   str(remote)], cluster, True)
            files = _same(local, remote)
            print(f" ({files} files identical, montecarlo.json included)")
            l_cpu, l_rate = _line(f"local --jobs {options.workers}", runs, lw, lc)
            d_cpu, d_rate = _line(f"dask {options.workers} workers", runs, dw, dc, cc)
            print(f"  ratio dask/local: CPU/run {d_cpu / l_cpu:.2f}x, "
                  f"runs/s {d_rate / l_rate:.2f}x")
    finally:
        if cluster is not None:
            cluster.stop()
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
