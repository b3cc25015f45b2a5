#!/usr/bin/env bash
# The main job on the embedded default: esgd on a SQLite file, spacecraft RDK-1 simulated with the
# paper's calibration profile and replayed through the client; prints the calibrated coefficients,
# a prediction across a 6 h gap (also a CCSDS AEM file), the alerts raised, and the offline
# model (1) versus model (10) long-gap comparison.
set -euo pipefail
cd "$(dirname "$0")/.."
build=${ESG_BUILD_DIR:-}
if [ -z "$build" ]; then
  bash scripts/build.sh
  build=build
fi
esg=$build/client/esg
esgd=$build/server/esgd
work=var/demo
port=${ESG_DEMO_PORT:-50051}
addr=127.0.0.1:$port
rm -rf "$work"
mkdir -p "$work"

step() { printf '\n== %s\n' "$*"; }

step "simulate RDK-1: 30 h of the paper's calibration profile (rotors displaced, star-tracker outliers)"
"$esg" simulate --config deploy/examples/rdk1.json --profile calibration \
  --scenario deploy/examples/scenarios/paper_calibration.json --hours 30 --seed 1 \
  --out "$work/flight.csv"

step "start esgd on $addr with $work/esg.db"
"$esgd" --listen "$addr" --db "$work/esg.db" >"$work/esgd.log" 2>&1 &
esgd_pid=$!
trap 'kill "$esgd_pid" 2>/dev/null || true; wait "$esgd_pid" 2>/dev/null || true' EXIT
for _ in $(seq 1 100); do
  "$esg" --server "$addr" status >/dev/null 2>&1 && break
  sleep 0.1
done

step "configure and replay through the client (model 10+11)"
"$esg" --server "$addr" configure --config deploy/examples/rdk1.json --model 10+11
"$esg" --server "$addr" replay --recording "$work/flight.csv" --wait

step "session"
"$esg" --server "$addr" status --spacecraft RDK-1

step "calibrated coefficients (latest snapshot per gyro, deg/h and arcsec)"
"$esg" --server "$addr" history --spacecraft RDK-1 --csv >"$work/history.csv"
head -1 "$work/history.csv"
tail -3 "$work/history.csv"

step "prediction across a 6 h gap without the star tracker (1-sigma envelope), AEM in $work/prediction.aem"
last=$(tail -1 "$work/flight.csv" | cut -d, -f1)
from=$(date -u -d "$last + 10 minutes" +%Y-%m-%dT%H:%M:%SZ)
to=$(date -u -d "$last + 6 hours" +%Y-%m-%dT%H:%M:%SZ)
"$esg" --server "$addr" predict --spacecraft RDK-1 --from "$from" --to "$to" --step 1800 \
  --aem "$work/prediction.aem"

step "alerts raised"
"$esg" --server "$addr" alerts --spacecraft RDK-1

step "offline: model (1) versus model (10) across a 12 h gap in varied orientations (paper Fig. 7/8)"
"$esg" simulate --config deploy/examples/rdk1.json --profile mixed \
  --scenario deploy/examples/scenarios/paper_fig78.json --hours 36 --seed 1 --out "$work/mixed.csv" 2>/dev/null
for model in 1+11 10+11; do
  "$esg" gap --config deploy/examples/rdk1.json --recording "$work/mixed.csv" --model "$model" \
    --gap-start 24 2>/dev/null | head -3
done
