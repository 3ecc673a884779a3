"""Benchmark: does ``gc.freeze()`` once the run's objects exist make the master's step cheaper?

The seed-000 loop (``experiments/seed000_models_abc.toml`` variant a, Gauss-Seidel, 1 ms)
runs through ``agv_cosim.execution.simulate`` as ``bench_step.py``'s orchestrator child
does, in a fresh child per run, in two ways, rounds interleaved:

plain
    as the master runs it;
freeze
    ``gc.freeze()`` at the first recorded row (after instantiation, initialisation and
    the generated step functions: every object of the run exists), ``gc.unfreeze()``
    after the run.

Each child counts the garbage collections in the timed stretch (``gc.callbacks``) and
their time. The script prints the medians of the CPU per macro step, the collections
per run, and checks that the recorded rows are the same bytes.

Run: ``python benchmarks/bench_gc.py [--fmus DIR] [--rounds 6] [--stop 10]``.
"""

import argparse
import gc
import hashlib
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def child(manifest, freeze):
    from agv_cosim.execution import RowObserver, simulate
    from agv_cosim.pipeline import prepare

    _, jobs, _ = prepare(manifest, variants=["a"])
    plan = jobs[0].plan
    n = int(round((plan.stop - plan.start) / plan.step))
    collections, spent, started = [0, 0, 0], [0.0], [0.0]

    def watch(phase, info):
        if phase == "start":
            started[0] = time.perf_counter()
        else:
            collections[info["generation"]] += 1
            spent[0] += time.perf_counter() - started[0]

    rows, stamps = [], []

    def write(row):
        if not stamps:
            if freeze:
                gc.freeze()
            gc.callbacks.append(watch)
        rows.append(tuple(row))
        stamps.append(time.process_time())

    try:
        simulate(plan, [RowObserver(write)], fast=True)
    finally:
        gc.unfreeze()
    digest = hashlib.sha256(repr(rows).encode()).hexdigest()[:16]
    print(json.dumps({"cpu": (stamps[-1] - stamps[0]) / n, "collections": collections,
                      "gc_time": spent[0], "digest": digest}))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--fmus", type=Path, help="FMUs built by this checkout (a folder)")
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--stop", type=float, default=10.0, help="simulated time [s]")
    parser.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child[0], args.child[1] == "freeze")
        return 0
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from bench_compiled_cores import write_manifest

    with tempfile.TemporaryDirectory(prefix="bench_gc_") as tmp:
        tmp = Path(tmp)
        fmus = args.fmus
        if fmus is None:
            fmus = tmp / "fmus"
            subprocess.run([sys.executable, "-m", "agv_cosim.cli", "build", "--out",
                            str(fmus)], check=True, cwd=ROOT, capture_output=True)
        manifest = write_manifest(fmus, tmp, args.stop)
        results = {"plain": [], "freeze": []}
        for _ in range(args.rounds):
            for kind in results:
                done = subprocess.run([sys.executable, __file__, "--child", str(manifest),
                                       kind], capture_output=True, text=True, check=True)
                results[kind].append(json.loads(done.stdout.strip().splitlines()[-1]))
        print(f"seed 000 model a through the master, {int(round(args.stop / 0.001))} macro "
              f"steps, {args.rounds} rounds interleaved:")
        for kind, runs in results.items():
            cpu = statistics.median(r["cpu"] for r in runs)
            print(f"  {kind:6s} CPU {cpu * 1e6:6.2f} us per macro step; collections per run "
                  f"(gen 0, 1, 2): {runs[0]['collections']}, "
                  f"{statistics.median(r['gc_time'] for r in runs) * 1e3:.2f} ms in all")
        if len({r["digest"] for runs in results.values() for r in runs}) != 1:
            print("  recorded rows DIFFER")
            return 1
        print("  recorded rows: the same in every run")
    return 0


if __name__ == "__main__":
    sys.exit(main())
