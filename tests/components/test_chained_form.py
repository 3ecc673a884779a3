"""Seed 002 chained-form (Samson) path-following law: core and FMU.

Tiers: (1) the law makes the exact model obey the chained system (finite differences,
closed-form distance response); (2) closed loop with the exact vehicle core: 2 m step at
2..14 km/h, responses against path arc length coincide with the closed form; (3) seed
002's sine path; (4) the FMU gives the core's numbers through fmpy.
"""

import math
import shutil
import sys

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from scipy.integrate import solve_ivp

from agv_core.chained_form import chained_form as cf
from agv_core.errors import ParameterError
from agv_core.vehicle.vehicle import Vehicle

KD, KP, L = 0.6, 0.09, 2.0
DMAX = math.pi / 4


def closed_form(s, a2_0, a3_0, kd=KD, kp=KP):
    """a2(s) of a2'' + Kd a2' + Kp a2 = 0 for the critically damped seed gains."""
    assert kd * kd == pytest.approx(4 * kp)  # Kd = 0.6, Kp = 0.09: double root -0.3
    r = kd / 2
    return (a2_0 + (a3_0 + r * a2_0) * s) * np.exp(-r * s)


# ---------------------------------------------------------------------------- (1) analytic
def test_law_reproduces_the_chained_system_on_random_states():
    """d a2/ds = a3 and d a3/ds = m3 for the model's d/ds, on random in-domain states."""
    rng = np.random.default_rng(2)
    worst2 = worst3 = 0.0
    for _ in range(200):
        c = rng.uniform(-0.3, 0.3)
        y = rng.uniform(-2.0, 2.0)
        if y * c > 0.8:
            y = -y
        theta = rng.uniform(-1.2, 1.2)
        dc = rng.uniform(-0.05, 0.05)
        delta, m3, ok = cf.steering_law(y, theta, c, dc, KD, KP, L, DMAX)
        assert ok
        dy, dtheta = cf.distance_derivatives(y, theta, c, delta, L)
        eps = 1e-5
        (p2, p3), (n2, n3) = [
            cf.chained_coordinates(y + sign * eps * dy, theta + sign * eps * dtheta,
                                   c + sign * eps * dc)
            for sign in (+1, -1)]
        a2_0, a3_0 = cf.chained_coordinates(y, theta, c)
        assert m3 == pytest.approx(-KD * a3_0 - KP * a2_0, rel=1e-14, abs=1e-15)
        worst2 = max(worst2, abs((p2 - n2) / (2 * eps) - a3_0) / (1 + abs(a3_0)))
        worst3 = max(worst3, abs((p3 - n3) / (2 * eps) - m3) / (1 + abs(m3)))
    # central difference, eps = 1e-5: truncation ~eps^2 * a''' ~ 1e-9 for |theta| <= 1.2,
    # rounding ~1e-16 / eps = 1e-11; 1e-7 leaves margin yet catches any wrong term
    # (dropping the dc/ds term alone changes d a3/ds by up to ~0.1)
    assert worst2 < 1e-7
    assert worst3 < 1e-7


def test_dropping_the_curvature_rate_term_is_detected():
    """Guard for the test above: the dc/ds term matters (the check is sensitive to it)."""
    y, theta, c, dc = 1.0, 0.5, 0.1, 0.05
    with_term = cf.steering_law(y, theta, c, dc, KD, KP, L, DMAX)[0]
    without = cf.steering_law(y, theta, c, 0.0, KD, KP, L, DMAX)[0]
    # tan(delta) changes by l cos^3 / (1-yc)^2 * dc y tan(theta) = 0.0459 here
    expected = L * math.cos(theta) ** 3 / 0.9 ** 2 * dc * y * math.tan(theta)
    assert math.tan(with_term) - math.tan(without) == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("c0, c1, y0, theta0", [(0.0, 0.0, -2.0, 0.0),
                                                (0.1, 0.0, 0.5, -0.3),
                                                (-0.05, 0.004, -0.8, 0.4)])
def test_distance_domain_response_is_the_closed_form(c0, c1, y0, theta0):
    """Integrate the exact model in s with the law: a2(s) = (A + B s) exp(-0.3 s)."""
    def rhs(s, z):
        y, theta = z
        c = c0 + c1 * s
        delta, _, ok = cf.steering_law(y, theta, c, c1, KD, KP, L, math.pi / 2 - 1e-9)
        assert ok
        return cf.distance_derivatives(y, theta, c, delta, L)

    s = np.linspace(0.0, 30.0, 301)
    sol = solve_ivp(rhs, (0.0, 30.0), [y0, theta0], t_eval=s, rtol=1e-11, atol=1e-12,
                    method="DOP853")
    a3_0 = (1 - y0 * c0) * math.tan(theta0)
    err = np.max(np.abs(sol.y[0] - closed_form(s, y0, a3_0)))
    # the law is exact, so only the integrator's error remains (rtol 1e-11): 1e-8 m
    assert err < 1e-8


def test_saturation_and_out_of_domain_commands():
    ctl = cf.ChainedFormController(KD, KP, L, math.radians(10))
    # y = -2 m, straight path: tan(delta) = l Kp 2 = 0.36 -> 19.8 deg, limited to 10 deg
    assert ctl.update(0.0, -2.0, 0.0, 0.0, 0.0) == pytest.approx(math.radians(10), abs=1e-15)
    assert ctl.outputs["delta_law"] == pytest.approx(math.atan(0.36), rel=1e-14)
    assert ctl.outputs["saturated"] and ctl.outputs["in_domain"]
    # pointing backwards (theta = 2 rad, left of the path): full lock right
    assert ctl.update(0.0, 0.3, 2.0, 0.0, 0.0) == -math.radians(10)
    assert not ctl.outputs["in_domain"]
    # beyond the centre of curvature (y c = 1.2): full lock towards the path (right)
    assert ctl.update(0.0, 6.0, 0.1, 0.2, 0.0) == -math.radians(10)
    assert not ctl.outputs["in_domain"]
    # theta given unwrapped: 2 pi - 0.1 is -0.1 rad
    a = ctl.update(0.0, 0.0, 2 * math.pi - 0.1, 0.0, 0.0)
    b = ctl.update(0.0, 0.0, -0.1, 0.0, 0.0)
    assert a == pytest.approx(b, abs=1e-12)


@pytest.mark.parametrize("name, kwargs", [("Kd", {"Kd": 0.0}), ("Kp", {"Kp": -1.0}),
                                          ("wheelbase", {"wheelbase": 0.0}),
                                          ("delta_max", {"delta_max": 2.0}),
                                          ("sample_period", {"sample_period": -0.1}),
                                          ("source", {"source": "gps"}),
                                          ("path", {"source": "pose", "path": ""}),
                                          ("path", {"source": "pose", "path": "spiral:a=1"})])
def test_bad_parameters_are_named(name, kwargs):
    with pytest.raises(ParameterError) as info:
        cf.make_controller(**kwargs)
    assert info.value.name == name


def test_sample_and_hold():
    ctl = cf.ChainedFormController(sample_period=0.1)
    d0 = ctl.update(0.0, -1.0, 0.0, 0.0, 0.0)
    assert ctl.update(0.05, -2.0, 0.0, 0.0, 0.0) == d0  # held between samples
    d1 = ctl.update(0.1, -2.0, 0.0, 0.0, 0.0)  # 0.1 / 0.1 rounds to sample 1
    assert d1 == pytest.approx(math.atan(L * KP * 2.0), rel=1e-14)
    # new inputs at the same instant (Gauss-Seidel master) replace the sample
    assert ctl.update(0.1, -1.0, 0.0, 0.0, 0.0) == d0
    saved = ctl.get_state()
    ctl.update(0.2, -3.0, 0.0, 0.0, 0.0)
    ctl.set_state(saved)
    assert ctl.update(0.15, -3.0, 0.0, 0.0, 0.0) == d0


# ---------------------------------------------------------------- (2) speed independence
def _step_run(kmh, h, length=38.0):
    """2 m lateral step on the straight path y = 0, rear-axle centre starts at y = -2."""
    v = kmh / 3.6
    vehicle = Vehicle(L, 0.0, -2.0, 0.0, reference_point="rear")
    ctl = cf.ChainedFormController(KD, KP, L, DMAX)
    s, y, t = [0.0], [-2.0], 0.0
    while vehicle.x < length:
        delta = ctl.update(t, vehicle.y, vehicle.heading, 0.0, 0.0)
        vehicle.step(delta, v, h)
        t += h
        s.append(vehicle.x)
        y.append(vehicle.y)
    return np.array(s), np.array(y)


def test_step_responses_against_distance_coincide_for_2_to_14_kmh():
    h = 0.002
    grid = np.linspace(0.0, 37.0, 1000)
    exact = closed_form(grid, -2.0, 0.0)
    runs = []
    for kmh in range(2, 16, 2):
        s, y = _step_run(kmh, h)
        runs.append(np.interp(grid, s, y))
        # the only error is the zero-order hold of delta over one step, a lag of about
        # half the distance step v h: measured 0.116 v h (0.13 mm at 2 km/h, 0.90 mm
        # at 14 km/h); 0.15 v h bounds it with margin and still fails for a 30 % drift
        assert np.max(np.abs(runs[-1] - exact)) < 0.15 * (kmh / 3.6) * h
    runs = np.array(runs)
    spread = np.max(runs.max(axis=0) - runs.min(axis=0))
    # measured 0.77 mm between 2 and 14 km/h (seed 002: < 2.7 cm); the bound is the hold
    # lag difference 0.15 (14 - 2) / 3.6 * h = 1.0 mm
    assert spread < 1.0e-3


# ---------------------------------------------------------------------- (3) sine path
A_SINE, W_SINE = 3.0, 30.0
K_SINE = 2 * math.pi / W_SINE


def _sine_derivs(x):
    u = K_SINE * x
    return (A_SINE * math.sin(u), A_SINE * K_SINE * math.cos(u),
            -A_SINE * K_SINE ** 2 * math.sin(u), -A_SINE * K_SINE ** 3 * math.cos(u))


def _sine_project(px, py, x_hint):
    """Closest point of y = 3 sin(2 pi x / 30) (Newton): x, offset, heading, c, dc/ds."""
    x = px if x_hint is None else x_hint
    for _ in range(50):
        f, d1, d2, _ = _sine_derivs(x)
        step = ((x - px) + (f - py) * d1) / (1 + d1 * d1 + (f - py) * d2)
        x -= step
        if abs(step) < 1e-13:
            break
    f, d1, d2, d3 = _sine_derivs(x)
    w = 1 + d1 * d1
    c = d2 / w ** 1.5
    dc = (d3 / w ** 1.5 - 3 * d2 * d2 * d1 / w ** 2.5) / math.sqrt(w)
    heading = math.atan(d1)
    offset = -(px - x) * math.sin(heading) + (py - f) * math.cos(heading)
    return x, offset, heading, c, dc


def test_sine_path_6_kmh_from_half_a_metre_off():
    h, v = 0.01, 6.0 / 3.6
    h0 = math.atan(_sine_derivs(0.0)[1])
    # rear-axle centre 0.5 m right of the path start, aligned with the tangent
    vehicle = Vehicle(L, 0.5 * math.sin(h0), -0.5 * math.cos(h0), h0, reference_point="rear")
    ctl = cf.ChainedFormController(KD, KP, L, DMAX)
    t, x_hint, xs, ys, deltas = 0.0, None, [], [], []
    while vehicle.x < 100.0:
        x, offset, heading, c, dc = _sine_project(vehicle.x, vehicle.y, x_hint)
        x_hint = x
        xs.append(x)
        ys.append(offset)
        deltas.append(ctl.update(t, offset, vehicle.heading - heading, c, dc))
        vehicle.step(deltas[-1], v, h)
        t += h
    xs, ys = np.array(xs), np.array(ys)
    assert ys[0] == pytest.approx(-0.5, abs=1e-12)
    assert max(np.abs(deltas)) < DMAX  # measured 0.273 rad: the law is never saturated
    settled = xs > 40.0  # transient 0.5 (1 + 0.3 s) e^(-0.3 s) = 4e-5 m at s = 40 m
    worst = np.max(np.abs(ys[settled]))
    # measured 1.45 mm (seed 002: within 25 cm). The law is exact, so what is left is
    # the hold of delta over v h = 1.7 cm of travel against a curvature up to 0.13 1/m;
    # 3 mm bounds it with margin
    assert worst < 3e-3
    # seed 002: the peaks sit at the crests (x = 7.5 m + 15 m k). Per half period, the
    # largest |y| lies within 1 m of the crest (measured 0.34 m before it)
    for k in range(3, 6):
        window = (xs >= 15.0 * k) & (xs < 15.0 * (k + 1))
        peak = xs[window][np.argmax(np.abs(ys[window]))]
        assert abs(peak - (15.0 * k + 7.5)) < 1.0


# ---------------------------------------------------------------------------- (4) FMU
def _forget_bundled_cores():
    """Forget the ``agv_core_<tag>`` modules an in-process build left in sys.modules.

    Work-around: the build leaves ``agv_core_<tag>`` in sys.modules with a ``__path__``
    in its deleted staging folder, so a later build or instance in this process that needs
    a submodule not imported yet fails (ModuleNotFoundError); reported to the lead.
    """
    for name in [m for m in sys.modules if m.startswith("agv_core_")]:
        del sys.modules[name]


@pytest.fixture(scope="module")
def fmu(component_fmus):
    path = str(component_fmus["agv_chained_form"])
    _forget_bundled_cores()
    md = read_model_description(path)
    folder = extract(path)
    yield path, md, folder
    shutil.rmtree(folder, ignore_errors=True)


def _instance(fmu, name, **start):
    path, md, folder = fmu
    refs = {v.name: v.valueReference for v in md.modelVariables}
    slave = FMU2Slave(guid=md.guid, unzipDirectory=folder,
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    for key, value in start.items():
        if isinstance(value, str):
            slave.setString([refs[key]], [value])
        else:
            slave.setReal([refs[key]], [value])
    slave.exitInitializationMode()
    return slave, refs


def test_fmu_sensor_mode_gives_the_core_delta(fmu):
    slave, refs = _instance(fmu, "sensor", wheelbase=1.5, delta_max=0.6)
    core = cf.ChainedFormController(KD, KP, 1.5, 0.6)
    names = ["lateral_error", "heading_error", "curvature", "curvature_rate"]
    cases = [(-2.0, 0.0, 0.0, 0.0), (0.3, -0.2, 0.1, 0.01), (1.0, 0.5, -0.05, 0.002),
             (0.1, 2.5, 0.0, 0.0)]
    t = 0.0
    try:
        for case in cases:
            slave.setReal([refs[n] for n in names], list(case))
            got, law = slave.getReal([refs["delta"], refs["delta_law"]])
            expected = core.update(t, *case)
            # the FMU runs the same code on the same doubles: identical up to rounding
            assert got == pytest.approx(expected, abs=1e-15)
            assert law == pytest.approx(core.outputs["delta_law"], abs=1e-15)
            assert slave.getBoolean([refs["saturated"], refs["in_domain"]]) == [
                core.outputs["saturated"], core.outputs["in_domain"]]
            slave.doStep(t, 0.01)
            t += 0.01
        assert got == -0.6  # the last case points backwards: full lock right
    finally:
        slave.terminate()
        slave.freeInstance()


def test_fmu_pose_mode_matches_the_core_and_the_exact_sine_projection(fmu):
    spec = "sine:amplitude=3,wavelength=30"
    slave, refs = _instance(fmu, "pose", source="pose", path=spec)
    core = cf.make_controller(source="pose", path=spec)
    t = 0.0
    try:
        for x, y, heading in [(1.0, 0.2, 0.4), (7.4, 3.3, 0.05), (20.0, -2.0, -0.3)]:
            slave.setReal([refs["x"], refs["y"], refs["heading"]], [x, y, heading])
            got = slave.getReal([refs["delta"]])[0]
            assert got == pytest.approx(core.update_from_pose(t, x, y, heading), abs=1e-15)
            _, offset, path_heading, c, dc = _sine_project(x, y, None)
            exact = cf.steering_law(offset, heading - path_heading, c, dc, KD, KP, L, DMAX)
            # agv_core.numerics.paths projects to better than 1e-12 m: the same delta to 1e-9 rad
            assert got == pytest.approx(exact[0], abs=1e-9)
            slave.doStep(t, 0.01)
            t += 0.01
    finally:
        slave.terminate()
        slave.freeInstance()


def test_fmu_closed_loop_with_vehicle_on_the_2_m_step(fmu, component_fmus):
    """Vehicle FMU + controller FMU (pose mode, 'line:step_at=5,step=2'), 6 km/h."""
    vehicle_fmu = str(component_fmus["agv_vehicle"])
    vmd = read_model_description(vehicle_fmu)
    vfolder = extract(str(vehicle_fmu))
    vrefs = {v.name: v.valueReference for v in vmd.modelVariables}
    vehicle = FMU2Slave(guid=vmd.guid, unzipDirectory=vfolder,
                        modelIdentifier=vmd.coSimulation.modelIdentifier, instanceName="veh")
    ctl, refs = _instance(fmu, "loop", source="pose", path="line:step_at=5,step=2")
    h, v = 0.01, 6.0 / 3.6
    try:
        vehicle.instantiate()
        vehicle.setupExperiment(startTime=0.0)
        vehicle.enterInitializationMode()
        vehicle.setReal([vrefs["wheelbase"], vrefs["v0"]], [L, v])
        vehicle.setString([vrefs["reference_point"]], ["rear"])
        vehicle.exitInitializationMode()
        xs, ys = [], []
        t = 0.0
        while True:  # Gauss-Seidel: vehicle pose -> controller -> vehicle alpha
            pose = vehicle.getReal([vrefs["x"], vrefs["y"], vrefs["heading"]])
            xs.append(pose[0])
            ys.append(pose[1])
            if pose[0] > 40.0:
                break
            ctl.setReal([refs["x"], refs["y"], refs["heading"]], pose)
            vehicle.setReal([vrefs["alpha"]], ctl.getReal([refs["delta"]]))
            vehicle.doStep(t, h)
            ctl.doStep(t, h)
            t += h
    finally:
        ctl.terminate()
        ctl.freeInstance()
        vehicle.terminate()
        vehicle.freeInstance()
        shutil.rmtree(vfolder, ignore_errors=True)
    xs, ys = np.array(xs), np.array(ys)
    after = xs >= 5.0
    # from s = 5 m the offset is y - 2 with a2(5) = -2, a3(5) = 0 (driving straight on y = 0)
    exact = 2.0 + closed_form(xs[after] - 5.0, -2.0, 0.0)
    assert np.all(np.abs(ys[~after]) < 1e-12)  # on the path before the step
    # hold lag ~0.12 v h = 2 mm plus where the step falls within a step (v h = 1.7 cm):
    # 6 mm bounds it
    assert np.max(np.abs(ys[after] - exact)) < 6e-3
