"""Class 6 of issue 10: one sampling rule in every sampled component.

Every sampled controller and sensor is driven through the same call sequence (the
issue's: T = 0.1 s, a call at 0.09 s, then two calls at 0.12 s with newer inputs at the
second, then an instant on a communication point, 0.2 s, called twice) and must show,
at every call, its own unsampled law applied to the input the rule of
agv_core.sampling selects: the input held at the sample instant, refreshed by every
call at an instant that is a communication point.
"""

import math

import pytest

from agv_core.chained_form import chained_form as cf
from agv_core.lateral_pid.pid import LateralPid
from agv_core.ltv_mpc.ltv_mpc import LtvMpc
from agv_core.numerics.paths import parse_path
from agv_core.numerics.sampling import TIME_EPS, SampleHold, at_instant, in_step, last_index
from agv_core.preview_lq.preview_lq import PreviewLQ
from agv_core.sensors.sensors import EPS, TotalStation, VisionSensor
from agv_core.state_feedback.state_feedback import StateFeedback

T = 0.1
LINE = parse_path("line:")
# a reference standing at the origin, heading along x, moving at 0.4 m/s (seed-001 inputs)
REF = {"x": 0.0, "y": 0.0, "heading": 0.0, "v": 0.4, "omega": 0.0}

# poses (x [m], y [m], heading [rad]) near the line y = 0
POSES = {name: (0.1 * i, 0.02 * (i + 1) * (-1) ** i, 0.01 * (i + 1))
         for i, name in enumerate("ABCDEFG")}

# (call, t, h or None, pose given, pose whose law must be shown)
SEQUENCE = [
    ("show", 0.0, None, "A", "A"),    # t0 is an instant: sampled from A
    ("step", 0.0, 0.09, "A", None),
    ("show", 0.09, None, "B", "A"),   # between instants: held
    ("step", 0.09, 0.03, "B", None),  # 0.1 lies in [0.09, 0.12): sampled from B (held)
    ("show", 0.12, None, "C", "B"),   # the 0.1 sample, not the inputs at 0.12 ...
    ("show", 0.12, None, "D", "B"),   # ... however often it is called
    ("step", 0.12, 0.08, "D", None),
    ("show", 0.2, None, "E", "E"),    # an instant on a communication point: the inputs
    ("show", 0.2, None, "F", "F"),    # at it, refreshed at every call there
    ("step", 0.2, 0.05, "F", None),   # commits the F sample
    ("show", 0.25, None, "G", "F"),   # held
]


class Controller:
    """A sampled controller and an unsampled twin of it (period 0)."""

    def __init__(self, make, show, step, inputs):
        self.sampled, self.make = make(T), make
        self._show, self._step, self.inputs = show, step, inputs

    def show(self, t, pose):
        return self._show(self.sampled, t, *self.inputs(pose))

    def step(self, t, h, pose):
        self._step(self.sampled, t, h, *self.inputs(pose))

    def law(self, pose):
        return self._show(self.make(0.0), 0.0, *self.inputs(pose))

    def expected(self, t, pose_name):
        return self.law(POSES[pose_name])


def _committed():
    """Instant k -> the pose whose sample the sequence commits there (the last shown)."""
    chosen = {}
    for call, t, _, _, expected in SEQUENCE:
        if call == "show":
            chosen[last_index(t, T)] = expected
    return chosen


def _mpc_law(poses):
    """The MPC's unsampled law (``compute``) chained by hand over ``poses``: u(k-1) and
    the warm start from the previous one, u(-1) = u_r."""
    core, u_prev, out = LtvMpc(sample_time=T), [REF["v"], REF["omega"]], None
    for pose in poses:
        out = core.compute(*pose, REF, u_prev)
        u_prev, core.warm = [out["v_c"], out["omega"]], core._next_warm
    return out


def _pid_law(poses):
    """The PID's unsampled law (``compute``) chained by hand: I(k-1), e(k-1)."""
    core, integral, e_prev, out = LateralPid(sample_time=T), 0.0, None, None
    for pose in poses:
        out, integral, e_prev = core.compute(*pose, REF, integral, e_prev)
    return out


class MemoryController(Controller):
    """A sampled controller with memory (integral, previous command): its law at
    instant k depends on the samples committed before. Expected: the unsampled law
    chained over the poses the rule commits at 0, T, ..., (k-1) T, then the pose due."""

    def __init__(self, make, chained):
        super().__init__(make, lambda c, t, *u: c.update(t, *u),
                         lambda c, t, h, *u: c.step(t, h, *u), lambda pose: (*pose, REF))
        self.chained = chained

    def law(self, pose):
        return self.chained([pose])

    def expected(self, t, pose_name):
        committed, k = _committed(), last_index(t, T)
        return self.chained([POSES[committed[j]] for j in range(k)] + [POSES[pose_name]])


class Sensor:
    """A sampled sensor with zero latency and noise; its law is a fresh sensor's
    reading at its first instant (t0 = 0)."""

    def __init__(self, make, inputs):
        self.sampled, self.make, self.inputs = make(), make, inputs

    def show(self, t, pose):
        return self._values(self.sampled.measure(t, *self.inputs(pose)))

    def step(self, t, h, pose):
        self.sampled.step(t, h, *self.inputs(pose))

    def law(self, pose):
        return self._values(self.make().measure(0.0, *self.inputs(pose)))

    def expected(self, t, pose_name):
        return self.law(POSES[pose_name])

    @staticmethod
    def _values(reading):
        return reading[:2] if len(reading) == 3 else reading  # total station: no fix_age


def _components():
    def chained_state(pose):
        return (pose[1], pose[2], 0.0, 0.0)

    return {
        "state feedback": Controller(
            lambda p: StateFeedback(sample_period=p),
            lambda c, t, *u: c.update(t, *u), lambda c, t, h, *u: c.step(t, h, *u),
            lambda pose: (0.0, pose[2], pose[1])),
        "chained form (sensor inputs)": Controller(
            lambda p: cf.ChainedFormController(sample_period=p),
            lambda c, t, *u: c.update(t, *u), lambda c, t, h, *u: c.step(t, h, *u),
            chained_state),
        "chained form (pose inputs)": Controller(
            lambda p: cf.ChainedFormController(sample_period=p, path=LINE),
            lambda c, t, *u: c.update_from_pose(t, *u),
            lambda c, t, h, *u: c.step_from_pose(t, h, *u), lambda pose: pose),
        "preview LQ": Controller(
            lambda p: PreviewLQ(LINE, sample_period=p),
            lambda c, t, *u: c.update(t, *u)["alpha_ref"],
            lambda c, t, h, *u: c.step(t, h, *u), lambda pose: (*pose, 0.0, 0.0)),
        "seed-001 LTV MPC (memory)": MemoryController(
            lambda p: LtvMpc(sample_time=p), _mpc_law),
        "seed-001 lateral PID (memory)": MemoryController(
            lambda p: LateralPid(sample_time=p), _pid_law),
        "vision sensor": Sensor(
            lambda: VisionSensor(LINE, frame_period=T, latency=0.0, noise_lateral=0.0,
                                 noise_heading=0.0), lambda pose: pose),
        "total station": Sensor(
            lambda: TotalStation(mean_interval=T, jitter=0.0, latency=0.0, noise=0.0),
            lambda pose: pose[:2]),
    }


@pytest.mark.parametrize("name", list(_components()))
def test_every_sampled_component_follows_the_one_rule(name):
    component = _components()[name]
    shown = []
    for call, t, h, given, expected in SEQUENCE:
        if call == "step":
            component.step(t, h, POSES[given])
            continue
        got = component.show(t, POSES[given])
        want = component.expected(t, expected)
        shown.append(expected)
        # the same law on the same input; 1e-12 only for a projection started from
        # another search hint
        assert got == pytest.approx(want, abs=1e-12), (name, t, given, expected)
    # the sequence does tell the inputs apart: the laws of B, C, D differ
    laws = [component.law(POSES[p]) for p in "BCD"]
    assert laws[0] != pytest.approx(laws[1], abs=1e-9)
    assert laws[0] != pytest.approx(laws[2], abs=1e-9)


def test_one_tolerance_and_the_instant_tests():
    assert EPS == TIME_EPS == 1e-9
    assert at_instant(0.30000000000000004, 0.3) and not at_instant(0.3 + 2e-9, 0.3)
    assert in_step(0.1, 0.09, 0.03) and not in_step(0.12, 0.09, 0.03)
    assert in_step(0.09 + 0.5e-9, 0.09, 0.03)           # on the point, within EPS
    assert last_index(0.3, 0.1) == 3 and last_index(0.29999999, 0.1) == 2
    assert last_index(0.03 * 10, 0.1) == 3               # 0.30000000000000004


def test_sample_hold_unsampled_and_state():
    calls = []

    def law(u):
        calls.append(u)
        return -u

    hold = SampleHold(0.0)
    assert [hold.output(t, (t,), law) for t in (0.0, 0.01)] == [-0.0, -0.01]
    hold = SampleHold(0.5)
    assert hold.output(0.2, (1.0,), law) == -1.0        # before any instant: first call
    hold.step(0.2, 0.1, (1.0,), law)                    # no instant in [0.2, 0.3)
    assert hold.output(0.3, (2.0,), law) == -1.0
    hold.step(0.3, 0.3, (3.0,), law)                    # 0.5 in [0.3, 0.6): from 3.0
    saved = hold.get_state()
    assert hold.output(0.6, (9.0,), law) == -3.0
    fresh = SampleHold(0.5)
    fresh.set_state(saved)
    assert fresh.output(0.7, (8.0,), law) == -3.0
    n = len(calls)
    hold = SampleHold(0.5)
    hold.output(1.0, (4.0,), law)
    hold.step(1.0, 0.1, (4.0,), law)                    # instant at 1.0, same inputs:
    assert len(calls) == n + 1                          # not evaluated twice
    assert math.isfinite(hold.value)


def test_sample_hold_with_memory():
    """A law with memory (here a sum of its samples) sees every instant of a long step
    once, and a re-evaluation at an instant starts again from the same prior sample."""
    hold = SampleHold(0.1, memory=True)

    def law(u):
        return (hold.prior or 0.0) + u

    assert hold.output(0.0, (1.0,), law) == 1.0
    hold.step(0.0, 0.35, (1.0,), law)          # instants 0 (shown), 0.1, 0.2, 0.3
    assert hold.value == 4.0 and hold.index == 3
    assert hold.output(0.4, (10.0,), law) == 14.0
    assert hold.output(0.4, (20.0,), law) == 24.0   # newer inputs at the same instant
    saved = hold.get_state()
    hold.step(0.4, 0.1, (20.0,), law)               # commits the 24 shown
    assert hold.output(0.5, (1.0,), law) == 25.0
    hold.set_state(saved)
    assert hold.output(0.4, (30.0,), law) == 34.0
    with pytest.raises(ValueError):
        SampleHold(0.0, memory=True)
