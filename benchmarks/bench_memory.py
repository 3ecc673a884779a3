"""Benchmark: peak memory of ``agv-cosim run`` against the simulated duration (issue 17).

One closed loop (seed 000 model a: AgvVehicle, AgvSteeringA, AgvVisionSensor,
AgvSteerSensor, AgvStateFeedback, 1 m/s on a sine path of amplitude 0.5 m and wavelength
20 m, so the error never dies out) is run through the real command

    agv-cosim run MANIFEST --out DIR --quiet --jobs 1

for each duration asked for (default 60 s and 8 h simulated), at a 10 ms step, recording
9 signals at every step, with the full ``[metrics]`` table (including the geometric
``reference`` error) and a ``[plots]`` table (signals and trajectory figures).

Two peaks are measured per run, as the Linux high-water mark ``VmHWM`` of
``/proc/<pid>/status``:

run process
    the process that simulates the run and computes its metrics (forked by the
    command's forkserver). It exits through ``os._exit``; the benchmark puts a
    ``sitecustomize.py`` on ``PYTHONPATH`` that wraps ``os._exit`` in processes named
    ``agv-cosim <label>`` to log ``VmHWM`` just before the exit.
parent
    the ``agv-cosim`` process itself (it waits for the runs, writes the summary, draws the
    plots). The same ``sitecustomize.py`` logs its ``VmHWM`` at interpreter exit
    (``atexit``).

The benchmark also polls ``VmHWM`` of the command and of all its descendants every 0.1 s
(this can only miss growth in the last 0.1 s of a process; the logged value misses what
the parent allocates during interpreter shutdown, after ``atexit``, about 0.4 MiB). The
peak reported is the larger of the logged and the polled value. ``os.wait4``'s
``ru_maxrss`` is not used: it folds in the reaped descendants and the pre-exec
high-water mark.

It prints, per duration: rows, wall time, the two peaks [MiB] (logged / polled in
brackets), and the ratio of each peak to the one of the first (shortest) duration
(target: <= 1.15).

Run: ``python benchmarks/bench_memory.py [--durations 60 28800] [--step 0.01] [--keep DIR]``
(from the repository, after ``make fmus``; 8 h simulated is 2.88 M steps, about an hour
of wall time on a 2-core machine).
"""

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FMUS = ROOT / "fmus"
PATH = "sine:amplitude=0.5,wavelength=20"

MANIFEST = """
name = "bench_memory"
[simulation]
start = 0.0
stop = {stop!r}
step = {step!r}
algorithm = "gauss-seidel"

[components.act]
fmu = "{fmus}/AgvSteeringA.fmu"
parameters = {{ K = 0.6, tau = 0.05 }}
[components.vehicle]
fmu = "{fmus}/AgvVehicle.fmu"
parameters = {{ wheelbase = 1.4944, v0 = 1.0, y0 = 0.1, reference_point = "front" }}
[components.sensor]
fmu = "{fmus}/AgvVisionSensor.fmu"
[components.sensor.parameters]
path = "{path}"
frame_period = 0.0
latency = 0.0
noise_lateral = 0.0
noise_heading = 0.0
[components.steer]
fmu = "{fmus}/AgvSteerSensor.fmu"
parameters = {{ noise = 0.0, resolution = 0.0 }}
[components.ctrl]
fmu = "{fmus}/AgvStateFeedback.fmu"
parameters = {{ Ka = 4.828, Kb = 3.767, Ke = 4.472 }}

[[connections]]
from = "vehicle.x"
to = "sensor.x"
[[connections]]
from = "vehicle.y"
to = "sensor.y"
[[connections]]
from = "vehicle.heading"
to = "sensor.heading"
[[connections]]
from = "sensor.lateral_error"
to = "ctrl.lateral_error"
[[connections]]
from = "sensor.heading_error"
to = "ctrl.heading_error"
[[connections]]
from = "act.alpha"
to = "steer.alpha"
[[connections]]
from = "steer.alpha_meas"
to = "ctrl.alpha"
[[connections]]
from = "ctrl.u"
to = "act.u"
[[connections]]
from = "act.alpha"
to = "vehicle.alpha"

[record]
variables = ["vehicle.x", "vehicle.y", "vehicle.heading", "vehicle.distance",
             "sensor.lateral_error", "sensor.heading_error",
             "act.alpha", "act.alpha_rate", "ctrl.u"]
interval = {step!r}

[metrics]
lateral_error = "sensor.lateral_error"
heading_error = "sensor.heading_error"
steering_angle = "act.alpha"
steering_rate = "act.alpha_rate"
control = "ctrl.u"
settle_band = 0.02
saturation = {{ signal = "act.alpha", limit = 0.3 }}
reference = {{ path = "{path}", x = "vehicle.x", y = "vehicle.y" }}

[plots]
signals = ["sensor.lateral_error", "vehicle.heading", "act.alpha", "ctrl.u"]
trajectory = {{ x = "vehicle.x", y = "vehicle.y", path = "{path}" }}
"""

#: Imported by every Python process of the command (PYTHONPATH): logs VmHWM of the
#: parent at exit and of each run process before its os._exit.
SITECUSTOMIZE = '''
import os as _os

_LOG = _os.environ.get("AGV_BENCH_RSS_LOG")


def _record(role):
    with open("/proc/self/status") as status:
        kib = next(int(line.split()[1]) for line in status if line.startswith("VmHWM:"))
    with open(_LOG, "a") as log:
        log.write(f"{role} {_os.getpid()} {kib}\\n")


if _LOG:
    import atexit as _atexit
    import sys as _sys

    if _os.path.basename(_sys.argv[0] if _sys.argv else "") == "agv-cosim":
        _atexit.register(_record, "parent")
    _real_exit = _os._exit

    def _exit(code):
        import multiprocessing

        if multiprocessing.current_process().name.startswith("agv-cosim "):
            _record("run")
        _real_exit(code)

    _os._exit = _exit
'''


def _hwm_kib(pid):
    try:
        with open(f"/proc/{pid}/status") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1])
    except OSError:
        return None
    return None


def _descendants(root):
    children = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as stat:
                    ppid = int(stat.read().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(ppid, []).append(int(entry))
    found, stack = [], [root]
    while stack:
        for child in children.get(stack.pop(), []):
            found.append(child)
            stack.append(child)
    return found


def measure(stop, step, folder):
    """Run the command once; return rows, wall time and peaks [KiB]."""
    manifest = folder / f"bench_{stop:g}.toml"
    manifest.write_text(MANIFEST.format(stop=float(stop), step=step, fmus=FMUS.as_posix(),
                                        path=PATH))
    log = folder / f"rss_{stop:g}.log"
    out = folder / f"out_{stop:g}"
    env = dict(os.environ, AGV_BENCH_RSS_LOG=str(log),
               PYTHONPATH=os.pathsep.join([str(folder)] + [p for p in [
                   os.environ.get("PYTHONPATH")] if p]))
    command = [str(Path(sys.executable).parent / "agv-cosim"), "run", str(manifest),
               "--out", str(out), "--quiet", "--jobs", "1"]
    begin = time.perf_counter()
    process = subprocess.Popen(command, env=env)
    polled = {"parent": 0, "others": 0}
    while process.poll() is None:
        polled["parent"] = max(polled["parent"], _hwm_kib(process.pid) or 0)
        for pid in _descendants(process.pid):
            polled["others"] = max(polled["others"], _hwm_kib(pid) or 0)
        time.sleep(0.1)
    wall = time.perf_counter() - begin
    if process.returncode != 0:
        raise SystemExit(f"bench_memory: agv-cosim run exited with {process.returncode}")
    logged = {}
    for line in log.read_text().splitlines():
        role, _, kib = line.split()
        logged[role] = max(logged.get(role, 0), int(kib))
    if set(logged) != {"parent", "run"}:
        raise SystemExit(f"bench_memory: expected a parent and a run entry in {log}, "
                         f"got {sorted(logged)}")
    rows = sum(1 for _ in open(next(out.glob("*/timeseries.csv")), "rb")) - 1
    for name in ("signals.png", "trajectory.png", "summary.csv"):
        if not (out / name).is_file():
            raise SystemExit(f"bench_memory: {out / name} was not written")
    return {"rows": rows, "wall": wall, "run": max(logged["run"], polled["others"]),
            "parent": max(logged["parent"], polled["parent"]), "logged_run": logged["run"],
            "logged_parent": logged["parent"], "polled_parent": polled["parent"],
            "polled_run": polled["others"], "out": out}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--durations", type=float, nargs="+", default=[60.0, 28800.0],
                        help="simulated durations [s], shortest first (default 60 28800)")
    parser.add_argument("--step", type=float, default=0.01, help="macro step [s]")
    parser.add_argument("--keep", type=Path, help="keep the outputs in this folder")
    args = parser.parse_args(argv)
    if not (FMUS / "AgvVehicle.fmu").is_file():
        raise SystemExit(f"bench_memory: no FMUs in {FMUS}: run 'make fmus' first")
    folder = Path(tempfile.mkdtemp(prefix="bench_memory_"))
    try:
        (folder / "sitecustomize.py").write_text(textwrap.dedent(SITECUSTOMIZE))
        results = []
        print(f"{'simulated':>10} {'rows':>10} {'wall':>8} {'run MiB':>8} {'parent MiB':>10} "
              f"{'run ratio':>9} {'parent ratio':>12}   (run, parent MiB: logged / polled)")
        for stop in args.durations:
            r = measure(stop, args.step, folder)
            results.append(r)
            base = results[0]
            print(f"{stop:>9g}s {r['rows']:>10} {r['wall']:>7.0f}s {r['run'] / 1024:>8.1f} "
                  f"{r['parent'] / 1024:>10.1f} {r['run'] / base['run']:>9.3f} "
                  f"{r['parent'] / base['parent']:>12.3f}   ({r['logged_run'] / 1024:.1f} / "
                  f"{r['polled_run'] / 1024:.1f}, {r['logged_parent'] / 1024:.1f} / "
                  f"{r['polled_parent'] / 1024:.1f})", flush=True)
        worst = max(max(r["run"] / results[0]["run"], r["parent"] / results[0]["parent"])
                    for r in results)
        print(f"largest ratio to the {args.durations[0]:g} s run: {worst:.3f} "
              f"(target <= 1.15): {'met' if worst <= 1.15 else 'missed'}")
        if args.keep:
            args.keep.mkdir(parents=True, exist_ok=True)
            for r in results:
                shutil.copytree(r["out"], args.keep / r["out"].name, dirs_exist_ok=True)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
