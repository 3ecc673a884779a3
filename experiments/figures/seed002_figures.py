"""Figures and tables of experiments/seed002.md, from the recorded results of its runs.

Reads results/seed002_step/, results/seed002_sine/ and results/cross_seed_controllers/
(written by make_seed002.sh: every run of the three manifests), draws
experiments/figures/seed002_step.png, seed002_sine.png, cross_seed_controllers.png and
prints the tables of the results page. The analysis definitions (eq (22)'s closed form,
settling distance, spread, true path offset, sine peaks) are those of
tests/seeds/test_seed002.py, imported from it, so the page and the tests use the same ones.

Usage (from the repository root): ``python experiments/figures/seed002_figures.py``
"""

import csv
import math
import sys
from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

ROOT = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(ROOT / "tests" / "seeds"), str(ROOT / "tests")]  # test_seed002, manifests

from agv_core.numerics.paths import parse_path  # noqa: E402
from test_seed002 import (KMH, LOOPS, SINE, load, on_grid, path_offset,  # noqa: E402
                          settle_distance, sine_peaks, spread, step_closed_form)

RESULTS = ROOT / "results"
FIGURES = ROOT / "experiments" / "figures"


def _figure(rows, cols, size, **kwargs):
    fig = Figure(figsize=size)
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, cols, squeeze=False, **kwargs)
    return fig, axes


def _save(fig, path):
    fig.tight_layout()
    fig.savefig(path, dpi=110, metadata={"Software": None})
    print("wrote", path)


def make_figures(results=RESULTS, figures=FIGURES):
    """Read the three manifests' results in ``results``; write the figures and tables."""
    figures.mkdir(parents=True, exist_ok=True)
    colors = matplotlib.colormaps["viridis"](np.linspace(0, 0.9, len(KMH)))

    def run(name):
        out = Path(results) / name
        with open(out / "summary.csv", newline="") as handle:
            status = {row["run"]: row["status"] for row in csv.DictReader(handle)}
        assert set(status.values()) == {"complete"}, f"{out}: runs not complete: {status}"
        return out

    # ---- step
    out = run("seed002_step")
    grid = np.linspace(0, 40, 4001)
    curves = {n: [] for n in LOOPS}
    table = []
    for kmh in KMH:
        _, sig = load(out, f"v{kmh:02d}kmh")
        v = kmh / 3.6
        row = [kmh]
        for n in LOOPS:
            c = on_grid(sig["veh_i.distance"], sig[f"veh_{n}.y_rear"], grid)
            curves[n].append(c)
        for n in LOOPS:
            dev = np.abs(curves[n][-1] - step_closed_form(grid)).max()
            row += [settle_distance(grid, curves[n][-1], 2.0), max(0.0, curves[n][-1].max() - 2),
                    np.abs(sig[f"veh_{n}.y_rear"] - step_closed_form(sig["veh_i.x_rear"])).max()
                    if n == "i" or n == "d" else dev]
        table.append(row)
    fig, axes = _figure(2, 2, (11, 7.5))
    for ax, n in zip(axes.flat, LOOPS):
        for kmh, c, col in zip(KMH, curves[n], colors):
            ax.plot(grid, c, color=col, lw=1.2, label=f"{kmh} km/h")
        ax.plot(grid, step_closed_form(grid), "k--", lw=0.8, label="eq (22)")
        gap, where = spread(curves[n])
        ax.set_title(f"{LOOPS[n]}: spread {100 * gap:.1f} cm at {grid[where]:.1f} m")
        ax.set_xlim(0, 30)
        ax.set_xlabel("distance travelled [m]")
        ax.set_ylabel("rear-axle y [m]")
        ax.grid(alpha=0.3)
        inset = ax.inset_axes([0.45, 0.12, 0.5, 0.45])
        for c, col in zip(curves[n], colors):
            inset.plot(grid, 100 * (c - step_closed_form(grid)), color=col, lw=1)
        inset.set_xlim(0, 30)
        inset.set_title("y - eq (22) [cm]", fontsize=8)
        inset.tick_params(labelsize=7)
        inset.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8, loc="upper left", ncol=2)
    fig.suptitle("Seed 002: 2 m lateral step (initial offset), chained-form law, 2-14 km/h")
    _save(fig, figures / "seed002_step.png")
    spreads = {n: spread(curves[n]) for n in LOOPS}

    # ---- sine
    out = run("seed002_sine")
    path = parse_path(SINE)
    variants = ["pose", "sampled", "camera", "latency_0_3", "wheelbase"]
    sine_rows, traces = [], {}
    for name in variants:
        _, sig = load(out, name)
        row = [name]
        for n in ("i", "d"):
            y, s = path_offset(path, sig[f"veh_{n}.x_rear"], sig[f"veh_{n}.y_rear"])
            x = sig[f"veh_{n}.x_rear"]
            traces[name, n] = (sig["veh_i.distance"], y, x)
            late = x >= 40
            peaks = sine_peaks(x, y)
            row += [np.abs(y[late]).max(), np.sqrt(np.mean(y[late] ** 2)),
                    np.mean([p[0] for p in peaks])]
        sine_rows.append(row)
    fig, axes = _figure(3, 1, (11, 9.5), gridspec_kw={"height_ratios": [1.2, 2, 2]})
    ax = axes[0, 0]
    xs = np.linspace(0, 100, 2001)
    ax.plot(xs, 3 * np.sin(2 * np.pi * xs / 30), "k-", lw=2.5, alpha=0.3, label="path")
    for name, col in zip(variants, ("C0", "C1", "C2", "C3", "C4")):
        _, y, x = traces[name, "d"]
        _, sig = load(out, name)
        ax.plot(sig["veh_d.x_rear"], sig["veh_d.y_rear"], color=col, lw=1, label=name)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title("Rear-axle trajectories, delayed actuator, 6 km/h (start 0.5 m right)")
    ax.set_xlim(0, 100)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=6, loc="lower left")
    for ax, n in zip(axes[1:, 0], ("i", "d")):
        for name, col in zip(variants, ("C0", "C1", "C2", "C3", "C4")):
            d, y, x = traces[name, n]
            ax.plot(x, 100 * y, color=col, lw=1, label=name)
        for xc in np.arange(7.5, 100, 15):
            ax.axvline(xc, color="k", lw=0.6, ls=":")
        ax.set_ylim(-30, 30)
        ax.set_xlim(0, 100)
        ax.axhline(25, color="r", lw=0.6, ls="--")
        ax.axhline(-25, color="r", lw=0.6, ls="--")
        ax.set_xlabel("x of the rear axle [m] (dotted: crests and troughs; red: paper's 25 cm)")
        ax.set_ylabel("true offset y [cm]")
        ax.set_title(f"{'Ideal' if n == 'i' else 'Delayed (AgvSteeringA angle mode)'} "
                     "actuator: lateral offset of the rear-axle centre")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, ncol=5, loc="lower right")
    _save(fig, figures / "seed002_sine.png")

    # ---- cross seed
    out = run("cross_seed_controllers")
    speeds = [0.5, 1.0, 2.0, 3.0, 4.0]
    fig, axes = _figure(2, 1, (11, 7.5))
    cross_rows = []
    summary = {r["run"]: r for r in csv.DictReader(open(out / "summary.csv"))}
    for ax, ctrl in zip(axes[:, 0], ("state_feedback", "chained_form")):
        for v, col in zip(speeds, matplotlib.colormaps["plasma"](np.linspace(0, 0.85, 5))):
            label = f"{ctrl}__vehicle.v0={v!r}"
            _, sig = load(out, label)
            ax.plot(sig["vehicle.distance"], sig["vehicle.y_rear"] - 0.5, color=col, lw=1.2,
                    label=f"{v} m/s")
            m = summary[label]
            f = (lambda k: float(m[k]) if m[k] not in ("", "None") else math.nan)
            cross_rows.append((ctrl, v, f("lateral_error_overshoot"), f("path_error_overshoot"),
                               f("path_error_settling_time") * v, f("steering_angle_peak"),
                               f("saturated_fraction")))
        ax.set_xlim(0, 30)
        ax.set_ylim(-0.6, 0.35)
        ax.set_xlabel("distance travelled [m]")
        ax.set_ylabel("rear-axle offset [m]")
        ax.set_title({"state_feedback": "Seed 000 state feedback (gains for 1 m/s), "
                      "actuator model a in command mode",
                      "chained_form": "Seed 002 chained-form law, same actuator in angle mode"}
                     [ctrl])
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, ncol=5, loc="lower right")
    fig.suptitle("Same vehicle (L = 1.4944 m), same actuator, 0.5 m lateral step: speed "
                 "dependence")
    _save(fig, figures / "cross_seed_controllers.png")

    # ---- tables
    print("\nstep: km/h | per loop (i, d, ic, dc): settle distance [m], overshoot [cm], "
          "max |y - eq22| [cm]")
    for row in table:
        cells = [f"{row[0]}"]
        for j in range(4):
            sd, os_, dev = row[1 + 3 * j: 4 + 3 * j]
            cells.append(f"{sd:.2f} / {100 * os_:.2f} / {100 * dev:.2f}")
        print(" | ".join(cells))
    print("spreads:", {n: (round(100 * g, 2), float(grid[w])) for n, (g, w) in spreads.items()})
    print("\nsine: variant | ideal max, rms [cm], mean peak - crest [m] | delayed same")
    for row in sine_rows:
        print(row[0], " | ".join(f"{100 * a:.2f} {100 * b:.2f} {c:+.2f}"
                                  for a, b, c in (row[1:4], row[4:7])))
    print("\ncross: controller, v, front overshoot [cm], rear overshoot [cm], rear settle "
          "distance [m], peak alpha [rad], saturated fraction")
    for r in cross_rows:
        print(r[0], r[1], f"{100 * r[2]:.1f} {100 * r[3]:.1f} {r[4]:.1f} {r[5]:.3f} {r[6]:.2f}")


if __name__ == "__main__":
    make_figures()
