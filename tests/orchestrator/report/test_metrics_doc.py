"""docs/metrics.md against the code: every metric the code can produce is documented
there with the unit, definition and empty meaning of ``metrics.METRICS`` (the page's and
the API's descriptions), and the reference documents no other."""

import re
from pathlib import Path

import numpy as np

from agv_cosim.report.metrics import METRICS, compute_metrics
from agv_cosim.report.page import MAIN_METRICS

DOC = Path(__file__).resolve().parents[3] / "docs" / "metrics.md"
FULL_SPEC = {"lateral_error": "s.e", "heading_error": "s.h", "steering_angle": "a.alpha",
             "steering_rate": "a.rate", "control": "c.u", "settle_band": 0.02,
             "saturation": {"signal": "a.alpha", "limit": 0.3},
             "reference": {"path": "sine:amplitude=2,wavelength=18.85", "x": "v.x",
                           "y": "v.y"}}


def _cell(text):
    return text.replace("|", "\\|")


def table_rows():
    """docs/metrics.md's table of every metric, rendered from METRICS."""
    rows = ["| metric | unit | definition | empty when |", "|---|---|---|---|"]
    rows += [f"| `{name}` | {_cell(doc.unit)} | {_cell(doc.definition)} | {_cell(doc.empty)} |"
             for name, doc in METRICS.items()]
    return rows


def _signals(t):
    e = 0.1 * np.exp(-t) * np.cos(3 * t)
    return {"s.e": e, "s.h": 0.3 * e, "a.alpha": 0.5 * np.sin(t), "a.rate": 0.5 * np.cos(t),
            "c.u": -2 * e, "v.x": t, "v.y": 2 * np.sin(t / 3) + e}


def test_every_metric_the_code_produces_is_documented_and_no_other():
    t = np.linspace(0.0, 10.0, 501)
    produced = compute_metrics(t, _signals(t), FULL_SPEC)
    assert list(produced) and set(produced) == set(METRICS)
    # a run that never settles and one with a single sample produce the same names
    short = t[:3]
    assert set(compute_metrics(short, {k: v[:3] for k, v in _signals(t).items()},
                               {**FULL_SPEC, "settle_band": 1e-9})) == set(METRICS)
    documented = re.findall(r"^\| `([a-z_]+)` \|", DOC.read_text(encoding="utf-8"), re.M)
    assert sorted(documented) == sorted(METRICS)
    assert set(MAIN_METRICS) <= set(METRICS)


def test_the_reference_table_is_the_codes():
    lines = DOC.read_text(encoding="utf-8").splitlines()
    start = lines.index(table_rows()[0])
    assert lines[start:start + len(table_rows())] == table_rows()


if __name__ == "__main__":  # print the table, to paste into docs/metrics.md
    print("\n".join(table_rows()))


def test_the_reports_units_are_the_documented_ones():
    from agv_cosim.report.page import metric_unit

    for name, doc in METRICS.items():
        if "unit(u)" in doc.unit:  # the control signal's: none without it
            assert metric_unit(name, {"control": "c.u"}, {"c.u": "V"}) == \
                doc.unit.replace("unit(u)", "(V)" if "^2" in doc.unit else "V")
        else:
            assert metric_unit(name, {}, {}) == doc.unit, name


def _resolves(dotted):
    import importlib

    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            value = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        try:
            for name in parts[cut:]:
                value = getattr(value, name)
        except AttributeError:
            return False
        return True
    return False


def test_every_agv_cosim_name_the_docs_and_manifests_give_exists():
    # e.g. example.toml's pointer to compute_metrics, where a user looks the keys up
    root = DOC.parents[1]
    files = [*sorted((root / "docs").glob("*.md")), *sorted((root / "experiments").glob("*.toml"))]
    named = {(path.name, name.rstrip(".")) for path in files
             for name in re.findall(r"\bagv_cosim(?:\.[A-Za-z_]\w*)+", path.read_text())}
    assert ("example.toml", "agv_cosim.report.metrics.compute_metrics") in named
    assert [(f, n) for f, n in sorted(named) if not _resolves(n)] == []


def test_the_key_metrics_are_the_pages():
    text = DOC.read_text(encoding="utf-8")
    section = text[text.index("## Key metrics"):text.index("(`MAIN_METRICS`")]
    assert re.findall(r"`([a-z_]+)`", section) == list(MAIN_METRICS)
