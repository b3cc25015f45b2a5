#!/bin/bash
# Durable ingest of several esgd nodes sharing one PostgreSQL database (docs/deploy.md
# "Capacity"): NODES esgd with session leases on DB, SPACECRAFT spacecraft configured and then
# streamed all at once, spacecraft i to node i mod NODES (straight to the nodes, no router), each
# with HOURS of the simulated calibration flight at 60 s (60 frames an hour). Prints the frames
# acknowledged durable per second over the whole run (from the first frame sent to the last
# acknowledgement), the database's commits during it (pg_stat_database.xact_commit), and the
# resident set of each node at the end. PARALLEL: replays at once (default 4 per node).
#   bash scripts/multi_node_throughput.sh DB [NODES] [SPACECRAFT] [HOURS]
# DB: an empty PostgreSQL database's URI (postgresql://user@host:port/name); NODES default 3,
# SPACECRAFT 30, HOURS 24. Needs the build (build/) and psql (Debian's postgresql-client).
set -euo pipefail
cd "$(dirname "$0")/.."
db=${1:?usage: multi_node_throughput.sh DB [NODES] [SPACECRAFT] [HOURS]}
nodes=${2:-3}
spacecraft=${3:-30}
hours=${4:-24}
esg=build/client/esg
esgd=build/server/esgd
for f in "$esg" "$esgd"; do
  [[ -x $f ]] || { echo "multi_node_throughput: $f is missing (build first)" >&2; exit 2; }
done
command -v psql >/dev/null || { echo "multi_node_throughput: psql is missing" >&2; exit 2; }
work=$(mktemp -d)
pids=()
trap 'for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done; wait 2>/dev/null || true; [[ -n ${KEEP:-} ]] || rm -rf "$work"' EXIT

ports=()
for n in $(seq 0 $((nodes - 1))); do
  "$esgd" --listen 127.0.0.1:0 --db "$db" --node-id "node-$n" --workers 2 \
    >"$work/out$n" 2>"$work/esgd$n.log" &
  pids+=($!)
  for _ in $(seq 100); do grep -q "listening on port" "$work/out$n" 2>/dev/null && break; sleep 0.1; done
  port=$(sed -n 's/.*listening on port \([0-9]*\).*/\1/p' "$work/out$n")
  [[ -n $port ]] || { echo "multi_node_throughput: node $n did not start:" >&2; cat "$work/esgd$n.log" >&2; exit 1; }
  ports+=("$port")
done

"$esg" simulate --config deploy/examples/rdk1.json --profile calibration \
  --scenario deploy/examples/scenarios/paper_calibration.json --hours "$hours" --seed 1 \
  --out "$work/flight.csv" >/dev/null
grep '^#' "$work/flight.csv" | grep -v -e '^# format:' -e '^# spacecraft_id:' >"$work/meta"
grep -v '^#' "$work/flight.csv" >"$work/rows"
rows=$(($(wc -l <"$work/rows") - 1))  # less the column header
for i in $(seq 1 "$spacecraft"); do
  id=$(printf "TP-%04d" "$i")
  server="127.0.0.1:${ports[$(((i - 1) % nodes))]}"
  sed "s/RDK-1/$id/" deploy/examples/rdk1.json >"$work/$id.json"
  { echo "# format: esg-recording-csv 1"; echo "# spacecraft_id: $id"; cat "$work/meta" "$work/rows"; } >"$work/$id.csv"
  "$esg" --server "$server" configure --config "$work/$id.json" >/dev/null
done

commits() { psql "$db" -Atc "SELECT xact_commit FROM pg_stat_database WHERE datname = current_database()"; }
commits_before=$(commits)
start=$(date +%s.%N)
# At most PARALLEL replays at once (default 4 per node): more client processes than that only
# compete for the cores with the nodes they measure.
parallel=${PARALLEL:-$((4 * nodes))}
replay_one() {  # spacecraft number i: its recording to node (i - 1) mod NODES
  local id ports
  id=$(printf "TP-%04d" "$1")
  read -r -a ports <<<"$PORTS"
  "$ESG" --server "127.0.0.1:${ports[$((($1 - 1) % ${#ports[@]}))]}" replay \
    --recording "$WORK/$id.csv" --json >"$WORK/$id.out" 2>"$WORK/$id.err" || true
}
export -f replay_one
PORTS="${ports[*]}" ESG="$esg" WORK="$work" \
  xargs -P "$parallel" -I{} bash -c 'replay_one {}' < <(seq 1 "$spacecraft")
end=$(date +%s.%N)
commits_after=$(commits)
accepted=0
failed=0
for i in $(seq 1 "$spacecraft"); do
  id=$(printf "TP-%04d" "$i")
  n=$(sed -n 's/^  "accepted": *\([0-9]*\).*/\1/p' "$work/$id.out" | head -1)
  [[ -n $n ]] || failed=$((failed + 1))
  accepted=$((accepted + ${n:-0}))
done
seconds=$(awk -v a="$start" -v b="$end" 'BEGIN { printf "%.3f", b - a }')
printf 'nodes %d, spacecraft %d, %d frames each (%d h at 60 s)\n' "$nodes" "$spacecraft" "$rows" "$hours"
printf 'acknowledged durable: %d of %d frames in %.2f s: %.0f frames/s; %d replays failed\n' \
  "$accepted" $((rows * spacecraft)) "$seconds" "$(awk -v n="$accepted" -v s="$seconds" 'BEGIN { print n / s }')" "$failed"
printf 'database commits during the run: %d (%.0f/s)\n' $((commits_after - commits_before)) \
  "$(awk -v n=$((commits_after - commits_before)) -v s="$seconds" 'BEGIN { print n / s }')"
for n in $(seq 0 $((nodes - 1))); do
  printf 'node-%d resident set: %d KiB\n' "$n" "$(awk '/VmRSS/ {print $2}' "/proc/${pids[$n]}/status")"
done
if [[ $failed -ne 0 || $accepted -ne $((rows * spacecraft)) ]]; then
  for f in "$work"/*.err; do [[ -s $f ]] && { echo "$f:"; tail -n 3 "$f"; }; done >&2
  exit 1
fi
