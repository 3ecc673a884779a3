#!/bin/sh
# Regenerate the seed-003 results, the figures of experiments/seed003.md and the numbers
# it quotes. Usage (from the repository root):
#   sh experiments/figures/make_seed003.sh
# Writes results/seed003_{curve,radius,speed,steering}/,
# experiments/figures/seed003_*.png and results/seed003_numbers.json (printed too).
# About 5 minutes on 2 cores (28 runs at 2 ms steps).
set -eu
cd "$(dirname "$0")/../.."
BIN=${BIN:-.venv/bin}
"$BIN/agv-cosim" build --out fmus
for m in curve radius speed steering; do
    "$BIN/agv-cosim" run "experiments/seed003_$m.toml" --out "results/seed003_$m" --jobs 2 --quiet
done
"$BIN/python" - <<'PY'
import csv
import json
import math
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from agv_core.axle_pd.fuzzy_pd import FuzzySchedule
from agv_core.axle_pd.track_path import parse_track_path
from agv_core.train.train import TrainGeometry, steady_offsets
from agv_cosim.timeseries import read_timeseries

FIG = Path("experiments/figures")
G = TrainGeometry(5.0, 3.0, 2.1, 9.0)
DEG = 180.0 / math.pi
SCHEDULE = FuzzySchedule()


def runs(name):
    out = Path("results") / name
    rows = list(csv.DictReader(open(out / "summary.csv", newline="")))
    return out, rows


def load(out, run):
    t, s = read_timeseries(out / run / "timeseries.csv")
    return t, s


def save(fig, name):
    FigureCanvasAgg(fig)
    fig.savefig(FIG / name, dpi=110, metadata={"Software": None})


def max_offsets(s):
    return [float(np.max(np.abs(s[f"err.e{i}"]))) for i in range(1, 5)]


def path_of(rows, run):
    for row in rows:
        if row["run"] == run and row.get("err.path"):
            return row["err.path"]
    return None


numbers = {}
out, rows = runs("seed003_curve")
curve = {r["run"]: load(out, r["run"]) for r in rows}
paths = {"fuzzy": "curve:straight=60,radius=20,angle=1.5707963267948966",
         "fixed": "curve:straight=60,radius=20,angle=1.5707963267948966",
         "fuzzy_clothoid": "curve:straight=60,radius=20,angle=1.5707963267948966,transition=10",
         "fixed_clothoid": "curve:straight=60,radius=20,angle=1.5707963267948966,transition=10"}

# ---- numbers: per-axle max offsets, steady angles, slip, closed-form steady state
kp_fuzzy = lambda e: math.radians(SCHEDULE.gains(e, 14.0)[0])   # noqa: E731
kp_fixed = lambda e: math.radians(710.0)                          # noqa: E731
for run, (t, s) in curve.items():
    path = parse_track_path(paths[run])
    entry = {"max_offset_m": max_offsets(s)}
    # steady window of each car: both its axles >= 10 m into the arc and on it
    arc_from, arc_to = path.s2, path.s3
    for car, (i, j) in (("head", (1, 2)), ("tail", (3, 4))):
        front, rear = s[f"err.s{i}"], s[f"err.s{j}"]
        mask = (rear >= arc_from + 10.0) & (front <= arc_to)
        entry[f"{car}_window_m"] = float(np.ptp(s["train.distance"][mask]))
        for k in (i, j):
            for name in (f"pd{k}.delta", f"ack.delta{k}_left", f"ack.delta{k}_right"):
                v = s[name][mask]
                entry[f"{name}_steady_deg"] = float(np.mean(v) * DEG)
                entry[f"{name}_ptp_deg"] = float(np.ptp(v) * DEG)
            entry[f"e{k}_steady_m"] = float(np.mean(s[f"err.e{k}"][mask]))
    slips = [np.max(np.abs(s[f"train.slip{k}_{side}"])) for k in range(1, 5)
             for side in ("left", "right")]
    entry["max_slip_deg"] = float(max(slips) * DEG)
    numbers[run] = entry
for label, kp in (("fuzzy", kp_fuzzy), ("fixed", kp_fixed)):
    e_f, e_r, d_f, d_r = steady_offsets(G, 20.0, kp)
    numbers[f"closed_form_{label}"] = {"e_front_m": e_f, "e_rear_m": e_r,
                                       "delta_front_deg": d_f * DEG,
                                       "delta_rear_deg": d_r * DEG}
numbers["closed_form_on_path_deg"] = math.asin(G.L1 / 40.0) * DEG

# ---- figure 1: path with the cars at a few instants (fuzzy, no transition)
t, s = curve["fuzzy"]
path = parse_track_path(paths["fuzzy"])
fig = Figure(figsize=(8.0, 7.0))
ax = fig.add_subplot(1, 1, 1)
px, py = path.polyline(-20.0, path.s4 + 30.0, 0.5)
ax.plot(px, py, color="0.6", lw=1.0, ls="--", label="reference path")


def body(x, y, psi, back, front, width):
    c, sn = math.cos(psi), math.sin(psi)
    corners = [(back, -width / 2), (front, -width / 2), (front, width / 2), (back, width / 2),
               (back, -width / 2)]
    return ([x + a * c - b * sn for a, b in corners], [y + a * sn + b * c for a, b in corners])


colours = ["tab:blue", "tab:orange", "tab:green", "tab:red"]
for n, when in enumerate((6.0, 13.5, 21.0, 28.5)):
    k = int(np.argmin(np.abs(t - when)))
    x1, y1 = s["train.x_J1"][k], s["train.y_J1"][k]
    x2, y2 = s["train.x_J2"][k], s["train.y_J2"][k]
    h1, h2, h3 = (s[f"train.heading{i}"][k] for i in (1, 2, 3))
    a1 = G.axle_offsets[0]
    for xs, ys in (body(x1, y1, h1, 0.0, a1 + 2.0, 2.5), body(x2, y2, h2, 0.0, G.Lm, 2.3),
                   body(x2, y2, h3, -(a1 + 2.0), 0.0, 2.5)):
        ax.fill(xs, ys, color=colours[n % 4], alpha=0.25)
        ax.plot(xs, ys, color=colours[n % 4], lw=0.8)
    for i in range(1, 5):
        ax.plot(s[f"train.x{i}"][k], s[f"train.y{i}"][k], "k.", ms=3)
    ax.annotate(f"t = {t[k]:.0f} s", (x1, y1), textcoords="offset points", xytext=(8, -12),
                fontsize=8)
ax.plot(s["train.x1"], s["train.y1"], color="k", lw=0.6, label="axle 1 centre")
ax.set_aspect("equal")
ax.set_xlabel("x [m]")
ax.set_ylabel("y [m]")
ax.set_title("Seed 003: three-car train at 14 km/h, 20 m radius quarter curve "
             "(fuzzy PD)\nhead car, floating car, tail car at four instants 7.5 s apart", fontsize=10)
ax.legend(loc="upper left", fontsize=8)
ax.grid(alpha=0.3)
save(fig, "seed003_path.png")

# ---- figure 2: lateral offset of every axle against its position on the path
fig = Figure(figsize=(9.0, 7.0))
for n, run in enumerate(("fuzzy", "fixed", "fuzzy_clothoid", "fixed_clothoid")):
    ax = fig.add_subplot(2, 2, n + 1)
    t, s = curve[run]
    p = parse_track_path(paths[run])
    for i in range(1, 5):
        ax.plot(s[f"err.s{i}"], 100 * s[f"err.e{i}"], color=colours[i - 1], lw=1.0,
                label=f"axle {i}")
    for edge in {p.s1, p.s2, p.s3, p.s4}:
        ax.axvline(edge, color="0.5", lw=0.6, ls=":")
    ax.axhline(2.5, color="k", lw=0.8, ls="--")
    ax.axhline(-2.5, color="k", lw=0.8, ls="--")
    ax.set_xlim(30, 130)
    ax.set_ylim(-3, 3)
    ax.set_title(run.replace("_", " + ") + (" (no transition)" if "clothoid" not in run
                                               else " (10 m clothoids)"), fontsize=9)
    ax.set_xlabel("axle position on the path s [m]")
    ax.set_ylabel("lateral offset [cm]")
    ax.grid(alpha=0.3)
    if n == 0:
        ax.legend(fontsize=7, loc="lower left")
fig.suptitle("Seed 003 Fig. 8 analogue: each axle's lateral offset (positive left), "
             "14 km/h, R = 20 m;\ndashed: the paper's 2.5 cm bound; dotted: curve and "
             "transition ends", fontsize=10)
fig.tight_layout()
save(fig, "seed003_offsets.png")

# ---- figure 3: axle and wheel angles
fig = Figure(figsize=(9.0, 6.5))
t, s = curve["fuzzy"]
for n, i in enumerate(range(1, 5)):
    ax = fig.add_subplot(2, 2, n + 1)
    x = s[f"err.s{i}"]
    ax.plot(x, DEG * s[f"pd{i}.delta"], "k", lw=1.2, label="axle (PD output)")
    ax.plot(x, DEG * s[f"ack.delta{i}_left"], color="tab:blue", lw=0.9, label="left wheel")
    ax.plot(x, DEG * s[f"ack.delta{i}_right"], color="tab:red", lw=0.9, label="right wheel")
    ax.axhline(numbers["closed_form_on_path_deg"] * (1 if i % 2 else -1), color="0.5",
               ls="--", lw=0.7, label="+-asin(L1/2R)")
    ax.set_xlim(30, 130)
    ax.set_title(f"axle {i} ({'head' if i < 3 else 'tail'} car)", fontsize=9)
    ax.set_xlabel("axle position on the path s [m]")
    ax.set_ylabel("angle [deg]")
    ax.grid(alpha=0.3)
    if n == 0:
        ax.legend(fontsize=7)
fig.suptitle("Seed 003: axle-equivalent and Ackermann wheel angles (fuzzy PD, 14 km/h, "
             "R = 20 m, no transition)", fontsize=10)
fig.tight_layout()
save(fig, "seed003_angles.png")

# ---- figure 4: sweeps
fig = Figure(figsize=(9.0, 3.8))
sweeps = {}
for k, (name, key, unit, scale) in enumerate((("seed003_speed", "train.v0", "km/h", 3.6),
                                              ("seed003_radius", "err.path", "m", None))):
    out, rows = runs(name)
    ax = fig.add_subplot(1, 2, k + 1)
    table = {}
    for row in rows:
        t, s = load(out, row["run"])
        if scale:
            xval = round(float(row[key]) * scale, 6)
        else:
            xval = float(row[key].split("radius=")[1].split(",")[0])
        table.setdefault(row["variant"], []).append((xval, max(max_offsets(s))))
    for variant, marker in (("fuzzy", "o-"), ("fixed", "s--")):
        pts = sorted(table[variant])
        ax.plot([p[0] for p in pts], [100 * p[1] for p in pts], marker, label=variant)
    ax.axhline(2.5, color="k", lw=0.8, ls=":")
    ax.set_xlabel(f"{'speed' if scale else 'radius'} [{unit}]")
    ax.set_ylabel("max |offset| over the 4 axles [cm]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    sweeps[name] = {v: sorted(p) for v, p in table.items()}
fig.suptitle("Seed 003: where the fuzzy scheduling matters (kinematic plant, ideal "
             "steering)", fontsize=10)
fig.tight_layout()
save(fig, "seed003_sweeps.png")
numbers["sweeps_max_offset_m"] = sweeps

# ---- figure 5: with steering actuators
out, rows = runs("seed003_steering")
fig = Figure(figsize=(9.0, 7.0))
steering = {}
for n, run in enumerate(("fuzzy_lag", "fixed_lag", "fuzzy_delay", "fixed_delay")):
    ax = fig.add_subplot(2, 2, n + 1)
    t, s = load(out, run)
    steering[run] = max_offsets(s)
    for i in range(1, 5):
        ax.plot(s[f"err.s{i}"], 100 * s[f"err.e{i}"], color=colours[i - 1], lw=0.9,
                label=f"axle {i}")
    for lim in (2.5, -2.5):
        ax.axhline(lim, color="k", lw=0.8, ls="--")
    ax.set_xlim(30, 130)
    ax.set_title(run.replace("_lag", ": 56 ms lag").replace("_delay", ": 50 ms delay servo"),
                 fontsize=9)
    ax.set_xlabel("axle position on the path s [m]")
    ax.set_ylabel("lateral offset [cm]")
    ax.grid(alpha=0.3)
    if n == 0:
        ax.legend(fontsize=7, loc="lower left")
fig.suptitle("Seed 003 with steering actuators between PD and Ackermann (14 km/h, R = 20 m);"
             "\ndashed: the paper's 2.5 cm bound", fontsize=10)
fig.tight_layout()
save(fig, "seed003_steering.png")
numbers["steering_max_offset_m"] = steering

Path("results/seed003_numbers.json").write_text(json.dumps(numbers, indent=1))
print(json.dumps(numbers, indent=1))
PY
echo "figures: experiments/figures/seed003_*.png"
