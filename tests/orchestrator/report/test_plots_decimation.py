"""Plots of long runs: M4 decimation keeps each bucket's min and max (peaks stay), gives
the same points however the samples are chunked, and read_run (chunked CSV) equals the
in-memory decimation."""

import numpy as np
import pytest

from agv_cosim.report.plots import Decimator, RunData, read_run, signals_figure, trajectory_figure
from agv_cosim.timeseries import CsvSink

SPEC = {"signals": ["s.e", "s.u"], "dpi": 10, "trajectory": {"x": "v.x", "y": "v.y"}}


def _signal(n, seed=5):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.01
    y = np.sin(t) + 0.05 * rng.standard_normal(n)
    y[n // 3] = 7.0             # a one-sample spike
    y[2 * n // 3] = -5.0
    return t, y


def test_each_bucket_keeps_its_min_max_first_last():
    n, buckets = 10_007, 50
    t, y = _signal(n)
    decimator = Decimator(n, buckets)
    decimator.add(t, y)
    x_kept, y_kept = decimator.result()
    size = -(-n // buckets)
    assert decimator.size == size and x_kept.size <= 4 * buckets < n
    for start in range(0, n, size):
        inside = (x_kept >= t[start]) & (x_kept <= t[min(start + size, n) - 1])
        chunk = y[start:start + size]
        kept = y_kept[inside]
        assert kept.max() == chunk.max() and kept.min() == chunk.min()
        assert kept[0] == chunk[0] and kept[-1] == chunk[-1]
    assert np.all(np.diff(x_kept) > 0)      # kept in their order
    assert y_kept.max() == 7.0 and y_kept.min() == -5.0


def test_short_lines_are_kept_whole():
    t, y = _signal(200)
    decimator = Decimator(200, 50)          # 200 <= 4 * 50: nothing to gain
    decimator.add(t, y)
    assert np.array_equal(decimator.result()[1], y)


@pytest.mark.parametrize("both", [False, True])
def test_chunked_feed_equals_whole_feed(both):
    n, buckets = 5_003, 40
    t, y = _signal(n)
    x = np.cos(t) * t if both else t
    whole = Decimator(n, buckets, both)
    whole.add(x, y)
    expected = whole.result()
    size = whole.size
    for chunk in (1, 2, 7, size - 1, size, size + 1, 999, n):
        parts = Decimator(n, buckets, both)
        for i in range(0, n, chunk):
            parts.add(x[i:i + chunk], y[i:i + chunk])
        got = parts.result()
        assert np.array_equal(got[0], expected[0]) and np.array_equal(got[1], expected[1])


def test_trajectory_keeps_the_extremes_of_x_and_y():
    n = 20_000
    t = np.linspace(0.0, 40.0 * np.pi, n)
    x, y = 10.0 * np.cos(t), 10.0 * np.sin(t)
    x[12_345] = 13.0
    decimator = Decimator(n, 100, both=True)
    decimator.add(x, y)
    kx, ky = decimator.result()
    assert kx.size <= 600 and kx.max() == 13.0 and ky.max() == y.max() and ky.min() == y.min()


def test_read_run_equals_in_memory_decimation(tmp_path):
    n = 3_001
    t, e = _signal(n)
    signals = {"s.e": e, "s.u": -e, "v.x": t, "v.y": np.sin(3 * t)}
    sink = CsvSink(tmp_path / "timeseries.csv", list(signals))
    for row in zip(t, *signals.values()):
        sink.write(row)
    sink.close()
    memory = RunData("r", t, signals)
    streamed = read_run(tmp_path / "timeseries.csv", SPEC, "r", chunk_rows=97)
    assert streamed.time.size == 0 and len(streamed.lines) == 3
    for make in (signals_figure, trajectory_figure):
        a, b = make([memory], SPEC), make([streamed], SPEC)
        for ax_a, ax_b in zip(a.axes, b.axes):
            for line_a, line_b in zip(ax_a.get_lines(), ax_b.get_lines()):
                assert np.array_equal(line_a.get_xdata(), line_b.get_xdata())
                assert np.array_equal(line_a.get_ydata(), line_b.get_ydata())
    # dpi 10: 2 buckets per column of 80, at most 4 points each; the spike is drawn
    line = signals_figure([streamed], SPEC).axes[0].get_lines()[0]
    assert len(line.get_ydata()) <= 4 * 160 < n and max(line.get_ydata()) == 7.0
    with pytest.raises(ValueError, match=r"plots\.signals\[1\]: run 'r' has no signal 's\.w'"):
        read_run(tmp_path / "timeseries.csv", {"signals": ["s.e", "s.w"]}, "r")


def test_only_figures_with_decimated_lines_are_drawn_in_chunks(tmp_path):
    from agv_cosim.report.plots import plot_runs

    long_t, long_y = _signal(5_000)
    short = RunData("short", long_t[:300], {"s.e": long_y[:300], "s.u": long_y[:300]})
    long = RunData("long", long_t, {"s.e": long_y, "s.u": -long_y})
    spec = {"signals": ["s.e", "s.u"], "dpi": 10}
    assert not getattr(signals_figure([short], spec), "agv_decimated", False)
    assert signals_figure([short, long], spec).agv_decimated
    (written,) = plot_runs([short, long], spec, tmp_path)
    assert written.stat().st_size > 0
