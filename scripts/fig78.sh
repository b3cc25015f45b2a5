#!/usr/bin/env bash
# The paper's Fig. 7/8 comparison: attitude error in inertial axes across a 24 h gap without the
# star tracker, after calibrating model (1) and model (10) (both with the random walk of model (11))
# on the first 24 h of a 48 h mixed-profile flight whose gyros have displaced rotors.
# Writes docs/fig78_gap_error.png (gnuplot) and prints both drift rates.
# Usage: scripts/fig78.sh [BUILD_DIR] [SEED] [SCENARIO]
# (default scenario: paper_fig78_low_rw.json, drift random walk 0.0005 deg/h/sqrt(h), consistent
# with the paper's own 0.005 deg/h; paper_fig78.json keeps rdk1.json's 0.0015)
set -euo pipefail
cd "$(dirname "$0")/.."
build=${1:-build}
seed=${2:-1}
scenario=${3:-deploy/examples/scenarios/paper_fig78_low_rw.json}
esg="$build/client/esg"
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
"$esg" simulate --config deploy/examples/rdk1.json --profile mixed \
  --scenario "$scenario" --hours 48 --seed "$seed" \
  --out "$out/flight.csv" 2>/dev/null >/dev/null
for model in 1+11 10+11; do
  "$esg" gap --config deploy/examples/rdk1.json --recording "$out/flight.csv" --model "$model" \
    --gap-start 24 --series-csv "$out/gap_$model.csv" --json 2>/dev/null >"$out/gap_$model.json"
  rate=$(sed -n 's/.*"driftRateDegH": *\([-0-9.eE+]*\).*/\1/p' "$out/gap_$model.json" | head -1)
  echo "model $model: drift-caused attitude error rate $rate deg/h"
  eval "rate_${model//+/_}=$rate"
done
gnuplot <<GP
set terminal pngcairo size 1100,760 font "DejaVu Sans,11" noenhanced
set output "docs/fig78_gap_error.png"
set datafile separator ","
set multiplot layout 2,1 title "Attitude error in inertial axes across a 24 h gap without the star tracker (seed $seed, $(basename "$scenario"))"
set grid
set xlabel "hours since the gap start"
set ylabel "error, arcmin"
set key top left
set title sprintf("model (1) + (11), like the paper's Fig. 7: %.4f deg/h", ${rate_1_11})
plot "$out/gap_1+11.csv" every ::1 using 2:3 with lines lw 1.5 title "x (inertial)", \
     "" every ::1 using 2:4 with lines lw 1.5 title "y", \
     "" every ::1 using 2:5 with lines lw 1.5 title "z"
set title sprintf("model (10) + (11), like the paper's Fig. 8: %.4f deg/h", ${rate_10_11})
plot "$out/gap_10+11.csv" every ::1 using 2:3 with lines lw 1.5 title "x (inertial)", \
     "" every ::1 using 2:4 with lines lw 1.5 title "y", \
     "" every ::1 using 2:5 with lines lw 1.5 title "z"
unset multiplot
GP
echo "wrote docs/fig78_gap_error.png"
