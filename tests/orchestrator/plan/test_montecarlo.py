"""Monte Carlo runs (issue 16): distributions, seed derivation, common random numbers
across variants, montecarlo.json checked against summary.csv, and one-line errors."""

import csv
import json
import math
import re
import statistics

import numpy as np
import pytest
from scipy import stats

from agv_cosim.cli import main
from agv_cosim.manifest import ManifestError, load_manifest
from agv_cosim.manifest import montecarlo as montecarlo_table
from agv_cosim.plan import plan_runs
from agv_cosim.plan import sampling as montecarlo


def _unplaced(text):
    """``text`` without the manifest's line number (``m.toml:12: key`` -> ``m.toml: key``;
    the positions are tested in test_cli_errors)."""
    return re.sub(r"\.toml:\d+: ", ".toml: ", text)


def _mc(parameters, samples=4096, seed=7, design="random", seeds=()):
    return montecarlo_table.parse("m.toml", {"samples": samples, "seed": seed, "design": design,
                                       "parameters": parameters, "seeds": list(seeds)})


def _column(mc, name):
    return np.asarray([sample[name] for sample in montecarlo.draw(mc)])


# --- distributions: moments and bounds ------------------------------------------------
# Tolerances: 4 standard errors of the sample mean (sigma / sqrt(n)) and of the sample
# std (about sigma / sqrt(2 n)) for n = 4096 random draws: a false failure has a
# probability of about 6e-5 per check, and the draws are fixed by the seed anyway.

def test_normal_has_its_mean_and_std():
    x = _column(_mc({"c.p": {"distribution": "normal", "mean": 2.0, "std": 0.5}}), "c.p")
    n = x.size
    assert abs(x.mean() - 2.0) < 4 * 0.5 / math.sqrt(n)
    assert abs(x.std(ddof=1) - 0.5) < 4 * 0.5 / math.sqrt(2 * n)


def test_uniform_stays_in_its_bounds_with_its_moments():
    x = _column(_mc({"c.p": {"distribution": "uniform", "low": -1.0, "high": 3.0}}), "c.p")
    sigma = 4.0 / math.sqrt(12.0)
    assert x.min() >= -1.0 and x.max() < 3.0
    assert abs(x.mean() - 1.0) < 4 * sigma / math.sqrt(x.size)
    assert abs(x.std(ddof=1) - sigma) < 4 * sigma / math.sqrt(2 * x.size)


def test_truncated_normal_is_bounded_with_scipys_moments():
    spec = {"distribution": "truncnormal", "mean": 0.1, "std": 0.05, "low": 0.0,
            "high": 0.25}
    x = _column(_mc({"c.p": spec}), "c.p")
    exact = stats.truncnorm((0.0 - 0.1) / 0.05, (0.25 - 0.1) / 0.05, loc=0.1, scale=0.05)
    assert x.min() >= 0.0 and x.max() <= 0.25
    assert abs(x.mean() - exact.mean()) < 4 * exact.std() / math.sqrt(x.size)
    assert abs(x.std(ddof=1) - exact.std()) < 4 * exact.std() / math.sqrt(2 * x.size)
    # the truncation matters: the untruncated mean would be 0.1 exactly
    assert exact.mean() > 0.1 + 1e-3


def test_choice_frequencies_follow_the_weights():
    spec = {"distribution": "choice", "values": ["a", 2, 3.5], "weights": [1, 2, 1]}
    x = [sample["c.p"] for sample in montecarlo.draw(_mc({"c.p": spec}))]
    assert set(x) == {"a", 2, 3.5}
    for value, p in (("a", 0.25), (2, 0.5), (3.5, 0.25)):
        # 4 binomial standard errors
        assert abs(x.count(value) / len(x) - p) < 4 * math.sqrt(p * (1 - p) / len(x))


def test_latin_hypercube_puts_one_sample_in_each_stratum():
    mc = _mc({"c.a": {"distribution": "uniform", "low": 0.0, "high": 1.0},
              "c.b": {"distribution": "uniform", "low": 0.0, "high": 1.0}},
             samples=50, design="lhs")
    u = montecarlo.unit_samples(mc)
    for j in range(2):  # exactly one point in each of the 50 intervals of each axis
        assert sorted(np.floor(u[:, j] * 50).astype(int)) == list(range(50))


def test_sobol_mean_is_far_closer_than_random_sampling():
    # scrambled Sobol of 1024 points: the mean of each coordinate is within 1e-3 of 1/2;
    # random sampling's standard error there is 0.009
    mc = _mc({f"c.p{j}": {"distribution": "uniform", "low": 0.0, "high": 1.0}
              for j in range(3)}, samples=1024, design="sobol")
    u = montecarlo.unit_samples(mc)
    assert u.shape == (1024, 3) and u.min() >= 0.0 and u.max() < 1.0
    assert np.all(np.abs(u.mean(axis=0) - 0.5) < 1e-3)


# --- seeds ------------------------------------------------------------------------------

def test_run_seeds_are_reproducible_and_depend_only_on_seed_and_index():
    mc8 = _mc({}, samples=8, seeds=["a.seed", "b.seed"])
    mc4 = _mc({}, samples=4, seeds=["a.seed", "b.seed"])
    first = montecarlo.run_seeds(mc8)
    assert first == montecarlo.run_seeds(mc8)
    assert montecarlo.run_seeds(mc4) == first[:4]  # more samples do not change earlier ones
    values = [s[name] for s in first for name in ("a.seed", "b.seed")]
    assert len(set(values)) == len(values)
    assert all(isinstance(v, int) and 0 <= v < 2 ** 31 for v in values)
    # the derivation is SeedSequence(seed) -> child 1 -> child i -> generate_state
    child = np.random.SeedSequence(7).spawn(2)[1].spawn(8)[5]
    assert [int(v >> 1) for v in child.generate_state(2, dtype=np.uint32)] == \
        [first[5]["a.seed"], first[5]["b.seed"]]
    other = montecarlo.run_seeds(_mc({}, samples=8, seed=8, seeds=["a.seed", "b.seed"]))
    assert other != first


def test_draws_are_the_same_on_every_call():
    mc = _mc({"c.p": {"distribution": "normal", "mean": 0.0, "std": 1.0}}, samples=16,
             design="sobol", seeds=["c.seed"])
    assert montecarlo.draw(mc) == montecarlo.draw(mc)


# --- manifests ----------------------------------------------------------------------------

MC = """
[variants.low]
[variants.low.components.gain]
parameters = {{ k = 1.0 }}
[variants.high]
[variants.high.components.gain]
parameters = {{ k = 4.0 }}

[metrics]
lateral_error = "gain.y"

[montecarlo]
samples = {samples}
seed = 11
design = "lhs"
seeds = ["int.seed_unused"]

[montecarlo.parameters]
"src.offset" = {{ distribution = "normal", mean = 1.0, std = 0.2 }}
"src.slope" = {{ distribution = "choice", values = [1.0, 2.0, 3.0] }}
"""


def test_variants_share_the_same_samples(chain):
    path = chain(extra=MC.format(samples=5).replace('seeds = ["int.seed_unused"]\n', ""))
    manifest = load_manifest(path)
    runs = plan_runs(manifest)
    assert [r.label for r in runs] == [f"{v}__mc{i:04d}" for v in ("low", "high")
                                       for i in range(5)]
    low, high = runs[:5], runs[5:]
    for a, b in zip(low, high):
        assert a.point == b.point  # common random numbers: same sample i in each variant
        assert a.components["src"].parameters == b.components["src"].parameters
        assert (a.components["gain"].parameters["k"], b.components["gain"].parameters["k"]) \
            == (1.0, 4.0)
    offsets = [r.components["src"].parameters["offset"] for r in low]
    assert len(set(offsets)) == 5


def test_montecarlo_json_matches_summary_csv(chain, tmp_path):
    """The statistics recomputed from summary.csv with the statistics module."""
    path = chain(stop=0.5, extra=MC.format(samples=6).replace(
        'seeds = ["int.seed_unused"]\n', ""))
    out = tmp_path / "out"
    assert main(["run", str(path), "--out", str(out), "--quiet"]) == 0
    with open(out / "summary.csv", newline="") as stream:
        rows = list(csv.DictReader(stream))
    assert len(rows) == 12
    assert {"montecarlo.sample", "src.offset", "src.slope"} <= set(rows[0])
    report = json.loads((out / "montecarlo.json").read_text())
    assert report["samples"] == 6 and report["design"] == "lhs"
    for variant in ("low", "high"):
        group = report["groups"][variant]
        mine = [row for row in rows if row["variant"] == variant]
        assert group["runs"] == 6 and group["failed_runs"] == 0
        for metric in ("lateral_error_max", "lateral_error_rms"):
            values = sorted(float(row[metric]) for row in mine)
            got = group["metrics"][metric]
            assert got["n"] == 6 and got["failures"] == 0
            assert got["mean"] == pytest.approx(statistics.fmean(values), rel=1e-12)
            assert got["std"] == pytest.approx(statistics.stdev(values), rel=1e-12)
            # linear-interpolation percentiles, written out: rank (n - 1) q
            for key, q in (("p5", 0.05), ("p50", 0.5), ("p95", 0.95)):
                rank = (len(values) - 1) * q
                lo = math.floor(rank)
                hi = min(lo + 1, len(values) - 1)
                want = values[lo] + (values[hi] - values[lo]) * (rank - lo)
                assert got[key] == pytest.approx(want, rel=1e-12)
    # gain y = k (offset + slope t): the high variant's max is 4x the low one's, run by run
    low = {r["montecarlo.sample"]: float(r["lateral_error_max"]) for r in rows
           if r["variant"] == "low"}
    high = {r["montecarlo.sample"]: float(r["lateral_error_max"]) for r in rows
            if r["variant"] == "high"}
    assert all(high[i] == pytest.approx(4 * low[i], rel=1e-12) for i in low)
    assert (out / "montecarlo.png").stat().st_size > 0


def test_a_crashing_sample_counts_as_a_failure(fmus, tmp_path):
    path = tmp_path / "crash.toml"
    path.write_text(f"""
name = "crashmc"
[simulation]
stop = 0.2
step = 0.01
[components.crashdut]
fmu = "{fmus['agv_test_crash']}"
[metrics]
lateral_error = "crashdut.t_out"
[montecarlo]
samples = 4
seed = 1
[montecarlo.parameters]
"crashdut.crash_time" = {{ distribution = "choice", values = [0.05, 10.0] }}
""")
    out = tmp_path / "out"
    assert main(["run", str(path), "--out", str(out), "--quiet"]) == 1
    report = json.loads((out / "montecarlo.json").read_text())
    group = report["groups"]["base"]
    with open(out / "summary.csv", newline="") as stream:
        rows = list(csv.DictReader(stream))
    crashed = sum(row["crashdut.crash_time"] == "0.05" for row in rows)
    assert 0 < crashed < 4  # the 4 draws from the seed contain both values
    assert group["failed_runs"] == crashed
    stat = group["metrics"]["lateral_error_max"]
    assert stat["failures"] == crashed and stat["n"] == 4 - crashed


@pytest.mark.parametrize("table, key", [
    ('samples = 0\nseed = 1\n[montecarlo.parameters]\n"src.offset" = { distribution = '
     '"uniform", low = 0.0, high = 1.0 }', "montecarlo.samples"),
    ('samples = 2\n[montecarlo.parameters]\n"src.offset" = { distribution = "uniform", '
     'low = 0.0, high = 1.0 }', "montecarlo.seed"),
    ('samples = 2\nseed = 1\ndesign = "grid"\n[montecarlo.parameters]\n"src.offset" = '
     '{ distribution = "uniform", low = 0.0, high = 1.0 }', "montecarlo.design"),
    ('samples = 2\nseed = 1\n[montecarlo.parameters]\n"src.offset" = { distribution = '
     '"normal", mean = 1.0, std = -1.0 }', "montecarlo.parameters.src.offset.std"),
    ('samples = 2\nseed = 1\n[montecarlo.parameters]\n"src.offset" = { distribution = '
     '"uniform", low = 1.0 }', "montecarlo.parameters.src.offset.high"),
    ('samples = 2\nseed = 1\n[montecarlo.parameters]\n"src.offset" = { distribution = '
     '"cauchy" }', "montecarlo.parameters.src.offset.distribution"),
    ('samples = 2\nseed = 1\n[montecarlo.parameters]\n"nope.offset" = { distribution = '
     '"uniform", low = 0.0, high = 1.0 }', "montecarlo.parameters.nope.offset"),
    ('samples = 2\nseed = 1\nsamplez = 3\n[montecarlo.parameters]\n"src.offset" = '
     '{ distribution = "uniform", low = 0.0, high = 1.0 }', "montecarlo.samplez"),
    ('samples = 2\nseed = 1\n[montecarlo.parameters]\n"src.offset" = { distribution = '
     '"choice", values = [1, 2], weights = [1] }', "montecarlo.parameters.src.offset.weights"),
])
def test_a_malformed_table_is_a_one_line_error_naming_the_key(chain, capsys, table, key):
    path = chain(extra="[montecarlo]\n" + table + "\n")
    assert main(["run", str(path), "--quiet"]) == 2
    err = _unplaced(capsys.readouterr().err.strip())
    assert len(err.splitlines()) == 1
    assert err.startswith(f"agv-cosim: error: {path}: {key}: "), err


def test_an_unknown_sampled_parameter_is_named_by_its_montecarlo_key(chain, capsys):
    path = chain(extra='[montecarlo]\nsamples = 2\nseed = 1\n[montecarlo.parameters]\n'
                       '"src.nope" = { distribution = "uniform", low = 0.0, high = 1.0 }\n')
    assert main(["run", str(path), "--quiet"]) == 2
    err = _unplaced(capsys.readouterr().err)
    assert f"{path}: montecarlo.parameters.src.nope: unknown parameter 'nope'" in err


def test_set_on_a_sampled_parameter_is_refused(chain):
    path = chain(extra='[montecarlo]\nsamples = 2\nseed = 1\n[montecarlo.parameters]\n'
                       '"src.offset" = { distribution = "uniform", low = 0.0, high = 1.0 }\n')
    with pytest.raises(ManifestError, match="--set: 'src.offset' is also sampled"):
        plan_runs(load_manifest(path), sets=["src.offset=2.0"])


#: a crashing FMU (tests/fmu_src/agv_test_crash.py) whose t_out is the lateral error
#: (e(t_0) = 0: no overshoot in any run), and a source whose offset is sampled; the
#: variant "doomed" crashes in its initialisation (every run failed, without metrics)
UNDEFINED = """
name = "undefined"
[simulation]
stop = 0.2
step = 0.01
[components.crashdut]
fmu = "{crash}"
parameters = {{ crash_time = 10.0 }}
[components.src]
fmu = "{source}"
[metrics]
lateral_error = "crashdut.t_out"
[variants.fine]
[variants.doomed.components.crashdut]
parameters = {{ crash_time = -1.0 }}
[montecarlo]
samples = 3
seed = 1
[montecarlo.parameters]
"src.offset" = {{ distribution = "uniform", low = 0.0, high = 1.0 }}
"""


def _statistics_rows(page):
    """The cells (text, title) of each row of the page's Monte Carlo table."""
    section = page.split("<h2 id=montecarlo>", 1)[1].split("</table>", 1)[0]
    head = re.findall(r"<th>(.*?)</th>", section)
    rows = []
    for row in re.findall(r"<tr>(.*?)</tr>", section.split("<tbody>", 1)[1]):
        cells = re.findall(r'<td(?:[^>]*?title="([^"]*)")?[^>]*>(.*?)</td>', row)
        rows.append({name: (text, title) for name, (title, text) in zip(head, cells)})
    return rows


def test_a_statistic_without_values_says_why(fmus, tmp_path):
    """A metric no run has (the overshoot of an error that starts at 0) and a variant
    whose runs all failed: montecarlo.json's statistics are null with a note saying why,
    every metric listed for the failed variant too; the page's cells say n/a, their
    title and the row's note the same reason: no statistic cell is blank."""
    path = tmp_path / "undefined.toml"
    path.write_text(UNDEFINED.format(crash=fmus["agv_test_crash"],
                                     source=fmus["agv_test_source"]))
    out = tmp_path / "out"
    assert main(["run", str(path), "--out", str(out), "--quiet", "--no-init"]) == 1
    groups = json.loads((out / "montecarlo.json").read_text())["groups"]
    fine, doomed = groups["fine"], groups["doomed"]
    assert (fine["runs"], fine["failed_runs"], doomed["runs"], doomed["failed_runs"]) == \
        (3, 0, 3, 3)
    assert list(doomed["metrics"]) == list(fine["metrics"])
    assert fine["metrics"]["lateral_error_overshoot"] == {
        "n": 0, "failures": 3, "mean": None, "std": None, "p5": None, "p50": None,
        "p95": None, "min": None, "max": None,
        "note": "n/a: 0 of 3 runs have a value (3 complete without a finite value)"}
    assert fine["metrics"]["lateral_error_settling_time"]["note"] == \
        "n/a: 0 of 3 runs have a value (3 complete that did not settle)"
    assert "note" not in fine["metrics"]["lateral_error_max"]
    assert fine["metrics"]["lateral_error_max"]["n"] == 3
    for got in doomed["metrics"].values():
        assert got["n"] == 0 and got["mean"] is None
        assert got["note"] == "n/a: 0 of 3 runs have a value (3 not complete)"

    page = (out / "index.html").read_text(encoding="utf-8")
    rows = _statistics_rows(page)
    statistics_columns = ("mean", "std", "p5", "p50", "p95", "min", "max", "n", "failures")
    assert {row["group"][0] for row in rows} == {"fine", "doomed"}
    for row in rows:
        assert all(row[s][0] for s in statistics_columns), row  # none blank
        note = groups[row["group"][0]]["metrics"][row["metric"][0]].get("note")
        assert row["note"][0] == (note or "")
        for s in statistics_columns[:7]:
            if row[s][0] == "n/a":
                assert row[s][1] == note
    assert sum(row["group"][0] == "doomed" for row in rows) == \
        sum(row["group"][0] == "fine" for row in rows) > 0

    # a montecarlo.json of an earlier agv-cosim (no notes): the page derives them from n,
    # runs and failed_runs (without the runs that did not settle, which it cannot tell)
    report = json.loads((out / "montecarlo.json").read_text())
    for group in report["groups"].values():
        for got in group["metrics"].values():
            got.pop("note", None)
    (out / "montecarlo.json").unlink()
    (out / "montecarlo.json").write_text(json.dumps(report))
    assert main(["report", str(out)]) == 0
    derived = _statistics_rows((out / "index.html").read_text(encoding="utf-8"))
    assert len(derived) == len(rows)
    for before, after in zip(rows, derived):
        assert {k: v[0] for k, v in after.items() if k != "note"} == \
            {k: v[0] for k, v in before.items() if k != "note"}
        note = before["note"][0].replace("complete that did not settle",
                                         "complete without a finite value")
        assert after["note"][0] == note
        assert all(after[s][1] == note for s in statistics_columns if after[s][0] == "n/a")


def test_the_note_of_a_statistic_without_its_values():
    """n = 1: the std only is n/a, and the note says so; n >= 2: no note; without the
    count of runs not complete (the pure statistics), no note."""
    from agv_cosim.report.montecarlo import statistics as stats_of

    one = stats_of([2.0, None, float("nan"), None], 4, 2)
    assert one["std"] is None and one["mean"] == 2.0
    assert one["note"] == ("std n/a: 1 of 4 runs has a value, std needs 2 "
                           "(2 not complete, 1 complete without a finite value)")
    assert "note" not in stats_of([1.0, 2.0], 3, 1)
    assert "note" not in stats_of([], 3)
    mixed = stats_of([None, None, None], 4, 1, 2)
    assert mixed["note"] == ("n/a: 0 of 4 runs have a value (1 not complete, 2 complete "
                             "that did not settle, 1 complete without a finite value)")
    alone = stats_of([], 1, 1)
    assert alone["note"] == "n/a: 0 of 1 run has a value (1 not complete)"


def test_no_statistics_at_all_are_said_so(fmus, tmp_path):
    """Every run failed before it recorded a row (no run has a metric): montecarlo.json's
    group has no metric, and the page says why there is no table instead of an empty
    one."""
    path = tmp_path / "undefined.toml"
    path.write_text(UNDEFINED.format(crash=fmus["agv_test_crash"],
                                     source=fmus["agv_test_source"])
                    .replace("crash_time = 10.0", "crash_time = -1.0")
                    .replace("[variants.fine]\n", "").replace(
                        "[variants.doomed.components.crashdut]\n"
                        "parameters = { crash_time = -1.0 }\n", ""))
    out = tmp_path / "out"
    assert main(["run", str(path), "--out", str(out), "--quiet", "--no-init"]) == 1
    groups = json.loads((out / "montecarlo.json").read_text())["groups"]
    assert groups == {"base": {"variant": None, "runs": 3, "failed_runs": 3, "metrics": {}}}
    section = (out / "index.html").read_text(encoding="utf-8").split(
        "<h2 id=montecarlo>", 1)[1].split("<h2", 1)[0]
    assert "<table" not in section
    assert "No Monte Carlo statistics: no run has a metric (3 of 3 runs not complete" \
        in section
