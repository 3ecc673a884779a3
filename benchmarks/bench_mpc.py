"""Seed-001 LTV MPC: QP solve time and OSQP iterations per sample, beside an anchor.

A real AGV must solve each sample's QP well within its sample time T. This script runs the
seed-001 closed loops with the plain cores (agv_core.double_steer.seed001_loop, the same
sequence as the FMU runs: one QP per sample) and times every controller update (QP
assembly + OSQP setup + solve + polish, what the FMU does per sample), warm-started (as in
the FMUs) and cold-started:

- circle (v_r = 0.4 m/s, omega_r = 0.074 rad/s), R = 0.1 I, N = 5, 6, 7, 8, 80 s;
- S-curve, N = 7, R = 0.1 I, 70 s.

Each update is timed twice: wall (``time.perf_counter``) and CPU of the thread
(``time.thread_time``). On a shared machine the wall time of an update also counts the
time the process waited for a core; the CPU time does not (it still grows with cache
contention from other jobs). Every round runs each side in a fresh child process, and
the per-sample minimum over the rounds is kept.

``--baseline REV`` runs the cores of git revision REV (unpacked with ``git archive``) as
an anchor in the same rounds, interleaved with this checkout, with the same Python and
packages: the ratio of the two separates a change of the code from a change of the
machine, its load or the installed packages. The script prints, per case and side, the
median, 99th percentile and maximum wall time [ms], the median CPU time [ms], median / T,
OSQP's iterations (median, max), and per case the CPU ratio this checkout / baseline;
also the load average before and after, and the versions of osqp, numpy and scipy.

``--parts`` instead splits this checkout's update of the S-curve case (warm) into its
parts, CPU time per update: QP assembly (``LtvMpc.qp``, dense numpy), the two sparse
conversions, OSQP's ``setup`` (which factorises) and ``solve`` (with polishing).

``--loop REV`` times the FMU loop instead: ``experiments/seed001_scurve.toml`` variant
``mpc`` (reference, MPC, inverse kinematics, vehicle; 350 steps of 0.2 s) through
``master.simulate`` in a child process, with the FMUs and code of REV (``git archive``,
built by its own build code, ``PYTHONPATH`` first) and of this checkout, interleaved
``--rounds`` times. It prints per side the median CPU time (``time.process_time``) and
wall time of the simulation, the number of OSQP solves (counted at ``osqp.OSQP.solve``,
which the FMUs' cores call in the same process), and the median of the per-round CPU
ratios REV / this checkout; the recordings of all runs must be bit-identical.

Run:  .venv/bin/python benchmarks/bench_mpc.py [--rounds 3] [--baseline a4daefc] [--parts]
      .venv/bin/python benchmarks/bench_mpc.py --loop 11281e9 [--rounds 5]
"""

import argparse
import importlib
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
T = 0.2


# ------------------------------------------------------------------------ child
def _core(new, old):
    """Module ``new`` (the component layout) or, in an older tree, ``old``."""
    try:
        return importlib.import_module(new)
    except ModuleNotFoundError:
        return importlib.import_module(old)


class _Timed:
    """A controller whose ``update`` calls are timed (wall and thread CPU [s])."""

    def __init__(self, controller):
        self.controller, self.wall, self.cpu = controller, [], []

    def update(self, *args):
        w0, c0 = time.perf_counter(), time.thread_time()
        out = self.controller.update(*args)
        c1, w1 = time.thread_time(), time.perf_counter()
        self.wall.append(w1 - w0)
        self.cpu.append(c1 - c0)
        return out

    def step(self, *args):
        return self.controller.step(*args)


def cases():
    """(name, reference, initial pose, stop [s], horizon N) of every case."""
    import math

    ref_mod = _core("agv_core.ref_trajectory.ref_trajectory", "agv_core.ref_trajectory")
    circle = ref_mod.RefTrajectory("circle", speed=0.4, omega=0.074)
    scurve = ref_mod.RefTrajectory("scurve", speed=0.4, amplitude=1.5, wavelength=12.0,
                                   peak_time=33.7)
    h = scurve.at(0.0)["heading"]
    for n in (5, 6, 7, 8):
        yield f"circle N={n}", circle, (0.0, -0.5, 0.0), 80.0, n
    yield "S-curve N=7", scurve, (0.5 * math.sin(h), -0.5 * math.cos(h), h), 70.0, 7


def child():
    """Every case once, warm and cold: per case the update times and iterations."""
    mpc = _core("agv_core.ltv_mpc.ltv_mpc", "agv_core.ltv_mpc")
    loop = _core("agv_core.double_steer.seed001_loop", "agv_core.seed001_loop")
    result = {}
    for name, ref, pose0, stop, n in cases():
        for warm in (True, False):
            timed = _Timed(mpc.LtvMpc(sample_time=T, horizon=n, lam=0.1, warm_start=warm))
            rows = loop.run_loop(timed, ref, pose0, stop, sample_time=T)
            result[f"{name} {'warm' if warm else 'cold'}"] = {
                "wall": timed.wall, "cpu": timed.cpu,
                "iterations": [int(r["iterations"]) for r in rows]}
    return result


def parts():
    """Median CPU time [s] per update of each part of the S-curve case's updates."""
    import numpy as np
    import osqp

    from agv_core.double_steer.seed001_loop import run_loop
    from agv_core.ltv_mpc import ltv_mpc

    spent = {"QP assembly (LtvMpc.qp)": [], "2 x scipy.sparse.csc_matrix": [],
             "OSQP setup": [], "OSQP solve + polish": [], "whole update": []}

    def timed(key, fn):
        def call(*args, **kwargs):
            c0 = time.thread_time()
            out = fn(*args, **kwargs)
            spent[key].append(time.thread_time() - c0)
            return out
        return call

    ltv_mpc.LtvMpc.qp = timed("QP assembly (LtvMpc.qp)", ltv_mpc.LtvMpc.qp)
    ltv_mpc.sp.csc_matrix = timed("2 x scipy.sparse.csc_matrix", ltv_mpc.sp.csc_matrix)
    osqp.OSQP.setup = timed("OSQP setup", osqp.OSQP.setup)
    osqp.OSQP.solve = timed("OSQP solve + polish", osqp.OSQP.solve)
    name, ref, pose0, stop, n = list(cases())[-1]
    timed_mpc = _Timed(ltv_mpc.LtvMpc(sample_time=T, horizon=n, lam=0.1))
    run_loop(timed_mpc, ref, pose0, stop, sample_time=T)
    spent["whole update"] = timed_mpc.cpu
    conversions = spent["2 x scipy.sparse.csc_matrix"]
    spent["2 x scipy.sparse.csc_matrix"] = [a + b for a, b in zip(conversions[::2],
                                                                  conversions[1::2])]
    print(f"{name}, warm start, {len(timed_mpc.cpu)} updates; {_versions()}; median CPU "
          "time per update [ms]")
    for key, values in spent.items():
        print(f"  {key:<30} {1e3 * float(np.median(values)):7.3f}")


LOOP_MANIFEST = "experiments/seed001_scurve.toml"
LOOP_VARIANT = "mpc"
LOOP_STEMS = ("agv_ref_trajectory", "agv_double_steer", "agv_double_steer_ik", "agv_ltv_mpc",
              "agv_lateral_pid")


def loop_child(manifest):
    """One simulation of the loop: CPU and wall time [s], OSQP solves, digest."""
    import hashlib
    import struct

    import osqp

    solves = [0]
    solve = osqp.OSQP.solve

    def counted(self, *args, **kwargs):
        solves[0] += 1
        return solve(self, *args, **kwargs)

    osqp.OSQP.solve = counted
    rows = []

    def record(row):
        rows.append(tuple(row))

    try:
        from agv_cosim.execution import RowObserver, simulate
        from agv_cosim.pipeline import prepare

        _, jobs, _ = prepare(manifest, variants=[LOOP_VARIANT])
        c0, w0 = time.process_time(), time.perf_counter()
        simulate(jobs[0].plan, [RowObserver(record)], fast=True)
    except ImportError:  # a tree before agv_cosim.pipeline (its runner and master modules)
        from agv_cosim.master import simulate
        from agv_cosim.runner import prepare

        _, jobs, _ = prepare(manifest, variants=[LOOP_VARIANT])
        c0, w0 = time.process_time(), time.perf_counter()
        simulate(jobs[0].plan, record)
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    digest = hashlib.sha256()
    for row in rows:
        digest.update(struct.pack(f"<{len(row)}d", *row))
    return {"cpu": cpu, "wall": wall, "solves": solves[0], "rows": len(rows),
            "digest": digest.hexdigest()[:16]}


def _loop_side(tree, folder):
    """Build the loop's FMUs from ``tree`` into ``folder/fmus`` with ``tree``'s build code
    and write its manifest into ``folder/experiments``; returns (manifest, env)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(tree / "orchestrator"), str(tree / "components")])
    (folder / "fmus").mkdir(parents=True)
    code = ("import sys\nfrom pathlib import Path\n"
            "from agv_cosim.build import build_one, default_components_dir, slave_scripts\n"
            "scripts = {p.stem: p for p in slave_scripts(default_components_dir())}\n"
            f"for stem in {list(LOOP_STEMS)!r}:\n"
            "    build_one(scripts[stem], Path(sys.argv[1]))\n")
    subprocess.run([sys.executable, "-c", code, str(folder / "fmus")], check=True, env=env,
                   cwd=str(folder), capture_output=True)
    manifest = folder / LOOP_MANIFEST
    manifest.parent.mkdir(parents=True)
    shutil.copyfile(tree / LOOP_MANIFEST, manifest)   # its FMUs are "../fmus/<name>.fmu"
    return manifest, env


def loop(rev, rounds, tmp):
    """The FMU loop of ``rev`` and of this checkout, interleaved (see the docstring)."""
    old_tree = tmp / "old_tree"
    old_tree.mkdir()
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(old_tree)], input=archive, check=True)
    sides = {rev: _loop_side(old_tree, tmp / "old"), "this checkout": _loop_side(ROOT,
                                                                                tmp / "new")}
    results = {side: [] for side in sides}
    load0 = os.getloadavg()
    for r in range(rounds):
        for side, (manifest, env) in sides.items():
            out = subprocess.run([sys.executable, __file__, "--loop-child", str(manifest)],
                                 check=True, capture_output=True, text=True, env=env,
                                 cwd=str(manifest.parent))
            res = json.loads(out.stdout.strip().splitlines()[-1])
            results[side].append(res)
            print(f"  round {r + 1}: {side:<14} CPU {res['cpu']:.3f} s, wall {res['wall']:.3f}"
                  f" s, {res['solves']} solves [{res['digest']}]", flush=True)
    load1 = os.getloadavg()
    print(f"{LOOP_MANIFEST} variant {LOOP_VARIANT} through master.simulate, {rounds} rounds; "
          f"load average {load0[0]:.1f} before, {load1[0]:.1f} after")
    for side, rs in results.items():
        print(f"  {side:<14} median CPU {statistics.median(r['cpu'] for r in rs):.3f} s, wall "
              f"{statistics.median(r['wall'] for r in rs):.3f} s, OSQP solves "
              f"{sorted({r['solves'] for r in rs})} for {rs[0]['rows']} samples")
    pairs = [o["cpu"] / n["cpu"] for o, n in zip(results[rev], results["this checkout"])]
    print(f"CPU {rev} / this checkout, median of rounds: {statistics.median(pairs):.2f} "
          f"({', '.join(f'{p:.2f}' for p in pairs)})")
    digests = {r["digest"] for rs in results.values() for r in rs}
    if len(digests) != 1:
        print(f"RECORDINGS DIFFER: {sorted(digests)}")
        return 1
    print(f"all {sum(len(rs) for rs in results.values())} recordings bit-identical "
          f"(digest {digests.pop()})")
    return 0


# ------------------------------------------------------------------------ parent
def _versions():
    import numpy
    import osqp
    import scipy

    return f"osqp {osqp.__version__}, numpy {numpy.__version__}, scipy {scipy.__version__}"


def _run_side(tree):
    env = dict(os.environ)
    env["PYTHONPATH"] = str(tree / "components")
    out = subprocess.run([sys.executable, __file__, "--child"], check=True,
                         capture_output=True, text=True, env=env, cwd=str(tree))
    return json.loads(out.stdout.strip().splitlines()[-1])


def _summary(rounds):
    """Per case: the per-sample minimum over rounds of wall and CPU [s], iterations."""
    import numpy as np

    out = {}
    for case in rounds[0]:
        wall = np.min([r[case]["wall"] for r in rounds], axis=0)
        cpu = np.min([r[case]["cpu"] for r in rounds], axis=0)
        its = rounds[0][case]["iterations"]
        out[case] = {"wall_med": float(np.median(wall)),
                     "wall_p99": float(np.percentile(wall, 99)),
                     "wall_max": float(wall.max()), "cpu_med": float(np.median(cpu)),
                     "it_med": statistics.median(its), "it_max": max(its)}
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3,
                        help="runs per case and side; the per-sample minimum is used")
    parser.add_argument("--baseline", metavar="REV",
                        help="git revision whose cores run beside this checkout's")
    parser.add_argument("--parts", action="store_true",
                        help="split this checkout's update into its parts (CPU time)")
    parser.add_argument("--loop", metavar="REV",
                        help="time the seed-001 FMU loop of REV against this checkout's")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--loop-child", metavar="MANIFEST", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.parts:
        parts()
        return 0
    if args.child:
        print(json.dumps(child()))
        return 0
    if args.loop_child:
        print(json.dumps(loop_child(args.loop_child)))
        return 0

    tmp = Path(tempfile.mkdtemp(prefix="agv_bench_mpc_"))
    try:
        if args.loop:
            return loop(args.loop, args.rounds, tmp)
        sides = {"this checkout": ROOT}
        if args.baseline:
            tree = tmp / "baseline"
            tree.mkdir()
            archive = subprocess.run(["git", "-C", str(ROOT), "archive", args.baseline,
                                      "components"], check=True, capture_output=True).stdout
            subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
            sides = {f"baseline {args.baseline}": tree, **sides}
        load0 = os.getloadavg()
        rounds = {side: [] for side in sides}
        for r in range(args.rounds):
            for side, tree in sides.items():
                rounds[side].append(_run_side(tree))
                print(f"  round {r + 1}: {side} done", file=sys.stderr, flush=True)
        load1 = os.getloadavg()
        stats = {side: _summary(rs) for side, rs in rounds.items()}
        print(f"seed-001 LTV MPC, one update per sample (T = {T} s), {args.rounds} rounds "
              f"(per-sample minimum); {_versions()}; load average {load0[0]:.1f} before, "
              f"{load1[0]:.1f} after; times in ms")
        print(f"{'case':<19} {'side':<18} {'wall med':>8} {'p99':>7} {'max':>7} "
              f"{'CPU med':>8} {'med/T':>8} {'it med':>6} {'it max':>6}")
        for case in stats["this checkout"]:
            for side in sides:
                s = stats[side][case]
                print(f"{case:<19} {side:<18} {1e3 * s['wall_med']:8.3f} "
                      f"{1e3 * s['wall_p99']:7.3f} {1e3 * s['wall_max']:7.3f} "
                      f"{1e3 * s['cpu_med']:8.3f} {s['wall_med'] / T:8.2e} "
                      f"{s['it_med']:6.0f} {s['it_max']:6d}")
        if args.baseline:
            base = f"baseline {args.baseline}"
            ratios = [stats["this checkout"][c]["cpu_med"] / stats[base][c]["cpu_med"]
                      for c in stats[base]]
            print(f"CPU median this checkout / {base}: "
                  + ", ".join(f"{r:.2f}" for r in ratios)
                  + f" (median {statistics.median(ratios):.2f})")
        return 0
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
