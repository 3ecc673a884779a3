#!/bin/sh
# Regenerate the seed-000 results and the figures of experiments/seed000.md.
# Usage (from the repository root, venv active or via its path):
#   sh experiments/figures/make_seed000.sh
# Writes results/seed000_models_abc/, results/seed000_speed/ and copies the figures to
# experiments/figures/seed000_*.png. About 1 minute on 2 cores.
set -eu
cd "$(dirname "$0")/../.."
BIN=${BIN:-.venv/bin}
"$BIN/agv-cosim" build --out fmus
"$BIN/agv-cosim" run experiments/seed000_models_abc.toml --out results/seed000_models_abc --quiet
"$BIN/agv-cosim" run experiments/seed000_speed.toml --out results/seed000_speed --quiet
cp results/seed000_models_abc/signals.png experiments/figures/seed000_models_abc.png
cp results/seed000_speed/signals.png experiments/figures/seed000_speed_ab.png
# One speed figure per model (the combined one overlays 10 runs).
"$BIN/python" - <<'PY'
import csv
from pathlib import Path

import numpy as np

from agv_cosim.report.plots import RunData, plot_runs

out = Path("results/seed000_speed")
labels = [row["run"] for row in csv.DictReader(open(out / "summary.csv", newline=""))]
names = {"a": "model a (nonlinear + 50 ms delay)", "b": "model b (linear, design model)"}
for model in "ab":
    runs = []
    for label in labels:
        if not label.startswith(model + "__"):
            continue
        rows = list(csv.reader(open(out / label / "timeseries.csv", newline="")))
        data = np.array(rows[1:], dtype=float)
        signals = {name: data[:, i] for i, name in enumerate(rows[0])}
        v0 = label.split("=")[1]
        runs.append(RunData(label=f"V0 = {v0} m/s", time=signals.pop("time"),
                            signals=signals, partial=False))
    spec = {"title": f"Seed 000 Fig. 5 analogue, {names[model]}: gains designed at 1 m/s",
            "signals": ["sensor.lateral_error", "act.alpha", "ctrl.u"],
            "units": {"sensor.lateral_error": "m", "act.alpha": "rad", "ctrl.u": "V"},
            "dpi": 110}
    tmp = out / f"_plot_{model}"
    plot_runs(runs, spec, tmp)
    (tmp / "signals.png").replace(Path(f"experiments/figures/seed000_speed_{model}.png"))
    tmp.rmdir()
PY
echo "figures: experiments/figures/seed000_*.png"
