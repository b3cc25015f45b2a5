#!/usr/bin/env bash
# The paper's Fig. 7/8 comparison over many seeds: for each seed, the drift-caused attitude error
# rate across a 24 h gap without the star tracker after calibrating model (1)+(11) and model
# (10)+(11) on the first 24 h of a 48 h mixed-profile flight (the same runs as scripts/fig78.sh,
# without the plot), then the medians, the ranges and how many seeds have model (1) at least twice
# model (10).
# With WALK=0 the truth's drift random walk is set to zero in a copy of the scenario (every gyro's
# randomWalkDegHSqrtH, docs/scenario.md): the control that separates what the calibration leaves
# from what the walk adds during the gap, which no prediction can remove (docs/measurements.md).
# Usage: scripts/fig78_seeds.sh [BUILD_DIR] [FIRST_SEED] [LAST_SEED] [SCENARIO]
# Prints "seed rate_model1 rate_model10 ratio" per seed [deg/h], then the summary.
set -euo pipefail
cd "$(dirname "$0")/.."
build=${1:-build}
first=${2:-1}
last=${3:-30}
scenario=${4:-deploy/examples/scenarios/paper_fig78.json}
esg="$build/client/esg"
config=deploy/examples/rdk1.json
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
if [[ "${WALK:-1}" == 0 ]]; then
  python3 - "$scenario" "$out/scenario.json" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
s["gyros"] = s.get("gyros") or [{"id": i} for i in (1, 2, 3)]
for g in s["gyros"]:
    g["randomWalkDegHSqrtH"] = 0
json.dump(s, open(sys.argv[2], "w"))
PY
  scenario="$out/scenario.json"
fi
rate() {  # the gap's driftRateDegH from `esg gap --json`
  sed -n 's/.*"driftRateDegH": *\([-0-9.eE+]*\).*/\1/p' "$1" | head -1
}
for seed in $(seq "$first" "$last"); do
  "$esg" simulate --config "$config" --profile mixed --scenario "$scenario" --hours 48 \
    --seed "$seed" --out "$out/flight.csv" >/dev/null 2>&1
  for model in 1+11 10+11; do
    "$esg" gap --config "$config" --recording "$out/flight.csv" --model "$model" \
      --gap-start 24 --json 2>/dev/null >"$out/gap_$model.json"
  done
  r1=$(rate "$out/gap_1+11.json")
  r10=$(rate "$out/gap_10+11.json")
  awk -v s="$seed" -v a="$r1" -v b="$r10" 'BEGIN { printf "%d %.4f %.4f %.2f\n", s, a, b, a / b }'
done | tee "$out/rows.txt"
sort -k2,2g "$out/rows.txt" | awk '{ a[NR] = $2 } END { printf "model (1)+(11):  median %.4f deg/h, %.4f-%.4f\n", (NR % 2 ? a[(NR + 1) / 2] : (a[NR / 2] + a[NR / 2 + 1]) / 2), a[1], a[NR] }'
sort -k3,3g "$out/rows.txt" | awk '{ a[NR] = $3 } END { printf "model (10)+(11): median %.4f deg/h, %.4f-%.4f\n", (NR % 2 ? a[(NR + 1) / 2] : (a[NR / 2] + a[NR / 2 + 1]) / 2), a[1], a[NR] }'
awk '{ n++; if ($4 >= 2) k++; if (n == 1 || $4 < m) m = $4 } END { printf "model (1) at least 2x model (10): %d of %d seeds (smallest ratio %.2f)\n", k, n, m }' "$out/rows.txt"
