"""Hostile round three, numbers: non-finite parameter values are refused wherever they
enter unless the FMU declares them legal, and Monte Carlo sampling is sound at the
extremes or refuses the table (one line, exit 2)."""

import json
import math
import re
import zipfile

import numpy as np
import pytest

from agv_cosim import cli
from agv_cosim.plan import sampling as montecarlo


def _unplaced(text):
    """``text`` without the manifest's line number (``m.toml:12: key`` -> ``m.toml: key``;
    the positions are tested in test_cli_errors)."""
    return re.sub(r"\.toml:\d+: ", ".toml: ", text)


def _fail(capsys, argv):
    code = cli.main(argv)
    err = [line for line in capsys.readouterr().err.strip().splitlines()
           if "warning" not in line]
    assert code == 2, err
    assert len(err) == 1 and err[0].startswith("agv-cosim: error: "), err
    return _unplaced(err[0])


NOT_FINITE = "is not a finite number (the FMU does not declare it legal"


# ---------------------------------------------------------------- non-finite values

@pytest.mark.parametrize("text", ["nan", "inf", "-inf", "1e999", "-1e999"])
def test_a_non_finite_manifest_value_is_refused(chain, capsys, text):
    path = chain()
    path.write_text(path.read_text().replace("parameters = { k = 3.0 }",
                                             f"parameters = {{ k = {text} }}"))
    line = _fail(capsys, ["validate", str(path), "--no-init"])
    assert line.startswith(f"agv-cosim: error: {path}: components.gain.parameters.k: "
                           "'gain.k' = ") and NOT_FINITE in line


@pytest.mark.parametrize("text", ["nan", "inf", "1e999"])
def test_a_non_finite_set_or_sweep_value_is_refused(chain, capsys, text):
    line = _fail(capsys, ["validate", str(chain()), "--no-init", "--set", f"gain.k={text}"])
    assert ": --set: 'gain.k' = " in line and NOT_FINITE in line
    swept = chain(extra=f'[sweep]\n"gain.k" = [1.0, {text}]\n', name="swept.toml")
    line = _fail(capsys, ["validate", str(swept), "--no-init"])
    assert ": sweep.gain.k: 'gain.k' = " in line and NOT_FINITE in line


@pytest.mark.parametrize("text", ["nan", "inf", "1e999"])
def test_a_non_finite_event_time_or_value_is_refused(chain, capsys, text):
    """An event at a non-finite time, or setting a non-finite value, is bad input."""
    at = chain(extra=f'[events.e]\nat = {text}\nset = {{ "gain.k" = 2.0 }}\n', name="at.toml")
    line = _fail(capsys, ["validate", str(at), "--no-init"])
    assert line.startswith(f"agv-cosim: error: {at}: events.e.at: "), line
    value = chain(extra=f'[events.e]\nat = 0.5\nset = {{ "gain.k" = {text} }}\n',
                  name="value.toml")
    line = _fail(capsys, ["validate", str(value), "--no-init"])
    assert line.startswith(f"agv-cosim: error: {value}: events.e"), line
    assert "finite" in line, line


def test_a_sample_that_overflows_is_refused(chain, capsys):
    path = chain(extra='[montecarlo]\nsamples = 16\nseed = 1\n[montecarlo.parameters]\n'
                       '"gain.k" = { distribution = "normal", mean = 1.7e308, std = 1e308 }\n')
    line = _fail(capsys, ["validate", str(path), "--no-init"])
    assert line.startswith(f"agv-cosim: error: {path}: montecarlo.parameters.gain.k: "
                           "normal: a sample is ") and "overflow a double" in line


NAMES = """
name = "names"
[simulation]
stop = 0.1
step = 0.05
[components.n]
fmu = "{fmu}"
parameters = {{ {parameters} }}
"""


def _names(fmus, tmp_path, parameters):
    path = tmp_path / "names.toml"
    path.write_text(NAMES.format(fmu=fmus["agv_test_names"], parameters=parameters))
    return path


def test_values_the_fmu_declares_legal_are_accepted(fmus, tmp_path, capsys):
    """inf_ok declares max = INF, nan_ok a NaN start value: those values pass, the
    opposite infinity and a NaN for another parameter do not."""
    path = _names(fmus, tmp_path, "inf_ok = inf, nan_ok = nan")
    assert cli.main(["validate", str(path)]) == 0
    assert cli.main(["run", str(path), "--out", str(tmp_path / "o"), "--quiet"]) == 0
    info = json.loads((tmp_path / "o" / "base" / "run.json").read_text())
    assert info["parameters"]["n"]["inf_ok"] == "inf"  # as given, not null
    assert info["parameters"]["n"]["nan_ok"] == "nan"
    capsys.readouterr()
    for bad, key in (("inf_ok = -inf", "inf_ok"), ("nan_ok = inf", "nan_ok"),
                     ('"gain.k" = nan', "gain.k")):
        line = _fail(capsys, ["validate", str(_names(fmus, tmp_path, bad)), "--no-init"])
        assert f"components.n.parameters.{key}: 'n.{key}' = " in line and NOT_FINITE in line


def _ssp(tmp_path, fmu, params):
    body = "".join(f'<ssv:Parameter name="{n}"><ssv:Real value="{v}"/></ssv:Parameter>'
                   for n, v in params)
    ssd = ('<?xml version="1.0" encoding="UTF-8"?>\n'
           '<ssd:SystemStructureDescription name="nums" version="1.0" '
           'xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription" '
           'xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon" '
           'xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues">'
           '<ssd:System name="nums"><ssd:Elements><ssd:Component name="n" '
           'source="resources/N.fmu" type="application/x-fmu-sharedlibrary">'
           '<ssd:ParameterBindings><ssd:ParameterBinding><ssd:ParameterValues>'
           '<ssv:ParameterSet version="1.0" name="p"><ssv:Parameters>' + body +
           '</ssv:Parameters></ssv:ParameterSet></ssd:ParameterValues>'
           '</ssd:ParameterBinding></ssd:ParameterBindings></ssd:Component>'
           '</ssd:Elements></ssd:System>'
           '<ssd:DefaultExperiment startTime="0.0" stopTime="0.1"><ssd:Annotations>'
           '<ssc:Annotation type="org.agv-cosim"><agv:Experiment '
           'xmlns:agv="https://agv-cosim.org/SSP/Experiment" algorithm="gauss-seidel" '
           'stepSize="0.05"/></ssc:Annotation></ssd:Annotations></ssd:DefaultExperiment>'
           '</ssd:SystemStructureDescription>\n')
    path = tmp_path / "nums.ssp"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("SystemStructure.ssd", ssd)
        archive.write(fmu, "resources/N.fmu")
    return path


def test_a_non_finite_ssp_value_is_refused_unless_declared_legal(fmus, tmp_path, capsys):
    fmu = fmus["agv_test_names"]
    assert cli.main(["validate", str(_ssp(tmp_path, fmu, [("inf_ok", "INF"),
                                                           ("nan_ok", "NaN")])),
                     "--no-init"]) == 0
    capsys.readouterr()
    ssp = _ssp(tmp_path, fmu, [("gain.k", "NaN")])
    line = _fail(capsys, ["validate", str(ssp), "--no-init"])
    assert line.startswith(f"agv-cosim: error: {ssp}: components.n.parameters.gain.k: "
                           "'n.gain.k' = nan") and NOT_FINITE in line


# ---------------------------------------------------------------- Monte Carlo extremes

def test_a_uniform_whose_width_overflows_is_refused(chain, capsys):
    path = chain(extra='[montecarlo]\nsamples = 4\nseed = 1\n[montecarlo.parameters]\n'
                       '"gain.k" = { distribution = "uniform", low = -1e308, high = 1e308 }\n')
    line = _fail(capsys, ["validate", str(path), "--no-init"])
    assert line == (f"agv-cosim: error: {path}: montecarlo.parameters.gain.k: uniform: "
                    "high - low = 1e+308 - -1e+308 overflows a double; give a narrower range")


def test_a_truncated_normal_beyond_scipys_reach_is_refused(chain, capsys):
    """Mean 0, std 1e-200 on [1, 2]: the bounds are 1e200 standard deviations away;
    scipy gives inf there, which was clipped into the upper bound (all the mass is at
    the lower one). Refused instead."""
    path = chain(extra='[montecarlo]\nsamples = 4\nseed = 1\n[montecarlo.parameters]\n'
                       '"gain.k" = { distribution = "truncnormal", mean = 0.0, '
                       'std = 1e-200, low = 1.0, high = 2.0 }\n')
    line = _fail(capsys, ["validate", str(path), "--no-init"])
    assert ": montecarlo.parameters.gain.k: truncnormal: the bounds are 1e+200 standard " \
           "deviations from the mean" in line


def test_a_truncated_normal_in_a_far_tail_is_sampled_soundly():
    """On [a, a + 1] with a = 30 standard deviations the truncated normal is, to
    O(1/a^2), a + Exp(rate a): its median is a + ln 2 / a (to ~1e-4 here) and every
    sample lies in [a, a + 1]."""
    spec = {"distribution": "truncnormal", "mean": 0.0, "std": 1.0, "low": 30.0,
            "high": 31.0}
    [median] = montecarlo.ppf(spec, [0.5])
    assert median == pytest.approx(30.0 + math.log(2.0) / 30.0, abs=1e-4)
    samples = montecarlo.ppf(spec, np.linspace(0.0, 1.0, 101, endpoint=False))
    assert min(samples) >= 30.0 and max(samples) <= 31.0
    assert samples == sorted(samples)  # an inverse CDF is monotone


def test_choice_weights_whose_sum_overflows_keep_their_ratio():
    """Weights [1e308, 1e308] (their sum overflows) are two equal halves; [1e308,
    3e307] keep 10 : 3."""
    spec = {"distribution": "choice", "values": ["a", "b"], "weights": [1e308, 1e308]}
    assert montecarlo.ppf(spec, [0.0, 0.25, 0.4999, 0.5001, 0.75, 0.999]) == \
        ["a", "a", "a", "b", "b", "b"]
    edges = montecarlo.choice_edges([1e308, 3e307])
    assert edges[0] == pytest.approx(10 / 13, rel=1e-15) and edges[-1] == 1.0
    assert montecarlo.choice_edges([1.0, 3.0]).tolist() == [0.25, 1.0]


def test_too_many_runs_are_refused_before_any_is_made(chain, capsys):
    path = chain(extra='[montecarlo]\nsamples = 10000000\nseed = 1\n'
                       '[montecarlo.parameters]\n'
                       '"gain.k" = { distribution = "uniform", low = 1.0, high = 2.0 }\n')
    line = _fail(capsys, ["validate", str(path), "--no-init"])
    assert line == (f"agv-cosim: error: {path}: montecarlo.samples: 10000000 must be "
                    "<= 100000")
    sweep = "".join(f'"gain{"2" if i else ""}.k" = {list(range(1, 400))}\n'
                    for i in range(2))
    wide = chain(extra=f"[sweep]\n{sweep}", name="wide.toml")
    line = _fail(capsys, ["validate", str(wide), "--no-init"])
    assert line == (f"agv-cosim: error: {wide}: sweep: 159201 runs (variants x sweep "
                    "points x samples); at most 100000")
