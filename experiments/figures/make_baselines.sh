#!/bin/sh
# Regenerate the results of experiments/baselines.md: the tuning grid, every scenario's
# runs, the figures and the tables. Usage (from the repository root):
#   sh experiments/figures/make_baselines.sh
# Writes results/baselines/ (tuning/, runs/, tuning.csv, table.csv) and
# experiments/figures/baselines_*.png, prints the tables. The tuning is 138 runs of 20 s,
# the comparison 6 laws x 17 scenarios of 30 s: about 5 s of CPU a run (43 minutes on 2
# busy shared cores, 2 jobs).
# A step reuses a result folder run from the very same manifest text.
set -eu
cd "$(dirname "$0")/../.."
BIN=${BIN:-.venv/bin}
"$BIN/agv-cosim" build --out fmus
export PYTHONPATH="${PYTHONPATH:+$PYTHONPATH:}experiments/figures"
"$BIN/python" experiments/figures/baselines.py tune
"$BIN/python" experiments/figures/baselines.py run
"$BIN/python" experiments/figures/baselines.py page
