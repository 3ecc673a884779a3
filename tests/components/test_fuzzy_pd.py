"""Fuzzy gain scheduling and the per-axle PD law (agv_core.fuzzy_pd)."""

import math

import numpy as np
import pytest

from agv_core.axle_pd.fuzzy_pd import AxlePD, FixedGains, FuzzySchedule
from agv_core.errors import ParameterError

#: Bilinear interpolation bounds on the default grid (1 mm x 2 km/h): Kp 15 deg/m, Kd
#: 6.5 deg s/m. The surfaces have kinks where min(mu_e, mu_v) switches operand, along
#: lines that cross grid cells, so the error is first order in the spacing. Measured:
#: a 4 x 4 lattice in every cell, then a 60 x 60 lattice in the 12 worst cells per
#: surface: sup 11.9 deg/m (at e = 0.0493 m, v = 1.05 km/h) and 4.9 deg s/m (e = 0.0494,
#: v = 79 km/h); between lattice points the error can rise by at most the surface's
#: slope times half the lattice spacing (~0.4), so the bounds keep ~20 % above the sup.
#: In steering terms: < 15 |e| deg, at most 0.4 deg at the claimed 2.5 cm against a
#: ~7 deg curve angle. The random sample below is a regression check of that bound.
KP_BOUND, KD_BOUND = 15.0, 6.5

# scikit-fuzzy 0.5's control module calls np.maximum with an out argument by position
pytestmark = pytest.mark.filterwarnings(
    "ignore:Passing more than 2 positional arguments:DeprecationWarning")


@pytest.fixture(scope="module")
def schedule():
    return FuzzySchedule()


def test_vectorised_inference_matches_scikit_fuzzy(schedule):
    """Our grid evaluator against skfuzzy.control on the same system, 25 random points
    (inputs also outside the universes: both clip). 0.02: skfuzzy samples the output
    universe at 601 points (plus the cut points), we at 3001; measured 0.005."""
    from skfuzzy import control as ctrl

    sim = ctrl.ControlSystemSimulation(schedule.control_system())
    rng = np.random.default_rng(11)
    for e, v in zip(rng.uniform(-0.06, 0.06, 25), rng.uniform(0.0, 90.0, 25)):
        sim.input["e"] = e
        sim.input["v"] = v
        sim.compute()
        kp, kd = schedule.direct(e, v)
        assert sim.output["kp"] == pytest.approx(kp[0], abs=0.02)
        assert sim.output["kd"] == pytest.approx(kd[0], abs=0.02)


@pytest.mark.slow  # seconds: the table against direct inference at 20 000 points
def test_interpolation_error_is_within_the_stated_bound(schedule):
    rng = np.random.default_rng(5)
    e = np.concatenate([rng.uniform(-0.05, 0.05, 20000)])
    v = rng.uniform(0.0, 80.0, e.size)
    kp, kd = schedule.direct(e, v)
    grid = np.array([schedule.gains(a, b) for a, b in zip(e, v)])
    assert np.max(np.abs(grid[:, 0] - kp)) < KP_BOUND
    assert np.max(np.abs(grid[:, 1] - kd)) < KD_BOUND
    # at the nodes the table is the direct evaluation (to rounding)
    for a, b in ((0.0, 14.0 - 14.0 % 2), (0.025, 40.0), (-0.013, 22.0)):
        assert schedule.gains(a, b) == pytest.approx(
            tuple(float(x[0]) for x in schedule.direct(a, b)), abs=1e-9)


def test_tables_follow_the_paper_principles(schedule):
    """Principle 1: large error -> Kp large at low speed, small at high speed, Kd small;
    principle 2: medium error -> Kd moderate; principle 3: small error -> both small.
    The proposed tables are symmetric in e and never negative."""
    kp = lambda e, v: schedule.gains(e, v)[0]   # noqa: E731
    kd = lambda e, v: schedule.gains(e, v)[1]   # noqa: E731
    assert kp(0.05, 0.0) > kp(0.05, 40.0) > kp(0.05, 80.0)
    assert kd(0.05, 14.0) < kd(0.025, 14.0)
    assert kp(0.0, 14.0) < kp(0.025, 14.0) and kd(0.0, 14.0) < kd(0.025, 14.0)
    for e in np.linspace(-0.05, 0.05, 21):
        for v in (0.0, 14.0, 80.0):
            assert schedule.gains(e, v) == pytest.approx(schedule.gains(-e, v), abs=1e-9)
            assert min(schedule.gains(e, v)) >= -1e-9


def test_pd_law_derivative_filter_and_saturation():
    """Fixed gains: delta = -(Kp e + Kd r) in rad from deg/m, deg s/m; after a step of e
    the filtered rate decays exactly as exp(-t / tau) / tau (exact discretisation)."""
    pd = AxlePD(FixedGains(600.0, 100.0), tau_d=0.05)
    assert pd.evaluate(0.02, 3.9)["error_rate"] == 0.0      # no kick before the first step
    out = pd.evaluate(0.0, 3.9)
    assert out["delta"] == 0.0
    pd.advance(0.0, 0.01)
    out = pd.evaluate(0.01, 3.9)
    assert out["error_rate"] == pytest.approx(0.01 / 0.05, rel=1e-15)
    assert out["delta"] == pytest.approx(-math.radians(600 * 0.01 + 100 * 0.2), rel=1e-14)
    for _ in range(7):
        pd.advance(0.01, 0.01)
    assert pd.evaluate(0.01, 3.9)["error_rate"] == pytest.approx(
        0.2 * math.exp(-0.07 / 0.05), rel=1e-12)
    big = AxlePD(FixedGains(1500.0, 0.0), delta_max=0.2).evaluate(-0.5, 3.9)
    assert big["delta"] == 0.2 and big["saturated"]


def test_parameter_errors():
    with pytest.raises(ParameterError, match="'kp_rules'"):
        FuzzySchedule(kp_rules="PB PM; PS")
    with pytest.raises(ParameterError, match="unknown label 'MS'"):
        FuzzySchedule(kd_rules="ZE ZE ZE; PS PS ZE; ZE ZE MS; PS PS ZE; ZE ZE ZE")
    with pytest.raises(ParameterError, match="'e_cells'"):
        FuzzySchedule(e_cells=10)
    with pytest.raises(ParameterError, match="'tau_d'"):
        AxlePD(FixedGains(1.0, 1.0), tau_d=0.0)
