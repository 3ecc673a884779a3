"""Scenarios, tuning, table and figures of experiments/baselines.md.

``experiments/baselines.toml`` is one scenario (kinematic vehicle, actuator a, sine,
2 m/s) with one variant per law. This script rewrites it into every scenario of the page
(:func:`scenario_manifest`: the vehicle, the actuator, the path and the speed, in every
place each appears: the vehicle's v0 and heading0, every ``path`` parameter, the metrics'
reference, the ``speed`` of the laws that read it), runs them through
:func:`agv_cosim.run`, and

- ``tune``: runs each law's gain grid (:data:`GRIDS`, a ``[sweep]`` added to the
  scenario manifest, one manifest per law and tuning scenario) on the tuning scenarios
  (:data:`TUNING`) and writes ``tuning.csv``: the cost :func:`cost` of every grid point,
  averaged over the tuning scenarios; the best point of each law is the one
  experiments/baselines.toml carries;
- ``run``: runs the six laws (the toml's gains) on every scenario (:data:`SCENARIOS`)
  and writes ``table.csv``;
- ``page``: draws the figures and prints the page's tables from those files.

Usage (from the repository root):
``python experiments/figures/baselines.py tune|run|page [--out results/baselines]``
(``sh experiments/figures/make_baselines.sh`` does all three).
"""

import argparse
import copy
import csv
import json
import math
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
MANIFEST = ROOT / "experiments" / "baselines.toml"
FIGURES = ROOT / "experiments" / "figures"
RESULTS = ROOT / "results" / "baselines"

SINE = "sine:amplitude=2,wavelength=18.84955592153876"
CIRCLE = "circle:radius=10"
PATHS = {"sine": (SINE, 0.5880026035475675), "circle": (CIRCLE, 0.0)}  # spec, start heading
VEHICLES = {"kin": "AgvVehicle", "dyn": "AgvDynamicVehicle"}
ACTUATORS = {"a": ("AgvSteeringA", {"tau": 0.05}), "c": ("AgvSteeringC", {})}
LAWS = {"state_feedback": "seed 000 LQR state feedback",
        "chained_form": "seed 002 chained form",
        "preview_lq": "seed 004 preview LQ",
        "pure_pursuit": "pure pursuit",
        "stanley": "Stanley",
        "rear_wheel": "rear-wheel feedback"}


def label(vehicle, actuator, path, speed):
    """The scenario's name, e.g. ``kin_a_sine_2.5``."""
    return f"{vehicle}_{actuator}_{path}_{speed:g}"


#: every scenario of the page: (vehicle, actuator, path, speed [m/s])
SCENARIOS = ([(v, "a", p, s) for v in VEHICLES for p in PATHS for s in (1.0, 2.5, 4.0)]
             + [("kin", "c", p, s) for p in PATHS for s in (1.0, 4.0)]
             + [("dyn", "c", "sine", 4.0)])
#: the tuning scenarios: every law is tuned on these, by the same grid search
TUNING = [("kin", "a", "sine", 1.0), ("kin", "a", "sine", 4.0), ("dyn", "a", "circle", 4.0)]
#: each law's main gains and the grid searched (every combination); the other parameters
#: keep the values of experiments/baselines.toml
GRIDS = {
    "state_feedback": {"ctrl.Ke": [2.0, 4.472, 8.0], "ctrl.Kb": [2.0, 3.767, 6.0]},
    "chained_form": {"ctrl.Kp": [0.09, 0.3, 1.0], "ctrl.Kd": [0.6, 1.2, 2.0]},
    "preview_lq": {"ctrl.tau": [0.2, 0.4, 0.65, 1.0, 1.5]},
    "pure_pursuit": {"ctrl.k_ld": [0.0, 0.2, 0.5], "ctrl.L_min": [1.0, 2.0, 3.0]},
    "stanley": {"ctrl.k": [0.5, 1.0, 2.5, 5.0, 10.0]},
    "rear_wheel": {"ctrl.k_theta": [0.5, 1.0, 2.0], "ctrl.k_e": [0.25, 0.5, 1.0]},
}
#: the tuning runs' length [s] (settled window 10-20 s; the page's runs are 30 s)
TUNING_STOP = 20.0
#: the steering-rate penalty of the cost [m per rad/s]
RATE_WEIGHT = 0.1


def cost(row):
    """The tuning cost [m] of one run's summary row: the RMS over the settled window of
    the rear-axle and the front-wheel offsets together, sqrt((rms_r^2 + rms_f^2) / 2),
    plus RATE_WEIGHT times the RMS wheel rate over the run; inf for a run that did not
    complete."""
    if row["status"] != "complete":
        return math.inf
    rear, front = float(row["lateral_error_settled_rms"]), float(row["path_error_settled_rms"])
    return math.sqrt((rear * rear + front * front) / 2.0) + RATE_WEIGHT * float(
        row["steering_rate_rms"])


# ---------------------------------------------------------------------------- manifests
def _toml_value(value):
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{_key(k)} = {_toml_value(v)}" for k, v in value.items()) + " }"
    raise TypeError(f"no TOML for {value!r}")


def _key(key):
    return key if key.replace("_", "").isalnum() else json.dumps(key)


#: keys whose tables are written inline (``key = { ... }``)
INLINE = ("parameters", "reference", "saturation", "interpolation", "units")


def to_toml(data, prefix=()):
    """TOML text of a manifest dict: scalars and INLINE tables as ``key = value``, other
    tables as ``[a.b]`` sections, lists of tables as ``[[a.b]]``."""
    lines, sections = [], []
    for key, value in data.items():
        if isinstance(value, dict) and key not in INLINE:
            sections.append((key, value))
        elif _is_table_list(value):
            sections.append((key, value))
        else:
            lines.append(f"{_key(key)} = {_toml_value(value)}")
    for key, value in sections:
        name = ".".join(_key(k) for k in (*prefix, key))
        if isinstance(value, list):
            for item in value:
                lines += ["", f"[[{name}]]", to_toml(item, (*prefix, key))]
        else:
            lines += ["", f"[{name}]", to_toml(value, (*prefix, key))]
    return "\n".join(lines).strip("\n")


def _is_table_list(value):
    return isinstance(value, list) and bool(value) and all(isinstance(v, dict) for v in value)


def load_base(manifest=MANIFEST):
    with open(manifest, "rb") as handle:
        return tomllib.load(handle)


def _set_path(parameters, spec):
    if "path" in parameters:
        parameters["path"] = spec


def scenario_manifest(base, vehicle, actuator, path, speed, fmus, stop=None):
    """The manifest dict of one scenario: ``base`` (experiments/baselines.toml) with the
    vehicle, actuator, path and speed replaced wherever they appear; FMU paths from
    ``fmus`` (model name -> path)."""
    data = copy.deepcopy(base)
    spec, heading0 = PATHS[path]
    data["name"] = f"baselines_{label(vehicle, actuator, path, speed)}"
    data["description"] = (f"{VEHICLES[vehicle]}, actuator {actuator}, {spec}, {speed:g} m/s "
                           "(experiments/figures/baselines.py from experiments/baselines.toml)")
    if stop is not None:
        data["simulation"]["stop"] = float(stop)
    comps = data["components"]
    comps["vehicle"]["fmu"] = VEHICLES[vehicle]
    comps["vehicle"]["parameters"].update(v0=float(speed), heading0=heading0)
    model, extra = ACTUATORS[actuator]
    comps["act"]["fmu"] = model
    act = comps["act"]["parameters"]
    act.pop("tau", None)
    act.update(extra)
    for component in comps.values():
        _set_path(component.get("parameters", {}), spec)
    for variant in data.get("variants", {}).values():
        for component in variant.get("components", {}).values():
            parameters = component.get("parameters", {})
            _set_path(parameters, spec)
            if "speed" in parameters:
                parameters["speed"] = float(speed)
    data["metrics"]["reference"]["path"] = spec
    _point_fmus(data, fmus)
    return data


def _point_fmus(data, fmus):
    def point(component):
        if "fmu" in component:
            stem = Path(component["fmu"]).stem
            component["fmu"] = str(fmus[stem])
    for component in data["components"].values():
        point(component)
    for variant in data.get("variants", {}).values():
        for component in variant.get("components", {}).values():
            point(component)


def default_fmus():
    """Model name -> FMU path of the repository's fmus/ folder."""
    return {p.stem: p.resolve() for p in (ROOT / "fmus").glob("*.fmu")}


def run_scenario(data, out, variants=None, sweep=None, jobs=2, reuse=True):
    """Write ``data`` (plus ``sweep``) to ``out``.toml and run it into ``out``; returns the
    summary rows (a run that did not complete has its status there). With ``reuse``, a
    result folder run from the very same manifest text is read, not run again."""
    import agv_cosim

    data = copy.deepcopy(data)
    if sweep:
        data["sweep"] = sweep
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    manifest = out.with_suffix(".toml")
    text = to_toml(data) + "\n"
    done = (out / "summary.csv").is_file() and manifest.is_file() and (
        manifest.read_text() == text and reuse)
    if not done:
        manifest.write_text(text)
        agv_cosim.run(manifest, out=out, variants=variants, quiet=True, overwrite=True,
                      jobs=jobs)
    with open(out / "summary.csv", newline="") as handle:
        return list(csv.DictReader(handle))


# ---------------------------------------------------------------------------- steps
def tune(out=RESULTS, fmus=None, scenarios=TUNING, grids=GRIDS, stop=TUNING_STOP, jobs=2):
    """Run every law's grid on the tuning scenarios; write and return tuning.csv's rows
    (law, gains, cost per scenario, mean cost)."""
    fmus = fmus or default_fmus()
    base = load_base()
    costs = {}
    for law, grid in grids.items():
        for scenario in scenarios:
            data = scenario_manifest(base, *scenario, fmus, stop=stop)
            rows = run_scenario(data, Path(out) / "tuning" / f"{law}_{label(*scenario)}",
                                variants=[law], sweep=grid, jobs=jobs)
            for row in rows:
                gains = tuple(float(row[name]) for name in grid)
                costs.setdefault((law, gains), {})[label(*scenario)] = cost(row)
    table = []
    for (law, gains), by_scenario in costs.items():
        names = [n.split(".", 1)[1] for n in grids[law]]
        table.append({"law": law, "gains": " ".join(f"{n}={g:g}" for n, g in zip(names, gains)),
                      **{k: f"{v:.6f}" for k, v in by_scenario.items()},
                      "mean_cost": f"{sum(by_scenario.values()) / len(by_scenario):.6f}"})
    _write_csv(Path(out) / "tuning.csv", table)
    return table


def best_gains(table):
    """law -> (gains text, mean cost) of the cheapest grid point."""
    best = {}
    for row in table:
        c = float(row["mean_cost"])
        if row["law"] not in best or c < best[row["law"]][1]:
            best[row["law"]] = (row["gains"], c)
    return best


def evaluate(out=RESULTS, fmus=None, scenarios=SCENARIOS, stop=None, jobs=2):
    """Run the six laws (the toml's gains) on ``scenarios``; write and return table.csv."""
    fmus = fmus or default_fmus()
    base = load_base()
    table = []
    for scenario in scenarios:
        data = scenario_manifest(base, *scenario, fmus, stop=stop)
        rows = run_scenario(data, Path(out) / "runs" / label(*scenario), jobs=jobs)
        for row in rows:
            table.append({"scenario": label(*scenario), "law": row["run"],
                          **{k: row[k] for k in COLUMNS}, "cost": f"{cost(row):.6f}"})
    _write_csv(Path(out) / "table.csv", table)
    return table


#: summary.csv columns kept in table.csv
COLUMNS = ["lateral_error_settled_max", "lateral_error_settled_rms", "path_error_settled_max",
           "path_error_settled_rms", "steering_rate_peak", "steering_rate_rms",
           "saturated_fraction", "steering_rate_rms"]


def _write_csv(path, rows):
    path.parent.mkdir(parents=True, exist_ok=True)
    names = list(dict.fromkeys(k for row in rows for k in row))
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, names)
        writer.writeheader()
        writer.writerows(rows)


def read_csv(path):
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


# ---------------------------------------------------------------------------- page
def table_lines(table):
    """The page's result table: one line per scenario and law (cm, rad/s)."""
    lines = ["| scenario | law | rear max [cm] | rear RMS [cm] | front max [cm] | "
             "front RMS [cm] | peak rate [rad/s] | cost [cm] |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for row in table:
        lines.append(
            f"| {row['scenario']} | {row['law']} | "
            f"{100 * float(row['lateral_error_settled_max']):.1f} | "
            f"{100 * float(row['lateral_error_settled_rms']):.1f} | "
            f"{100 * float(row['path_error_settled_max']):.1f} | "
            f"{100 * float(row['path_error_settled_rms']):.1f} | "
            f"{float(row['steering_rate_peak']):.2f} | {100 * float(row['cost']):.1f} |")
    return lines


def tuning_lines(tuning):
    """The page's tuning table: every grid point's cost [cm] per tuning scenario and mean."""
    names = [label(*s) for s in TUNING]
    lines = ["| law | gains | " + " | ".join(f"{n} [cm]" for n in names) + " | mean [cm] |",
             "| --- | --- | " + " | ".join("---" for _ in names) + " | --- |"]
    for row in tuning:
        cells = [f"{100 * float(row[n]):.2f}" for n in names]
        lines.append(f"| {row['law']} | {row['gains']} | " + " | ".join(cells)
                     + f" | {100 * float(row['mean_cost']):.2f} |")
    return lines


def winners(table):
    """scenario -> laws sorted by cost (cheapest first), with their costs."""
    by = {}
    for row in table:
        by.setdefault(row["scenario"], []).append((float(row["cost"]), row["law"]))
    return {k: sorted(v) for k, v in by.items()}


def figures(out=RESULTS, figures_dir=FIGURES):
    """The page's figures: cost per law and scenario; rear and front offsets on two
    scenarios."""
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from agv_core.numerics.paths import parse_path, project_trajectory
    from agv_cosim.timeseries import read_timeseries

    table = read_csv(Path(out) / "table.csv")
    scenarios = list(dict.fromkeys(row["scenario"] for row in table))
    figure = Figure(figsize=(11, 5))
    FigureCanvasAgg(figure)
    ax = figure.subplots()
    width = 0.8 / len(LAWS)
    for i, law in enumerate(LAWS):
        values = [next(100 * float(r["cost"]) for r in table
                       if r["scenario"] == s and r["law"] == law) for s in scenarios]
        ax.bar(np.arange(len(scenarios)) + (i - 2.5) * width, values, width, label=LAWS[law])
    ax.set_xticks(np.arange(len(scenarios)), scenarios, rotation=40, ha="right", fontsize=8)
    ax.set_ylabel("cost J [cm] (log scale)")
    ax.set_yscale("log")
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=8, ncol=3)
    ax.set_title("Six laws, tuned once on the same scenarios, on every scenario "
                 "(vehicle_actuator_path_speed)", fontsize=10)
    figure.tight_layout()
    figure.savefig(figures_dir / "baselines_cost.png", dpi=110)

    for name in ("kin_a_sine_2.5", "dyn_a_circle_4"):
        if name not in scenarios:
            continue
        spec = SINE if "sine" in name else CIRCLE
        path = parse_path(spec)
        figure = Figure(figsize=(9, 6.5))
        FigureCanvasAgg(figure)
        rear, front = figure.subplots(2, 1, sharex=True)
        for law in LAWS:
            t, data = read_timeseries(Path(out) / "runs" / name / law / "timeseries.csv")
            rear.plot(t, 100 * data["truth.lateral_error"], label=LAWS[law], lw=1)
            offset, _ = project_trajectory(path, data["vehicle.x_front"],
                                           data["vehicle.y_front"])
            front.plot(t, 100 * offset, label=LAWS[law], lw=1)
        for ax, what in ((rear, "rear-axle centre"), (front, "front-wheel centre")):
            ax.axvline(10.0, color="0.5", lw=0.8, ls=":")
            ax.set_ylabel(f"{what} offset [cm]")
            ax.grid(alpha=0.3)
        rear.set_title(f"{name}: offset from the path (+ left; dotted: start of the settled "
                       "window)", fontsize=10)
        front.set_xlabel("time [s]")
        rear.legend(fontsize=8, ncol=3)
        figure.tight_layout()
        figure.savefig(figures_dir / f"baselines_{name.replace('.', '_')}.png", dpi=110)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("step", choices=["tune", "run", "page"])
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args(argv)
    if args.step == "tune":
        table = tune(args.out, jobs=args.jobs)
        for law, (gains, c) in best_gains(table).items():
            print(f"{law}: {gains} mean cost {100 * c:.2f} cm")
    elif args.step == "run":
        evaluate(args.out, jobs=args.jobs)
    else:
        figures(args.out)
        table = read_csv(args.out / "table.csv")
        print("\n".join(table_lines(table)))
        for scenario, ranked in winners(table).items():
            print(scenario, ", ".join(f"{law} {100 * c:.1f}" for c, law in ranked))
        tuning = read_csv(args.out / "tuning.csv")
        print("\n".join(tuning_lines(tuning)))
        for law, (gains, c) in best_gains(tuning).items():
            print(f"best {law}: {gains} mean cost {100 * c:.2f} cm")
    return 0


if __name__ == "__main__":
    sys.exit(main())
