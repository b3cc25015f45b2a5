#!/bin/bash
# Per-session memory of one esgd: its resident set (VmRSS) before and after N sessions are
# configured and fed FRAMES frames (default 60: one hour) of the demo flight each, with the time
# each phase took (docs/performance.md "Sessions per node").
#   bash scripts/session_memory.sh [N] [DB]
# N: sessions (default 300). DB: an empty PostgreSQL database's URI (esgd then runs with session
# leases, --node-id memory), or omitted for an SQLite file in a temporary directory. Needs the
# build (build/), the demo flight (var/demo/flight.csv: bash scripts/demo.sh --no-serve) and
# build/tests/bench/esg_fleet_client (cmake --build build --target esg_fleet_client), which
# configures the sessions with 64 ConfigureSpacecraft calls in flight and streams their frames
# over 4 StreamTelemetry calls. ESG_BIN=DIR takes esgd and esg_fleet_client from DIR instead (a
# copy, while the build is being relinked). FRAMES=0 configures only.
set -euo pipefail
cd "$(dirname "$0")/.."
n=${1:-300}
db=${2:-}
frames=${FRAMES:-60}
esgd=${ESG_BIN:-build/server}/esgd
fleet=${ESG_BIN:-build/tests/bench}/esg_fleet_client
flight=var/demo/flight.csv
for f in "$fleet" "$esgd" "$flight"; do
  [[ -e $f ]] || { echo "session_memory: $f is missing (build esgd and esg_fleet_client, then bash scripts/demo.sh --no-serve)" >&2; exit 2; }
done
work=$(mktemp -d)
trap 'kill "$pid" 2>/dev/null || true; rm -rf "$work"' EXIT
args=(--listen 127.0.0.1:0 --workers 2)
if [[ -n $db ]]; then args+=(--db "$db" --node-id memory); else args+=(--db "$work/esg.db"); fi
"$esgd" "${args[@]}" >"$work/out" 2>"$work/esgd.log" &
pid=$!
for _ in $(seq 50); do grep -q "listening on port" "$work/out" 2>/dev/null && break; sleep 0.1; done
port=$(sed -n 's/.*listening on port \([0-9]*\).*/\1/p' "$work/out")
[[ -n $port ]] || { echo "session_memory: esgd did not start:" >&2; cat "$work/esgd.log" >&2; exit 1; }
rss() { awk '/VmRSS/ {print $2}' "/proc/$pid/status"; }
before=$(rss)
fleet_args=(--server "127.0.0.1:$port" --config deploy/examples/rdk1.json --count "$n" --prefix MEM-)
if [[ $frames -gt 0 ]]; then fleet_args+=(--recording "$flight" --frames "$frames"); fi
"$fleet" "${fleet_args[@]}"
sleep 2
after=$(rss)
per_session=$(awk -v a="$after" -v b="$before" -v n="$n" 'BEGIN {printf "%.1f", (a - b) / n}')
echo "sessions $n: esgd resident set ${before} KiB before, ${after} KiB after: ${per_session} KiB per session"
