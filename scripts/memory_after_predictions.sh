#!/usr/bin/env bash
# esgd's resident set around eight concurrent 100 000-sample predictions with AEM (issue 40,
# docs/service.md "Limits"): starts this build's esgd on a free port over a temp database, feeds
# it 1 h of the demo flight with the esg CLI, then prints VmRSS (/proc/PID/status) before, at
# its highest while the predictions run (sampled every 50 ms), right after, and every 10 s for a
# minute. ESGD / ESG name other binaries (a before/after comparison); ESG_PREDICT the esg that
# runs the eight predictions (default ESG): this build's esg streams them (PredictAttitudeStream),
# an esg built before issue 40's stream asks for each whole (PredictAttitude), so the two compare
# the rpcs against the same esgd. Extra arguments go to esgd.
#   scripts/memory_after_predictions.sh [ESGD_ARGS...]
#   ESG_PREDICT=/path/to/older/esg scripts/memory_after_predictions.sh
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
ESGD=${ESGD:-$ROOT/build/server/esgd}
ESG=${ESG:-$ROOT/build/client/esg}
ESG_PREDICT=${ESG_PREDICT:-$ESG}
TMP=$(mktemp -d)
trap 'kill $PID 2>/dev/null || true; wait 2>/dev/null || true; rm -rf "$TMP"' EXIT

"$ESG" simulate --config "$ROOT/deploy/examples/rdk1.json" --profile calibration \
  --scenario "$ROOT/deploy/examples/scenarios/paper_calibration.json" --hours 1 --seed 1 \
  --out "$TMP/flight.csv" >/dev/null
"$ESGD" --listen 127.0.0.1:0 --db "$TMP/esg.db" --max-predictions-per-caller 8 "$@" \
  >"$TMP/esgd.out" 2>"$TMP/esgd.log" &
PID=$!
for _ in $(seq 100); do grep -q 'listening on port' "$TMP/esgd.out" && break; sleep 0.1; done
PORT=$(sed -n 's/.*listening on port \([0-9]*\).*/\1/p' "$TMP/esgd.out")
esg() { "$ESG" --server "127.0.0.1:$PORT" "$@"; }
esg configure --config "$ROOT/deploy/examples/rdk1.json" --model 10+11 >/dev/null
esg replay --recording "$TMP/flight.csv" --wait >/dev/null 2>&1
rss() { sed -n 's/^VmRSS:[[:space:]]*\([0-9]*\) kB/\1/p' "/proc/$PID/status"; }
# 100 000 samples: 48 h after the last frame (2019-03-01T01:00:00Z) every 1.728 s.
FROM=2019-03-01T01:00:01Z
TO=2019-03-03T01:00:00Z
esg predict --spacecraft RDK-1 --from "$FROM" --to 2019-03-01T02:00:00Z --json >/dev/null
sleep 1
BEFORE=$(rss)
PEAK=$BEFORE
CLIENTS=()
for i in $(seq 8); do
  "$ESG_PREDICT" --server "127.0.0.1:$PORT" predict --spacecraft RDK-1 --from "$FROM" --to "$TO" \
    --step 1.728 --aem "$TMP/p$i.aem" --json >/dev/null &
  CLIENTS+=($!)
done
running() { for c in "${CLIENTS[@]}"; do kill -0 "$c" 2>/dev/null && return 0; done; return 1; }
while running; do
  R=$(rss); [ "$R" -gt "$PEAK" ] && PEAK=$R
  sleep 0.05
done
for c in "${CLIENTS[@]}"; do wait "$c"; done
echo "predictions by $ESG_PREDICT ($("$ESG_PREDICT" predict --help | sed -n 's/.*(\(PredictAttitude[A-Za-z]*\)).*/\1/p' | head -1))"
echo "AEM file of one prediction: $(stat -c %s "$TMP/p1.aem") bytes"
echo "esgd VmRSS: before $((BEFORE / 1024)) MiB, peak $((PEAK / 1024)) MiB, right after $(($(rss) / 1024)) MiB"
for t in 10 20 30 40 50 60; do
  sleep 10
  echo "  ${t} s after: $(($(rss) / 1024)) MiB"
done
