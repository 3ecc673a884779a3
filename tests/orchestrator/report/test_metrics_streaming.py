"""The streamed metrics (compute_metrics_csv, bounded memory) against the in-memory
reference compute_metrics: equal bit for bit, keys in the same order, whatever the chunk
size, also when a chunk boundary falls on the settling or overshoot sample."""

import math

import numpy as np
import pytest

from agv_cosim.report.metrics import PairwiseSum, compute_metrics, compute_metrics_csv
from agv_cosim.timeseries import CsvSink, count_rows, iter_timeseries, read_timeseries

SPEC = {
    "lateral_error": "s.e",
    "heading_error": "s.h",
    "steering_angle": "a.alpha",
    "steering_rate": "a.rate",
    "control": "c.u",
    "settle_band": 0.02,
    "saturation": {"signal": "a.alpha", "limit": 0.3},
    "reference": {"path": "line:x0=0,y0=0,heading=0", "x": "v.x", "y": "v.y"},
}
NAMES = ["s.e", "s.h", "a.alpha", "a.rate", "c.u", "v.x", "v.y"]


def _signals(n=1500, seed=3):
    """A damped second-order lateral response (overshoot, then settling) on a
    non-uniform grid, with the other signals derived from it."""
    rng = np.random.default_rng(seed)
    t = 2.0 + np.cumsum(rng.uniform(0.005, 0.015, n))
    e = 0.4 * np.exp(-0.6 * (t - t[0])) * np.cos(2.5 * (t - t[0]))
    e += 1e-4 * rng.standard_normal(n)
    signals = {"s.e": e, "s.h": np.gradient(e, t), "a.alpha": np.clip(-2.0 * e, -0.3, 0.3),
               "a.rate": rng.standard_normal(n), "c.u": -3.0 * e + 0.1,
               "v.x": t - t[0], "v.y": e + 0.01 * np.sin(t)}
    return t, signals


def _write(path, t, signals):
    sink = CsvSink(path, list(signals))
    for row in zip(t, *signals.values()):
        sink.write(row)
    sink.close()
    return path


def _assert_same(got, ref):
    assert list(got) == list(ref)
    for key in ref:
        # bit for bit: same float (or both None); math.copysign tells 0.0 from -0.0
        assert (got[key] is None) == (ref[key] is None), key
        if ref[key] is not None:
            assert got[key] == ref[key] and \
                math.copysign(1, got[key]) == math.copysign(1, ref[key]), key


def _events(t, e, band):
    """Indices of the last sample outside the band and of the overshoot peak."""
    last_outside = int(np.flatnonzero(np.abs(e) > band)[-1])
    peak = int(np.argmax(-math.copysign(1.0, e[0]) * e))
    return last_outside, peak


@pytest.mark.parametrize("settle_after", [None, 3.0])
@pytest.mark.slow  # seconds: builds or runs FMUs in processes
def test_streamed_equals_reference_at_every_chunk_boundary(tmp_path, settle_after):
    t, signals = _signals()
    path = _write(tmp_path / "timeseries.csv", t, signals)
    spec = dict(SPEC)
    if settle_after is not None:
        spec["settle_after"] = settle_after
    ref = compute_metrics(t, signals, spec)
    assert ref["lateral_error_overshoot"] > 0.1 and ref["lateral_error_settling_time"] > 1.0
    last_outside, peak = _events(t, signals["s.e"], spec["settle_band"])
    window_start = int(np.searchsorted(t, t[0] + 3.0, side="right"))
    sizes = {1, 2, 3, 7, 128, 129, len(t) - 1, len(t), 10_000}
    for k in (last_outside, peak, window_start):
        sizes |= {k - 1, k, k + 1, k + 2}   # chunk ends just before / on / after sample k
    for size in sorted(sizes):
        _assert_same(compute_metrics_csv(path, spec, chunk_rows=size), ref)


@pytest.mark.parametrize("case", ["never_settles", "never_leaves", "zero_start", "nan",
                                  "one_row", "two_rows", "window_empty"])
def test_streamed_equals_reference_in_edge_cases(tmp_path, case):
    t, signals = _signals(n=300)
    spec = dict(SPEC)
    if case == "never_settles":
        signals["s.e"] = signals["s.e"] + np.where(np.arange(t.size) == t.size - 1, 1.0, 0.0)
    elif case == "never_leaves":
        signals["s.e"] = 0.01 * signals["s.e"]
    elif case == "zero_start":
        signals["s.e"] = signals["s.e"] - signals["s.e"][0]
    elif case == "nan":
        for name in ("s.e", "v.y", "c.u"):
            signals[name] = signals[name].copy()
            signals[name][150] = np.nan
    elif case in ("one_row", "two_rows"):
        keep = 1 if case == "one_row" else 2
        t = t[:keep]
        signals = {name: values[:keep] for name, values in signals.items()}
    elif case == "window_empty":
        spec["settle_after"] = 1e3
    path = _write(tmp_path / "timeseries.csv", t, signals)
    ref = compute_metrics(t, signals, spec)
    for size in (1, 2, 5, 149, 150, 151, 10_000):
        _assert_same(compute_metrics_csv(path, spec, chunk_rows=size), ref)


def test_streamed_errors_name_the_culprit(tmp_path):
    t, signals = _signals(n=20)
    path = _write(tmp_path / "timeseries.csv", t, signals)
    with pytest.raises(ValueError, match=r"metrics\.control: signal 'c\.v' is not in"):
        compute_metrics_csv(path, {"lateral_error": "s.e", "control": "c.v"})
    t_bad = t.copy()
    t_bad[12] = t_bad[11]           # not strictly increasing, inside a later chunk
    bad = _write(tmp_path / "bad.csv", t_bad, signals)
    with pytest.raises(ValueError, match="strictly increasing"):
        compute_metrics_csv(bad, {"lateral_error": "s.e"}, chunk_rows=12)


def test_pairwise_sum_equals_numpy_sum():
    rng = np.random.default_rng(7)
    sizes = list(range(0, 300)) + [1023, 1024, 1025, 8191, 8192, 8193, 100_003]
    for n in sizes:
        values = rng.standard_normal(n) * 10.0 ** rng.integers(-8, 8, n)
        total = PairwiseSum(n)
        cuts = np.sort(rng.integers(0, n + 1, 4)) if n else []
        for piece in np.split(values, cuts):
            total.add(piece)
        assert total.total() == float(np.sum(values)), n
    zeros = PairwiseSum(3)
    zeros.add(np.array([-0.0, -0.0, -0.0]))
    assert math.copysign(1, zeros.total()) == math.copysign(1, np.sum([-0.0, -0.0, -0.0]))
    short = PairwiseSum(5)
    short.add(np.ones(4))
    with pytest.raises(ValueError, match="fewer"):
        short.total()
    with pytest.raises(ValueError, match="more"):
        short.add(np.ones(2))


def test_iter_timeseries_concatenates_to_read_timeseries(tmp_path):
    t, signals = _signals(n=101)
    path = _write(tmp_path / "timeseries.csv", t, signals)
    t_all, s_all = read_timeseries(path, ["s.e", "v.x"])
    chunks = list(iter_timeseries(path, ["s.e", "v.x"], chunk_rows=10))
    assert [c[0].size for c in chunks] == [10] * 10 + [1]
    assert np.array_equal(np.concatenate([c[0] for c in chunks]), t_all)
    for name in ("s.e", "v.x"):
        assert np.array_equal(np.concatenate([c[1][name] for c in chunks]), s_all[name])
    assert count_rows(path) == 101
    cut = tmp_path / "cut.csv"      # a process that died mid-line: the piece counts as a row
    cut.write_bytes(path.read_bytes()[:-7])
    assert count_rows(cut) == 101
    cut.write_bytes(b"time,a\n")
    assert count_rows(cut) == 0


LATERAL = ["max", "mean", "rms", "signed_mean", "std", "settling_time", "settled_max",
           "settled_mean", "settled_rms", "settled_signed_mean", "settled_std", "overshoot",
           "overshoot_ratio"]
#: The keys of a result of SPEC, in order (as metrics.json and summary.csv write them).
KEYS = ["duration", *(f"lateral_error_{m}" for m in LATERAL),
        *(f"path_error_{m}" for m in LATERAL), "heading_error_rms", "heading_error_max",
        "steering_angle_peak", "steering_angle_rms", "steering_rate_peak",
        "steering_rate_rms", "control_effort", "control_peak", "control_rms"]


@pytest.mark.parametrize("finite", [True, False])
def test_keys_in_a_fixed_order_with_and_without_finite_samples(tmp_path, finite):
    t, signals = _signals()
    if not finite:  # every signal has a NaN: all its metrics None
        signals = {name: np.where(np.arange(t.size) == 100, np.nan, values)
                   for name, values in signals.items()}
    saturation = ["saturated_time", "saturated_fraction"] if finite else \
        ["saturated_fraction", "saturated_time"]
    path = _write(tmp_path / "timeseries.csv", t, signals)
    for result in (compute_metrics(t, signals, SPEC), compute_metrics_csv(path, SPEC)):
        assert list(result) == KEYS + saturation
        assert result["duration"] == t[-1] - t[0]
        assert all((value is not None) == finite for key, value in result.items()
                   if key != "duration"), result
