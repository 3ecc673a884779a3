"""Figures and numbers of the kinematic-vs-dynamic experiments (seed 000, 003, 004).

Usage (from the repository root, after the runs of experiments/figures/make_dynamic.sh):

    python experiments/figures/dynamic_figures.py seed000|seed003|seed004

Reads results/<manifest>/, writes experiments/figures/<seed>_dynamic*.png and
results/<seed>_dynamic_numbers.json, and prints the tables the results pages quote.
"""

import csv
import json
import math
import sys
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from agv_cosim.timeseries import read_timeseries

FIG = Path("experiments/figures")
RESULTS = Path("results")
DEG = 180.0 / math.pi


def save(fig, name):
    FigureCanvasAgg(fig)
    fig.savefig(FIG / name, dpi=110, metadata={"Software": None})


def summary(name):
    with open(RESULTS / name / "summary.csv", newline="") as handle:
        return {row["run"]: row for row in csv.DictReader(handle)}


def series(name, run):
    return read_timeseries(RESULTS / name / run / "timeseries.csv")


def prony_damping(t, e, order, t_max=8.0):
    """Damping ratio of the oscillatory pole pair with the largest real part of a
    least-squares ``order`` recurrence fitted to e(t) (uniform samples, t <= t_max)."""
    e = e[t <= t_max]
    ts = t[1] - t[0]
    n = len(e)
    lhs = np.column_stack([e[order - 1 - i:n - 1 - i] for i in range(order)])
    coeffs = np.linalg.lstsq(lhs, e[order:], rcond=None)[0]
    poles = np.log(np.roots(np.r_[1.0, -coeffs]).astype(complex)) / ts
    pairs = poles[poles.imag > 0.1]
    pair = pairs[np.argmax(pairs.real)]
    return float(-pair.real / abs(pair))


# ---------------------------------------------------------------------------- seed 000
def seed000_plant(coefficient_per_deg=0.12):
    """The seed-000 AGV of experiments/seed000_dynamic.toml (linear tyres)."""
    from agv_core.dynamic_vehicle.dynamic_vehicle import SingleTrackParameters

    load = 400.0 * 9.81 / 2.0
    c = coefficient_per_deg * DEG * load
    return SingleTrackParameters(1.4944, 400.0, 167.0, 0.7472, c, c, 0.8, "linear")


def seed000():
    from scipy.optimize import brentq

    from agv_core.state_feedback.state_feedback import PAPER_GAINS, loop_poles

    name = "seed000_dynamic"
    rows = summary(name)
    speeds = sorted({float(r["vehicle.v0"]) for r in rows.values()})
    L, K, E0 = 1.4944, 0.6, 0.1
    plant = seed000_plant()
    numbers = {"runs": {}, "analysis": {}, "limits": {}}
    table = []
    for model in "abc":
        for v in speeds:
            kin, dyn = f"{model}_kin__vehicle.v0={v}", f"{model}_dyn__vehicle.v0={v}"
            tk, sk = series(name, kin)
            td, sd = series(name, dyn)
            ek, ed = sk["sensor.lateral_error"], sd["sensor.lateral_error"]
            entry = {"status": (rows[kin]["status"], rows[dyn]["status"]),
                     "overshoot": (float(rows[kin]["lateral_error_overshoot_ratio"]),
                                   float(rows[dyn]["lateral_error_overshoot_ratio"])),
                     "settling": tuple(float(rows[r]["lateral_error_settling_time"] or "nan")
                                       for r in (kin, dyn)),
                     "max_difference_e0": float(np.max(np.abs(ek - ed)) / E0),
                     "late_e0": (float(np.max(np.abs(ek[tk >= 13.0])) / E0),
                                 float(np.max(np.abs(ed[td >= 13.0])) / E0)),
                     "peak_alpha": (float(np.max(np.abs(sk["act.alpha"]))),
                                    float(np.max(np.abs(sd["act.alpha"]))))}
            if model in "ab":
                delay = 0.05 if model == "a" else 0.0
                entry["zeta_linear"] = (
                    loop_poles(PAPER_GAINS, v, L, K, delay=delay)["dominant_damping"],
                    loop_poles(PAPER_GAINS, v, L, K, plant, delay=delay)["dominant_damping"])
            if model == "b":
                entry["zeta_fitted"] = (prony_damping(tk, ek, 3), prony_damping(td, ed, 5))
            numbers["runs"][f"{model} {v}"] = entry
            table.append((model, v, entry))
    # stability limits (analysis) and their sensitivity to the cornering stiffness
    for coefficient in (0.08, 0.12, 0.18):
        p = seed000_plant(coefficient)

        def zeta(V, delay, p=p):
            return loop_poles(PAPER_GAINS, V, L, K, p, delay=delay)["dominant_damping"]

        numbers["limits"][str(coefficient)] = {"a": brentq(lambda V: zeta(V, 0.05), 1.0, 8.0),
                                               "b": brentq(lambda V: zeta(V, 0.0), 1.0, 8.0)}
    numbers["limits"]["kinematic"] = {"a": brentq(lambda V: loop_poles(
        PAPER_GAINS, V, L, K, delay=0.05)["dominant_damping"], 1.0, 8.0)}
    (RESULTS / "seed000_dynamic_numbers.json").write_text(json.dumps(numbers, indent=1))

    print("| model | V0 [m/s] | overshoot / e0 kin / dyn | settling [s] kin / dyn | "
          "max \\|e_dyn - e_kin\\| / e0 | \\|e\\| / e0 in 13-15 s kin / dyn | "
          "zeta linear kin / dyn | zeta fitted kin / dyn |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for model, v, e in table:
        def fmt(pair, digits=3):
            return " / ".join("> 15" if math.isnan(x) else f"{x:.{digits}f}" for x in pair)
        zl = fmt(e["zeta_linear"]) if "zeta_linear" in e else "-"
        zf = fmt(e["zeta_fitted"]) if "zeta_fitted" in e else "-"
        print(f"| {model} | {v:g} | {fmt(e['overshoot'])} | {fmt(e['settling'], 2)} | "
              f"{e['max_difference_e0']:.3f} | {fmt(e['late_e0'])} | {zl} | {zf} |")
    print(json.dumps(numbers["limits"], indent=1))

    # figure 1: deviations, kinematic dashed, dynamic solid
    show = [v for v in (2.0, 3.0, 3.5, 4.0) if v in speeds]
    fig = Figure(figsize=(11.0, 8.0))
    for r, model in enumerate("abc"):
        for c, v in enumerate(show[:4]):
            ax = fig.add_subplot(3, min(4, len(show)), r * min(4, len(show)) + c + 1)
            for plant_name, style in (("kin", "--"), ("dyn", "-")):
                t, s = series(name, f"{model}_{plant_name}__vehicle.v0={v}")
                ax.plot(t, 100 * s["sensor.lateral_error"], style, lw=1.0,
                        color="tab:blue" if plant_name == "kin" else "tab:red",
                        label="kinematic" if plant_name == "kin" else "dynamic (tyre slip)")
            ax.set_ylim(-12, 12)
            ax.grid(alpha=0.3)
            ax.set_title(f"model {model}, V0 = {v:g} m/s", fontsize=9)
            if c == 0:
                ax.set_ylabel("e [cm]")
            if r == 2:
                ax.set_xlabel("t [s]")
            if r == 0 and c == 0:
                ax.legend(fontsize=7)
    fig.suptitle("Seed 000 with tyre slip: 0.1 m step, the 1 m/s gains; kinematic (dashed) "
                 "vs dynamic single-track vehicle (solid)\n(1 m/s: the two coincide within "
                 "1.2 % of the step; an end stop at 35 deg bounds the unstable runs)",
                 fontsize=10)
    fig.tight_layout()
    save(fig, "seed000_dynamic.png")

    # figure 2: damping of the dominant pair against speed
    fig = Figure(figsize=(9.0, 5.0))
    ax = fig.add_subplot(1, 1, 1)
    grid = np.linspace(0.8, 5.5, 95)  # below ~0.7 m/s the loop poles are real
    for model, delay, colour in (("a", 0.05, "tab:red"), ("b", 0.0, "tab:blue")):
        kin = [loop_poles(PAPER_GAINS, V, L, K, delay=delay)["dominant_damping"] for V in grid]
        ax.plot(grid, kin, "--", color=colour, label=f"model {model}, kinematic")
        band = np.array([[loop_poles(PAPER_GAINS, V, L, K, seed000_plant(c), delay=delay)
                          ["dominant_damping"] for V in grid] for c in (0.08, 0.12, 0.18)])
        ax.plot(grid, band[1], "-", color=colour, label=f"model {model}, dynamic (0.12 /deg)")
        ax.fill_between(grid, band[0], band[2], color=colour, alpha=0.15)
    fitted = [(v, numbers["runs"][f"b {v}"]["zeta_fitted"]) for v in speeds]
    ax.plot([v for v, _ in fitted], [z[0] for _, z in fitted], "o", mfc="none",
            color="tab:blue", label="model b, fitted to the kinematic runs")
    ax.plot([v for v, _ in fitted], [z[1] for _, z in fitted], "s", color="tab:blue",
            label="model b, fitted to the dynamic runs")
    ax.axhline(0.0, color="k", lw=0.8)
    ax.axvline(3.0, color="0.5", lw=0.8, ls=":")
    ax.set_xlabel("speed V0 [m/s]")
    ax.set_ylabel("damping ratio of the dominant pole pair")
    ax.set_ylim(-0.3, 1.0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper right")
    ax.set_title("Seed 000: closed-loop damping, linear analysis (lines; band: cornering "
                 "stiffness 0.08-0.18 /deg of load)\nand fits to the simulations (markers); "
                 "dotted: the paper's 3 m/s", fontsize=9)
    fig.tight_layout()
    save(fig, "seed000_dynamic_damping.png")


# ---------------------------------------------------------------------------- seed 003
def max_offsets(s):
    return [float(np.max(np.abs(s[f"err.e{i}"]))) for i in range(1, 5)]


def seed003():
    numbers = {}
    fig = Figure(figsize=(13.0, 4.4))
    panels = (("seed003_dynamic_speed", "train.v0", "speed [km/h] (R = 20 m)"),
              ("seed003_dynamic_fast", "train.v0", "speed [km/h] (R = 200 m, 0.5 rad)"),
              ("seed003_dynamic_radius", "err.path", "radius [m] (14 km/h)"))
    for k, (name, key, label) in enumerate(panels):
        rows = summary(name)
        table = {}
        for run, row in rows.items():
            _, s = series(name, run)
            if key == "train.v0":
                x = round(float(row[key]) * 3.6, 6)
            else:
                x = float(row[key].split("radius=")[1].split(",")[0])
            table.setdefault(row["variant"], {})[x] = {
                "max_offsets_m": max_offsets(s), "status": row["status"],
                "max_pd_delta_deg": max(float(np.max(np.abs(s[f"pd{i}.delta"]))) * DEG
                                        for i in range(1, 5))}
        numbers[name] = table
        xs = sorted(table["kin_fuzzy"])
        print(f"\n{name}: max |offset| over the 4 axles [cm] (axles 1 / 2 / 3 / 4 for dyn)")
        print("| " + ("speed [km/h]" if key == "train.v0" else "radius [m]") +
              " | kinematic fuzzy | kinematic fixed | dynamic fuzzy | dynamic fixed | "
              "dynamic fuzzy, per axle | dynamic fixed, per axle |")
        print("| --- | --- | --- | --- | --- | --- | --- |")
        for x in xs:
            cells = [f"{100 * max(table[v][x]['max_offsets_m']):.2f}"
                     for v in ("kin_fuzzy", "kin_fixed", "dyn_fuzzy", "dyn_fixed")]
            per = [" / ".join(f"{100 * e:.2f}" for e in table[v][x]["max_offsets_m"])
                   + ("" if table[v][x]["status"] == "complete"
                      else f" (run {table[v][x]['status']})")
                   for v in ("dyn_fuzzy", "dyn_fixed")]
            print(f"| {x:g} | " + " | ".join(cells + per) + " |")
        ax = fig.add_subplot(1, 3, k + 1)
        for variant, style, colour in (("kin_fuzzy", "o--", "tab:blue"),
                                       ("kin_fixed", "s--", "tab:orange"),
                                       ("dyn_fuzzy", "o-", "tab:blue"),
                                       ("dyn_fixed", "s-", "tab:orange")):
            ax.plot(xs, [100 * max(table[variant][x]["max_offsets_m"]) for x in xs], style,
                    color=colour, label=variant.replace("_", ", ").replace("kin", "kinematic")
                    .replace("dyn", "dynamic"), mfc="none" if "kin" in variant else None)
        ax.axhline(2.5, color="k", lw=0.8, ls=":")
        ax.set_yscale("log")
        ax.set_xlabel(label)
        ax.set_ylabel("max |offset| over the 4 axles [cm]")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    fig.suptitle("Seed 003: kinematic (open markers, dashed) vs dynamic train (solid), fuzzy "
                 "vs fixed PD; dotted: the paper's 2.5 cm", fontsize=10)
    fig.tight_layout()
    save(fig, "seed003_dynamic_sweeps.png")

    # offsets along the path at the speeds where the plants part
    name = "seed003_dynamic_speed"
    rows = summary(name)
    speeds = (14.0, 30.0, 35.0)
    fig = Figure(figsize=(11.0, 7.5))
    colours = ["tab:blue", "tab:orange", "tab:green", "tab:red"]
    for c, kmh in enumerate(speeds):
        for r, variant in enumerate(("kin_fuzzy", "dyn_fuzzy", "dyn_fixed")):
            run = next(k for k, row in rows.items() if row["variant"] == variant
                       and abs(float(row["train.v0"]) * 3.6 - kmh) < 1e-6)
            _, s = series(name, run)
            ax = fig.add_subplot(3, len(speeds), r * len(speeds) + c + 1)
            for i in range(1, 5):
                ax.plot(s[f"err.s{i}"], 100 * s[f"err.e{i}"], color=colours[i - 1], lw=0.9,
                        label=f"axle {i}")
            ax.axhline(2.5, color="k", lw=0.7, ls="--")
            ax.axhline(-2.5, color="k", lw=0.7, ls="--")
            ax.set_xlim(40, 140)
            lim = max(3.0, min(60.0, 1.1 * 100 * max(max_offsets(s))))
            ax.set_ylim(-lim, lim)
            ax.set_title(f"{variant.replace('_', ', ')}, {kmh:g} km/h", fontsize=9)
            ax.grid(alpha=0.3)
            if r == 2:
                ax.set_xlabel("axle position on the path s [m]")
            if c == 0:
                ax.set_ylabel("offset [cm]")
            if r == 0 and c == 0:
                ax.legend(fontsize=7)
    fig.suptitle("Seed 003: each axle's lateral offset through the 20 m curve (arc from "
                 "s = 60 to 91 m); dashed: 2.5 cm", fontsize=10)
    fig.tight_layout()
    save(fig, "seed003_dynamic_offsets.png")
    (RESULTS / "seed003_dynamic_numbers.json").write_text(json.dumps(numbers, indent=1))


# ---------------------------------------------------------------------------- seed 004
def seed004():
    name = "seed004_dynamic"
    out = RESULTS / name
    field = {"sine": (20, 1, 10), "r907": (20, 8, 5), "r440": (13, 2, 3), "r277": (35, 15, 12)}
    titles = {"sine": "sine y = 2 sin(x/3)", "r907": "circle r = 9.07 m (slope)",
              "r440": "circle r = 4.40 m", "r277": "circle r = 2.77 m"}
    numbers = {}
    print("| path | field max / mean / std | plant | paper's law | with dead reckoning | "
          "rear-axle slip, mean [deg] |")
    print("| --- | --- | --- | --- | --- | --- |")
    for path in field:
        for plant in ("kin", "dyn", "soft"):
            cells = []
            for dr in ("False", "True"):
                run = f"{path}_{plant}__ctrl.dead_reckoning={dr}"
                m = json.loads((out / run / "metrics.json").read_text())
                stats = [100 * m[f"lateral_error_settled_{k}"]
                         for k in ("max", "signed_mean", "std")]
                numbers[run] = stats
                cells.append(f"{stats[0]:.1f} / {stats[1]:+.1f} / {stats[2]:.1f}")
            # the rear axle's sideslip: direction of its recorded (noise-free, simulated)
            # track minus the heading, by central differences of the 50 ms record
            t, s = series(name, f"{path}_{plant}__ctrl.dead_reckoning=False")
            x, y, h = s["vehicle.x_rear"], s["vehicle.y_rear"], s["vehicle.heading"]
            track = np.arctan2(y[2:] - y[:-2], x[2:] - x[:-2])
            slip_series = np.angle(np.exp(1j * (track - h[1:-1])))
            slip = f"{np.mean(slip_series[t[1:-1] >= 10.0]) * DEG:+.2f}"
            numbers[f"{path}_{plant}_rear_slip_deg"] = float(slip)
            f = field[path]
            plant_text = {"kin": "kinematic", "dyn": "dynamic 0.08 /deg",
                          "soft": "dynamic 0.04 /deg"}[plant]
            print(f"| {titles[path]} | {f[0]} / {f[1]} / {f[2]} | {plant_text} | "
                  f"{cells[0]} | {cells[1]} | {slip} |")
    (RESULTS / "seed004_dynamic_numbers.json").write_text(json.dumps(numbers, indent=1))

    fig = Figure(figsize=(11.0, 8.0))
    for i, path in enumerate(field):
        for j, dr in enumerate(("False", "True")):
            ax = fig.add_subplot(4, 2, 2 * i + j + 1)
            for plant, colour in (("kin", "tab:blue"), ("dyn", "tab:red"),
                                  ("soft", "tab:purple")):
                t, s = series(name, f"{path}_{plant}__ctrl.dead_reckoning={dr}")
                ax.plot(s["vehicle.distance"], 100 * s["truth.lateral_error"], color=colour,
                        lw=0.9, label={"kin": "kinematic", "dyn": "dynamic, 0.08 /deg",
                                       "soft": "dynamic, 0.04 /deg"}[plant])
            f = field[path][0]
            ax.axhline(f, color="k", lw=0.7, ls=":")
            ax.axhline(-f, color="k", lw=0.7, ls=":")
            ax.axvline(15.0, color="0.5", lw=0.6)
            ax.set_title(f"{titles[path]}, " + ("paper's law" if dr == "False"
                                                else "with dead reckoning"), fontsize=9)
            ax.set_ylabel("e [cm]")
            ax.grid(alpha=0.3)
            if i == 3:
                ax.set_xlabel("distance travelled [m] (statistics from 15 m)")
            if i == 0 and j == 0:
                ax.legend(fontsize=7)
    fig.suptitle("Seed 004 with tyre slip: rear-axle offset (positive left), 1.5 m/s, total "
                 "station 0.65 s; dotted: the field's max |e|", fontsize=10)
    fig.tight_layout()
    save(fig, "seed004_dynamic.png")


if __name__ == "__main__":
    {"seed000": seed000, "seed003": seed003, "seed004": seed004}[sys.argv[1]]()
