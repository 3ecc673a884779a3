"""Plain-Python closed loop of the seed-001 experiments, for calibration and benchmarks.

The experiments run through the FMUs (experiments/seed001_*.toml); this loop chains the
same cores in the same order as the orchestrator's Gauss-Seidel step with the
communication step equal to the controller's sample time: at every t_k = k T the
reference is evaluated, the controller reads the pose and the reference, the inverse
kinematics maps its (v_c, omega) to the wheels, and the vehicle advances one sample with
the wheels held. tests/seeds/test_seed001.py checks that it reproduces an FMU run to rounding.
It is used where many runs or per-step timings are needed: the PID calibration
(experiments/seed001_pid_calibration.py) and the MPC solve-time benchmark
(benchmarks/bench_mpc.py).
"""

import time
from collections.abc import Mapping, Sequence
from typing import Any, Protocol

from ..ref_trajectory.ref_trajectory import RefTrajectory
from .double_steer import DoubleSteerVehicle, inverse_kinematics


class LoopController(Protocol):
    """What :func:`run_loop` asks of a controller core (LtvMpc, LateralPid)."""

    def update(self, t: float, x: float, y: float, heading: float, ref: Mapping[str, float]
               ) -> dict[str, Any]: ...

    def step(self, t: float, h: float, x: float, y: float, heading: float,
             ref: Mapping[str, float]) -> None: ...


def run_loop(controller: LoopController, reference: RefTrajectory, pose0: Sequence[float],
             stop: float, sample_time: float = 0.2, wheelbase: float = 1.0,
             timing: bool = False) -> list[dict[str, Any]]:
    """Simulate the loop from 0 to ``stop`` [s].

    Parameters
    ----------
    controller : LtvMpc or LateralPid
        A core with ``update(t, x, y, heading, ref) -> dict`` and ``step(t, h, x, y,
        heading, ref)``.
    reference : RefTrajectory
    pose0 : tuple of float
        Initial centroid x, y [m] and yaw [rad].
    stop : float
        End time [s], a whole number of samples.
    sample_time : float
        T [s]: the step of the loop (and the controller's sample time).
    wheelbase : float
        L [m].
    timing : bool
        Also measure the wall-clock time [s] of every controller update.

    Returns
    -------
    list of dict
        One row per sample: ``t`` and the controller's output keys, ``theta_f`` [rad],
        and with ``timing`` the update time ``wall`` [s].
    """
    vehicle = DoubleSteerVehicle(wheelbase, *pose0)
    n = int(round(stop / sample_time))
    rows = []
    for k in range(n + 1):
        t = k * sample_time
        ref = reference.at(t)
        start = time.perf_counter() if timing else 0.0
        out = controller.update(t, vehicle.x, vehicle.y, vehicle.yaw, ref)
        if timing:
            out["wall"] = time.perf_counter() - start
        theta_f, v_f, theta_b, v_b = inverse_kinematics(wheelbase, out["v_c"], out["omega"])
        out["t"], out["theta_f"] = t, theta_f
        rows.append(out)
        if k < n:
            controller.step(t, sample_time, vehicle.x, vehicle.y, vehicle.yaw, ref)  # commit
            vehicle.step(theta_f, v_f, theta_b, v_b, sample_time)
    return rows
