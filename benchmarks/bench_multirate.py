"""Benchmark: multirate stepping (a component's own ``step``) against every component at
the simulation's step, in FMU calls and CPU time per simulated second.

Two loops, each run single-rate (every component at the manifest's step) and multirate
(the slow components at their own step), in alternating rounds within one run:

- seed 000 (``experiments/seed000_models_abc.toml`` variant ``a``, 12 s at 1 ms): the
  vision sensor, the steering-angle sensor and the controller at 10 ms, the actuator and
  the vehicle at 1 ms;
- seed 004 (``experiments/seed004_sample_time.toml`` variant ``t065``, both loops, 45 s
  at 10 ms): the preview controllers, total stations, gyros and steering sensors at
  50 ms (the controllers' own sample period), the actuators, vehicles and truth probes at
  10 ms.

FMU calls: every FMI get, set and doStep the master makes in one run, counted by a
separate run through counting wrappers of the FMI functions (the same calls, made
through Python). CPU: the process time of :func:`agv_cosim.execution.simulate`
(``fast=True``, as the workers run it: compiled per-step programs, and for single-rate
runs the compiled stretches of macro steps), the median of ``--rounds`` rounds. The
multirate runs change the results (the slow components sample and hold): the script
prints the largest difference of each recorded signal as a reminder, not a figure of
merit.

Run: ``python benchmarks/bench_multirate.py [--fmus DIR] [--rounds 3]``; ``--fmus`` is
the folder of the built component FMUs (default ``fmus/``, ``make fmus``).
"""

import argparse
import statistics
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from agv_cosim.execution import RowObserver, simulate, units
from agv_cosim.manifest import Manifest, load_manifest
from agv_cosim.pipeline import prepare

ROOT = Path(__file__).resolve().parents[1]

#: (name, manifest, variant, {component: its own step [s]})
CASES: list[tuple[str, str, str, dict[str, float]]] = [
    ("seed 000 (1 ms; sensors + controller at 10 ms)", "seed000_models_abc.toml", "a",
     {"sensor": 0.01, "steer": 0.01, "ctrl": 0.01}),
    ("seed 004 (10 ms; controllers + sensors at 50 ms)", "seed004_sample_time.toml",
     "t065", {f"{c}_{loop}": 0.05 for c in ("ctrl", "ts", "gyro", "steer")
              for loop in "sc"}),
]


def manifest_of(name: str, fmus: Path, folder: Path) -> Path:
    """The shipped manifest ``name`` pointed at the FMUs in ``fmus``."""
    text = (ROOT / "experiments" / name).read_text().replace("../fmus/", f"{fmus}/")
    path = folder / name
    path.write_text(text)
    return path


def system_of(path: Path, variant: str, steps: dict[str, float]) -> Any:
    manifest: Manifest = load_manifest(path)
    for cname, step in steps.items():
        manifest.components[cname].step = step
    _, jobs, _ = prepare(manifest, [variant])
    return jobs[0].plan


def run(system: Any) -> tuple[float, np.ndarray]:
    rows: list[list[float]] = []
    begin = time.process_time()
    simulate(system, [RowObserver(lambda row: rows.append(list(row)))], fast=True)
    return time.process_time() - begin, np.array(rows)


def count_calls(system: Any) -> Counter[str]:
    """Every FMI function the master calls in one run of ``system``, by name."""
    counts: Counter[str] = Counter()
    original = units.c_function

    def counting(slave: Any, name: str) -> Any:
        function = original(slave, name)

        def call(*args: Any) -> Any:
            counts[name] += 1
            return function(*args)
        return call

    units.c_function = counting
    try:
        simulate(system, [], fast=True)
    finally:
        units.c_function = original
    return counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fmus", type=Path, default=ROOT / "fmus")
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    fmus = args.fmus.resolve()
    with tempfile.TemporaryDirectory(prefix="bench_multirate_") as tmp:
        for title, name, variant, steps in CASES:
            path = manifest_of(name, fmus, Path(tmp))
            single = system_of(path, variant, {})
            multi = system_of(path, variant, steps)
            span = single.stop - single.start
            calls = {kind: count_calls(system)
                     for kind, system in (("single", single), ("multi", multi))}
            cpu: dict[str, list[float]] = {"single": [], "multi": []}
            results: dict[str, np.ndarray] = {}
            for _ in range(args.rounds):
                for kind, system in (("single", single), ("multi", multi)):
                    seconds, rows = run(system)
                    cpu[kind].append(seconds)
                    results[kind] = rows
            print(f"{title}: {span:g} s simulated, {args.rounds} rounds")
            for kind in ("single", "multi"):
                total = sum(calls[kind].values())
                steps_ = sum(n for f, n in calls[kind].items() if f.endswith("DoStep"))
                print(f"  {kind:6s}: {total / span:10.0f} FMU calls/s simulated "
                      f"({steps_ / span:8.0f} doStep), CPU "
                      f"{statistics.median(cpu[kind]) / span * 1e3:8.2f} ms per s "
                      f"simulated (rounds {', '.join(f'{c:.3f}' for c in cpu[kind])} s)")
            ratio_calls = sum(calls["single"].values()) / sum(calls["multi"].values())
            ratio_cpu = statistics.median(cpu["single"]) / statistics.median(cpu["multi"])
            print(f"  single / multi: FMU calls x{ratio_calls:.2f}, CPU x{ratio_cpu:.2f}")
            names = ["time"] + list(single.record)
            diff = np.max(np.abs(results["single"] - results["multi"]), axis=0)
            worst = sorted(zip(diff[1:], names[1:]), reverse=True)[:3]
            print("  largest result differences (the hold): " +
                  ", ".join(f"{n} {d:.3g}" for d, n in worst))


if __name__ == "__main__":
    main()
