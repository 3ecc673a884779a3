"""Tests of the seed-001 LTV MPC (agv_core.ltv_mpc) and the comparison PID (agv_core.pid)."""

import math
import shutil

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from agv_core.errors import ParameterError
from agv_core.lateral_pid.pid import LateralPid
from agv_core.ltv_mpc.ltv_mpc import LtvMpc, MpcSolveError, error_model, prediction_matrices

BIG = dict(u_min=(-1e3, -1e3), u_max=(1e3, 1e3), du_min=(-1e3, -1e3), du_max=(1e3, 1e3))


def test_error_model_is_forward_difference_of_unicycle_jacobian():
    v, a, T = 0.4, 0.7, 0.2
    A, B = error_model(v, a, T)
    Ac = np.array([[0, 0, -v * math.sin(a)], [0, 0, v * math.cos(a)], [0, 0, 0]])
    Bc = np.array([[math.cos(a), 0], [math.sin(a), 0], [0, 1]])
    assert np.array_equal(A, np.eye(3) + T * Ac)
    assert np.allclose(B, T * Bc, rtol=0, atol=1e-17)


def _simulate(A, B, x, u_prev, dU, N):
    """Predicted errors eta(k+1..k+N) by stepping the augmented model one sample at a time."""
    out, u = [], np.array(u_prev, float)
    x = np.array(x, float)
    for i in range(N):
        if 2 * i < len(dU):
            u = u + dU[2 * i:2 * i + 2]
        x = A @ x + B @ u
        out.append(x)
    return np.concatenate(out)


@pytest.mark.parametrize("N,Nc", [(5, 5), (7, 3), (1, 1)])
def test_prediction_matrices_match_step_by_step_simulation(N, Nc):
    A, B = error_model(0.4, 1.1, 0.2)
    Phi, Theta = prediction_matrices(A, B, N, Nc)
    rng = np.random.default_rng(1)
    x, u_prev, dU = rng.normal(size=3), rng.normal(size=2), rng.normal(size=2 * Nc)
    direct = _simulate(A, B, x, u_prev, dU, N)
    assert np.allclose(Phi @ np.concatenate([x, u_prev]) + Theta @ dU, direct,
                       rtol=0, atol=1e-13)


def test_unconstrained_solution_is_the_least_squares_optimum():
    """With inactive bounds the QP optimum is the weighted least-squares solution, built here
    from impulse responses of the step-by-step model (no Phi/Theta)."""
    N, lam, q = 6, 0.1, np.array([1.0, 1.0, 0.5])
    mpc = LtvMpc(horizon=N, lam=lam, q=q, eps=1e-10, **BIG)
    v, a = 0.4, 0.3
    A, B = error_model(v, a, mpc.T)
    x, u_prev = np.array([0.1, -0.5, 0.05]), np.array([0.02, -0.01])
    free = _simulate(A, B, x, u_prev, np.zeros(0), N)
    cols = [_simulate(A, B, np.zeros(3), np.zeros(2), np.eye(2 * N)[j], N)
            for j in range(2 * N)]
    G = np.column_stack(cols)
    w = np.sqrt(np.tile(q, N))
    M = np.vstack([w[:, None] * G, math.sqrt(lam) * np.eye(2 * N)])
    rhs = np.concatenate([-w * free, np.zeros(2 * N)])
    expected = np.linalg.lstsq(M, rhs, rcond=None)[0]
    z, _, _ = mpc.solve(x, u_prev, v, a, np.array([v, 0.0]))
    # OSQP with polishing solves the equality-free QP to ~1e-9 on this scale
    assert np.allclose(z[:-1], expected, rtol=0, atol=1e-7)
    assert z[-1] == pytest.approx(0.0, abs=1e-9)   # inert slack


def test_bounded_single_move_matches_box_least_squares():
    """N_c = 1: the increment and input bounds are a box on Delta u; compare with scipy."""
    N, lam, q = 5, 1.0, np.array([1.0, 1.0, 0.5])
    mpc = LtvMpc(horizon=N, control_horizon=1, lam=lam, q=q, eps=1e-10)
    v, a = 0.4, 0.0
    A, B = error_model(v, a, mpc.T)
    x, u_prev_err, u_r = np.array([0.0, -0.5, 0.0]), np.array([0.0, 0.0]), np.array([v, 0.0])
    free = _simulate(A, B, x, u_prev_err, np.zeros(0), N)
    G = np.column_stack([_simulate(A, B, np.zeros(3), np.zeros(2), e, N)
                         for e in np.eye(2)])
    w = np.sqrt(np.tile(q, N))
    M = np.vstack([w[:, None] * G, math.sqrt(lam) * np.eye(2)])
    rhs = np.concatenate([-w * free, np.zeros(2)])
    lo = np.maximum(mpc.du_min, mpc.u_min - u_r - u_prev_err)
    hi = np.minimum(mpc.du_max, mpc.u_max - u_r - u_prev_err)
    expected = lsq_linear(M, rhs, bounds=(lo, hi), tol=1e-14).x
    z, _, _ = mpc.solve(x, u_prev_err, v, a, u_r)
    assert np.any(np.isclose(expected, hi)) or np.any(np.isclose(expected, lo))  # active
    assert np.allclose(z[:-1], expected, rtol=0, atol=1e-7)


def test_bounds_hold_over_the_horizon():
    mpc = LtvMpc(horizon=7, lam=0.1)
    u_r = np.array([0.4, 0.074])
    z, _, _ = mpc.solve([0.3, -0.8, 0.2], [0.0, 0.0], 0.4, 0.0, u_r)
    dU = z[:-1].reshape(-1, 2)
    tol = 1e-6   # OSQP feasibility tolerance after polishing
    assert np.all(dU >= mpc.du_min - tol) and np.all(dU <= mpc.du_max + tol)
    u = u_r + np.cumsum(dU, axis=0)
    assert np.all(u >= mpc.u_min - tol) and np.all(u <= mpc.u_max + tol)


def test_slack_softens_the_position_bound():
    """With e_max smaller than the current error the bound is infeasible unless relaxed:
    gamma > 0 and every predicted |e_X|, |e_Y| <= e_max + gamma."""
    mpc = LtvMpc(horizon=5, lam=0.1, e_max=0.1, eps=1e-9)
    x, u_prev = np.array([0.0, -0.5, 0.0]), np.zeros(2)
    z, _, _ = mpc.solve(x, u_prev, 0.4, 0.0, np.array([0.4, 0.0]))
    gamma = z[-1]
    assert gamma > 0.3
    A, B = error_model(0.4, 0.0, mpc.T)
    pred = _simulate(A, B, x, u_prev, z[:-1], 5).reshape(-1, 3)
    assert np.all(np.abs(pred[:, :2]) <= 0.1 + gamma + 1e-6)


def test_failed_solve_raises_naming_the_status():
    mpc = LtvMpc(horizon=5, max_iter=1)
    with pytest.raises(MpcSolveError, match="OSQP status 'maximum iterations reached'"):
        mpc.solve([0.0, -0.5, 0.0], [0.0, 0.0], 0.4, 0.0, np.array([0.4, 0.0]))


def _ref(t):
    return {"x": 0.4 * t, "y": 0.0, "heading": 0.0, "v": 0.4, "omega": 0.0}


def test_sample_and_hold_and_state_round_trip_bit_identical():
    mpc = LtvMpc(horizon=5, sample_time=0.2)
    a = mpc.update(0.0, 0.0, -0.5, 0.0, _ref(0.0))
    assert mpc.update(0.1, 9.0, 9.0, 0.0, _ref(0.1)) == a          # held between samples
    b = mpc.update(0.2, 0.08, -0.49, 0.01, _ref(0.2))
    snap = mpc.get_state()
    c1 = mpc.update(0.4, 0.16, -0.47, 0.02, _ref(0.4))
    mpc.set_state(snap)
    c2 = mpc.update(0.4, 0.16, -0.47, 0.02, _ref(0.4))
    assert c1 == c2 and b != a
    # the increment of the second sample starts from the first output
    assert b["v_c"] == pytest.approx(a["v_c"] + b["dv_c"], abs=1e-15)


def test_mpc_parameter_errors_are_named():
    for kwargs, name in (({"horizon": 0}, "horizon"), ({"lam": 0.0}, "lam"),
                         ({"control_horizon": 9}, "control_horizon"),
                         ({"u_min": (1.0, 0.0), "u_max": (0.0, 1.0)}, "u_v"),
                         ({"sample_time": -1.0}, "sample_time")):
        with pytest.raises(ParameterError, match=f"'{name}'"):
            LtvMpc(**kwargs)


def test_pid_law_and_signs():
    pid = LateralPid(kp=0.8, ki=0.03, kd=1.8, sample_time=0.2, omega_max=10.0)
    out = pid.update(0.0, 0.0, 0.1, 0.0, _ref(0.0))     # 0.1 m left of the reference
    assert out["e_lat"] == pytest.approx(0.1)
    # first sample: no derivative, I = T e
    assert out["omega"] == pytest.approx(-(0.8 * 0.1 + 0.03 * 0.2 * 0.1))
    assert out["v_c"] == 0.4
    out = pid.update(0.2, 0.08, 0.08, 0.0, _ref(0.2))
    d = (0.08 - 0.1) / 0.2
    assert out["omega"] == pytest.approx(-(0.8 * 0.08 + 0.03 * 0.2 * 0.18 + 1.8 * d))


def test_pid_saturates_and_holds_its_integral():
    pid = LateralPid(kp=10.0, ki=1.0, kd=0.0, omega_max=0.6)
    for k in range(5):
        out = pid.update(0.2 * k, 0.4 * 0.2 * k, -2.0, 0.0, _ref(0.2 * k))
        assert out["omega"] == 0.6
    assert out["integral"] == 0.0   # saturated from the first sample: never integrated
    out = pid.update(1.0, 0.4, -0.01, 0.0, _ref(1.0))   # back in the linear range
    assert out["omega"] < 0.6 and out["integral"] == pytest.approx(-0.002)


# ---------------------------------------------------------------------- the FMU
def _pose(t):
    """A measured pose that moves at every communication point."""
    return 0.4 * t + 0.01 * math.sin(3 * t), -0.5 + 0.05 * t, 0.02 * math.cos(t)


@pytest.mark.parametrize("h, reads_before_sets", [(0.2, False), (0.05, False), (0.2, True)])
def test_mpc_fmu_solves_once_per_sample_and_reads_show_the_current_inputs(
        tmp_path, monkeypatch, h, reads_before_sets):
    """The MPC FMU in the master's Gauss-Seidel pattern (at each communication point:
    set the inputs, read the outputs, step) solves one QP per sample instant (T = 0.2 s,
    communication step ``h``), counted at OSQP's ``solve`` over every FMI call from
    exitInitializationMode on; the outputs read equal the
    plain core's to the last bit. ``reads_before_sets``: the outputs are also read right
    after each step, before the sets (FMI: they are those of the held inputs at the new
    time), which is a second QP at each instant, as it must be."""
    import osqp
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    from agv_cosim.build import build_one, slave_script

    solves = [0]
    solve = osqp.OSQP.solve

    def counted(self, *args, **kwargs):
        solves[0] += 1
        return solve(self, *args, **kwargs)

    monkeypatch.setattr(osqp.OSQP, "solve", counted)
    fmu = build_one(slave_script("agv_ltv_mpc"), tmp_path).fmu
    md = read_model_description(str(fmu))
    refs = {v.name: v.valueReference for v in md.modelVariables}
    inputs = [refs[n] for n in ("x", "y", "heading", "x_ref", "y_ref", "heading_ref",
                                "v_ref", "omega_ref")]
    outputs = [refs[n] for n in ("v_c", "omega", "dv_c", "domega", "iterations")]
    folder = extract(str(fmu))
    core = LtvMpc()                # the FMU's parameter defaults are the core's
    steps, fmu_solves = int(round(4.0 / h)), 0
    try:
        slave = FMU2Slave(guid=md.guid, unzipDirectory=folder,
                          modelIdentifier=md.coSimulation.modelIdentifier,
                          instanceName="mpc")
        slave.instantiate()
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        before = solves[0]
        slave.exitInitializationMode()     # no QP: the first read after the sets solves
        fmu_solves += solves[0] - before
        held = None
        for k in range(steps + 1):
            t = k * h
            if reads_before_sets and held is not None:
                before = solves[0]
                got = slave.getReal(outputs)
                fmu_solves += solves[0] - before
                want = core.update(t, *held[:3], _ref(held[3]))
                assert got == [want["v_c"], want["omega"], want["dv_c"], want["domega"],
                               float(want["iterations"])]
            x, y, hd = _pose(t)
            r = _ref(t)
            before = solves[0]
            slave.setReal(inputs, [x, y, hd, r["x"], r["y"], r["heading"], r["v"],
                                   r["omega"]])
            got = slave.getReal(outputs)
            fmu_solves += solves[0] - before
            want = core.update(t, x, y, hd, r)
            assert got == [want["v_c"], want["omega"], want["dv_c"], want["domega"],
                           float(want["iterations"])], t
            if k < steps:
                before = solves[0]
                slave.doStep(t, h)
                fmu_solves += solves[0] - before
                core.step(t, h, x, y, hd, r)
                held = (x, y, hd, t)
        slave.terminate()
        slave.freeInstance()
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    samples = int(round(4.0 / 0.2)) + 1
    assert fmu_solves == (2 * samples - 1 if reads_before_sets else samples)
