"""The per-step fast paths of issue 16 give exactly what the plain rules give.

Each fast path (kept tentative noise, the actuator's short delay-line scan, plain-float
control law, cached cos/sin, one projection per pose) is checked bit for bit against the
rule it replaces, written out here in its simplest form, or against a fresh generator;
the control law against numpy's dot within its rounding bound (BLAS picks the order of
the sum by CPU, see there).
"""

import json
import math
import random

import numpy as np
import pytest

from agv_core.numerics.paths import LinePath, heading_error, parse_path
from agv_core.sensors.sensors import InstantSensor, TotalStation, VisionSensor
from agv_core.state_feedback.state_feedback import StateFeedback
from agv_core.steering.actuator import DelayedIntegratorActuator
from agv_core.vehicle.vehicle import Vehicle


def pose(t):
    return (t, 0.1 * math.sin(t), 0.05 * math.cos(t))


# ---------------------------------------------------------------------- sensors
def run_vision(sensor, h, n, reads):
    """Outputs after every step; ``reads(k)`` extra reads at each point before the step."""
    shown = []
    for k in range(n):
        t = k * h
        for _ in range(reads(k)):
            sensor.measure(t, *pose(t))
        sensor.step(t, h, *pose(t))
        shown.append(sensor.measure(t + h, *pose(t + h)))
    return shown


@pytest.mark.parametrize("period, latency", [(0.0, 0.0), (0.04, 0.0), (0.04, 0.04),
                                             (0.003, 0.0)])
def test_vision_noise_does_not_depend_on_how_often_outputs_are_read(period, latency):
    make = lambda: VisionSensor(parse_path("circle:radius=4"), frame_period=period,  # noqa
                                latency=latency, noise_lateral=0.01, noise_heading=0.02,
                                seed=5)
    never = run_vision(make(), 0.01, 60, lambda k: 0)
    often = run_vision(make(), 0.01, 60, lambda k: k % 3)
    assert often == never                      # bit for bit


def test_vision_committed_noise_is_the_generator_stream_in_order():
    # frame at every point, no latency: sample k carries draws 2k and 2k + 1
    path = LinePath()
    sensor = VisionSensor(path, frame_period=0.0, latency=0.0, noise_lateral=0.01,
                          noise_heading=0.02, seed=11)
    shown = run_vision(sensor, 0.01, 20, lambda k: 2)
    z = np.random.default_rng(11).standard_normal(2 * 21)
    for k, values in enumerate(shown, start=1):
        t = (k - 1) * 0.01 + 0.01              # the point run_vision reads at
        p = path.project(*pose(t)[:2])
        assert values[0] == p.offset + 0.01 * z[2 * k]
        assert values[1] == heading_error(pose(t)[2], p.heading) + 0.02 * z[2 * k + 1]


def test_vision_kept_noise_serves_a_skipped_instant_and_the_saved_state():
    make = lambda: VisionSensor(LinePath(), frame_period=0.0, latency=0.0,  # noqa: E731
                                noise_lateral=0.01, noise_heading=0.02, seed=2)
    plain, read = make(), make()
    read.measure(0.0, *pose(0.0))              # tentative sample of t = 0 ...
    saved = json.loads(json.dumps(read.get_state()))
    assert saved["ahead"] is not None and plain.get_state()["ahead"] is None
    for s in (plain, read):
        s.step(0.5, 0.01, *pose(0.5))          # ... and t = 0 is never committed
    assert read.measure(0.51, *pose(0.51)) == plain.measure(0.51, *pose(0.51))
    restored = make()
    restored.set_state(saved)
    fresh = make()
    for s in (restored, fresh):
        s.step(0.0, 0.01, *pose(0.0))
    assert restored.measure(0.01, *pose(0.01)) == fresh.measure(0.01, *pose(0.01))


class _SavedStateVision(VisionSensor):
    """The rule the kept numbers replace: generator state saved before a tentative draw,
    put back when another instant is committed, saved state from before the draw."""

    NOISE_ONLY_STREAM = False


@pytest.mark.parametrize("period, latency", [(0.0, 0.0), (0.04, 0.0), (0.04, 0.04),
                                             (0.003, 0.0), (0.025, 0.0)])
def test_vision_kept_numbers_equal_the_saved_state_rule(period, latency):
    # reads at odd points, skipped stretches (a step that starts later than the last one
    # ended), state saved and restored through JSON with a tentative draw outstanding
    def run(cls):
        make = lambda: cls(parse_path("circle:radius=4"), frame_period=period,  # noqa
                           latency=latency, noise_lateral=0.01, noise_heading=0.02, seed=9)
        sensor, out, rng = make(), [], random.Random(3)
        t, h = 0.0, 0.01
        for k in range(300):
            for _ in range(rng.randrange(3)):
                out.append(sensor.measure(t, *pose(t)))
            if k % 37 == 36:
                state = json.loads(json.dumps(sensor.get_state()))
                sensor = make()
                sensor.set_state(state)
            sensor.step(t, h, *pose(t))
            t += h * (1 if k % 23 else 3)       # now and then instants are skipped
            out.append(sensor.measure(t, *pose(t)))
        return out

    assert run(VisionSensor) == run(_SavedStateVision)     # bit for bit


def test_total_station_stream_with_reads_on_fix_instants():
    # jitter 0 and a 10 ms interval put every fix on a 5 ms communication point
    make = lambda: TotalStation(mean_interval=0.01, jitter=0.0, latency=0.0,  # noqa: E731
                                noise=0.003, seed=4)

    def run(station, reads):
        out = []
        for k in range(80):
            t = k * 0.005
            for _ in range(reads(k)):
                station.measure(t, t, -t)
            station.step(t, 0.005, t, -t)
            out.append(station.measure(t + 0.005, t + 0.005, -t - 0.005))
        return out

    assert run(make(), lambda k: k % 4) == run(make(), lambda k: 0)
    jittered = lambda: TotalStation(mean_interval=0.01, jitter=0.004, latency=0.0,  # noqa
                                    noise=0.003, seed=4)
    assert run(jittered(), lambda k: 2) == run(jittered(), lambda k: 0)


def test_instant_sensor_reads_and_state_keep_the_stream():
    def run(sensor, reads, save_at=None):
        out = []
        for k in range(50):
            t = k * 0.01
            for _ in range(reads(k)):
                sensor.measure(t, 0.2)
            if k == save_at:
                state = json.loads(json.dumps(sensor.get_state()))
                sensor = InstantSensor(noise=0.01, seed=99)
                sensor.set_state(state)
            out.append(sensor.measure(t, 0.2))
            sensor.step(t, 0.01)
        return out

    never = run(InstantSensor(noise=0.01, seed=7), lambda k: 0)
    assert run(InstantSensor(noise=0.01, seed=7), lambda k: k % 3) == never
    assert run(InstantSensor(noise=0.01, seed=7), lambda k: 1, save_at=20) == never
    z = np.random.default_rng(7).standard_normal(50)
    assert never == [0.2 + 0.01 * v for v in z]


def test_vision_projects_a_pose_once_for_its_sample_and_its_commit():
    calls = []

    class Counting(LinePath):
        def project(self, x, y, s_hint=None):
            calls.append((x, y))
            return super().project(x, y, s_hint)

    sensor = VisionSensor(Counting(), frame_period=0.0, latency=0.0, noise_lateral=0.0,
                          noise_heading=0.0)
    x, y, heading = 1.0, 0.2, 0.0
    sensor.measure(0.0, x, y, heading)         # tentative sample of t = 0
    sensor.step(0.0, 0.01, x, y, heading)      # initial value and commit: same objects
    assert len(calls) == 1
    sensor.measure(0.01, x, y, heading)        # new hint (the committed s): projected
    sensor.measure(0.01, x, y, heading)        # read again: kept
    assert len(calls) == 2
    sensor.measure(0.01, float("1.0"), y, heading)  # an equal value, another object
    assert len(calls) == 3


# ---------------------------------------------------------------------- actuator
def reference_step(act, t, h, u):
    """Model a's step as first written: every breakpoint scanned at every step."""
    eps = act.delay.eps(h)
    hist = act.history
    if hist and hist[-1][0] >= t - eps:
        hist[-1] = [t, float(u)]
        if len(hist) > 1 and hist[-2][1] == float(u):
            hist.pop()
    elif not hist or hist[-1][1] != float(u):
        hist.append([t, float(u)])
    t_end = t + h
    cuts = [time + act.tau for time, _ in hist if t + eps < time + act.tau < t_end - eps]
    start = t
    for stop in cuts + [t_end]:
        act._advance_constant_rate(act.K * act.delay.delayed(start - act.tau + eps), stop - start)
        start = stop
    s = t_end - act.tau + eps
    keep = 0
    for i, (time, _) in enumerate(hist):
        if time <= s:
            keep = i
    del hist[:keep]


@pytest.mark.parametrize("h, limits", [(0.001, {}), (0.007, {}), (0.02, {}),
                                       (0.003, {"rate_max": 0.05, "alpha_max": 0.02})])
def test_delay_line_matches_the_full_scan_bit_for_bit(h, limits):
    rnd = random.Random(3)
    fast = DelayedIntegratorActuator(tau=0.05, **limits)
    slow = DelayedIntegratorActuator(tau=0.05, **limits)
    longest = 0
    for k in range(3000):
        u = rnd.choice([0.0, 0.3, -0.2, rnd.uniform(-1, 1)])  # repeats and changes
        t = k * h
        fast.step(t, h, u)
        reference_step(slow, t, h, u)
        slow.time = t + h
        assert fast.alpha == slow.alpha
        assert fast.history == slow.history
        assert fast.rate() == slow.rate()
        longest = max(longest, len(fast.history))
    # the line holds what the dead time spans, not the whole run
    assert longest <= math.ceil(0.05 / h) + 2


# ---------------------------------------------------------------------- control law
def test_state_feedback_plain_floats_equal_numpy_dot():
    """The plain-float law against the numpy dot it replaces, within the rounding of a
    three-term dot product: each of the two is within gamma_3 = 3 u sum |k_i x_i| of the
    exact value (u = eps / 2), so they differ by at most 3 eps sum |k_i x_i|. Not bit
    for bit: numpy's dot of float64 vectors calls OpenBLAS's ddot, whose summation order
    and use of FMA depend on the kernel OpenBLAS picks for the CPU (equal to the plain
    sum with the Haswell and Sandybridge kernels, an ulp off in some cases with SkylakeX
    and Prescott, OPENBLAS_CORETYPE). The plain law adds in index order, so against
    that order it is exact."""
    rnd = random.Random(8)
    k = (4.828, 3.767, 4.472)
    law = StateFeedback(Ka=k[0], Kb=k[1], Ke=k[2])
    gains = np.array(k)
    for _ in range(20000):
        x = [rnd.uniform(-1, 1) * 10.0 ** rnd.randint(-8, 2) for _ in range(3)]
        products = [float(k) * xi for k, xi in zip(gains, x)]
        assert law.law(*x) == -((products[0] + products[1]) + products[2])
        bound = 3 * np.finfo(float).eps * sum(abs(p) for p in products)
        assert abs(law.law(*x) - -float(gains @ np.array(x))) <= bound, x


# ---------------------------------------------------------------------- vehicle
def test_vehicle_cos_sin_follow_the_heading_after_a_restore():
    car = Vehicle(1.5, 0.0, 0.1, 0.2, reference_point="front")
    for _ in range(10):
        car.step(0.1, 1.0, 0.01)
    state = car.get_state()
    state["heading"] = -0.7
    car.set_state(state)
    assert car.rear() == (car.x - 1.5 * math.cos(-0.7), car.y - 1.5 * math.sin(-0.7))
    rear = Vehicle(1.5, 1.0, 2.0, 0.3, reference_point="rear")
    rear.step(0.2, 1.0, 0.05)
    assert rear.front() == (rear.x + 1.5 * math.cos(rear.heading),
                            rear.y + 1.5 * math.sin(rear.heading))


# ---------------------------------------------------------------------- adapter
LAZY_CASES = {  # slave script: (parameters, inputs as functions of t, outputs)
    "agv_vision_sensor": ({"frame_period": 0.003, "latency": 0.0, "noise_lateral": 0.01,
                           "noise_heading": 0.02, "seed": 3},
                          {"x": lambda t: t, "y": lambda t: 0.1 * math.sin(t),
                           "heading": lambda t: 0.05 * math.cos(t)},
                          ("lateral_error", "heading_error", "s")),
    "agv_steer_sensor": ({"noise": 0.01, "resolution": 0.0, "seed": 4},
                         {"alpha": lambda t: 0.2 * math.sin(3 * t)}, ("alpha_meas",)),
    "agv_state_feedback": ({}, {"alpha": lambda t: 0.1 * t, "heading_error": math.sin,
                                "lateral_error": math.cos}, ("u",)),
}
# the seed-001 tracking controllers, sampled every 2 steps (30 samples in the 60 steps)
_TRACKING_INPUTS = {"x": lambda t: 0.4 * t + 0.01 * math.sin(50 * t),
                    "y": lambda t: -0.5 + 2 * t, "heading": lambda t: 0.1 * math.cos(40 * t),
                    "x_ref": lambda t: 0.4 * t, "y_ref": lambda t: 0.0,
                    "heading_ref": lambda t: 0.0, "v_ref": lambda t: 0.4,
                    "omega_ref": lambda t: 0.0}
LAZY_CASES["agv_ltv_mpc"] = ({"sample_time": 0.002}, _TRACKING_INPUTS,
                             ("v_c", "omega", "dv_c", "iterations"))
LAZY_CASES["agv_lateral_pid"] = ({"sample_time": 0.002}, _TRACKING_INPUTS,
                                 ("v_c", "omega", "e_lat"))


def _drive(fmu, folder, params, inputs, outputs, read_after_step, read_every, set_every=1):
    """Outputs read after the sets of every ``read_every``-th point (and, with
    ``read_after_step``, once right after each doStep, before the sets); inputs set at
    every ``set_every``-th point only."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(fmu)
    var = {v.name: v for v in md.modelVariables}
    unzipped = extract(fmu, unzipdir=folder)
    slave = FMU2Slave(guid=md.guid, unzipDirectory=unzipped,
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="i")
    slave.instantiate()
    h, shown = 0.001, []
    try:
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        for name, value in params.items():
            (slave.setInteger if var[name].type == "Integer" else slave.setReal)(
                [var[name].valueReference], [value])
        slave.exitInitializationMode()
        in_vrs = [var[n].valueReference for n in inputs]
        out_vrs = [var[n].valueReference for n in outputs]
        for k in range(60):
            t = k * h
            if k and read_after_step:
                slave.getReal(out_vrs)            # publication at the step, as before
            if k % set_every == 0:
                slave.setReal(in_vrs, [f(t) for f in inputs.values()])
            if k % read_every == 0:
                shown.append(tuple(slave.getReal(out_vrs)))
            slave.doStep(t, h)
        slave.terminate()
    finally:
        slave.freeInstance()
    return shown


@pytest.mark.parametrize("stem", sorted(LAZY_CASES))
def test_lazy_publication_after_a_step_equals_publishing_at_the_step(stem, component_fmus,
                                                                     tmp_path):
    # The rule replaced: publish at the end of every doStep (with the held inputs), then
    # again at the read after the master's sets. A read right after each doStep forces
    # that publication; the shortcut publishes at the read after the sets only, or not
    # at all at points nobody reads.
    params, inputs, outputs = LAZY_CASES[stem]
    run = lambda name, *how: _drive(component_fmus[stem], tmp_path / name,  # noqa: E731
                                    params, inputs, outputs, *how)
    eager = run("eager", True, 1)
    assert run("lazy", False, 1) == eager                 # bit for bit
    assert run("sparse", False, 4) == eager[::4]          # points not read: no publication
    assert len(set(eager)) >= 20                          # the outputs do move (vision:
    #                                                       a frame every 3 steps)


def test_lazy_publication_after_a_step_without_sets_shows_the_new_time(component_fmus,
                                                                       tmp_path):
    # inputs set at every other point only: a read after a step without a set must show
    # the sample of the new point from the held pose (the core's own answer)
    params, inputs, outputs = LAZY_CASES["agv_vision_sensor"]
    shown = _drive(component_fmus["agv_vision_sensor"], tmp_path / "x", params, inputs,
                   outputs, False, 1, 2)
    core = VisionSensor(parse_path("line"), **{k: v for k, v in params.items()})
    expected, held, h = [], None, 0.001
    for k in range(60):
        t = k * h
        if k % 2 == 0:
            held = [f(t) for f in inputs.values()]
        expected.append(core.measure(t, *held)[:3])
        core.step(t, h, *held)
    assert shown == expected


# ---------------------------------------------------------------------- master
def test_set_passes_the_source_buffer_only_where_it_holds_the_same_values():
    from ctypes import c_double, c_int

    from agv_cosim.execution.fastpath import shared_values as _shared_values

    src = (c_double * 5)(1.5, -0.0, 2.5, float("nan"), 7.0)
    other = (c_double * 5)(*src)
    three = (c_double * 3)()
    # the rule replaced: copy each linked value into the input buffer, pass that buffer
    for links in ([(0, src, 1), (1, src, 2), (2, src, 3)],
                  [(2, src, 4), (0, src, 2), (1, src, 3)]):
        shared = _shared_values(three, links)
        for j, buf, pos in links:
            three[j] = buf[pos]
        assert shared is not None
        assert [struct_bits(shared[i]) for i in range(3)] == \
            [struct_bits(v) for v in three]               # bit for bit, -0.0 and NaN too
    assert _shared_values(three, [(0, src, 0), (1, src, 2), (2, src, 3)]) is None  # gap
    assert _shared_values(three, [(0, src, 0), (1, other, 1), (2, src, 2)]) is None
    assert _shared_values(three, [(0, src, 0), (1, src, 1)]) is None     # not all linked
    assert _shared_values(three, [(0, src, 3), (1, src, 4), (2, src, 5)]) is None
    assert _shared_values((c_int * 1)(), [(0, src, 0)]) is None           # other C type


def struct_bits(value):
    import struct

    return struct.pack("<d", value)
