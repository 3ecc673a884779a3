#!/bin/sh
# Regenerate the kinematic-vs-dynamic results (seeds 000, 003, 004), the figures of the
# sections "With tyre slip" / "With tyre forces" of experiments/seed000.md, seed003.md and
# seed004.md, and the numbers they quote (results/seed00X_dynamic_numbers.json; the
# tables are printed). Usage (from the repository root):
#   sh experiments/figures/make_dynamic.sh [seed000] [seed003] [seed004]
# (default: all three). Measured on the 2-core machine, shared: seed 000 36 runs 1.5 min,
# seed 003 28 + 20 + 16 runs at 2 ms ~12 min with lumped axles, ~45 min with two tyres per
# axle (measured under load), seed 004 24 runs 2 min.
set -eu
cd "$(dirname "$0")/../.."
BIN=${BIN:-.venv/bin}
SEEDS=${*:-seed000 seed003 seed004}
"$BIN/agv-cosim" build --out fmus
for seed in $SEEDS; do
    case $seed in
        seed000) manifests="seed000_dynamic" ;;
        seed003) manifests="seed003_dynamic_speed seed003_dynamic_fast seed003_dynamic_radius" ;;
        seed004) manifests="seed004_dynamic" ;;
        *) echo "unknown seed $seed" >&2; exit 2 ;;
    esac
    for m in $manifests; do
        "$BIN/agv-cosim" run "experiments/$m.toml" --out "results/$m" --jobs 2 --quiet
    done
    "$BIN/python" experiments/figures/dynamic_figures.py "$seed"
done
echo "figures: experiments/figures/seed00*_dynamic*.png"
