#!/usr/bin/env bash
# Detection power of `esg diagnose` against effect size (docs/discovery.md, "Proof"): per effect
# SEEDS (default 5) 30 h recordings at each size factor of SCALES (default 0.125,0.25,0.5,1;
# 1 = the confusion matrix's size), EFFECTS a comma list (default: the library's effects, the
# drift step and the one-gyro random walk). Prints the Markdown table; with OUT (default
# docs/discovery_power.png) also plots the curves with gnuplot. JOBS (default 2) diagnoses at
# once. About 25 min on two idle cores with the defaults. Builds esg_bench in BUILD_DIR.
# FROM=FILE plots the saved output (stdout) of an earlier run instead of running one.
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD_DIR="${BUILD_DIR:-build}"
OUT="${OUT:-docs/discovery_power.png}"
if [ ! -f "$BUILD_DIR/CMakeCache.txt" ]; then
  cmake -S . -B "$BUILD_DIR" -DCMAKE_BUILD_TYPE=Release >/dev/null
fi
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
if [ -n "${FROM:-}" ]; then  # plot a saved run's output again (SCALES as in that run)
  cp "$FROM" "$tmp/out.txt"
else
  cmake --build "$BUILD_DIR" -j2 --target esg_bench >/dev/null
  ESG_POWER_SEEDS="${SEEDS:-5}" ESG_POWER_SCALES="${SCALES:-0.125,0.25,0.5,1}" \
    ESG_POWER_EFFECTS="${EFFECTS:-}" ESG_DISCOVERY_JOBS="${JOBS:-2}" \
    "$BUILD_DIR/tests/bench/esg_bench" --benchmark_filter=DiscoveryPower | tee "$tmp/out.txt"
fi
awk '/^# data/{on=1; next} on && NF==3 {print > "'"$tmp"'/" $1 ".dat"}' "$tmp/out.txt"
if command -v gnuplot >/dev/null && [ -n "$OUT" ] && compgen -G "$tmp/*.dat" >/dev/null; then
  # Tics at the measured sizes, the axis just around them.
  scales="${SCALES:-0.125,0.25,0.5,1}"
  xtics="$(echo "$scales" | tr ',' '\n' | awk '{printf "%s\"%s\" %s", (NR > 1 ? ", " : ""), $1, $1}')"
  plots=""
  for f in "$tmp"/*.dat; do
    name="$(basename "$f" .dat)"
    plots="${plots:+$plots, }'$f' using 2:(100*\$3) with linespoints title '$name'"
  done
  gnuplot <<GP
set terminal pngcairo size 900,560 noenhanced
set output '$OUT'
set title 'Detection power of esg diagnose against effect size (30 h recordings)'
set xlabel 'effect size, factor of the confusion matrix size'
set ylabel 'found in the right gyro, %'
set logscale x 2
set xtics ($xtics)
set autoscale xfix
set offsets graph 0.04, graph 0.04, 0, 0
set yrange [0:105]
set key outside right
set grid
plot $plots
GP
  echo "plot: $OUT" >&2
fi
