#!/usr/bin/env bash
# The main job on the embedded default: esgd on a SQLite file, spacecraft RDK-1 simulated with the
# paper's calibration profile and replayed through the client; prints the calibrated coefficients,
# a prediction across a 6 h gap (also a CCSDS AEM file), the alerts raised, and the offline
# model (1) versus model (10) long-gap comparison; then serves the console (Open MCT, through the
# console gateway, docs/console-gateway.md) on http://127.0.0.1:8080/ until Ctrl-C.
#   bash scripts/demo.sh [--no-serve]    --no-serve (or ESG_DEMO_NO_SERVE=1): exit after the steps
#   ESG_DEMO_PORT (esgd, default 50051), ESG_CONSOLE_PORT (console, default 8080)
set -euo pipefail
cd "$(dirname "$0")/.."
serve=1
[ "${ESG_DEMO_NO_SERVE:-0}" = 1 ] && serve=0
for arg in "$@"; do
  case "$arg" in
    --no-serve) serve=0 ;;
    *) echo "demo.sh: unknown option '$arg' (usage: bash scripts/demo.sh [--no-serve])" >&2; exit 2 ;;
  esac
done
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
console_pid=
cleanup() {
  for pid in $console_pid $esgd_pid; do
    kill "$pid" 2>/dev/null || true
    wait "$pid" 2>/dev/null || true
  done
}
trap cleanup EXIT
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

if [ "$serve" = 0 ]; then
  exit 0
fi

console_port=${ESG_CONSOLE_PORT:-8080}
step "console: Open MCT through the console gateway on 127.0.0.1:$console_port (log in $work/console.log)"
# scripts/console.sh installs the console's npm packages first if they are missing.
bash scripts/console.sh --esgd "$addr" --listen "127.0.0.1:$console_port" >"$work/console.log" 2>&1 &
console_pid=$!
for _ in $(seq 1 1200); do
  grep -q '^console: listening on' "$work/console.log" && break
  if ! kill -0 "$console_pid" 2>/dev/null; then
    echo "demo.sh: the console gateway did not start:" >&2
    tail -5 "$work/console.log" >&2
    exit 1
  fi
  sleep 0.1
done
grep -q '^console: listening on' "$work/console.log" || { echo "demo.sh: the console gateway did not start in 120 s" >&2; exit 1; }
echo "console: http://127.0.0.1:$console_port/ (Ctrl-C to stop)"
# Ctrl-C reaches esgd and the gateway too (same process group); both shut down gracefully and
# the EXIT trap waits for them. The gateway exits 0 only when told to stop by a signal, so a 0
# here is a stop even where this shell itself does not see the signal (started with SIGINT
# ignored, as background jobs of scripts are).
trap 'echo; echo "demo: stopped"; exit 0' INT TERM
console_status=0
wait "$console_pid" || console_status=$?
if [ "$console_status" = 0 ]; then
  echo "demo: stopped"
  exit 0
fi
echo "demo.sh: the console gateway ended with status $console_status (see $work/console.log)" >&2
exit 1
