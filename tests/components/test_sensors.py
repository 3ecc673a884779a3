"""Tests of agv_core.sensors and the vision-sensor FMU."""

import hashlib
import json
import math
import shutil

import numpy as np
import pytest

from agv_core.numerics.paths import heading_error, parse_path
from agv_core.sensors.sensors import EPS, GYRO_DRIFT, InstantSensor, TotalStation, VisionSensor


def pose(t):
    """A test trajectory: x, y, heading as functions of time (distinct every step)."""
    return 1.5 * t, 0.3 + 0.2 * math.sin(t), 0.1 * math.cos(t)


def run_vision(sensor, h, n):
    out = []
    for i in range(n):
        t = i * h
        sensor.step(t, h, *pose(t))
        out.append(sensor.measure((i + 1) * h, *pose((i + 1) * h)))
    return np.array(out)


def test_vision_zero_latency_noise_is_projection():
    path = parse_path("sine:amplitude=3,wavelength=30")
    sensor = VisionSensor(path, frame_period=0.0, latency=0.0, noise_lateral=0.0,
                          noise_heading=0.0)
    hint = None
    for i in range(50):
        t = 0.1 * i
        x, y, hd = pose(t)
        p = path.project(x, y, hint)
        got = sensor.measure(t, x, y, hd)
        # the same computation: identical to the last bit
        assert got == (p.offset, heading_error(hd, p.heading), p.s, p.curvature,
                       p.curvature_rate)
        sensor.step(t, 0.1, x, y, hd)
        hint = p.s


@pytest.mark.parametrize("h, period, latency", [(0.03, 0.04, 0.1), (0.01, 0.04, 0.04),
                                                (0.05, 0.0, 0.12), (0.07, 0.04, 0.0)])
def test_vision_timing_is_exact(h, period, latency):
    path = parse_path("line")
    sensor = VisionSensor(path, period, latency, 0.0, 0.0)
    out = run_vision(sensor, h, 60)
    for i, row in enumerate(out):
        end = (i + 1) * h
        # oracle: newest capture t_k (multiples of period, or every step start) with
        # t_k + latency <= end, seen with the input held over the step containing t_k
        if period > 0:
            ks = np.arange(0, int(end / period) + 2) * period
        else:
            ks = np.arange(0, i + 2) * h
        ok = ks[ks + latency <= end + EPS]
        t_k = ok[-1] if ok.size else None
        if t_k is None:
            expected = pose(0.0)[1]                     # initial pose, noise-free
        elif latency == 0 and abs(t_k - end) < EPS:
            expected = pose(end)[1]                     # feedthrough at a capture point
        else:
            held = math.floor((t_k + EPS) / h) * h      # step start holding t_k
            expected = pose(held)[1]
        # lateral offset from the line y = 0 is y itself: exact arithmetic, 1e-15 m
        assert row[0] == pytest.approx(expected, abs=1e-15), (i, t_k)


def test_vision_seeds_and_noise_statistics():
    path = parse_path("line")
    kw = dict(frame_period=0.0, latency=0.0, noise_lateral=0.01, noise_heading=0.02)
    a = run_vision(VisionSensor(path, seed=7, **kw), 0.01, 4000)
    b = run_vision(VisionSensor(path, seed=7, **kw), 0.01, 4000)
    c = run_vision(VisionSensor(path, seed=8, **kw), 0.01, 4000)
    assert np.array_equal(a, b)
    assert not np.allclose(a[:, 0], c[:, 0])
    truth = np.array([pose((i + 1) * 0.01) for i in range(4000)])
    lat = a[:, 0] - truth[:, 1]
    hd = a[:, 1] - truth[:, 2]
    # 4000 samples: std of the sample std is 1/sqrt(2N) = 1.1 %: 5 % is > 4 sigma;
    # the mean's std is sigma/sqrt(N) = 1.6 % of sigma: 0.08 sigma is 5 sigma
    assert np.std(lat) == pytest.approx(0.01, rel=0.05)
    assert np.std(hd) == pytest.approx(0.02, rel=0.05)
    assert abs(np.mean(lat)) < 0.08 * 0.01


def test_vision_repeated_reads_and_state_round_trip():
    path = parse_path("circle:radius=4")
    sensor = VisionSensor(path, frame_period=0.0, latency=0.0, seed=3)
    run_vision(sensor, 0.02, 10)
    first = sensor.measure(0.2, *pose(0.2))
    assert sensor.measure(0.2, *pose(0.2)) == first   # reading does not consume noise
    saved = json.loads(json.dumps(sensor.get_state()))
    ahead = [sensor.measure(0.2 + 0.02 * i, *pose(0.2)) for i in range(1)]
    sensor.step(0.2, 0.02, *pose(0.2))
    after = sensor.measure(0.22, *pose(0.22))
    other = VisionSensor(path, frame_period=0.0, latency=0.0, seed=99)
    other.set_state(saved)
    assert [other.measure(0.2, *pose(0.2))] == ahead
    other.step(0.2, 0.02, *pose(0.2))
    assert other.measure(0.22, *pose(0.22)) == after


def test_instant_sensor_state_carries_its_start_time():
    """The drift runs from the start time t0, which the FMU takes from its clock when it
    builds the core: a state restored into a core built at another time (a fresh FMU
    instance, or one rebuilt from the state's parameters) reads as the saved one."""
    sensor = InstantSensor(drift=GYRO_DRIFT * 1e4, noise=0.01, seed=4, t0=0.0)
    for k in range(5):
        sensor.measure(0.1 * k, 0.2)
        sensor.step(0.1 * k, 0.1)
    saved = json.loads(json.dumps(sensor.get_state()))
    other = InstantSensor(drift=GYRO_DRIFT * 1e4, noise=0.01, seed=4, t0=0.5)
    other.set_state(saved)
    assert other.measure(0.5, 0.2) == sensor.measure(0.5, 0.2)
    assert other.get_state() == sensor.get_state()


def test_vision_state_carries_its_start_time():
    path = parse_path("circle:radius=4")
    sensor = VisionSensor(path, frame_period=0.1, latency=0.05, seed=3, t0=0.0)
    saved = json.loads(json.dumps(sensor.get_state()))
    other = VisionSensor(path, frame_period=0.1, latency=0.05, seed=3, t0=0.7)
    other.set_state(saved)
    assert other.t0 == 0.0  # the first frame's time, the reading before the first sample
    assert other.get_state() == sensor.get_state()


def run_station(station, h, n, xy=lambda t: (t, -t)):
    return np.array([(station.step(i * h, h, *xy(i * h)),
                      station.measure((i + 1) * h, *xy((i + 1) * h)))[1] for i in range(n)])


def test_total_station_interval_latency_and_noise():
    h, n = 0.01, 60000                                   # 600 s, about 920 fixes
    station = TotalStation(latency=0.1, noise=0.0, seed=1)
    out = run_station(station, h, n)
    t = (np.arange(n) + 1) * h
    capture = t - out[:, 2]
    # noise-free: the fix is the held input at its capture instant: x_meas = t_k held
    fixes = np.unique(np.round(capture[t > 0.2], 9))
    intervals = np.diff(fixes)
    # uniform jitter +-0.15 s: mean of ~900 intervals has std 0.087/sqrt(900) = 3 ms
    assert intervals.mean() == pytest.approx(0.65, abs=0.012)
    assert intervals.min() >= 0.5 - EPS and intervals.max() <= 0.8 + EPS
    # a fix is shown exactly from capture + latency: ages never below the latency and
    # each new fix appears within one step of capture + latency
    new = np.flatnonzero(np.diff(capture) > 1e-6) + 1
    assert np.all(out[new, 2] >= 0.1 - EPS) and np.all(out[new, 2] < 0.1 + h + EPS)
    held = np.floor((capture[new] + EPS) / h) * h
    assert np.allclose(out[new, 0], held, atol=1e-12)


def test_total_station_seeds_and_noise():
    a = run_station(TotalStation(seed=5, noise=0.003), 0.05, 4000, xy=lambda t: (0.0, 0.0))
    b = run_station(TotalStation(seed=5, noise=0.003), 0.05, 4000, xy=lambda t: (0.0, 0.0))
    c = run_station(TotalStation(seed=6, noise=0.003), 0.05, 4000, xy=lambda t: (0.0, 0.0))
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    fixes = np.unique(a[a[:, 2] < a[:, 2].max(), :2], axis=0)
    # ~300 fixes x 2 coordinates: std of the std ~ 1/sqrt(1200) = 3 %: allow 12 %
    assert fixes.shape[0] > 250
    assert np.std(fixes) == pytest.approx(0.003, rel=0.12)


def test_gyro_drift_resolution_and_noise():
    gyro = InstantSensor(drift=GYRO_DRIFT, resolution=0.0)
    # 0.5 deg/h; after one hour the reading is off by exactly 0.5 deg (rounding 1e-15)
    assert GYRO_DRIFT == pytest.approx(math.radians(0.5) / 3600, rel=1e-15)
    assert gyro.measure(3600.0, 1.0) - 1.0 == pytest.approx(math.radians(0.5), abs=1e-15)
    res = math.radians(0.01)
    q = InstantSensor(drift=0.0, resolution=res)
    for v in np.linspace(-1, 1, 101):
        m = q.measure(0.0, v)
        assert abs(m - v) <= res / 2 + 1e-15 and abs(m / res - round(m / res)) < 1e-9
    noisy = InstantSensor(noise=0.01, seed=4)
    same = InstantSensor(noise=0.01, seed=4)
    vals = []
    for i in range(4000):
        assert noisy.measure(i * 0.1, 0.0) == noisy.measure(i * 0.1, 0.0)
        vals.append(noisy.measure(i * 0.1, 0.0))
        assert same.measure(i * 0.1, 0.0) == vals[-1]
        noisy.step(i * 0.1, 0.1)
        same.step(i * 0.1, 0.1)
    # 4000 samples: 5 % on the std is > 4 sigma
    assert np.std(vals) == pytest.approx(0.01, rel=0.05)


# ---------------------------------------------------------------------- integration
def test_vision_fmu_reproduces_projection(component_fmus):
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    fmu = component_fmus["agv_vision_sensor"]
    md = read_model_description(str(fmu))
    refs = {v.name: v.valueReference for v in md.modelVariables}
    lateral = next(o for o in md.outputs if o.variable.name == "lateral_error")
    assert sorted(d.name for d in lateral.dependencies) == ["heading", "x", "y"]
    unit = next(v for v in md.modelVariables if v.name == "curvature_rate").unit
    assert unit == "1/m2"
    folder = extract(str(fmu))
    try:
        slave = FMU2Slave(guid=md.guid, unzipDirectory=folder,
                          modelIdentifier=md.coSimulation.modelIdentifier,
                          instanceName="vision")
        slave.instantiate()
        spec = "sine:amplitude=3,wavelength=30"
        slave.setString([refs["path"]], [spec])
        slave.setReal([refs[k] for k in ("frame_period", "latency", "noise_lateral",
                                         "noise_heading")], [0.0] * 4)
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        path = parse_path(spec)
        names = ["lateral_error", "heading_error", "s", "curvature", "curvature_rate"]
        h, hint = 0.1, None
        for i in range(30):
            x, y, hd = pose(i * h)
            slave.setReal([refs["x"], refs["y"], refs["heading"]], [x, y, hd])
            got = slave.getReal([refs[n] for n in names])
            p = path.project(x, y, hint)
            # same computation in the FMU's bundled copy: equal to 1e-12
            assert got == pytest.approx([p.offset, heading_error(hd, p.heading), p.s,
                                         p.curvature, p.curvature_rate], abs=1e-12)
            slave.doStep(i * h, h)
            hint = p.s
        slave.terminate()
        slave.freeInstance()
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def test_steer_sensor_fmu_noise_and_resolution(component_fmus):
    """The steering-angle sensor FMU, defaults: 1 mrad white noise, 0.1 deg resolution.

    Over 4000 samples of a constant 0.2 rad: every reading is a whole multiple of the
    resolution (to 1e-12 rad), the mean error is within the quantisation half-step plus
    4 standard errors (0.5 * 1.745e-3 + 4 * 1e-3 / sqrt(4000)), and the spread is that of
    the noise plus uniform quantisation, sqrt(1e-6 + res^2 / 12), within 10 %.
    """
    import fmpy
    fmu = component_fmus["agv_steer_sensor"]
    result = fmpy.simulate_fmu(str(fmu), stop_time=40.0, step_size=0.01,
                               output_interval=0.01, start_values={"alpha": 0.2})
    readings = result["alpha_meas"][1:]
    resolution = 0.001745329251994
    assert len(readings) == 4000
    multiples = readings / resolution
    assert np.max(np.abs(multiples - np.round(multiples))) < 1e-12 / resolution
    assert abs(np.mean(readings) - 0.2) < 0.5 * resolution + 4 * 1e-3 / np.sqrt(4000)
    expected = np.sqrt(1e-6 + resolution ** 2 / 12)
    assert abs(np.std(readings) / expected - 1) < 0.10


def test_total_station_dropout_loses_fixes_and_keeps_the_random_stream():
    """available = False from 2 s to 3 s: no fix captured then reaches the output (the
    last one before stays, its age grows); from the first fix after the dropout on, the
    outputs equal an undisturbed station's (same seed), since the lost fixes are drawn."""
    h = 0.01
    clean, cut = TotalStation(seed=3), TotalStation(seed=3)
    worst_age, same_after = 0.0, None
    for k in range(600):
        t = k * h
        cut.available = not (2.0 <= t < 3.0)
        xy = (0.5 * t, 0.1 * t)
        clean.step(t, h, *xy)
        cut.step(t, h, *xy)
        a, b = clean.measure(t + h, *xy), cut.measure(t + h, *xy)
        if 2.0 <= t < 3.0:
            # nothing captured in the dropout shows up
            assert b[2] > (t + h) - 2.0 - 1e-9
        worst_age = max(worst_age, b[2])
        if t > 4.0:
            same_after = (same_after is None or same_after) and a == b
    assert worst_age > 1.0          # the fix shown aged over the whole dropout
    assert same_after               # and the stream is unchanged afterwards


# ---------------------------------------------------------------------- random numbers
class _NoDraws:
    """Stands in for a sensor's generator: any use of it fails the test."""

    def __getattr__(self, name):
        raise AssertionError(f"the generator was used (rng.{name})")


def _trace(sensor, kind, h=0.01, n=300):
    """SHA-256 digests (16 hex digits) of what ``sensor`` shows over ``n`` steps of ``h``
    [s], read twice at every point (a tentative sample must not take new numbers): of
    the values (their repr), and of the values and the generator's final state."""
    rows = []
    for i in range(n + 1):
        t = i * h
        x, y, hd = pose(t)
        args = {"vision": (t, x, y, hd), "station": (t, x, y)}.get(kind, (t, hd))
        first = sensor.measure(*args)
        assert sensor.measure(*args) == first
        rows.append(tuple(first) if kind in ("vision", "station") else (first,))
        if i < n:
            if kind == "vision":
                sensor.step(t, h, x, y, hd)
            elif kind == "station":
                sensor.step(t, h, x, y)
            else:
                sensor.step(t, h)
    values = hashlib.sha256(repr(rows).encode())
    stream = values.copy()
    if not isinstance(sensor.rng, _NoDraws):
        stream.update(repr(sensor.rng.bit_generator.state).encode())
    return values.hexdigest()[:16], stream.hexdigest()[:16]


def _sensors():
    """(name, kind, factory) of the configurations pinned below."""
    sine = parse_path("sine:amplitude=3,wavelength=30")
    return [
        ("vision, feedthrough", "vision",
         lambda **k: VisionSensor(sine, frame_period=0.0, latency=0.0, seed=7, **k)),
        ("vision, frames and latency", "vision",
         lambda **k: VisionSensor(sine, frame_period=0.04, latency=0.04, seed=7, **k)),
        ("total station, feedthrough", "station",
         lambda **k: TotalStation(mean_interval=0.1, latency=0.0, seed=7, **k)),
        ("total station, latency", "station",
         lambda **k: TotalStation(mean_interval=0.1, latency=0.05, seed=7, **k)),
        ("gyro / steering sensor", "instant",
         lambda **k: InstantSensor(drift=GYRO_DRIFT, resolution=1e-4, seed=7, **k)),
    ]


#: parameters without random spread, per kind
_ZERO = {"vision": dict(noise_lateral=0.0, noise_heading=0.0),
         "station": dict(noise=0.0, jitter=0.0), "instant": dict(noise=0.0)}

#: parameters with random spread, per kind (with a zero-weighted number that is still
#: drawn because another is not)
_SPREAD = {"vision": [dict(noise_lateral=0.002, noise_heading=0.004),
                      dict(noise_lateral=0.0, noise_heading=0.004)],
           "station": [dict(noise=0.003, jitter=0.02), dict(noise=0.0, jitter=0.02),
                       dict(noise=0.003, jitter=0.0)],
           "instant": [dict(noise=0.001)]}

#: _trace's digests recorded with the sensors of commit 11281e9, which drew every
#: number whatever the spread: "<name>-zero" the values without spread (then drawn and
#: multiplied by 0), "<name>-<i>" the values and the stream with _SPREAD[kind][i]
_RECORDED = {
    "vision, feedthrough-zero": "db61530c657f441f",
    "vision, feedthrough-0": "b81ea6c5d762c04e",
    "vision, feedthrough-1": "d6b7cd3addffee46",
    "vision, frames and latency-zero": "ebd986b9abc24203",
    "vision, frames and latency-0": "3fc9a34db759a5ba",
    "vision, frames and latency-1": "b5ec4302d998c02e",
    "total station, feedthrough-zero": "5b30b3e449335032",
    "total station, feedthrough-0": "7462f927e8d69775",
    "total station, feedthrough-1": "f86d3601becc065e",
    "total station, feedthrough-2": "00ad9efbea5a2e8f",
    "total station, latency-zero": "8c79272b95d157f5",
    "total station, latency-0": "06361ac491cdbd58",
    "total station, latency-1": "15d5ced6054d5086",
    "total station, latency-2": "1e951189ed107d01",
    "gyro / steering sensor-zero": "ed778939c78883fb",
    "gyro / steering sensor-0": "c388bd188ca2061d",
}


@pytest.mark.parametrize("name, kind, make", _sensors(), ids=[n for n, _, _ in _sensors()])
def test_a_sensor_without_random_spread_never_uses_its_generator(name, kind, make):
    """Zero noise (total station: and zero jitter): the generator is never called (a
    stand-in fails on any use), and the values are those recorded when the noise was
    drawn and multiplied by zero."""
    sensor = make(**_ZERO[kind])
    sensor.rng = _NoDraws()
    values, _ = _trace(sensor, kind)
    assert values == _RECORDED[f"{name}-zero"]


@pytest.mark.parametrize("name, kind, i", [(name, kind, i) for name, kind, _ in _sensors()
                                           for i in range(len(_SPREAD[kind]))])
def test_a_sensor_with_random_spread_draws_the_stream_recorded_before(name, kind, i):
    make = next(m for n, _, m in _sensors() if n == name)
    _, stream = _trace(make(**_SPREAD[kind][i]), kind)
    assert stream == _RECORDED[f"{name}-{i}"]
