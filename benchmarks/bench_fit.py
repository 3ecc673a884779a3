"""Benchmark: a 2-parameter ``agv-cosim fit`` on the seed-000 loop, runs and CPU, local
and on a local Dask cluster.

The loop is ``experiments/seed000_models_abc.toml`` variant ``a`` (5 FMUs: vehicle,
vision sensor, steering-angle sensor, LQR state feedback, actuator model a; 1 ms step),
cut to ``--stop`` seconds. The "measurement" is that loop run with the actuator's
``K`` = 0.5 rad/(V.s) and ``tau`` = 0.07 s (the manifest has 0.6 and 0.05), its lateral
error and wheel angle recorded every 10 ms, plus seeded white noise (0.5 mm, 1 mrad).
The fit (``[fit]`` appended to the manifest) recovers ``act.K`` and ``act.tau`` from the
manifest's values, bounds [0.2, 1.5] and [0.01, 0.15] s, both signals at their default
weights.

Measured, for ``agv-cosim fit --jobs --workers`` and for ``agv-cosim fit --dask`` on a
local cluster of ``--workers`` stock ``dask worker`` processes (bench_dask.py's
:class:`Cluster`): the runs (fit.json's, plus the run at the fitted values), the
iterations, the wall time, the CPU of every process that did the work (the command and
its descendants; for Dask plus the cluster's processes while it ran) and per run; the
fitted values against the truth in standard errors, and local against Dask (the same
values: the runs are deterministic wherever they run).

Run: ``.venv/bin/python benchmarks/bench_fit.py [--stop 4] [--workers 2]
[--fmus fmus] [--skip-dask]``
"""

import argparse
import json
import re
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_dask import Cluster, _command, _subreaper  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
TRUE = {"act.K": 0.5, "act.tau": 0.07}
NOISE = {"e": 0.0005, "alpha": 0.001}

FIT = """
[fit]
data = "measured.csv"
signals = { "sensor.lateral_error" = "e", "act.alpha" = "alpha" }
[fit.parameters]
"act.K" = { min = 0.2, max = 1.5 }
"act.tau" = { min = 0.01, max = 0.15 }
"""


def _manifest(folder, fmus, stop):
    text = (ROOT / "experiments" / "seed000_models_abc.toml").read_text()
    text = re.sub(r"(?m)^stop = .*$", f"stop = {stop!r}", text)
    text = text.replace('"../fmus/', f'"{Path(fmus).resolve()}/')
    path = Path(folder) / "seed000_fit.toml"
    path.write_text(text + FIT)
    return path


def _measure(folder, manifest, cluster):
    """Run the loop at the true values; write measured.csv with noise."""
    _command(["run", str(manifest), "--variant", "a", "--quiet", "--out",
              str(folder / "truth"), "--set", f"act.K={TRUE['act.K']}",
              "--set", f"act.tau={TRUE['act.tau']}"], cluster)
    from agv_cosim.timeseries import read_timeseries

    t, columns = read_timeseries(folder / "truth" / "a" / "timeseries.csv",
                                 ["sensor.lateral_error", "act.alpha"])
    rng = np.random.default_rng(0)
    e = columns["sensor.lateral_error"] + rng.normal(0.0, NOISE["e"], t.size)
    alpha = columns["act.alpha"] + rng.normal(0.0, NOISE["alpha"], t.size)
    np.savetxt(folder / "measured.csv", np.column_stack([t, e, alpha]), delimiter=",",
               header="time,e,alpha", comments="", fmt="%.17g")
    return t.size


def _fit(folder, manifest, name, extra, cluster, on_cluster):
    out = folder / name
    wall, cpu, cluster_cpu = _command(["fit", str(manifest), "--variant", "a", "--out",
                                       str(out), *extra], cluster, on_cluster)
    result = json.loads((out / "fit.json").read_text())
    runs = json.loads((out / "fit_run.json").read_text())["runs"]
    total = cpu + cluster_cpu
    print(f"{name}: {runs} runs ({result['runs']} fitting + 1 at the fitted values), "
          f"{result['iterations']} iterations, wall {wall:.1f} s, CPU {total:.1f} s"
          + (f" (command {cpu:.1f} + cluster {cluster_cpu:.1f})" if on_cluster else "")
          + f", {total / runs:.3f} s/run; converged {result['converged']}")
    for p, true in TRUE.items():
        entry = result["parameters"][p]
        print(f"  {p} = {entry['value']:.6g} +- {entry['stderr']:.2g} (true {true}: "
              f"{(entry['value'] - true) / entry['stderr']:+.2f} stderr)")
    return result


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stop", type=float, default=4.0, help="simulated seconds")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--fmus", default=str(ROOT / "fmus"))
    parser.add_argument("--skip-dask", action="store_true")
    options = parser.parse_args()
    _subreaper()
    with tempfile.TemporaryDirectory(prefix="bench-fit-") as tmp:
        folder = Path(tmp)
        manifest = _manifest(folder, options.fmus, options.stop)
        cluster = None if options.skip_dask else Cluster(folder, options.workers)
        try:
            dummy = cluster or _NoCluster()
            samples = _measure(folder, manifest, dummy)
            print(f"seed-000 loop (variant a, 5 FMUs, 1 ms step) over {options.stop} s; "
                  f"{samples} samples of 2 signals")
            local = _fit(folder, manifest, f"local --jobs {options.workers}",
                         ["--jobs", str(options.workers)], dummy, False)
            if cluster is not None:
                remote = _fit(folder, manifest, f"dask {options.workers} workers",
                              ["--dask", cluster.address], cluster, True)
                same = local["parameters"] == remote["parameters"]
                print(f"fitted values local == dask: {same}")
        finally:
            if cluster is not None:
                cluster.stop()


class _NoCluster:
    wrappers = ()

    def cpu(self):
        return 0.0


if __name__ == "__main__":
    main()
