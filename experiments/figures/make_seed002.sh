#!/bin/sh
# Regenerate the seed-002 results, the figures of experiments/seed002.md and the tables it
# quotes. Usage (from the repository root, venv active or via its path):
#   sh experiments/figures/make_seed002.sh
# Writes results/seed002_step/, results/seed002_sine/, results/cross_seed_controllers/,
# experiments/figures/seed002_step.png, seed002_sine.png, cross_seed_controllers.png and
# prints the tables. About 2 minutes on 2 cores.
set -eu
cd "$(dirname "$0")/../.."
BIN=${BIN:-.venv/bin}
"$BIN/agv-cosim" build --out fmus
for name in seed002_step seed002_sine cross_seed_controllers; do
    "$BIN/agv-cosim" run "experiments/$name.toml" --out "results/$name" --jobs 2 --quiet
done
"$BIN/python" experiments/figures/seed002_figures.py
echo "figures: experiments/figures/seed002_*.png, cross_seed_controllers.png"
