"""The figure and table of experiments/controllers.md, from the recorded runs.

Reads results/controllers_rewired/ (written by make_controllers.sh: the three runs of
experiments/controllers_rewired.toml), draws experiments/figures/controllers_rewired.png
(the rear-axle and the front-wheel offset from the sine against the distance travelled,
one line per controller) and prints the table of the results page from summary.csv.

Usage (from the repository root): ``python experiments/figures/controllers_figures.py``
"""

import csv
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from agv_core.numerics.paths import parse_path, project_trajectory
from agv_cosim.timeseries import read_timeseries

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "results" / "controllers_rewired"
FIGURES = ROOT / "experiments" / "figures"
SINE = "sine:amplitude=2,wavelength=18.84955592153876"
RUNS = {"lqr": "seed 000 LQR state feedback", "chained_form": "seed 002 chained form",
        "preview_lq": "seed 004 preview LQ"}
#: summary.csv columns of the page's table, and how each is shown (scale, digits)
COLUMNS = [("lateral_error_settled_max", 100, 1), ("lateral_error_settled_std", 100, 1),
           ("path_error_settled_max", 100, 1), ("path_error_settled_std", 100, 1),
           ("heading_error_rms", 1000, 1), ("steering_angle_peak", 1, 3),
           ("steering_rate_peak", 1, 2), ("steering_rate_rms", 1, 3)]


def main(results=RESULTS, figures=FIGURES):
    with open(results / "summary.csv", newline="") as handle:
        summary = {row["run"]: row for row in csv.DictReader(handle)}
    assert {row["status"] for row in summary.values()} == {"complete"}, summary
    path = parse_path(SINE)
    figure = Figure(figsize=(9, 6.5))
    FigureCanvasAgg(figure)
    rear, front = figure.subplots(2, 1, sharex=True)
    notes = []
    for label, name in RUNS.items():
        t, data = read_timeseries(results / label / "timeseries.csv")
        distance = data["vehicle.distance"]
        e = data["truth.lateral_error"]
        rear.plot(distance, 100 * e, label=name)
        offset, _ = project_trajectory(path, data["vehicle.x_front"], data["vehicle.y_front"])
        front.plot(distance, 100 * offset, label=name)
        notes.append(f"{label}: " + _notes(t, distance, e, offset, data))
    for ax, what in ((rear, "rear-axle centre"), (front, "front-wheel centre")):
        ax.axvline(20.0, color="0.5", lw=0.8, ls=":")
        ax.set_ylabel(f"offset of the {what} [cm]")
        ax.set_ylim(-45, 35)
        ax.grid(alpha=0.3)
    rear.set_title("Sine y = 2 sin(x/3) at 1 m/s, one vehicle and actuator: offset from the "
                   "path (+ left; dotted: start of the settled window)", fontsize=10)
    front.set_xlabel("distance travelled by the rear axle [m]")
    rear.legend(fontsize=8, loc="lower right")
    figure.tight_layout()
    out = figures / "controllers_rewired.png"
    figure.savefig(out, dpi=110, metadata={"Software": None})
    print("wrote", out)
    print("| controller | " + " | ".join(c for c, _, _ in COLUMNS) + " |")
    for label, name in RUNS.items():
        row = summary[label]
        cells = [f"{float(row[c]) * scale:.{digits}f}" for c, scale, digits in COLUMNS]
        print(f"| {name} | " + " | ".join(cells) + " |")
    print("\n".join(notes))


def _notes(t, distance, e, front, data, settled=20.0):
    """The numbers the page quotes besides summary.csv: start transient (last distance
    with |rear offset| > 20 cm, > 10 cm), over the settled window the largest front minus
    rear offset, the correlation of each offset with the path's curvature, and where the
    largest rear offset lies from the nearest apex (arc length; + after)."""
    def last_outside(band):
        outside = np.flatnonzero(np.abs(e) > band)
        return f"{distance[outside[-1]]:.1f} m" if outside.size else "never"

    window = t >= settled
    ew, fw = e[window], front[window]
    s, c = data["truth.s"][window], data["truth.curvature"][window]
    inner = np.arange(1, c.size - 1)
    apex = s[inner[(np.abs(c[inner]) >= np.abs(c[inner - 1]))
                   & (np.abs(c[inner]) > np.abs(c[inner + 1]))]]
    peak = s[np.argmax(np.abs(ew))]
    nearest = apex[np.argmin(np.abs(apex - peak))]
    return (f"rear outside 20 cm until {last_outside(0.2)}, 10 cm until "
            f"{last_outside(0.1)}; front - rear max {100 * np.max(np.abs(fw - ew)):.1f} cm; "
            f"correlation with curvature rear {np.corrcoef(ew, c)[0, 1]:+.2f}, front "
            f"{np.corrcoef(fw, c)[0, 1]:+.2f}; largest rear offset {peak - nearest:+.1f} m "
            "from an apex")


if __name__ == "__main__":
    main()
