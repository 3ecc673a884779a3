"""The report page (agv_cosim.report.page) and the comparison styles of agv_cosim.report.plots."""

import html
import json
import math
import re

import numpy as np
import pytest

from agv_cosim import cli
from agv_cosim.report.page import RECORD, metric_unit, read_runs, summary_table
from agv_cosim.report.plots import (
    LEGEND_CAP,
    RunData,
    montecarlo_figure,
    run_styles,
    signals_figure,
    spearman,
    sweep_metrics_figure,
    trajectory_figure,
)

SWEEP12 = """
[variants.one.components.gain2]
parameters = { k = 1.0 }
[variants.two.components.gain2]
parameters = { k = 2.0 }
[sweep]
"gain.k" = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
[metrics]
lateral_error = "int.y"
[plots]
title = "chain sweep"
signals = ["int.y", "gain.y"]
"""

MC = """
[metrics]
lateral_error = "int.y"
[plots]
signals = ["int.y"]
[montecarlo]
samples = 20
seed = 7
[montecarlo.parameters]
"src.slope" = { distribution = "uniform", low = 0.5, high = 1.5 }
"gain.k" = { distribution = "uniform", low = 1.0, high = 3.0 }
"""


# --------------------------------------------------------------------------- styles

def _run(label, variant=None, point=None, partial=False):
    t = np.linspace(0.0, 1.0, 11)
    return RunData(label, t, {"s.e": t.copy(), "v.x": 10.0 * t, "v.y": 0.3 + 0.0 * t},
                   partial=partial, variant=variant, point=point or {})


def test_twelve_sweep_runs_are_coloured_by_value_with_a_colour_bar():
    runs = [_run(f"{v}_{k}", v, {"gain.k": float(k)}) for v in ("a", "b")
            for k in range(1, 7)]
    styles = run_styles(runs, {"gain.k": "1"})
    assert styles.mappable is not None and styles.bar_label == "gain.k [1]"
    assert styles.bar_ticks == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    # the colour is the value's on the colour map; the line style is the variant's
    for run, style in zip(runs, styles.lines):
        assert style["color"] == styles.mappable.to_rgba(run.point["gain.k"])
        assert style["linestyle"] == ("-" if run.variant == "a" else "--")
    assert len({s["color"] for s in styles.lines}) == 6
    assert [label for _, label in styles.legend] == ["a", "b"]
    figure = signals_figure(runs, {"signals": ["s.e"]})
    assert len(figure.axes) == 2  # the signal's axes and the colour bar
    assert [t.get_text() for t in figure.legends[0].get_texts()] == ["a", "b"]


def test_fifty_samples_get_one_legend_entry_per_group():
    runs = [_run(f"{v}_mc{i}", v, {"montecarlo.sample": i, "ts.noise": 0.001 * i})
            for v in ("paper", "dr") for i in range(50)]
    styles = run_styles(runs, sampled=["ts.noise"])
    assert styles.mappable is None
    assert [label for _, label in styles.legend] == ["paper (50 runs)", "dr (50 runs)"]
    assert len({s["color"] for s in styles.lines}) == 2
    figure = signals_figure(runs, {"signals": ["s.e"]}, sampled=["ts.noise"])
    assert len(figure.legends[0].get_texts()) == 2


def test_a_legend_is_capped():
    runs = [_run(f"v{i}", f"v{i}", {"mode": f"m{i}"}) for i in range(LEGEND_CAP + 5)]
    figure = signals_figure(runs, {"signals": ["s.e"]})
    texts = [t.get_text() for t in figure.legends[0].get_texts()]
    assert len(texts) == LEGEND_CAP and texts[-1] == "... and 6 more"


def test_few_runs_keep_a_legend_entry_each():
    runs = [_run("x", point={"k": 1.0}), _run("y", point={"k": 2.0}, partial=True)]
    styles = run_styles(runs)
    assert styles.mappable is None  # two values: a legend, no colour bar
    assert [s["label"] for s in styles.lines] == ["x", "y (partial)"]


def test_trajectory_shows_the_offset_along_the_path():
    from agv_core.numerics.paths import parse_path

    runs = [_run("a"), _run("b")]
    figure = trajectory_figure(runs, {"trajectory": {"x": "v.x", "y": "v.y",
                                                     "path": "line:"}},
                               parse_path("line:"), units={"v.x": "m", "v.y": "m"})
    xy, offset = figure.axes[:2]
    assert xy.get_aspect() == 1.0 and xy.get_xlabel() == "v.x [m]"
    lines = [line for line in offset.get_lines() if len(line.get_xdata()) > 2]
    # 0.3 m to the left of the x axis along 10 m: the panel shows 0.3 at every arc length
    np.testing.assert_allclose(lines[0].get_ydata(), 0.3, atol=1e-9)
    np.testing.assert_allclose(lines[0].get_xdata(), np.linspace(0.0, 10.0, 11),
                               atol=1e-9)


def test_spearman():
    assert spearman([1, 2, 3, 4], [1, 4, 9, 16]) == pytest.approx(1.0)
    assert spearman([1, 2, 3, 4], [4, 3, 2, 1]) == pytest.approx(-1.0)
    assert spearman([1, 2], [1, 2]) is None
    assert spearman([1, 1, 1], [1, 2, 3]) is None


def test_comparison_figures_draw_the_values_given():
    rows = [{"variant": v, "point": {"k": float(k)}, "status": "complete",
             "metrics": {"m": k * (2 if v == "b" else 1)}} for v in "ab" for k in (3, 1, 2)]
    figure = sweep_metrics_figure(rows, "k", ["m"], {"m": "m", "k": "1"})
    lines = figure.axes[0].get_lines()
    assert [line.get_label() for line in lines] == ["a", "b"]
    np.testing.assert_array_equal(lines[1].get_xdata(), [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(lines[1].get_ydata(), [2, 4, 6])
    assert figure.axes[0].get_ylabel() == "m [m]"
    mc = [{"group": "g", "point": {"p": float(i)}, "status": "complete",
           "metrics": {"m": float(i * i)}} for i in range(10)]
    figure = montecarlo_figure(mc, ["p"], ["m"], {"m": "cm"})
    box, scatter = figure.axes[:2]
    assert box.get_ylabel() == "m [cm]"
    assert any(t.get_text() == "rho = +1.00" for t in scatter.texts)


def test_metric_units():
    spec = {"lateral_error": "s.e", "control": "c.u", "reference": {"x": "v.x"}}
    units = {"s.e": "m", "c.u": "V", "v.x": "m"}
    assert metric_unit("lateral_error_max", spec, units) == "m"
    assert metric_unit("lateral_error_settling_time", spec, units) == "s"
    assert metric_unit("lateral_error_overshoot_ratio", spec, units) == "1"
    assert metric_unit("path_error_rms", spec, units) == "m"
    assert metric_unit("heading_error_max", {}, {}) == "rad"
    assert metric_unit("steering_rate_peak", {}, {}) == "rad/s"
    assert metric_unit("control_effort", spec, units) == "(V)^2 s"
    assert metric_unit("control_peak", {}, {}) is None
    assert metric_unit("something_else", spec, units) is None


def test_metric_units_of_a_damaged_metrics_table_are_the_documented_ones():
    """A manifest.toml copy whose [metrics] names a signal by something other than text
    (before: TypeError, unhashable list, and no page): the documented unit."""
    spec = {"lateral_error": ["s.e"], "reference": {"x": ["v.x"]}, "control": 3}
    units = {"s.e": "mm", "v.x": "mm"}
    assert metric_unit("lateral_error_max", spec, units) == "m"
    assert metric_unit("path_error_rms", spec, units) == "m"
    assert metric_unit("control_peak", spec, units) is None


def test_summary_table():
    runs = [{"label": "a" * 60, "status": "complete",
             "metrics": {"lateral_error_max": 0.123456, "other": 1.0}},
            {"label": "b", "status": "failed", "metrics": {}}]
    lines = summary_table(runs, {"lateral_error_max": "m"}, width=100).splitlines()
    assert lines[0].split() == ["run", "status", "lateral_error_max", "[m]", "other"]
    assert "0.1235" in lines[1] and lines[2].startswith("b ")
    assert max(map(len, lines)) <= 100
    # narrower: the metrics that do not fit are left out, the label is cut
    lines = summary_table(runs, {"lateral_error_max": "m"}, width=70).splitlines()
    assert lines[0].split() == ["run", "status", "lateral_error_max", "[m]"]
    assert max(map(len, lines)) <= 70 and "…" in lines[1]



def test_summary_columns_are_the_same_whatever_values_differ():
    """The terminal's columns depend on the metrics' names only: one run, two runs that
    differ in one metric or in another, all show the same columns in the same order (the
    manifest's [metrics] signals first, in its order; then MAIN_METRICS)."""
    base = {"heading_error_max": 0.2, "lateral_error_rms": 0.05, "steering_angle_peak": 0.3,
            "lateral_error_max": 0.1}

    def columns(*changes, manifest=None):
        runs = [{"label": f"r{k}", "status": "complete", "metrics": {**base, **change}}
                for k, change in enumerate(changes)]
        return summary_table(runs, width=200, manifest=manifest).splitlines()[0].split()

    expected = ["run", "status", "lateral_error_max", "lateral_error_rms",
                "heading_error_max", "steering_angle_peak"]
    assert columns({}) == expected
    assert columns({}, {"lateral_error_max": 0.2}) == expected
    assert columns({}, {"steering_angle_peak": 0.4}) == expected
    spec = {"metrics": {"steering_angle": "act.alpha", "lateral_error": "sensor.e",
                        "settle_band": 0.05}}
    assert columns({}, {"heading_error_max": 1.0}, manifest=spec) == [
        "run", "status", "steering_angle_peak", "lateral_error_max", "lateral_error_rms",
        "heading_error_max"]

# --------------------------------------------------------------------------- the page

def _images(page):
    return re.findall(r'<img src="([^"]+)"', page)


@pytest.mark.slow  # runs FMUs
def test_report_of_a_sweep(chain, tmp_path, capsys):
    path = chain(extra=SWEEP12)
    out = tmp_path / "out"
    assert cli.main(["run", str(path), "--out", str(out)]) == 0
    page = (out / "index.html").read_text(encoding="utf-8")
    runs = read_runs(out)
    assert len(runs) == 12
    # the terminal: a table of the main metrics per run, then the one-line summary
    captured = capsys.readouterr()
    assert "report:" not in captured.err  # the page was written without a problem
    printed = captured.out.splitlines()
    assert printed[0].split()[:2] == ["run", "status"] and "[1]" in printed[0]
    assert len(printed) == 1 + 12 + 1 and printed[-1].endswith("12/12 run(s) complete")
    for line, run in zip(printed[1:], runs):
        label, status, first = line.split()[:3]
        assert (label, status) == (run["folder"], "complete")
        name = printed[0].split()[2]
        assert float(first) == pytest.approx(run["metrics"][name], rel=1e-3)
    for run in runs:  # every run, with its metrics' exact values
        assert html.escape(run["folder"]) in page
        value = run["metrics"]["lateral_error_max"]
        assert f'title="{value!r}"' in page
    # int.y is in [1]; the header wraps at its underscores and links to the definition
    assert ("lateral_<wbr>error_<wbr>max <span class=unit>[1]</span> "
            '<a class=def href="#metric-lateral_error_max"') in page
    for name in runs[0]["metrics"]:  # every metric's column links to its definition
        assert page.count(f'href="#metric-{name}"') >= 1
        assert page.count(f'<tr id="metric-{name}">') == 1
    assert "<p class=\"description\">" not in page  # the chain has no description
    images = _images(page)
    assert images[:2] == ["signals.png", "sweep_metrics.png"]
    for name in images:
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert json.loads((out / RECORD).read_text())["files"] == ["index.html",
                                                               "sweep_metrics.png"]
    assert "http://" not in page and "https://" not in page  # nothing from the network
    # rebuilt from the folder: the same bytes
    before = {name: (out / name).read_bytes() for name in ("index.html",
                                                           "sweep_metrics.png")}
    capsys.readouterr()
    assert cli.main(["report", str(out)]) == 0
    assert capsys.readouterr().out.strip() == str(out / "index.html")
    assert {name: (out / name).read_bytes() for name in before} == before


@pytest.mark.slow  # runs FMUs
def test_report_replaces_only_its_own_files(chain, tmp_path, capsys):
    path = chain(extra=SWEEP12.replace('"gain.k" = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]',
                                       '"gain.k" = [1.0, 2.0, 3.0]'))
    out = tmp_path / "out"
    assert cli.main(["run", str(path), "--out", str(out), "--quiet"]) == 0
    assert capsys.readouterr().out == ""  # --quiet: no table, no summary line
    # a page the report did not write (no record of it) is never replaced
    (out / RECORD).unlink()
    (out / "sweep_metrics.png").unlink()
    (out / "index.html").unlink()
    (out / "index.html").write_text("mine")
    capsys.readouterr()
    assert cli.main(["report", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "index.html: exists and was not written by" in err
    assert (out / "index.html").read_text() == "mine"
    assert not (out / RECORD).exists()
    (out / "index.html").unlink()
    assert cli.main(["report", str(out)]) == 0
    # a file of the record that became a symbolic link is not written through
    outside = tmp_path / "outside.html"
    outside.write_text("keep")
    (out / "index.html").unlink()
    (out / "index.html").symlink_to(outside)
    capsys.readouterr()
    assert cli.main(["report", str(out)]) == 2
    assert "index.html: exists and was not written" in capsys.readouterr().err
    assert outside.read_text() == "keep"
    # a folder without our marker is refused
    other = tmp_path / "other"
    other.mkdir()
    assert cli.main(["report", str(other)]) == 2
    assert "not a result folder of agv-cosim" in capsys.readouterr().err
    assert list(other.iterdir()) == []


@pytest.mark.slow  # runs FMUs
def test_report_of_a_montecarlo_run(chain, tmp_path):
    path = chain(extra=MC)
    out = tmp_path / "mc"
    assert cli.main(["run", str(path), "--out", str(out), "--quiet"]) == 0
    page = (out / "index.html").read_text(encoding="utf-8")
    assert "montecarlo_scatter.png" in _images(page)
    assert "<h2 id=montecarlo>Monte Carlo</h2>" in page
    stats = json.loads((out / "montecarlo.json").read_text())
    mean = stats["groups"]["base"]["metrics"]["lateral_error_max"]["mean"]
    assert f'title="{mean!r}"' in page
    assert len(read_runs(out)) == 20
    assert math.isfinite(mean)


# --------------------------------------------------------------------------- SSP runs

@pytest.mark.slow  # runs FMUs
def test_an_exported_experiment_keeps_its_metrics_and_plots(chain, tmp_path):
    import zipfile

    path = chain(extra=SWEEP12.split("[sweep]")[0].replace(
        '[variants.two.components.gain2]\nparameters = { k = 2.0 }\n', "") +
        SWEEP12.split('"gain.k" = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]')[1])
    package = tmp_path / "chain.ssp"
    assert cli.main(["export-ssp", str(path), "-o", str(package)]) == 0
    direct, via_ssp = tmp_path / "direct", tmp_path / "ssp"
    assert cli.main(["run", str(path), "--out", str(direct), "--quiet"]) == 0
    assert cli.main(["run", str(package), "--out", str(via_ssp), "--quiet"]) == 0
    # the same metrics, the same figure, and a report
    assert json.loads((via_ssp / "base" / "metrics.json").read_text()) == \
        json.loads((direct / "one" / "metrics.json").read_text())
    assert (via_ssp / "signals.png").is_file() and (via_ssp / "index.html").is_file()
    assert "lateral_error_max" in (via_ssp / "summary.csv").read_text().splitlines()[0]
    # a package without our annotation: its Real outputs are plotted, nothing measured
    stripped = tmp_path / "foreign.ssp"
    with zipfile.ZipFile(package) as source, zipfile.ZipFile(stripped, "w") as target:
        for item in source.infolist():
            data = source.read(item)
            if item.filename == "SystemStructure.ssd":
                text = data.decode()
                text = re.sub(r'<ssc:Annotation type="org.agv-cosim">.*?</ssc:Annotation>',
                              "", text, flags=re.S)
                assert "agv:" not in text
                data = text.encode()
            target.writestr(item, data)
    foreign = tmp_path / "foreign"
    assert cli.main(["run", str(stripped), "--out", str(foreign), "--quiet"]) == 0
    assert (foreign / "signals.png").is_file()
    from agv_cosim.ssp.importer import opened

    with opened(stripped) as manifest:
        assert manifest.plots.signals == ["src.y", "src.t_out", "gain.y", "gain2.y",
                                          "int.y"]  # Real outputs; not src.count
        assert manifest.metrics is None


def test_sweep_metrics_mark_runs_without_a_value():
    # b's run at k = 3 never settled (its settling time is empty), a's at k = 2 failed:
    # each is an open triangle on the top edge in its line's colour, the panel says so
    rows = [{"variant": v, "point": {"k": float(k)}, "status":
             "failed" if (v, k) == ("a", 2) else "complete",
             "metrics": {} if (v, k) == ("a", 2) else
             {"lateral_error_settling_time": None if (v, k) == ("b", 3) else float(k)}}
            for v in "ab" for k in (1, 2, 3)]
    figure = sweep_metrics_figure(rows, "k", ["lateral_error_settling_time"], {})
    ax = figure.axes[0]
    marks = [line for line in ax.get_lines() if line.get_marker() == "v"]
    assert [(list(m.get_xdata()), list(m.get_ydata())) for m in marks] == \
        [([2.0], [1.0]), ([3.0], [1.0])]
    lines = [line for line in ax.get_lines() if line.get_marker() == "o"]
    assert [line.get_color() for line in lines] == [m.get_color() for m in marks]
    assert marks[0].get_transform() == ax.get_xaxis_transform()
    assert "did not settle" in ax.get_title(loc="right")


def test_trajectory_without_path_scales_to_what_moved():
    # 0.1 m of lateral deviation over 16 m of travel: with equal axes a flat line
    t = np.linspace(0.0, 16.0, 161)
    runs = [RunData("a", t, {"v.x": t - 8.0, "v.y": 0.1 * np.sin(t)})]
    figure = trajectory_figure(runs, {"trajectory": {"x": "v.x", "y": "v.y"}})
    ax = figure.axes[0]
    assert ax.get_aspect() == "auto" and "not to scale" in ax.get_title(loc="right")
    low, high = ax.get_ylim()
    assert high - low < 0.3  # the deviation fills the panel's height
    # a path that moves in both directions keeps equal axes
    runs = [RunData("a", t, {"v.x": t - 8.0, "v.y": 3.0 * np.sin(t / 5)})]
    figure = trajectory_figure(runs, {"trajectory": {"x": "v.x", "y": "v.y"}})
    assert figure.axes[0].get_aspect() == 1.0


def test_a_run_that_never_settles_says_so():
    """Terminal and page write "did not settle" for the settling metrics of a run whose
    error never settled; another empty value is not called so."""
    from agv_cosim.report.page import _metric_cell

    never = {"lateral_error_max": 0.3, "lateral_error_settling_time": None,
             "lateral_error_settled_rms": None, "lateral_error_overshoot": None}
    settled = {"lateral_error_max": 0.1, "lateral_error_settling_time": 2.5,
               "lateral_error_settled_rms": 0.01, "lateral_error_overshoot": None}
    runs = [{"label": "never", "status": "complete", "metrics": never},
            {"label": "settled", "status": "complete", "metrics": settled},
            {"label": "failed", "status": "failed", "metrics": {}}]
    lines = summary_table(runs, {"lateral_error_settling_time": "s"}, count=3,
                          width=120).splitlines()
    assert lines[0].split()[2:] == ["lateral_error_max", "lateral_error_settling_time",
                                    "[s]", "lateral_error_overshoot"]
    assert "did not settle" in lines[1] and "2.5" in lines[2]
    assert "did not settle" not in lines[2] + lines[3]
    assert "did not settle" in _metric_cell("lateral_error_settled_rms", never)
    assert "did not settle" in _metric_cell("lateral_error_settling_time", never)
    overshoot = _metric_cell("lateral_error_overshoot", settled)
    assert "did not settle" not in overshoot and "e(t_0) = 0" in overshoot
    assert _metric_cell("lateral_error_settling_time", {}) == "<td></td>"
