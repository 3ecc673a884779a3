"""Figures and metric tables of experiments/seed001.md, from the runs' recorded results.

Reads results/seed001_circle_lambda/, results/seed001_circle_horizon/, results/seed001_scurve/
(written by make_seed001.sh), draws experiments/figures/seed001_*.png and prints the
per-run metrics as Markdown tables (pasted into the results page). Metrics, on the
0.2 s sample grid of the records:

- first-10-s error: time mean of the position error e_pos = |(x, y) - (x_r, y_r)| over
  [0, 10] s (trapezoidal), the initial phase of claim 001-R2;
- late error: time mean of e_pos over [60, 80] s (circle) or of |e_lat| over
  [18, 70] s (S-curve);
- v_c overshoot: max(v_c) - v_r;
- max steering rate: max |theta_f(k) - theta_f(k-1)| / T over the commanded front-wheel
  angle at consecutive samples (the steering is ideal, so the wheel follows each sample's
  command: this is the discrete rate the paper's 0.2 rad/s statement refers to);
- settling time: the orchestrator's lateral_error_settling_time (band 1 cm);
- OSQP iterations per sample: median and max of ctrl.iterations.
"""

import csv
import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from agv_core.ref_trajectory.ref_trajectory import RefTrajectory  # noqa: E402
from agv_cosim.timeseries import read_timeseries  # noqa: E402

T = 0.2
V_R = 0.4
ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "results"
FIGURES = ROOT / "experiments" / "figures"


def window_mean(t, x, t0, t1):
    """Trapezoidal time mean of x over [t0, t1] (samples inside the window)."""
    m = (t >= t0 - 1e-9) & (t <= t1 + 1e-9)
    return float(np.trapezoid(x[m], t[m]) / (t[m][-1] - t[m][0]))


def runs(name):
    """[(label, time, signals, metrics)] of the runs of results/<name>/ in summary order."""
    out = RESULTS / name
    labels = [row["run"] for row in csv.DictReader(open(out / "summary.csv", newline=""))]
    data = []
    for label in labels:
        t, sig = read_timeseries(out / label / "timeseries.csv")
        metrics = json.loads((out / label / "metrics.json").read_text())
        data.append((label, t, sig, metrics))
    return data


def seed001_metrics(t, sig, metrics, late=(60.0, 80.0), late_signal="ctrl.e_pos"):
    """The metrics of the module docstring, as a dict."""
    rate = np.abs(np.diff(sig["ik.theta_f"])) / T
    row = {
        "first10_cm": 100 * window_mean(t, sig["ctrl.e_pos"], 0.0, 10.0),
        "late_cm": 100 * window_mean(t, np.abs(sig[late_signal]), *late),
        "vc_overshoot_cms": 100 * (sig["ctrl.v_c"].max() - V_R),
        "max_rate": float(rate.max()),
        "max_rate_after_first": float(rate[1:].max()),
        "settling_s": metrics.get("lateral_error_settling_time"),
    }
    if "ctrl.iterations" in sig:
        row["iter_median"] = float(np.median(sig["ctrl.iterations"]))
        row["iter_max"] = float(sig["ctrl.iterations"].max())
    return row


def table(rows, key_name):
    head = (f"| {key_name} | error 0-10 s [cm] | late error [cm] | v_c overshoot [cm/s] | "
            "max steering rate [rad/s] | settling (1 cm) [s] | OSQP iterations median / max |")
    lines = [head, "| " + " | ".join("---" for _ in range(7)) + " |"]
    for key, r in rows:
        settle = "-" if r["settling_s"] is None else f"{r['settling_s']:.1f}"
        iters = (f"{r['iter_median']:.0f} / {r['iter_max']:.0f}" if "iter_median" in r
                 else "-")
        lines.append(f"| {key} | {r['first10_cm']:.2f} | {r['late_cm']:.2g} | "
                     f"{r['vc_overshoot_cms']:.2f} | {r['max_rate']:.3f} | {settle} | {iters} |")
    return "\n".join(lines)


def circle_figure(data, key, title, path):
    fig, axes = plt.subplots(2, 2, figsize=(10, 6.5), sharex=True)
    for label, t, sig, _ in data:
        name = f"{key} = {label.split('=')[-1]}"
        axes[0, 0].plot(t, 100 * sig["ctrl.e_x"], label=name)
        axes[0, 1].plot(t, 100 * sig["ctrl.e_y"], label=name)
        axes[1, 0].plot(t, sig["ctrl.e_heading"], label=name)
        axes[1, 1].plot(t, sig["ctrl.v_c"], label=name)
    for ax, ylabel in zip(axes.flat, ("e_X [cm]", "e_Y [cm]", "e_alpha [rad]",
                                      "v_c command [m/s]")):
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        ax.set_xlim(0, 40)
    for ax in axes[1]:
        ax.set_xlabel("time [s]")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def horizon_rate_figure(data, path):
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for label, t, sig, _ in data:
        name = f"N = {label.split('=')[-1]}"
        axes[0].plot(t, sig["ctrl.v_c"], label=name)
        rate = np.diff(sig["ik.theta_f"]) / T
        axes[1].step(t[1:], rate, where="post", label=name)
    axes[1].axhline(0.2, color="k", ls="--", lw=0.8)
    axes[1].axhline(-0.2, color="k", ls="--", lw=0.8, label="0.2 rad/s (paper)")
    axes[0].set_ylabel("v_c command [m/s]")
    axes[1].set_ylabel("front-wheel angle rate [rad/s]")
    for ax in axes:
        ax.set_xlim(0, 15)
        ax.set_xlabel("time [s]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("Seed 001 Fig. 5 analogue: initial phase, R = 0.1 I, horizon N")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def scurve_figures(data, path_err, path_xy):
    ref = RefTrajectory("scurve", speed=0.4, amplitude=1.5, wavelength=12.0, peak_time=33.7)
    fig, ax = plt.subplots(figsize=(10, 4))
    for label, t, sig, _ in data:
        ax.plot(t, 100 * sig["ctrl.e_lat"], label=label.upper())
    ax.axvline(33.7, color="k", ls=":", lw=1, label="first curvature peak, 33.7 s")
    ax.axvline(18.0, color="grey", ls="--", lw=0.8, label="18 s")
    ax.axhspan(-1.0, 1.1, color="g", alpha=0.15, label="[-1, 1.1] cm")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("lateral error e_lat [cm] (left +)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("Seed 001 Fig. 6 analogue: S-curve, LTV MPC (N = 7, R = 0.1 I) against PID")
    fig.tight_layout()
    fig.savefig(path_err, dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(10, 5))
    tt = np.linspace(0, 70, 1401)
    pts = [ref.at(x) for x in tt]
    ax.plot([p["x"] for p in pts], [p["y"] for p in pts], "k--", lw=1.0, zorder=5,
            label="reference")
    for label, t, sig, _ in data:
        ax.plot(sig["vehicle.x"], sig["vehicle.y"], label=label.upper())
    p = ref.at(33.7)
    ax.plot(p["x"], p["y"], "k*", ms=10, label="first curvature peak (33.7 s)")
    ax.set_aspect("equal")
    ax.set_xlabel("X [m]")
    ax.set_ylabel("Y [m]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("S-curve: reference and centroid trajectories")
    fig.tight_layout()
    fig.savefig(path_xy, dpi=110)
    plt.close(fig)


def rate_limit_figure(data, path):
    """Initial phase of experiments/seed001_rate_limit.toml: actuators with / without
    the 0.2 rad/s limit, colour = N, line style = variant."""
    fig, axes = plt.subplots(3, 1, figsize=(10, 8), sharex=True)
    colours = {"5": "C0", "6": "C1", "7": "C2", "8": "C3"}
    for label, t, sig, _ in data:
        variant, n = label.split("__")[0], label.split("=")[-1]
        style = "-" if variant == "limited" else ":"
        kw = dict(color=colours[n], ls=style, label=f"{variant}, N = {n}")
        axes[0].plot(t, 100 * sig["ctrl.e_pos"], **kw)
        axes[1].plot(t, sig["act_f.alpha"], **kw)
        axes[2].plot(t, sig["act_f.alpha_rate"], **kw)
    axes[2].axhline(0.2, color="k", ls="--", lw=0.8)
    axes[2].set_ylim(-0.6, 0.6)
    for ax, ylabel in zip(axes, ("e_pos [cm]", "front wheel angle [rad]",
                                 "front wheel rate [rad/s] (clipped view)")):
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    axes[2].set_xlim(0, 15)
    axes[2].set_xlabel("time [s]")
    axes[0].legend(fontsize=7, ncol=2)
    fig.suptitle("Seed 001 N3: steering actuators with the 0.2 rad/s limit (solid) or "
                 "without (dotted)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main():
    lam = runs("seed001_circle_lambda")
    hor = runs("seed001_circle_horizon")
    sc = runs("seed001_scurve")
    circle_figure(lam, "lambda", "Seed 001 Fig. 4 analogue: circle, p = 5, R = lambda I",
                  FIGURES / "seed001_circle_lambda.png")
    circle_figure(hor, "N", "Seed 001 Fig. 5 analogue: circle, R = 0.1 I, horizon N",
                  FIGURES / "seed001_circle_horizon.png")
    horizon_rate_figure(hor, FIGURES / "seed001_circle_horizon_rate.png")
    scurve_figures(sc, FIGURES / "seed001_scurve.png", FIGURES / "seed001_scurve_path.png")
    if (RESULTS / "seed001_rate_limit" / "summary.csv").is_file():
        limited = runs("seed001_rate_limit")
        rate_limit_figure(limited, FIGURES / "seed001_rate_limit.png")
        print("### steering actuators (seed001_rate_limit)\n")
        print("| run | error 0-10 s [cm] | e_pos 30-50 s [mm] | v_c overshoot [cm/s] | "
              "time at 0.2 rad/s [s] | settling (1 cm) [s] |")
        print("| --- | --- | --- | --- | --- | --- |")
        for label, t, sig, m in limited:
            print(f"| {label.replace('__ctrl.horizon=', ', N = ')} | "
                  f"{100 * window_mean(t, sig['ctrl.e_pos'], 0.0, 10.0):.2f} | "
                  f"{1000 * window_mean(t, sig['ctrl.e_pos'], 30.0, 50.0):.4f} | "
                  f"{100 * (sig['ctrl.v_c'].max() - V_R):.2f} | {m['saturated_time']:.2f} | "
                  f"{m['lateral_error_settling_time']:.1f} |")
        print()
    print("### circle, lambda sweep (p = 5)\n")
    print(table([(f"lambda = {l.split('=')[-1]}", seed001_metrics(t, s, m))
                 for l, t, s, m in lam], "run"))
    print("\n### circle, horizon sweep (R = 0.1 I)\n")
    print(table([(f"N = {l.split('=')[-1]}", seed001_metrics(t, s, m))
                 for l, t, s, m in hor], "run"))
    print("\n### S-curve (late error = mean |e_lat| over 18-70 s)\n")
    print(table([(l.upper(), seed001_metrics(t, s, m, late=(18.0, 70.0),
                                              late_signal="ctrl.e_lat"))
                 for l, t, s, m in sc], "run"))
    print("\n### S-curve, lateral error details\n")
    for l, t, s, m in sc:
        e = s["ctrl.e_lat"]
        after = t >= 18.0 - 1e-9
        w = (t >= 33.7) & (t <= 40.0)
        i = int(np.argmax(np.abs(np.where(w, e, 0.0))))
        print(f"- {l.upper()}: e_lat for t >= 18 s in [{100 * e[after].min():.2f}, "
              f"{100 * e[after].max():.2f}] cm; peak in [33.7, 40] s {100 * e[i]:.2f} cm at "
              f"{t[i]:.1f} s; RMS for t >= 18 s "
              f"{100 * m['lateral_error_settled_rms']:.2f} cm")
    return 0


if __name__ == "__main__":
    sys.exit(main())
