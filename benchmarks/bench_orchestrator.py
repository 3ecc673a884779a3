"""Benchmark: per-macro-step wall time of the agv-cosim master vs a minimal FMI loop.

The closed loop is seed 000 model a (5 FMUs) at a 1 ms communication step::

    vehicle (AgvVehicle) --x, y, heading--> sensor (AgvVisionSensor)
    sensor --lateral_error, heading_error--> controller (AgvStateFeedback)
    actuator (AgvSteeringA) --alpha--> steer (AgvSteerSensor) --alpha_meas--> controller
    controller --u--> actuator --alpha--> vehicle

Two runners do the same work on the same FMUs:

orchestrator
    ``agv_cosim.pipeline.prepare`` on a manifest written to a temporary folder, then
    ``agv_cosim.execution.simulate`` (fast path) with an observer that copies each recorded row into
    a preallocated numpy array (no CSV, so both sides record the same way).
minimal
    A hand-written Gauss-Seidel loop: per macro step one ``fmi2DoStep`` per FMU, then
    one batched ``fmi2GetReal`` of the actuator (its alpha closes the loop backwards, to
    the vehicle, visited first), then in the same feedthrough order one batched
    ``fmi2SetReal`` and one batched ``fmi2GetReal`` per FMU (preallocated ctypes arrays,
    raw ctypes function pointers, status checked), then the same signals copied into a
    preallocated numpy array at the same record interval. It does not check outputs for
    NaN/inf (the master does).

The per-step time of each is the wall time from the first recorded row (after
initialisation) to the last one, divided by the number of macro steps, so FMU loading
is excluded. Rounds alternate orchestrator / minimal; the medians and their ratio are
printed, and the two recordings are checked to be bit-identical.

Peak memory: the orchestrator runs 60 s and 3600 s simulated in child processes, each
calling ``runner.run_job`` (what ``run_manifest``'s per-run process calls:
``master.simulate`` with the CSV streamed to disk). Each child reports its own peak RSS
(VmHWM from /proc/self/status) at the end of the run. (``os.wait4``'s ``ru_maxrss`` is
printed too but is no measure of the run: Linux keeps the pre-exec high-water mark, so it
is at least this benchmark process's peak.)

Run: ``python benchmarks/bench_orchestrator.py [--rounds 3] [--stop 20] [--record-interval
0.001] [--no-memory]``.
"""

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np

from agv_cosim.build import build_one, slave_script
from agv_cosim.execution import RowObserver, simulate
from agv_cosim.pipeline import prepare, run_job

STEP = 0.001
SCRIPTS = {"vehicle": "agv_vehicle.py", "actuator": "agv_steering_a.py",
           "sensor": "agv_vision_sensor.py", "steer": "agv_steer_sensor.py",
           "controller": "agv_state_feedback.py"}
PARAMETERS = {
    "vehicle": {"wheelbase": 1.4944, "reference_point": "front", "y0": 0.1, "v0": 1.0},
    "actuator": {},
    "sensor": {"path": "line:", "frame_period": 0.0, "latency": 0.0, "noise_lateral": 0.0,
               "noise_heading": 0.0},
    "steer": {"noise": 0.0, "resolution": 0.0},
    "controller": {},
}
CONNECTIONS = [("vehicle.x", "sensor.x"), ("vehicle.y", "sensor.y"),
               ("vehicle.heading", "sensor.heading"),
               ("sensor.lateral_error", "controller.lateral_error"),
               ("sensor.heading_error", "controller.heading_error"),
               ("actuator.alpha", "steer.alpha"), ("steer.alpha_meas", "controller.alpha"),
               ("controller.u", "actuator.u"), ("actuator.alpha", "vehicle.alpha")]
#: The master's Gauss-Seidel order for this loop, hard-coded in the minimal loop.
GS_ORDER = ["vehicle", "sensor", "steer", "controller", "actuator"]
RECORD = ["vehicle.x", "vehicle.y", "vehicle.heading", "sensor.lateral_error",
          "sensor.heading_error", "actuator.alpha", "steer.alpha_meas", "controller.u"]


def _toml_value(value):
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    return repr(value)


def write_manifest(folder, fmus, stop, step, record_interval):
    """Write the seed-000 model-a manifest into ``folder``; return its path."""
    lines = ['name = "bench"', "[simulation]", "start = 0.0", f"stop = {stop!r}",
             f"step = {step!r}", 'algorithm = "gauss-seidel"']
    for cname, params in PARAMETERS.items():
        lines += [f"[components.{cname}]", f"fmu = {json.dumps(str(fmus[cname]))}"]
        if params:
            body = ", ".join(f"{k} = {_toml_value(v)}" for k, v in params.items())
            lines.append(f"parameters = {{ {body} }}")
    for source, target in CONNECTIONS:
        lines += ["[[connections]]", f'from = "{source}"', f'to = "{target}"']
    lines += ["[record]", f"variables = {json.dumps(RECORD)}",
              f"interval = {record_interval!r}"]
    path = Path(folder) / f"bench_{stop:g}_{step:g}.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def build(folder):
    """Build the five FMUs into ``folder``; return component name -> FMU path."""
    return {c: build_one(slave_script(Path(s).stem), folder).fmu for c, s in SCRIPTS.items()}


# ------------------------------------------------------------------------ orchestrator
def load_baseline(rev):
    """``agv_cosim/master.py`` as of git revision ``rev``, imported beside the current one.

    It runs with the current package's other modules (model, ...), so it measures the
    master's own loop: the before/after comparison of a change to master.py in one run.
    """
    import importlib.util

    root = Path(__file__).resolve().parent.parent
    source = subprocess.run(["git", "-C", str(root), "show",
                             f"{rev}:orchestrator/agv_cosim/master.py"],
                            check=True, capture_output=True, text=True).stdout
    folder = Path(tempfile.mkdtemp(prefix="agv_bench_baseline_"))
    path = folder / "master_baseline.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("agv_cosim._master_baseline", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    shutil.rmtree(folder, ignore_errors=True)
    return module.simulate


def run_orchestrator(manifest_path, baseline=None):
    """Run through ``execution.simulate`` (or a ``--baseline`` master's
    ``simulate(plan, write_row)``); return (per-step wall [s], CPU [s], recording)."""
    _, jobs, _ = prepare(manifest_path)
    plan = jobs[0].plan
    n_steps = int(round((plan.stop - plan.start) / plan.step))
    n_rows = -(-n_steps // plan.record_every) + 1
    out = np.empty((n_rows, 1 + len(plan.record)))
    stamps = []
    i = 0

    def write_row(row):
        nonlocal i
        out[i] = row
        i += 1
        if i == 1 or i == n_rows:
            stamps.append((time.perf_counter(), time.process_time()))

    if baseline is None:
        simulate(plan, [RowObserver(write_row)], fast=True)
    else:  # the --baseline master's simulate(plan, write_row)
        baseline(plan, write_row)
    assert i == n_rows, (i, n_rows)
    return ((stamps[1][0] - stamps[0][0]) / n_steps,
            (stamps[1][1] - stamps[0][1]) / n_steps, out)


# ------------------------------------------------------------------------ minimal loop
class _Fmu:
    """One FMU instantiated with fmpy's FMU2Slave, its raw ctypes functions and buffers."""

    def __init__(self, fmu_path, name, params, outputs, inputs):
        from fmpy import read_model_description
        from fmpy.fmi2 import FMU2Slave, fmi2Real, fmi2ValueReference

        self.dir = tempfile.mkdtemp(prefix=f"bench_{name}_")
        with zipfile.ZipFile(fmu_path) as archive:
            archive.extractall(self.dir)
        md = read_model_description(fmu_path)
        vars_ = {v.name: v for v in md.modelVariables}
        self.slave = FMU2Slave(guid=md.guid, unzipDirectory=self.dir,
                               modelIdentifier=md.coSimulation.modelIdentifier,
                               instanceName=name)
        self.slave.instantiate()
        self.slave.setupExperiment(startTime=0.0)
        for pname, value in params.items():
            vr = [vars_[pname].valueReference]
            if isinstance(value, str):
                self.slave.setString(vr, [value])
            else:
                self.slave.setReal(vr, [float(value)])
        self.slave.enterInitializationMode()
        self.slave.exitInitializationMode()
        fns = self.slave._functions
        self.c = self.slave.component
        self.do_step, self.set_real, self.get_real = (
            fns["fmi2DoStep"], fns["fmi2SetReal"], fns["fmi2GetReal"])
        self.n_out, self.n_in = len(outputs), len(inputs)
        self.out_vr = (fmi2ValueReference * self.n_out)(
            *[vars_[v].valueReference for v in outputs])
        self.out = (fmi2Real * self.n_out)()
        self.in_vr = (fmi2ValueReference * max(1, self.n_in))(
            *[vars_[v].valueReference for v in inputs])
        self.inp = (fmi2Real * max(1, self.n_in))()

    def close(self):
        self.slave.terminate()
        self.slave.freeInstance()
        shutil.rmtree(self.dir, ignore_errors=True)


def _check(status, what):
    if status > 1:  # fmi2Warning = 1: anything worse stops the run
        raise RuntimeError(f"{what} returned status {status}")


def run_minimal(fmus, stop, step, record_every):
    """Hand-written Gauss-Seidel loop; return (per-step wall [s], CPU [s], recording)."""
    veh = _Fmu(fmus["vehicle"], "vehicle", PARAMETERS["vehicle"], ["x", "y", "heading"],
               ["alpha"])
    act = _Fmu(fmus["actuator"], "actuator", {}, ["alpha"], ["u"])
    sen = _Fmu(fmus["sensor"], "sensor", PARAMETERS["sensor"],
               ["lateral_error", "heading_error"], ["x", "y", "heading"])
    ste = _Fmu(fmus["steer"], "steer", PARAMETERS["steer"], ["alpha_meas"], ["alpha"])
    ctl = _Fmu(fmus["controller"], "controller", {}, ["u"],
               ["alpha", "heading_error", "lateral_error"])
    units = [veh, act, sen, ste, ctl]  # the manifest's order: the master's doStep order
    n_steps = int(round(stop / step))
    n_rows = -(-n_steps // record_every) + 1
    rec = np.empty((n_rows, 1 + len(RECORD)))
    vo, ao, so, to, co = veh.out, act.out, sen.out, ste.out, ctl.out
    vi, ai, si, ti, ci = veh.inp, act.inp, sen.inp, ste.inp, ctl.inp

    def propagate():
        # One Gauss-Seidel pass as master.simulate makes it. First the actuator's outputs
        # are read: actuator.alpha feeds the vehicle, which is visited before the actuator,
        # and alpha does not depend directly on u, so this is the value of this instant.
        # Then, in the master's order (vehicle, sensor, steer, controller, actuator:
        # topological in the feedthrough graph), each FMU is set from the buffers as they
        # are at its turn, then read.
        _check(act.get_real(act.c, act.out_vr, 1, ao), "fmi2GetReal")
        vi[0] = ao[0]
        _check(veh.set_real(veh.c, veh.in_vr, 1, vi), "fmi2SetReal")
        _check(veh.get_real(veh.c, veh.out_vr, 3, vo), "fmi2GetReal")
        si[0], si[1], si[2] = vo[0], vo[1], vo[2]
        _check(sen.set_real(sen.c, sen.in_vr, 3, si), "fmi2SetReal")
        _check(sen.get_real(sen.c, sen.out_vr, 2, so), "fmi2GetReal")
        ti[0] = ao[0]
        _check(ste.set_real(ste.c, ste.in_vr, 1, ti), "fmi2SetReal")
        _check(ste.get_real(ste.c, ste.out_vr, 1, to), "fmi2GetReal")
        ci[0], ci[1], ci[2] = to[0], so[1], so[0]
        _check(ctl.set_real(ctl.c, ctl.in_vr, 3, ci), "fmi2SetReal")
        _check(ctl.get_real(ctl.c, ctl.out_vr, 1, co), "fmi2GetReal")
        ai[0] = co[0]
        _check(act.set_real(act.c, act.in_vr, 1, ai), "fmi2SetReal")
        _check(act.get_real(act.c, act.out_vr, 1, ao), "fmi2GetReal")

    def record(i, t):
        rec[i] = (t, vo[0], vo[1], vo[2], so[0], so[1], ao[0], to[0], co[0])

    try:
        # The output buffers start at 0.0 (ctypes), like the master's.
        propagate()
        record(0, 0.0)
        begin, begin_cpu = time.perf_counter(), time.process_time()
        row = 1
        do_steps = [(u.do_step, u.c) for u in units]
        for k in range(n_steps):
            t = k * step
            for do_step, c in do_steps:
                _check(do_step(c, t, step, 1), "fmi2DoStep")
            propagate()
            if (k + 1) % record_every == 0 or k + 1 == n_steps:
                record(row, (k + 1) * step)
                row += 1
        end, end_cpu = time.perf_counter(), time.process_time()
    finally:
        for u in units:
            u.close()
    return (end - begin) / n_steps, (end_cpu - begin_cpu) / n_steps, rec


# ------------------------------------------------------------------------ peak memory
def _vm_hwm_kib():
    """This process's peak RSS [KiB]: VmHWM of /proc/self/status (reset by exec)."""
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    raise RuntimeError("no VmHWM in /proc/self/status")


def memory_child(manifest_path, out_dir):
    """Child process: one run as ``runner.run_manifest``'s run process makes it.

    ``run_manifest`` runs each job in a grandchild forked by a forkserver
    (``runner._run_isolated``), out of this benchmark's reach. So this child calls
    ``runner.run_job`` itself, the function that grandchild runs: ``master.simulate``
    with the CSV streamed to disk by ``results.CsvSink``, then run.json. The simulation
    runs in this process, which reports its own peak RSS (VmHWM) when the run is done.
    """
    _, jobs, _ = prepare(manifest_path)
    result = run_job(jobs[0], Path(out_dir) / jobs[0].label)
    if result["status"] != "complete":
        raise SystemExit(f"run failed: {result['error']}")
    print(json.dumps({"rows": result["rows"], "vm_hwm_kib": _vm_hwm_kib()}))


def peak_rss(folder, fmus, stop, step):
    """Peak RSS [MiB], wall time [s] and rows of a child running the orchestrator to ``stop``.

    The peak is the child's own VmHWM. ``os.wait4``'s ``ru_maxrss`` is not used: Linux
    carries the high-water mark of the memory a process had before ``execve`` over into
    the new program, so a child started by ``subprocess`` reports at least this (large)
    benchmark process's peak, whatever the run itself uses. It is returned too, to show.
    """
    manifest = write_manifest(folder, fmus, stop, step, step)
    out_dir = Path(folder) / f"out_{stop:g}_{step:g}"
    begin = time.perf_counter()
    child = subprocess.Popen([sys.executable, __file__, "--memory-child", str(manifest),
                              str(out_dir)], stdout=subprocess.PIPE)
    stdout = child.stdout.read()
    _, status, usage = os.wait4(child.pid, 0)
    child.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - begin
    if child.returncode != 0:
        raise SystemExit(f"memory run to {stop} s failed (exit {child.returncode})")
    report = json.loads(stdout)
    shutil.rmtree(out_dir, ignore_errors=True)
    # VmHWM and ru_maxrss are in KiB on Linux
    return report["vm_hwm_kib"] / 1024.0, wall, report["rows"], usage.ru_maxrss / 1024.0


# ------------------------------------------------------------------------ main
def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3, help="alternating rounds (3)")
    parser.add_argument("--stop", type=float, default=20.0, help="simulated time [s] (20)")
    parser.add_argument("--record-interval", type=float, default=STEP,
                        help="record interval [s], a multiple of 1 ms (0.001)")
    parser.add_argument("--no-memory", action="store_true", help="skip the peak-RSS runs")
    parser.add_argument("--baseline", metavar="REV",
                        help="also run master.py of git revision REV (before/after ratio)")
    parser.add_argument("--memory-child", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.memory_child:
        memory_child(*args.memory_child)
        return 0

    tmp = Path(tempfile.mkdtemp(prefix="agv_bench_"))
    try:
        fmus = build(tmp / "fmus")
        manifest = write_manifest(tmp, fmus, args.stop, STEP, args.record_interval)
        _, jobs, _ = prepare(manifest)
        if jobs[0].plan.order != GS_ORDER:
            raise SystemExit(f"the master's order {jobs[0].plan.order} is not the minimal "
                             f"loop's {GS_ORDER}")
        every = jobs[0].plan.record_every
        n_steps = int(round(args.stop / STEP))
        print(f"closed loop: 5 FMUs (seed 000 model a), step {STEP * 1e3:g} ms, "
              f"{args.stop:g} s simulated = {n_steps} macro steps, recording "
              f"{len(RECORD)} signals every {every} step(s)")
        names = ["orchestrator", "minimal"]
        baseline = None
        if args.baseline:
            baseline = load_baseline(args.baseline)
            names.insert(1, "baseline")
        wall = {name: [] for name in names}
        cpu = {name: [] for name in names}
        reference = None
        for r in range(args.rounds):
            for name in names:
                if name == "orchestrator":
                    per_step, per_cpu, rec = run_orchestrator(manifest)
                elif name == "baseline":
                    per_step, per_cpu, rec = run_orchestrator(manifest, baseline)
                else:
                    per_step, per_cpu, rec = run_minimal(fmus, args.stop, STEP, every)
                if reference is None:
                    reference = rec
                elif not np.array_equal(rec, reference):
                    raise SystemExit(f"round {r + 1}: {name} recorded other values")
                wall[name].append(per_step)
                cpu[name].append(per_cpu)
                print(f"  round {r + 1} {name:<12} {per_step * 1e6:8.1f} us/step wall, "
                      f"{per_cpu * 1e6:8.1f} us/step CPU")
        med = {k: statistics.median(v) for k, v in wall.items()}
        med_cpu = {k: statistics.median(v) for k, v in cpu.items()}
        ratio = med["orchestrator"] / med["minimal"]
        print("recordings of all runs bit-identical: yes")
        print(f"median wall per macro step: orchestrator {med['orchestrator'] * 1e6:.1f} us, "
              f"minimal loop {med['minimal'] * 1e6:.1f} us")
        print(f"median CPU per macro step:  orchestrator "
              f"{med_cpu['orchestrator'] * 1e6:.1f} us, minimal loop "
              f"{med_cpu['minimal'] * 1e6:.1f} us (ratio "
              f"{med_cpu['orchestrator'] / med_cpu['minimal']:.3f})")
        print(f"RATIO orchestrator / minimal (median wall) = {ratio:.3f}  "
              f"(target <= 1.10: {'met' if ratio <= 1.10 else 'MISSED'})")
        if baseline is not None:
            print(f"median wall per macro step: baseline master ({args.baseline}) "
                  f"{med['baseline'] * 1e6:.1f} us, CPU {med_cpu['baseline'] * 1e6:.1f} us")
            print(f"RATIO orchestrator / baseline {args.baseline} (median wall) = "
                  f"{med['orchestrator'] / med['baseline']:.3f}, (median CPU) = "
                  f"{med_cpu['orchestrator'] / med_cpu['baseline']:.3f}")

        if not args.no_memory:
            long_step = STEP if med["orchestrator"] * 3600 / STEP < 300 else 0.01
            own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
            print(f"peak memory (orchestrator, runner.run_job: simulate + CSV, step "
                  f"{long_step * 1e3:g} ms, recording every step):")
            for stop in (60.0, 3600.0):
                mib, wall, rows, wait4_mib = peak_rss(tmp, fmus, stop, long_step)
                print(f"  {stop:6g} s simulated: peak RSS {mib:7.1f} MiB  ({rows} rows, "
                      f"{wall:.0f} s wall; wait4 ru_maxrss {wait4_mib:.1f} MiB, floored "
                      f"by this process's {own:.1f} MiB before exec)")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
