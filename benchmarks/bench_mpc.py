"""Seed-001 LTV MPC: QP solve time and OSQP iterations per sample (issue 13).

A real AGV must solve each sample's QP well within its sample time T. This script runs the
seed-001 closed loops with the plain cores (agv_core.seed001_loop, the same sequence as
the FMU runs) and times every controller update (QP assembly + OSQP setup + solve, i.e.
what the FMU does per sample), warm-started (as in the FMUs) and cold-started:

- circle (v_r = 0.4 m/s, omega_r = 0.074 rad/s), R = 0.1 I, N = 5, 6, 7, 8, 80 s;
- S-curve, N = 7, R = 0.1 I, 70 s.

It prints, per case, the median and maximum update time [ms], the 99th percentile, the
ratio median / T and max / T (T = 0.2 s), and the median and maximum OSQP iterations.
Wall-clock numbers depend on the machine and its load; run it on a quiet machine.

Run:  .venv/bin/python benchmarks/bench_mpc.py [--rounds 3]
"""

import argparse
import statistics

import numpy as np

from agv_core.ltv_mpc.ltv_mpc import LtvMpc
from agv_core.ref_trajectory.ref_trajectory import RefTrajectory
from agv_core.double_steer.seed001_loop import run_loop

T = 0.2


def cases():
    circle = RefTrajectory("circle", speed=0.4, omega=0.074)
    scurve = RefTrajectory("scurve", speed=0.4, amplitude=1.5, wavelength=12.0,
                           peak_time=33.7)
    h = scurve.at(0.0)["heading"]
    for n in (5, 6, 7, 8):
        yield f"circle N={n}", circle, (0.0, -0.5, 0.0), 80.0, n
    yield "S-curve N=7", scurve, (0.5 * np.sin(h), -0.5 * np.cos(h), h), 70.0, 7


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3,
                        help="runs per case; the per-sample minimum over rounds is used")
    args = parser.parse_args()
    print(f"{'case':<14} {'start':<5} {'median ms':>9} {'p99 ms':>7} {'max ms':>7} "
          f"{'median/T':>9} {'max/T':>7} {'iter med':>8} {'iter max':>8}")
    for name, ref, pose0, stop, n in cases():
        for warm in (True, False):
            walls, iters = None, None
            for _ in range(args.rounds):
                rows = run_loop(LtvMpc(sample_time=T, horizon=n, lam=0.1, warm_start=warm),
                                ref, pose0, stop, sample_time=T, timing=True)
                w = np.array([r["wall"] for r in rows])
                walls = w if walls is None else np.minimum(walls, w)
                iters = [r["iterations"] for r in rows]
            print(f"{name:<14} {'warm' if warm else 'cold':<5} "
                  f"{1e3 * np.median(walls):9.3f} {1e3 * np.percentile(walls, 99):7.3f} "
                  f"{1e3 * walls.max():7.3f} {np.median(walls) / T:9.2e} "
                  f"{walls.max() / T:7.2e} {statistics.median(iters):8.0f} {max(iters):8d}")


if __name__ == "__main__":
    main()
