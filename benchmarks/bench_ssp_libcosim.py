"""Benchmark: the same SSP package stepped by libcosim and by the agv-cosim master.

The package is seed 000 model a (experiments/seed000_models_abc.toml, variant a, Jacobi, its
step) exported with ``agv_cosim.ssp.exporter.export_ssp`` from FMUs built into a temporary
folder. Both masters load the package, then the time of the macro steps alone is taken:

libcosim
    ``CosimExecution.from_ssp_file`` (fixed step, Jacobi, worker threads), the recorded
    variables observed by a time-series observer; timed: ``execution.step(n)``.
agv-cosim
    ``agv_cosim.ssp.importer.load_ssp`` + ``pipeline.prepare`` + ``execution.simulate`` in
    this process (not through ``runner.run_manifest``, which would run it in a child
    process of its own), with rows copied into a list (no CSV); timed: first recorded row
    (after initialisation) to the last.

Rounds alternate; medians of the per-step times and their ratio (libcosim / ours; > 1
means ours is faster) are printed. Usage::

    python benchmarks/bench_ssp_libcosim.py [--stop 20] [--rounds 3]
"""

import argparse
import re
import statistics
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def make_package(folder, stop):
    from agv_cosim.build import build_fmus, default_components_dir, slave_scripts
    from agv_cosim.ssp.exporter import export_ssp

    results = build_fmus(Path(folder) / "fmus", slave_scripts(default_components_dir()))
    by_model = {r.fmu.stem: r.fmu for r in results}
    text = (ROOT / "experiments" / "seed000_models_abc.toml").read_text()
    text = re.sub(r'"\.\./fmus/(\w+)\.fmu"', lambda m: f'"{by_model[m.group(1)]}"', text)
    text = re.sub(r"(?m)^stop = [0-9.]+", f"stop = {float(stop)!r}", text)
    text = re.sub(r'(?m)^algorithm = "[a-z-]+"', 'algorithm = "jacobi"', text)
    manifest = Path(folder) / "loop.toml"
    manifest.write_text(text)
    return export_ssp(manifest, Path(folder) / "loop.ssp", variant="a")


def time_ours(package, work):
    from agv_cosim.execution import RowObserver, simulate
    from agv_cosim.pipeline import prepare
    from agv_cosim.ssp.importer import load_ssp

    _, jobs, _ = prepare(load_ssp(package, work))
    plan = jobs[0].plan
    stamps, rows = [], []

    def write(row):
        stamps.append(time.perf_counter())
        rows.append(list(row))

    simulate(plan, [RowObserver(write)], fast=True)
    n = int(round((plan.stop - plan.start) / plan.step))
    return (stamps[-1] - stamps[0]) / n, plan.record, plan.step, n


def time_libcosim(package, record, step, n):
    from libcosimpy.CosimEnums import CosimVariableType
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver

    log_output_level(CosimLogLevel.WARNING)
    execution = CosimExecution.from_ssp_file(str(package), step_size=int(round(step * 1e9)))
    observer = CosimObserver.create_time_series(buffer_size=n + 2)
    execution.add_observer(observer)
    for item in record:
        cname, vname = item.split(".")
        index = execution.slave_index_from_instance_name(cname)
        ref = next(v.reference for v in execution.slave_variables(index)
                   if v.name.decode() == vname)
        observer.start_time_series(index, ref, CosimVariableType.REAL)
    execution.step(1)  # initialisation happens on the first step; not timed
    begin = time.perf_counter()
    assert execution.step(n - 1)
    return (time.perf_counter() - begin) / (n - 1)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--stop", type=float, default=10.0, help="simulated time [s]")
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_ssp_") as tmp:
        package = make_package(tmp, args.stop)
        ours, theirs = [], []
        for i in range(args.rounds):
            per_step, record, step, n = time_ours(package, Path(tmp) / f"work{i}")
            ours.append(per_step)
            theirs.append(time_libcosim(package, record, step, n))
        a, b = statistics.median(ours), statistics.median(theirs)
        print(f"seed 000 model a, 5 FMUs, {n} macro steps of {step * 1e3:g} ms, "
              f"{args.rounds} rounds")
        print(f"agv-cosim master (Jacobi): {a * 1e6:8.1f} us per macro step")
        print(f"libcosim 0.11 (Jacobi):    {b * 1e6:8.1f} us per macro step")
        print(f"ratio libcosim / agv-cosim: {b / a:.2f}  "
              f"({'ours faster' if b > a else 'libcosim faster'})")


if __name__ == "__main__":
    main()
