#!/bin/bash
# Per-session memory of one esgd: its resident set (VmRSS) before and after N sessions are
# configured through the esg CLI and fed 60 frames (one hour) of the demo flight each.
#   bash scripts/session_memory.sh [N] [DB]
# N: sessions (default 300). DB: an empty PostgreSQL database's URI (esgd then runs with session
# leases, --node-id memory), or omitted for an SQLite file in a temporary directory. Needs the
# build (build/) and the demo flight (var/demo/flight.csv: bash scripts/demo.sh --no-serve).
set -euo pipefail
cd "$(dirname "$0")/.."
n=${1:-300}
db=${2:-}
esg=build/client/esg
esgd=build/server/esgd
flight=var/demo/flight.csv
for f in "$esg" "$esgd" "$flight"; do
  [[ -e $f ]] || { echo "session_memory: $f is missing (build, then bash scripts/demo.sh --no-serve)" >&2; exit 2; }
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
# The flight's header without its spacecraft, and its first hour of frames.
grep '^#' "$flight" | grep -v -e '^# format:' -e '^# spacecraft_id:' >"$work/meta"
awk '!/^#/ && n++ < 62' "$flight" >"$work/rows"
before=$(rss)
for i in $(seq 1 "$n"); do
  id=$(printf "MEM-%04d" "$i")
  sed "s/RDK-1/$id/" deploy/examples/rdk1.json >"$work/config.json"
  "$esg" --server "127.0.0.1:$port" configure --config "$work/config.json" >/dev/null
  { echo "# format: esg-recording-csv 1"; echo "# spacecraft_id: $id"; cat "$work/meta" "$work/rows"; } >"$work/r.csv"
  "$esg" --server "127.0.0.1:$port" replay --recording "$work/r.csv" --wait >/dev/null 2>&1
done
sleep 2
after=$(rss)
echo "sessions $n: esgd resident set ${before} KiB before, ${after} KiB after: $(( (after - before) / n )) KiB per session"
