"""Benchmark: the Model Exchange solvers of agv_cosim.execution.model_exchange, CVODE
(fmpy.sundials) and scipy's solve_ivp (LSODA), on accuracy and speed.

Each Reference FMU (FMI 2.0, its ``<CoSimulation>`` removed so it is model-exchange-only)
runs through :func:`agv_cosim.execution.simulate` at the reference CSV's communication
step, for each solver and relative tolerance. Error: the largest absolute difference of
the recorded states from the exact solution, at the communication points:

- Dahlquist (x' = -x, 0..10 s, step 0.1 s): exp(-t);
- BouncingBall (0..3 s, step 0.01 s): the closed-form free fall with restitution 0.7
  (height h);
- VanDerPol (mu = 1, 0..20 s, step 0.01 s): CVODE at relative tolerance 1e-12 run by
  fmpy's own ``simulate_fmu(fmi_type="ModelExchange")`` (x0, x1).

Time: the median wall-clock time of ``--rounds`` runs (instantiation included), and the
time per communication step.

Run: ``python benchmarks/bench_model_exchange.py [--fmus DIR] [--rounds 3]``; ``--fmus``
is the FMI 2.0 Reference FMUs' folder (built here from ``../shared/third-party/
Reference-FMUs`` with cmake when not given).
"""

import argparse
import math
import statistics
import subprocess
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np

from agv_cosim.execution import RowObserver, simulate
from agv_cosim.execution.model_exchange import SOLVERS, use_model_exchange
from agv_cosim.pipeline import prepare

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ROOT.parent / "shared" / "third-party" / "Reference-FMUs"
G, E, V_MIN = 9.81, 0.7, 0.1


def build(folder: Path) -> Path:
    """The FMI 2.0 Reference FMUs built into ``folder``."""
    build_dir, install = folder / "build", folder / "fmi2"
    build_dir.mkdir()
    for command in (["cmake", "-DFMI_VERSION=2", f"-DCMAKE_INSTALL_PREFIX={install}",
                     str(SOURCES)], ["make", "-j2", "install"]):
        subprocess.run(command, cwd=build_dir, check=True, capture_output=True)
    return install


def me_only(source: Path, target: Path) -> Path:
    with zipfile.ZipFile(source) as zin, zipfile.ZipFile(target, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item)
            if item.filename == "modelDescription.xml":
                text = data.decode()
                start = text.index("<CoSimulation")
                end = text.index("</CoSimulation>", start) + len("</CoSimulation>") \
                    if "</CoSimulation>" in text else text.index("/>", start) + 2
                data = (text[:start] + text[end:]).encode()
            zout.writestr(item, data)
    return target


def ball_height(t: float) -> float:
    t1 = math.sqrt(2 / G)
    if t <= t1:
        return 1 - G * t * t / 2
    start, v = t1, G * t1 * E
    while v >= V_MIN:
        end = start + 2 * v / G
        if t <= end:
            tau = t - start
            return v * tau - G * tau * tau / 2
        start, v = end, v * E
    return 0.0


def run(fmu: Path, folder: Path, stop: float, step: float, solver: str,
        tolerance: float) -> tuple[list[str], np.ndarray, float]:
    manifest = folder / "bench.toml"
    manifest.write_text(f'[simulation]\nstop = {stop}\nstep = {step}\n'
                        f'[components.m]\nfmu = "{fmu}"\n')
    _, jobs, _ = prepare(manifest)
    system = jobs[0].plan
    system.models["m"] = use_model_exchange(system.models["m"], solver=solver,
                                            tolerance=tolerance)
    rows: list[list[float]] = []
    began = time.perf_counter()
    simulate(system, [RowObserver(lambda row: rows.append(list(row)))])
    return system.record, np.array(rows, dtype=float), time.perf_counter() - began


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fmus", type=Path, help="folder of the FMI 2.0 Reference FMUs")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--tolerances", type=float, nargs="+", default=[1e-4, 1e-6, 1e-9])
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        fmus = args.fmus or build(folder)
        from fmpy import simulate_fmu

        vdp = me_only(fmus / "VanDerPol.fmu", folder / "VanDerPol.fmu")
        exact_vdp = simulate_fmu(str(vdp), fmi_type="ModelExchange", stop_time=20.0,
                                 output_interval=0.01, relative_tolerance=1e-12,
                                 record_events=False, output=["x0", "x1"])
        cases = [("Dahlquist", 10.0, 0.1,
                  lambda t: {"x": np.exp(-t)}),
                 ("BouncingBall", 3.0, 0.01,
                  lambda t: {"h": np.array([ball_height(x) for x in t])}),
                 ("VanDerPol", 20.0, 0.01,
                  lambda t: {"x0": exact_vdp["x0"], "x1": exact_vdp["x1"]})]
        print(f"{'model':<13}{'solver':<8}{'tolerance':>10}{'max error':>12}"
              f"{'time [s]':>10}{'us/step':>9}")
        for model, stop, step, exact in cases:
            fmu = me_only(fmus / f"{model}.fmu", folder / f"{model}.fmu")
            for tolerance in args.tolerances:
                for solver in SOLVERS:
                    times = []
                    for _ in range(args.rounds):
                        names, rows, took = run(fmu, folder, stop, step, solver, tolerance)
                        times.append(took)
                    expected = exact(rows[:, 0])
                    error = max(float(np.max(np.abs(rows[:, 1 + names.index(f"m.{n}")]
                                                    - values)))
                                for n, values in expected.items())
                    wall = statistics.median(times)
                    print(f"{model:<13}{solver:<8}{tolerance:>10.0e}{error:>12.2e}"
                          f"{wall:>10.3f}{1e6 * wall / (len(rows) - 1):>9.0f}")


if __name__ == "__main__":
    main()
