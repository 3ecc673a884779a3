#!/bin/sh
# Regenerate the seed-001 results and the figures of experiments/seed001.md.
# Usage (from the repository root):
#   sh experiments/figures/make_seed001.sh
# Writes results/seed001_circle_lambda/, results/seed001_circle_horizon/,
# results/seed001_scurve/, results/seed001_rate_limit/, the figures experiments/figures/seed001_*.png, and prints the
# metric tables of the results page. About 1-2 minutes (the rate-limit runs step at 10 ms).
set -eu
cd "$(dirname "$0")/../.."
BIN=${BIN:-.venv/bin}
"$BIN/agv-cosim" build --out fmus
for name in seed001_circle_lambda seed001_circle_horizon seed001_scurve seed001_rate_limit; do
    "$BIN/agv-cosim" run "experiments/$name.toml" --out "results/$name" --quiet
done
"$BIN/python" experiments/figures/seed001_figures.py
echo "figures: experiments/figures/seed001_*.png"
