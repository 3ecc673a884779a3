"""Tests of agv_cosim.plots: figure content, files, determinism, spec errors, an FMU run."""

import math

import numpy as np
import pytest
from matplotlib.image import imread

from agv_cosim.report.plots import (RunData, plot_runs, referenced_signals, signals_figure,
                             trajectory_figure)


def _has_paths():
    try:
        import agv_core.numerics.paths  # noqa: F401
    except ImportError:
        return False
    return True


def _runs():
    t = np.linspace(0.0, 10.0, 501)
    full = RunData("Ke=1", t, {"s.e": 0.5 * np.exp(-t), "v.h": 0.1 * np.sin(t),
                               "v.x": t, "v.y": 0.5 * np.exp(-t), "v.d": 2.0 * t})
    tp = t[:200]
    part = RunData("Ke=4", tp, {"s.e": -0.2 * np.exp(-tp), "v.h": 0.1 * np.cos(tp),
                                "v.x": tp, "v.y": -0.2 * np.exp(-tp), "v.d": 2.0 * tp},
                   partial=True)
    return [full, part]


SPEC = {"title": "demo", "signals": ["s.e", "v.h"], "units": {"s.e": "m"},
        "trajectory": {"x": "v.x", "y": "v.y"}}


def test_signals_figure_content():
    runs = _runs()
    figure = signals_figure(runs, SPEC)
    axes = figure.axes
    assert len(axes) == 2                       # one subplot per signal
    assert axes[0].get_ylabel() == "s.e [m]"    # unit from `units`
    assert axes[1].get_ylabel() == "v.h"        # no unit given
    assert axes[1].get_xlabel() == "time [s]"
    lines = axes[0].get_lines()
    assert [line.get_label() for line in lines] == ["Ke=1", "Ke=4 (partial)"]
    assert [line.get_linestyle() for line in lines] == ["-", "--"]
    # the data drawn are the data given, unchanged
    np.testing.assert_array_equal(lines[1].get_ydata(), runs[1].signals["s.e"])
    np.testing.assert_array_equal(lines[1].get_xdata(), runs[1].time)
    assert figure.get_suptitle() == "demo"
    assert [text.get_text() for text in figure.legends[0].get_texts()] == [
        "Ke=1", "Ke=4 (partial)"]


def test_signals_against_another_signal():
    runs = _runs()
    figure = signals_figure(runs, {"signals": ["s.e"], "x": "v.d", "units": {"v.d": "m"}})
    ax = figure.axes[0]
    assert ax.get_xlabel() == "v.d [m]"
    np.testing.assert_array_equal(ax.get_lines()[0].get_xdata(), runs[0].signals["v.d"])


def test_trajectory_figure_without_path():
    runs = _runs()
    figure = trajectory_figure(runs, SPEC)
    ax = figure.axes[0]
    assert ax.get_aspect() == 1.0               # "equal"
    assert [line.get_label() for line in ax.get_lines()] == ["Ke=1", "Ke=4 (partial)"]
    np.testing.assert_array_equal(ax.get_lines()[0].get_ydata(), runs[0].signals["v.y"])


@pytest.mark.skipif(not _has_paths(), reason="agv_core.paths not available yet")
def test_trajectory_reference_path_is_drawn(tmp_path):
    from agv_core.numerics.paths import parse_path

    # seed 004's sine y = 2 sin(x / 3): wavelength 6 pi
    path = f"sine:amplitude=2,wavelength={6 * math.pi!r}"
    runs = _runs()
    spec = {"trajectory": {"x": "v.x", "y": "v.y", "path": path}}
    figure = trajectory_figure(runs, spec, parse_path(path))
    reference = figure.axes[0].get_lines()[0]
    assert reference.get_label() == "reference path"
    x, y = reference.get_xdata(), reference.get_ydata()
    # drawn from s = 0 to (about) the furthest run point, x = 10 m: the polyline points lie
    # on the curve to the path module's 1e-9 m accuracy
    np.testing.assert_allclose(y, 2.0 * np.sin(x / 3.0), atol=1e-8)
    assert x[0] == pytest.approx(0.0, abs=1e-12)
    # the last projected point is within one subsample step (0.2 m) of x = 10
    assert x[-1] == pytest.approx(10.0, abs=0.25)
    written = plot_runs(runs, spec, tmp_path)
    assert written == [tmp_path / "trajectory.png"]


@pytest.mark.parametrize("fmus", [["x"], "x", 3])
def test_a_run_json_whose_fmus_is_not_a_table_names_no_fmu(tmp_path, fmus):
    """A run's run.json whose ``fmus`` is not a table (before: AttributeError, no
    figure): the run's FMUs are unknown (no units from them), the figures are drawn."""
    import json

    from agv_cosim.report.plots import describe_runs

    runs = _runs()
    for run in runs:
        (tmp_path / run.label).mkdir()
        (tmp_path / run.label / "run.json").write_text(json.dumps(
            {"fmus": fmus if run is runs[0] else {"s": "s.fmu"}, "variant": "v"}))
    assert describe_runs(runs, tmp_path) == {"s": "s.fmu"}
    assert [run.variant for run in runs] == ["v", "v"]
    assert plot_runs(_runs(), SPEC, tmp_path) == [tmp_path / "signals.png",
                                                  tmp_path / "trajectory.png"]


def test_files_written_with_size_and_deterministic(tmp_path):
    runs = _runs()
    first = plot_runs(runs, dict(SPEC, dpi=100), tmp_path / "a")
    second = plot_runs(runs, dict(SPEC, dpi=100), tmp_path / "b")
    assert [p.name for p in first] == ["signals.png", "trajectory.png"]
    for a, b in zip(first, second):
        assert a.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert a.read_bytes() == b.read_bytes()     # same data, same bytes
    # signals: 8 in x (1 + 2 * 2) in at 100 dpi; trajectory 8 x 6 in
    assert imread(first[0]).shape[:2] == (500, 800)
    assert imread(first[1]).shape[:2] == (600, 800)
    assert b"Software" not in first[0].read_bytes()


def test_nothing_to_plot_writes_nothing(tmp_path):
    assert plot_runs(_runs(), {}, tmp_path / "none") == []
    assert not (tmp_path / "none").exists()


def test_referenced_signals():
    assert referenced_signals(SPEC) == ["s.e", "v.h", "v.x", "v.y"]
    assert referenced_signals({"signals": ["a.b", "v.x"], "x": "v.d",
                               "trajectory": {"x": "v.x", "y": "v.y"}}) == [
        "a.b", "v.x", "v.d", "v.y"]
    assert referenced_signals({}) == []


@pytest.mark.parametrize("spec, key", [
    ({"signal": ["a.b"]}, "plots.signal"),
    ({"signals": "a.b"}, "plots.signals"),
    ({"signals": []}, "plots.signals"),
    ({"signals": ["a.b", "nodot"]}, r"plots.signals\[1\]"),
    ({"x": "distance"}, "plots.x"),
    ({"units": ["m"]}, "plots.units"),
    ({"units": {"a.b": 1}}, "plots.units.a.b"),
    ({"title": 3}, "plots.title"),
    ({"dpi": 0}, "plots.dpi"),
    ({"dpi": 120.5}, "plots.dpi"),
    ({"trajectory": {"x": "v.x"}}, "plots.trajectory.y"),
    ({"trajectory": {"x": "v.x", "y": "v.y", "z": "v.z"}}, "plots.trajectory.z"),
    ({"trajectory": {"x": "v.x", "y": "v.y", "path": 3}}, "plots.trajectory.path"),
    ({"trajectory": "v.x"}, "plots.trajectory"),
])
def test_bad_spec_names_the_key(spec, key, tmp_path):
    pattern = key.replace(".", r"\.") + "[: ]"
    with pytest.raises(ValueError, match=pattern):
        referenced_signals(spec)
    with pytest.raises(ValueError, match=pattern):
        plot_runs(_runs(), spec, tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_missing_signal_fails_before_any_file(tmp_path):
    spec = {"signals": ["s.e"], "trajectory": {"x": "v.x", "y": "v.nope"}}
    with pytest.raises(ValueError, match=r"plots\.trajectory\.y: run 'Ke=1' has no signal"):
        plot_runs(_runs(), spec, tmp_path)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.skipif(not _has_paths(), reason="agv_core.paths not available yet")
def test_bad_path_string_names_the_key(tmp_path):
    spec = {"trajectory": {"x": "v.x", "y": "v.y", "path": "spiral:r=1"}}
    with pytest.raises(ValueError, match=r"plots\.trajectory\.path"):
        plot_runs(_runs(), spec, tmp_path)


def test_plot_a_vehicle_fmu_run(component_fmus, tmp_path):
    """Two vehicle-FMU runs through fmpy (one cut short as partial) end up in the files."""
    from fmpy import simulate_fmu

    fmu = component_fmus["agv_vehicle"]
    runs = []
    for label, alpha, stop in (("alpha=0.1", 0.1, 6.0), ("alpha=0.2", 0.2, 3.0)):
        result = simulate_fmu(str(fmu), stop_time=stop, step_size=0.02, output_interval=0.02,
                              start_values={"alpha": alpha}, output=["x", "y", "heading"])
        signals = {f"vehicle.{name}": np.asarray(result[name])
                   for name in ("x", "y", "heading")}
        runs.append(RunData(label, np.asarray(result["time"]), signals,
                            partial=stop < 6.0))
    spec = {"signals": ["vehicle.heading"], "units": {"vehicle.heading": "rad"},
            "trajectory": {"x": "vehicle.x", "y": "vehicle.y"}}
    written = plot_runs(runs, spec, tmp_path / "plots")
    assert [p.name for p in written] == ["signals.png", "trajectory.png"]
    figure = signals_figure(runs, spec)
    line = figure.axes[0].get_lines()[0]
    # constant alpha: heading = v tan(alpha) / L t exactly (arc integration), v = L = 1
    np.testing.assert_allclose(line.get_ydata(), math.tan(0.1) * line.get_xdata(),
                               atol=1e-12)
    assert figure.axes[0].get_lines()[1].get_linestyle() == "--"
