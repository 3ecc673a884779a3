#!/bin/sh
# Regenerate the results of experiments/controllers.md: its figure and the table it
# quotes. Usage (from the repository root, venv active or via its path):
#   sh experiments/figures/make_controllers.sh
# Writes results/controllers_rewired/ and experiments/figures/controllers_rewired.png and
# prints the table. About 30 s on 2 cores (after the FMUs are built).
set -eu
cd "$(dirname "$0")/../.."
BIN=${BIN:-.venv/bin}
"$BIN/agv-cosim" build --out fmus
"$BIN/agv-cosim" run experiments/controllers_rewired.toml --out results/controllers_rewired \
    --jobs 2 --quiet
"$BIN/python" experiments/figures/controllers_figures.py
