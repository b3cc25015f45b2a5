#!/usr/bin/env bash
# The main job on the embedded default: esgd on a SQLite file, spacecraft RDK-1 simulated with the
# paper's calibration profile and replayed through the client; prints one screen (at most 40
# lines of 100 columns, scripts/demo_summary.py): the calibrated coefficients against the
# simulated truth, the offline model (1) versus model (10) long-gap comparison, the prediction for
# the 6 h after the last frame with its source (also a CCSDS AEM file), the alerts raised; then
# serves the console (Open MCT, through the console gateway, docs/console-gateway.md) on
# http://127.0.0.1:8080/ until Ctrl-C. The build's output goes to var/build.log (errors shown).
#   bash scripts/demo.sh [--no-serve]    --no-serve (or ESG_DEMO_NO_SERVE=1): exit after the steps
#   ESG_DEMO_PORT (esgd, default 50051; 0: any free port), ESG_CONSOLE_PORT (console, default 8080)
#   ESG_BUILD_DIR (binaries already built there: no build), ESG_DEMO_DIR (default var/demo)
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
  mkdir -p var
  echo "demo: installing and building (a first build takes about 20 min; log in var/build.log)"
  if ! bash scripts/build.sh >var/build.log 2>&1; then
    echo "demo.sh: the build failed; its errors (the whole log: var/build.log):" >&2
    if grep -qE 'error|Error|ERROR' var/build.log; then
      grep -E 'error|Error|ERROR' var/build.log | head -20 >&2 || true
    else
      tail -20 var/build.log >&2
    fi
    exit 1
  fi
  build=build
fi
esg=$build/client/esg
esgd=$build/server/esgd
work=${ESG_DEMO_DIR:-var/demo}
port=${ESG_DEMO_PORT:-50051}
rm -rf "$work"
mkdir -p "$work"

# Each step's output goes to its log in $work; a failing step shows its log's end.
run() {
  local log=$work/$1
  shift
  if ! "$@" >"$log" 2>"$log.err"; then
    echo "demo.sh: failed: $* (in $log.err):" >&2
    tail -20 "$log.err" >&2
    exit 1
  fi
}

run flight.log "$esg" simulate --config deploy/examples/rdk1.json --profile calibration \
  --scenario deploy/examples/scenarios/paper_calibration.json --hours 30 --seed 1 \
  --out "$work/flight.csv" --truth "$work/truth.csv"

"$esgd" --listen "127.0.0.1:$port" --db "$work/esg.db" >"$work/esgd.out" 2>"$work/esgd.log" &
esgd_pid=$!
console_pid=
cleanup() {
  for pid in $console_pid $esgd_pid; do
    kill "$pid" 2>/dev/null || true
    wait "$pid" 2>/dev/null || true
  done
}
trap cleanup EXIT
# esgd prints "esgd listening on port N" once it serves (port 0: the one the OS chose).
for _ in $(seq 1 100); do
  grep -q 'listening on port' "$work/esgd.out" 2>/dev/null && break
  sleep 0.1
done
port=$(sed -n 's/.*listening on port \([0-9]*\).*/\1/p' "$work/esgd.out" | head -1)
if [ -z "$port" ]; then
  echo "demo.sh: esgd did not start:" >&2
  tail -5 "$work/esgd.log" >&2
  exit 1
fi
addr=127.0.0.1:$port
at=(--server "$addr")

run configure.log "$esg" "${at[@]}" configure --config deploy/examples/rdk1.json --model 10+11
run replay.log "$esg" "${at[@]}" replay --recording "$work/flight.csv" --wait
run status.json "$esg" "${at[@]}" status --spacecraft RDK-1 -o json
last=$(tail -1 "$work/flight.csv" | cut -d, -f1)
run history.json "$esg" "${at[@]}" history --spacecraft RDK-1 --from "$last" -o json
# Hours 1 to 6 after the last frame, each hour.
from=$(date -u -d "$last + 1 hour" +%Y-%m-%dT%H:%M:%SZ)
to=$(date -u -d "$last + 6 hours" +%Y-%m-%dT%H:%M:%SZ)
run predict.json "$esg" "${at[@]}" predict --spacecraft RDK-1 --from "$from" --to "$to" \
  --step 3600 --aem "$work/prediction.aem" -o json
run alerts.json "$esg" "${at[@]}" alerts --spacecraft RDK-1 -o json
# Offline, the paper's Fig. 7/8: model (1) against model (10) across a 12 h gap in varied
# orientations.
run mixed.log "$esg" simulate --config deploy/examples/rdk1.json --profile mixed \
  --scenario deploy/examples/scenarios/paper_fig78.json --hours 36 --seed 1 --out "$work/mixed.csv"
for model in 1 10; do
  run "gap_$model.json" "$esg" gap --config deploy/examples/rdk1.json --recording "$work/mixed.csv" \
    --model "$model+11" --gap-start 24 -o json
done

python3 scripts/demo_summary.py "$work"
echo
echo "Next: esg --server $addr help (docs/cli.md)"
echo "The prediction as a CCSDS AEM file: $work/prediction.aem"

if [ "$serve" = 0 ]; then
  exit 0
fi

console_port=${ESG_CONSOLE_PORT:-8080}
echo "console: starting Open MCT through the console gateway (log in $work/console.log)"
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
